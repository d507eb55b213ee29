//! What the skin is matched to without correspondence ([`Observation`]):
//! a closed surface of any triangulation or a cleaned point cloud, its
//! checks against the model, and the field a match pairs the skin on.

use std::borrow::Cow;

use rayon::prelude::*;

use super::matching::{
    CLOUD_EDGE_SPACINGS, CLOUD_NOISE, FIELD_CELL_EDGES, FIELD_MARGIN, HELD_OFF, MAX_REACH,
    MAX_VOLUME_CHANGE, mean_edge,
};
use super::{Cloud, ObservationError};
use crate::field::{SurfaceField, signed_distances};
use crate::{Error, SurfaceMesh, Vec3};

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
    Cloud { field: SurfaceField, spacing: f32 },
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
    /// noise across the skin averaged out ([`Cloud::cleaned`] with `noise`,
    /// or [`CLOUD_NOISE`] spacings; the points set aside are counted,
    /// [`Observation::outliers`]), its normals turned away from `inside`
    /// (a point inside the organ: [`Cloud::oriented_from`]).
    ///
    /// # Errors
    ///
    /// [`Error::Observation`] where too few points are kept or its grid
    /// cannot be made.
    pub fn cloud(cloud: &Cloud, noise: Option<f32>, inside: Vec3) -> Result<Self, Error> {
        let noise = noise.unwrap_or(CLOUD_NOISE * cloud.spacing());
        let (cleaned, outliers) = cloud.cleaned(noise)?;
        let cleaned = cleaned.oriented_from(inside);
        let spacing = cleaned.spacing();
        Ok(Self {
            points: cleaned.points().to_vec(),
            outliers,
            kind: Kind::Cloud {
                field: cleaned.field(FIELD_MARGIN * spacing)?,
                spacing,
            },
        })
    }

    /// Checks what [`Observation::cloud`] would refuse in `cloud`, without
    /// its grid (a long sequence of scans is checked whole before its
    /// first frame, each grid made when its frame comes).
    ///
    /// # Errors
    ///
    /// As [`Observation::cloud`].
    pub fn check_cloud(cloud: &Cloud, noise: Option<f32>) -> Result<(), Error> {
        let noise = noise.unwrap_or(CLOUD_NOISE * cloud.spacing());
        let (cleaned, _) = cloud.cleaned(noise)?;
        cleaned.check_field(FIELD_MARGIN * cleaned.spacing())?;
        Ok(())
    }

    /// Per point of `points`, whether the observation sees it: every one
    /// for a surface; for a cloud, those within [`CLOUD_EDGE_SPACINGS`]
    /// of its nearest point (the skin past the cloud's edge is not seen).
    pub fn sees(&self, points: &[Vec3]) -> Vec<bool> {
        match &self.kind {
            Kind::Surface(_) => vec![true; points.len()],
            Kind::Cloud { field, spacing } => points
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
    /// corner), where no free particle belongs, in cells of
    /// [`FIELD_CELL_EDGES`] mean edges or the model's mean connection
    /// length `spacing`, the longer; a cloud's as it is.
    pub(super) fn pairing_field(
        &self,
        held: Option<&SurfaceField>,
        reach: f32,
        spacing: f32,
    ) -> Result<Cow<'_, SurfaceField>, Error> {
        let mesh = match &self.kind {
            Kind::Cloud { field, .. } => return Ok(Cow::Borrowed(field)),
            Kind::Surface(mesh) => mesh,
        };
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
        let free = SurfaceMesh {
            vertices: mesh.vertices.clone(),
            triangles: if kept.is_empty() {
                mesh.triangles.clone()
            } else {
                kept
            },
        };
        let edge = mean_edge(&free);
        let cell = (FIELD_CELL_EDGES * edge).max(spacing);
        Ok(Cow::Owned(
            SurfaceField::new(&free, cell, FIELD_MARGIN * edge).map_err(ObservationError::from)?,
        ))
    }
}
