//! What held a matched answer's skin on its observation
//! ([`HeldObservation`]): the field it was paired on, the last stage's
//! pairing, and how to make the field again with the observation moved
//! (a sample of its error), for the uncertainty's re-solves.

use rayon::prelude::*;
use tissue_solve::stage2::Pairing;
use tissue_solve::stage2::uncertainty::HeldBy;

use super::ObservationError;
use crate::field::SurfaceField;
use crate::{Error, SurfaceMesh, Vec3};

/// A sample's field of points ([`HeldBy::moved`] of a scan, or of a
/// surface paired with its smoothed plane) has cells this many times the
/// observation's: a sample's re-solve pairs through some 30-90
/// iterations, too few for a scan's finer grid to pay for its making
/// (breast_d's scan at 10,000 particles: the estimate 5.2 s against
/// 6.6 s, the regions the same within 1e-5 mm; a remeshed surface's, in
/// cells of two mean edges already, as fast either way).
pub const SAMPLE_CELLS: f32 = 2.0;

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

    fn moved(&self, offset: &(dyn Fn(Vec3) -> f32 + Sync)) -> Result<SurfaceField, Error> {
        let field = &self.field;
        let started = std::time::Instant::now();
        let made = match &self.remake {
            Remake::Points { reach } => {
                let normals: Vec<Vec3> = field.normals.iter().map(|n| n[0]).collect();
                let points: Vec<Vec3> = field
                    .corners
                    .par_iter()
                    .zip(&normals)
                    .map(|(c, &n)| c[0] + offset(c[0]) * n)
                    .collect();
                let cell = SAMPLE_CELLS * field.cell;
                SurfaceField::of_cloud_within(&points, &normals, cell, field.margin, *reach)
            }
            Remake::Triangles(mesh) => {
                let normals = tissue_core::deform::vertex_normals(mesh);
                let moved = SurfaceMesh {
                    vertices: mesh
                        .vertices
                        .par_iter()
                        .zip(&normals)
                        .map(|(&v, &n)| v + offset(v) * n.normalize_or_zero())
                        .collect(),
                    ..mesh.clone()
                };
                SurfaceField::new(&moved, field.cell, field.margin)
            }
        };
        log::debug!(
            "the observation moved by a sample of its error: its field made again in {:.3} s",
            started.elapsed().as_secs_f64()
        );
        Ok(made.map_err(ObservationError::from)?)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use tissue_solve::stage2::{NO_LIMIT, PairingRule};

    use super::*;

    fn pairing() -> Pairing {
        Pairing {
            skin: Vec::new(),
            rule: PairingRule {
                weight: 1.0,
                edge: NO_LIMIT,
                robust: NO_LIMIT,
                cloud: true,
                smooth: 1.0,
            },
        }
    }

    /// A sphere of radius `radius` about the origin, triangulated.
    fn sphere(radius: f32) -> SurfaceMesh {
        let (vertices, triangles) = tissue_testkit::sphere(radius, 4);
        SurfaceMesh::new(vertices, triangles)
    }

    /// Moved along its normals, a field of points answers as the moved
    /// points would (a flat patch lifted by a quarter stays flat, a
    /// quarter higher; moved by nothing, as it was), in cells of
    /// [`SAMPLE_CELLS`] times its own; a field of triangles moved
    /// outward by a constant grows its sphere by as much.
    #[test]
    fn a_moved_observation_answers_as_its_moved_points() {
        let mut points = Vec::new();
        for i in 0..21 {
            for j in 0..21 {
                points.push(Vec3::new(i as f32 * 0.5, j as f32 * 0.5, 0.0));
            }
        }
        let normals = vec![Vec3::Z; points.len()];
        let reach = 1.5;
        let field = SurfaceField::of_cloud_within(&points, &normals, 0.5, 2.0, reach).unwrap();
        let held = HeldObservation::of_points(field.clone(), pairing(), reach);
        let q = Vec3::new(5.1, 4.9, 0.8);
        let (point, normal) = field.smooth_plane(q, 0.5).unwrap();
        let still = held.moved(&|_| 0.0).unwrap();
        assert_eq!(still.cell, SAMPLE_CELLS * field.cell);
        let (same, same_normal) = still.smooth_plane(q, 0.5).unwrap();
        assert!((same - point).length() < 1e-5 && (same_normal - normal).length() < 1e-5);
        let lifted = held.moved(&|_| 0.25).unwrap();
        let (up, up_normal) = lifted.smooth_plane(q, 0.5).unwrap();
        assert!((up.z - 0.25).abs() < 1e-5, "{up}");
        assert!((up_normal - Vec3::Z).length() < 1e-5);
        assert!((lifted.nearest(q).point - Vec3::new(5.0, 5.0, 0.25)).length() < 1e-5);

        let ball = sphere(10.0);
        let field = SurfaceField::new(&ball, 2.0, 3.0).unwrap();
        let held = HeldObservation::of_triangles(field, pairing(), ball);
        let grown = held.moved(&|_| 0.5).unwrap();
        let distance = grown.nearest(Vec3::new(0.0, 0.0, 12.0)).distance;
        assert!((distance - 1.5).abs() < 0.05, "{distance}");
    }
}
