//! What the skin is matched to without correspondence ([`Observation`]):
//! a closed surface of any triangulation or a cleaned point cloud, its
//! checks against the model, and the field a match pairs the skin on.

use std::borrow::Cow;

use rayon::prelude::*;

use super::held::HeldObservation;
use super::matching::{
    CLOUD_EDGE_SPACINGS, CLOUD_NOISE, FIELD_CELL_EDGES, FIELD_MARGIN, HELD_OFF, MAX_REACH,
    MAX_VOLUME_CHANGE, mean_edge,
};
use super::{Cloud, ObservationError};
use crate::field::{SMOOTH_REACH, SurfaceField, signed_distances};
use crate::{Error, SurfaceMesh, Vec3};
use tissue_solve::stage2::{CLOUD_SMOOTHING, Pairing};

/// What the model's skin is matched to without correspondence: a closed
/// surface of any triangulation, or a point cloud with its normals.
#[derive(Debug, Clone)]
pub struct Observation {
    /// The observed points the residual is measured from: the surface's
    /// vertices, or the cloud's points kept.
    pub(super) points: Vec<Vec3>,
    /// A cloud's points set aside as outliers.
    pub(super) outliers: usize,
    pub(super) kind: Kind,
}

#[derive(Debug, Clone)]
pub(super) enum Kind {
    Surface(SurfaceMesh),
    Cloud {
        field: SurfaceField,
        spacing: f32,
        noise: f32,
        /// Whether its points were moved onto their neighbours' planes
        /// ([`tissue_solve::stage2::Cleaned::flattened`]).
        flattened: bool,
        /// Its points on lines of points, each with the line's direction
        /// ([`Cloud::lines`]): their normals are the skin's
        /// ([`Observation::turned_on`]).
        lines: Vec<(u32, Vec3)>,
    },
}

/// A scan cleaned, its normals turned and its grid's size checked, as
/// [`Observation::cloud`] makes it, without the grid
/// ([`Observation::clean_cloud`]).
#[derive(Debug, Clone)]
pub struct CleanedScan {
    cloud: Cloud,
    set_aside: usize,
    flattened: bool,
    noise: f32,
}

impl CleanedScan {
    /// The points kept.
    pub fn len(&self) -> usize {
        self.cloud.points().len()
    }

    /// Whether no point is kept (never, for a scan that was cleaned).
    pub fn is_empty(&self) -> bool {
        self.cloud.points().is_empty()
    }
}

impl Observation {
    /// A closed surface of the organ, of any triangulation.
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where the surface has no triangles.
    pub fn surface(mesh: &SurfaceMesh) -> Result<Self, Error> {
        if mesh.triangles.is_empty() {
            return Err(ObservationError::Field(tissue_core::FieldError::NoVertices).into());
        }
        Ok(Self {
            points: mesh.vertices.clone(),
            outliers: 0,
            kind: Kind::Surface(mesh.clone()),
        })
    }

    /// A scanned point cloud ([`Cloud`]) without its outliers and with its
    /// noise across the skin averaged out where the skin is flat enough
    /// over a neighbourhood ([`Cloud::cleaned`] with `noise`,
    /// or [`CLOUD_NOISE`] spacings; the points set aside are counted,
    /// [`Observation::outliers`]), its normals turned away from `inside`
    /// (a point inside the organ: [`Cloud::oriented_from`]). Its noise
    /// scale ([`Observation::cloud_noise`]) is `noise`, or the larger of
    /// [`CLOUD_NOISE`] spacings and the points' own scatter about their
    /// neighbours' planes ([`Cleaned::scatter`](super::Cleaned::scatter)):
    /// a dense scan may be noisier than a fifth of its spacing.
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where too few points are kept or its grid
    /// cannot be made.
    pub fn cloud(cloud: &Cloud, noise: Option<f32>, inside: Vec3) -> Result<Self, Error> {
        Self::of_cleaned(&Self::clean_cloud(cloud, noise, inside)?)
    }

    /// [`Observation::cloud`] up to its grid: the scan cleaned, its
    /// normals turned away from `inside` and its grid's size checked
    /// ([`CleanedScan`]). A long sequence of scans is cleaned whole before
    /// its first frame, each grid made when its frame comes
    /// ([`Observation::of_cleaned`]).
    ///
    /// # Errors
    ///
    /// As [`Observation::cloud`].
    pub fn clean_cloud(
        cloud: &Cloud,
        noise: Option<f32>,
        inside: Vec3,
    ) -> Result<CleanedScan, Error> {
        let given = noise;
        let noise = given.unwrap_or(CLOUD_NOISE * cloud.spacing());
        let cleaned = cloud.cleaned(noise)?;
        let cloud = cleaned.cloud.oriented_from(inside);
        let spacing = cloud.spacing();
        cloud.check_field(FIELD_MARGIN * spacing)?;
        Ok(CleanedScan {
            noise: given.unwrap_or((CLOUD_NOISE * spacing).max(cleaned.scatter)),
            set_aside: cleaned.set_aside,
            flattened: cleaned.flattened,
            cloud,
        })
    }

    /// The observation of a scan cleaned by [`Observation::clean_cloud`]:
    /// [`Observation::cloud`]'s, its grid made here.
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where its grid cannot be made.
    pub fn of_cleaned(scan: &CleanedScan) -> Result<Self, Error> {
        let cloud = &scan.cloud;
        let spacing = cloud.spacing();
        Ok(Self {
            points: cloud.points().to_vec(),
            outliers: scan.set_aside,
            kind: Kind::Cloud {
                field: cloud.field(FIELD_MARGIN * spacing)?,
                spacing,
                noise: scan.noise,
                flattened: scan.flattened,
                lines: cloud.lines(),
            },
        })
    }

    /// How many of a cloud's points lie on lines of points (a stylus's
    /// strips, [`Cloud::lines`]), whose normals are the model's skin's;
    /// 0 for a surface.
    pub fn on_lines(&self) -> usize {
        match &self.kind {
            Kind::Cloud { lines, .. } => lines.len(),
            Kind::Surface(_) => 0,
        }
    }

    /// A cloud's field with the normals of its points on lines of points
    /// taken from `skin` (the model's skin where the match starts): the
    /// normal of its nearest point there, turned square to the line (the
    /// line lies in the skin; its points' own plane turns about it).
    /// `None` where no point lies on a line, and for a surface.
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where `skin`'s field cannot be made.
    pub(super) fn turned_on(&self, skin: &SurfaceMesh) -> Result<Option<SurfaceField>, Error> {
        let Kind::Cloud { field, lines, .. } = &self.kind else {
            return Ok(None);
        };
        if lines.is_empty() {
            return Ok(None);
        }
        let edge = mean_edge(skin);
        let skin_field =
            SurfaceField::new(skin, edge, FIELD_MARGIN * edge).map_err(ObservationError::from)?;
        let turned: Vec<Vec3> = lines
            .par_iter()
            .map(|&(i, along)| {
                let normal = skin_field.nearest(self.points[i as usize]).normal;
                let square = normal - normal.dot(along) * along;
                square.try_normalize().unwrap_or(normal)
            })
            .collect();
        let mut field = field.clone();
        for (&(i, _), normal) in lines.iter().zip(turned) {
            field.normals[i as usize] = [normal; 7];
        }
        Ok(Some(field))
    }

    /// Per point of `points`, whether the observation sees it: every one
    /// for a surface; for a cloud, those within [`CLOUD_EDGE_SPACINGS`]
    /// of its nearest point (the skin past the cloud's edge is not seen).
    pub fn sees(&self, points: &[Vec3]) -> Vec<bool> {
        match &self.kind {
            Kind::Surface(_) => vec![true; points.len()],
            Kind::Cloud { field, spacing, .. } => points
                .par_iter()
                .map(|&p| (p - field.nearest(p).point).length() <= CLOUD_EDGE_SPACINGS * spacing)
                .collect(),
        }
    }

    /// The observed points set aside as outliers (a cloud's; none of a
    /// surface's).
    pub fn outliers(&self) -> usize {
        self.outliers
    }

    /// The observed points: the surface's vertices or the cloud's points.
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Whether it is a point cloud.
    pub fn is_cloud(&self) -> bool {
        matches!(self.kind, Kind::Cloud { .. })
    }

    /// A cloud's spacing (the median distance to a point's nearest other
    /// point); `None` for a surface.
    pub fn cloud_spacing(&self) -> Option<f32> {
        match self.kind {
            Kind::Cloud { spacing, .. } => Some(spacing),
            Kind::Surface(_) => None,
        }
    }

    /// Whether a cloud was kept as scanned: its points left where they
    /// were, not moved onto their neighbours' planes, which lie under a
    /// skin that bends within a neighbourhood by more than
    /// [`tissue_solve::stage2::FLAT_BEND`] of the noise (a scan sparse for
    /// the skin's curvature). `false` for a surface.
    pub fn kept_as_scanned(&self) -> bool {
        matches!(
            self.kind,
            Kind::Cloud {
                flattened: false,
                ..
            }
        )
    }

    /// A cloud's noise scale (model units): the one it was made with, or
    /// the larger of [`CLOUD_NOISE`] spacings and its points' scatter
    /// ([`Observation::cloud`]); `None` for a surface.
    pub fn cloud_noise(&self) -> Option<f32> {
        match self.kind {
            Kind::Cloud { noise, .. } => Some(noise),
            Kind::Surface(_) => None,
        }
    }

    /// The change of the organ's volume that meeting the observation
    /// would take, against the model's rest surface `rest` (its volume over
    /// the rest one's, less one), and the observed points' mean signed
    /// distance from `rest` (positive outside). A closed surface's is its
    /// own volume's; a cloud sees part of the skin, so its is the volume
    /// between it and the rest skin: the mean distance times the area the
    /// points cover (about their count times the spacing squared).
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where `rest` has no triangles or no volume.
    pub fn implied_volume_change(&self, rest: &SurfaceMesh) -> Result<(f32, f32), Error> {
        let (change, mean, _) = self.against_rest(rest)?;
        Ok((change, mean))
    }

    /// [`Observation::implied_volume_change`] and the median of the
    /// observed points' distances from `rest`.
    fn against_rest(&self, rest: &SurfaceMesh) -> Result<(f32, f32, f32), Error> {
        let volume = rest.signed_volume();
        if !(volume.is_finite() && volume > 0.0) {
            return Err(ObservationError::Field(tissue_core::FieldError::NoVertices).into());
        }
        let mut distances = signed_distances(rest, &self.points).map_err(ObservationError::from)?;
        let mean =
            distances.iter().map(|&d| f64::from(d)).sum::<f64>() / distances.len().max(1) as f64;
        let median = match distances.len() {
            0 => 0.0,
            n => {
                let middle = n / 2;
                distances
                    .select_nth_unstable_by(middle, |a, b| a.abs().total_cmp(&b.abs()))
                    .1
                    .abs()
            }
        };
        let change = match &self.kind {
            Kind::Surface(mesh) => mesh.signed_volume() / volume - 1.0,
            Kind::Cloud { spacing, .. } => {
                let area = self.points.len() as f64 * f64::from(*spacing).powi(2);
                mean * area / volume
            }
        };
        Ok((change as f32, mean as f32, median))
    }

    /// Refuses an observation that cannot be of the model in its frame and
    /// unit: one whose points' median distance from the rest surface is
    /// above [`MAX_REACH`] of its size (nowhere near it), a closed surface
    /// away from the model's held region (`held`: per rest vertex; its
    /// median distance above [`HELD_OFF`] mean connection lengths,
    /// `spacing`), or one that would change the organ's volume by more than
    /// [`MAX_VOLUME_CHANGE`].
    ///
    /// # Errors
    ///
    /// [`ObservationError::Unreachable`], [`ObservationError::HeldOff`],
    /// [`ObservationError::VolumeChange`] (in [`Error::Observation`]), or
    /// where `rest` has no volume.
    pub fn check_against(
        &self,
        rest: &SurfaceMesh,
        held: Option<&[bool]>,
        spacing: f32,
    ) -> Result<(), Error> {
        let (change, mean, median) = self.against_rest(rest)?;
        let size = rest.bounds().map_or(0.0, |(lo, hi)| (hi - lo).length());
        let most = MAX_REACH * size;
        if median > most {
            return Err(ObservationError::Unreachable { median, most }.into());
        }
        if let (Kind::Surface(mesh), Some(held)) = (&self.kind, held) {
            let held: Vec<Vec3> = rest
                .vertices
                .iter()
                .zip(held)
                .filter(|(_, h)| **h)
                .map(|(&v, _)| v)
                .collect();
            let mut distances: Vec<f32> = signed_distances(mesh, &held)
                .map_err(ObservationError::from)?
                .into_iter()
                .map(f32::abs)
                .collect();
            if !distances.is_empty() {
                let middle = distances.len() / 2;
                let distance = *distances.select_nth_unstable_by(middle, f32::total_cmp).1;
                let most = HELD_OFF * spacing;
                if distance > most {
                    return Err(ObservationError::HeldOff { distance, most }.into());
                }
            }
        }
        if change.abs() > MAX_VOLUME_CHANGE {
            return Err(ObservationError::VolumeChange {
                change,
                mean,
                most: MAX_VOLUME_CHANGE,
            }
            .into());
        }
        Ok(())
    }

    /// The field the skin is paired on: a surface's without its triangles
    /// that show the held region (`held`, within `reach` of it at each
    /// corner), where no free particle belongs; with `smoothing` above
    /// zero the field of its vertices for a plane smoothed over
    /// `smoothing` mean edges ([`smoothed_surface_field`]), else of its
    /// triangles in cells of [`FIELD_CELL_EDGES`] mean edges or the
    /// model's mean connection length `spacing`, the longer; a cloud's as
    /// it is.
    pub(super) fn pairing_field(
        &self,
        held: Option<&SurfaceField>,
        reach: f32,
        spacing: f32,
        smoothing: f32,
    ) -> Result<PairingField<'_>, Error> {
        let free = match &self.kind {
            Kind::Cloud { field, .. } => {
                return Ok(PairingField {
                    field: Cow::Borrowed(field),
                    smoothed_edge: None,
                    free: None,
                    reach: SMOOTH_REACH * CLOUD_SMOOTHING * field.cell,
                });
            }
            Kind::Surface(mesh) => free_of_held(mesh, held, reach),
        };
        let edge = mean_edge(&free);
        let cell = (FIELD_CELL_EDGES * edge).max(spacing);
        if smoothing > 0.0 {
            return Ok(PairingField {
                field: Cow::Owned(smoothed_surface_field(&free, cell, edge, smoothing * edge)?),
                smoothed_edge: Some(edge),
                free: Some(free),
                reach: SMOOTH_REACH * smoothing * edge,
            });
        }
        Ok(PairingField {
            field: Cow::Owned(
                SurfaceField::new(&free, cell, FIELD_MARGIN * edge)
                    .map_err(ObservationError::from)?,
            ),
            smoothed_edge: None,
            free: Some(free),
            reach: 0.0,
        })
    }
}

/// `mesh` without its triangles that show the held region (`held`, within
/// `reach` of it at each corner), where no free particle belongs; all of
/// it where that would leave none.
fn free_of_held(mesh: &SurfaceMesh, held: Option<&SurfaceField>, reach: f32) -> SurfaceMesh {
    let on_held = |t: usize| {
        held.is_some_and(|held| {
            mesh.corners(t)
                .iter()
                .all(|&c| held.nearest(c).distance.abs() <= reach)
        })
    };
    let kept: Vec<[u32; 3]> = (0..mesh.triangles.len())
        .filter(|&t| !on_held(t))
        .map(|t| mesh.triangles[t])
        .collect();
    SurfaceMesh {
        vertices: mesh.vertices.clone(),
        triangles: if kept.is_empty() {
            mesh.triangles.clone()
        } else {
            kept
        },
    }
}

/// The field a match pairs the skin on ([`Observation::pairing_field`]).
pub(super) struct PairingField<'a> {
    pub(super) field: Cow<'a, SurfaceField>,
    /// For a surface paired by its smoothed plane, its mean edge.
    pub(super) smoothed_edge: Option<f32>,
    /// For a surface, its triangles the skin is paired on (the held
    /// region's left out).
    pub(super) free: Option<SurfaceMesh>,
    /// For a field of points (a cloud's, a smoothed surface's), how far
    /// around a cell its cells list the points.
    pub(super) reach: f32,
}

impl PairingField<'_> {
    /// What held the skin at the answer: this field paired by `pairing`
    /// ([`HeldObservation`]).
    pub(super) fn held(self, pairing: Pairing) -> HeldObservation {
        match (self.smoothed_edge, self.free) {
            (None, Some(free)) => {
                HeldObservation::of_triangles(self.field.into_owned(), pairing, free)
            }
            _ => HeldObservation::of_points(self.field.into_owned(), pairing, self.reach),
        }
    }
}

/// The field of `mesh`'s vertices (those of its triangles) for the plane
/// smoothed over radius `h` around a particle ([`SurfaceField::smooth_plane`],
/// as a cloud's): each vertex with the normal of its triangles (summed
/// weighted by their areas), lifted along it by how far the plane
/// smoothed around the vertex passes from it. Smoothed over points on a
/// curved surface, the plane passes inside a convex bend (about
/// `h^2 / 2R` at a radius of curvature `R`) and pulled the skin with it;
/// lifted, it passes through the vertices to second order. In cells of
/// `cell`, exact within [`FIELD_MARGIN`] mean edges `edge` of a vertex.
///
/// # Errors
///
/// [`Error::Observation`] where no triangle has an area or the grid
/// cannot be made.
pub(super) fn smoothed_surface_field(
    mesh: &SurfaceMesh,
    cell: f32,
    edge: f32,
    h: f32,
) -> Result<SurfaceField, Error> {
    let (points, normals) = vertex_normals(mesh);
    if points.is_empty() {
        return Err(ObservationError::Field(tissue_core::FieldError::NoVertices).into());
    }
    let margin = FIELD_MARGIN * edge;
    let reach = SMOOTH_REACH * h;
    let unlifted = SurfaceField::of_cloud_within(&points, &normals, cell, margin, reach)
        .map_err(ObservationError::from)?;
    let lifted: Vec<Vec3> = points
        .par_iter()
        .zip(&normals)
        .map(|(&p, &n)| {
            let lift = unlifted
                .smooth_plane(p, h)
                .map_or(0.0, |(point, normal)| normal.dot(p - point));
            p + lift * n
        })
        .collect();
    Ok(
        SurfaceField::of_cloud_within(&lifted, &normals, cell, margin, reach)
            .map_err(ObservationError::from)?,
    )
}

/// The vertices of `mesh`'s triangles and their unit normals, each the
/// sum of its triangles' area-weighted normals; vertices of no triangle,
/// or of triangles without area, are left out.
fn vertex_normals(mesh: &SurfaceMesh) -> (Vec<Vec3>, Vec<Vec3>) {
    let mut sums = vec![Vec3::ZERO; mesh.vertices.len()];
    for (t, triangle) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t);
        let twice_area = (b - a).cross(c - a);
        for &v in triangle {
            sums[v as usize] += twice_area;
        }
    }
    mesh.vertices
        .iter()
        .zip(sums)
        .filter_map(|(&p, sum)| {
            let normal = sum.normalize_or_zero();
            (normal != Vec3::ZERO).then_some((p, normal))
        })
        .unzip()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;

    /// A sphere of radius `radius` about the origin, triangulated.
    fn sphere(radius: f32) -> SurfaceMesh {
        let (vertices, triangles) = tissue_testkit::sphere(radius, 4);
        SurfaceMesh::new(vertices, triangles)
    }

    /// Smoothed over points on a sphere, the plane passes inside it by
    /// about `h^2 / 2R`; lifted, through it, between the vertices as at
    /// them.
    #[test]
    fn the_lifted_vertices_smooth_planes_that_pass_through_the_surface() {
        let radius = 50.0;
        let mesh = sphere(radius);
        let edge = mean_edge(&mesh);
        let h = super::super::matching::SURFACE_SMOOTHING * edge;
        let lifted = smoothed_surface_field(&mesh, 2.0 * edge, edge, h).unwrap();
        let (points, normals) = vertex_normals(&mesh);
        let unlifted = SurfaceField::of_cloud_within(
            &points,
            &normals,
            2.0 * edge,
            FIELD_MARGIN * edge,
            SMOOTH_REACH * h,
        )
        .unwrap();
        let mut next = tissue_testkit::xorshift(7);
        let off = |field: &SurfaceField, p: Vec3| {
            let (point, normal) = field.smooth_plane(p, h).unwrap();
            normal.dot(p - point)
        };
        let (mut before, mut after) = (0.0f32, 0.0f32);
        for _ in 0..200 {
            let direction = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
            let p = radius * direction;
            before = before.max(off(&unlifted, p).abs());
            after = after.max(off(&lifted, p).abs());
            // The normal the plane turns to is the sphere's.
            let (_, normal) = lifted.smooth_plane(p, h).unwrap();
            assert!(normal.dot(direction) > 0.999, "{normal} at {direction}");
        }
        let bias = h * h / (2.0 * radius);
        eprintln!("h {h}, h^2/2R {bias}: unlifted {before}, lifted {after}");
        assert!(before > 0.5 * bias, "unlifted {before}, h^2/2R {bias}");
        assert!(after < 0.1 * bias, "lifted {after}, unlifted {before}");
    }
}
