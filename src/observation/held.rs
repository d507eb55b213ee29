//! What held a matched answer's skin on its observation
//! ([`HeldObservation`]): the field it was paired on, the last stage's
//! pairing, and how to make the field again with the observation moved
//! (a sample of its error), for the uncertainty's re-solves.

use tissue_solve::stage2::Pairing;
use tissue_solve::stage2::uncertainty::HeldBy;

use super::ObservationError;
use crate::field::SurfaceField;
use crate::{Error, SurfaceMesh, Vec3};

/// The observation a match held the skin on, as its last stage paired
/// it: the uncertainty's re-solves pair the skin with it again at every
/// iteration, as the match did ([`crate::uncertainty::HeldBy`]).
#[derive(Debug, Clone)]
pub struct HeldObservation {
    field: SurfaceField,
    pairing: Pairing,
    remake: Remake,
}

/// How the field is made again from moved points.
#[derive(Debug, Clone)]
enum Remake {
    /// Points with their normals (a cloud, or a surface's lifted vertices
    /// for its smoothed plane), listing every point within `reach` of a
    /// band cell.
    Points { reach: f32 },
    /// A surface's triangles (paired with their nearest point).
    Triangles(SurfaceMesh),
}

impl HeldObservation {
    /// The field of points `field` (a cloud's, or a surface's lifted
    /// vertices) whose cells list the points within `reach`, paired by
    /// `pairing`.
    pub(super) fn of_points(field: SurfaceField, pairing: Pairing, reach: f32) -> Self {
        Self {
            field,
            pairing,
            remake: Remake::Points { reach },
        }
    }

    /// The field of the triangles of `mesh`, paired by `pairing`.
    pub(super) fn of_triangles(field: SurfaceField, pairing: Pairing, mesh: SurfaceMesh) -> Self {
        Self {
            field,
            pairing,
            remake: Remake::Triangles(mesh),
        }
    }

    /// The particles paired and how.
    pub fn pairing(&self) -> &Pairing {
        &self.pairing
    }
}

impl HeldBy for HeldObservation {
    fn field(&self) -> &SurfaceField {
        &self.field
    }

    fn pairing(&self) -> &Pairing {
        &self.pairing
    }

    fn moved(&self, offset: &dyn Fn(Vec3) -> f32) -> Result<SurfaceField, Error> {
        let field = &self.field;
        let started = std::time::Instant::now();
        let made = match &self.remake {
            Remake::Points { reach } => {
                let normals: Vec<Vec3> = field.normals.iter().map(|n| n[0]).collect();
                let points: Vec<Vec3> = field
                    .corners
                    .iter()
                    .zip(&normals)
                    .map(|(c, &n)| c[0] + offset(c[0]) * n)
                    .collect();
                SurfaceField::of_cloud_within(&points, &normals, field.cell, field.margin, *reach)
            }
            Remake::Triangles(mesh) => {
                let normals = tissue_core::deform::vertex_normals(mesh);
                let moved = SurfaceMesh {
                    vertices: mesh
                        .vertices
                        .iter()
                        .zip(&normals)
                        .map(|(&v, &n)| v + offset(v) * n.normalize_or_zero())
                        .collect(),
                    ..mesh.clone()
                };
                SurfaceField::new(&moved, field.cell, field.margin)
            }
        };
        log::debug!(
            "the observation moved by a sample of its error, its field made again in {:.3} s",
            started.elapsed().as_secs_f64()
        );
        Ok(made.map_err(ObservationError::from)?)
    }
}
