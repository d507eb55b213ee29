//! The model's held region (the chest wall) as a match sees it: the field
//! of its surface triangles, which no free skin particle is paired on
//! ([`HeldRegion`]), and the rest vertices an observed closed surface
//! shows did not move ([`held_on`]).

use std::collections::BTreeSet;

use tissue_cpu::model::Embedding;

use super::ObservationError;
use super::matching::mean_edge;
use crate::backend::Solver;
use crate::field::{SurfaceField, signed_distances};
use crate::{Error, ParticleModel, SurfaceMesh, Vec3};

/// The model's held region as a match pairs around it (the field of its
/// surface triangles that hold control points), made once for a sequence
/// of matches of one solver ([`super::match_observation_held`]: `tissue track`'s
/// frames) instead of at every match.
/// It also holds the model's surface bound to the solver's particles, which
/// every match carries to its answer; a match made with another solver's
/// control points or reference positions makes both again.
#[derive(Debug, Clone)]
pub struct HeldRegion {
    /// The control points it was made for.
    controls: Vec<bool>,
    /// Its field; `None` without a held region.
    pub(super) field: Option<SurfaceField>,
    /// The positions the surface was bound at (the solver's reference).
    reference: Vec<Vec3>,
    /// The model's surface vertices bound to the particles there.
    pub(super) surface: Embedding,
}

impl HeldRegion {
    /// The held region of `model` under `solver`'s plan.
    ///
    /// # Errors
    ///
    /// Where the held triangles' field cannot be made.
    pub fn of(solver: &Solver, model: &ParticleModel) -> Result<Self, Error> {
        let controls = solver.plan().controls.clone();
        let field = held_field(model, &controls)?;
        Ok(Self {
            controls,
            field,
            reference: solver.reference().to_vec(),
            surface: Embedding::new(solver.reference(), &model.surface.vertices),
        })
    }

    /// Whether it was made for `solver`'s control points and reference.
    pub(super) fn made_for(&self, solver: &Solver) -> bool {
        self.controls == solver.plan().controls && self.reference == solver.reference()
    }
}

/// The field of the model's held region at rest (the surface triangles of
/// its control points), or `None` where nothing is held.
pub(super) fn held_field(
    model: &ParticleModel,
    controls: &[bool],
) -> Result<Option<SurfaceField>, Error> {
    let triangles: BTreeSet<[u32; 3]> = (0..model.len())
        .filter(|&i| controls[i])
        .filter_map(|i| model.attachments[i].map(|a| model.surface.triangles[a.triangle as usize]))
        .collect();
    if triangles.is_empty() {
        return Ok(None);
    }
    let held = SurfaceMesh {
        vertices: model.surface.vertices.clone(),
        triangles: triangles.into_iter().collect(),
    };
    let cell = mean_edge(&held);
    Ok(Some(
        SurfaceField::new(&held, cell, 2.0 * cell).map_err(ObservationError::from)?,
    ))
}

/// The rest vertices of `rest` within `tolerance` of `observed` (a closed
/// surface of the organ without correspondence): the region that did not
/// move, to hold where the caller gives none ([`super::HELD_TOLERANCE`] mean
/// connection lengths is `tissue deform`'s).
///
/// # Errors
///
/// [`Error::Observation`] where `observed` has no triangles, or no
/// triangle of `rest` lies on it (nothing is known to be held).
pub fn held_on(
    observed: &SurfaceMesh,
    rest: &SurfaceMesh,
    tolerance: f32,
) -> Result<Vec<bool>, Error> {
    let held: Vec<bool> = signed_distances(observed, &rest.vertices)
        .map_err(ObservationError::from)?
        .into_iter()
        .map(|d| d.abs() <= tolerance)
        .collect();
    let triangles = rest
        .triangles
        .iter()
        .filter(|t| t.iter().all(|&v| held[v as usize]))
        .count();
    if triangles == 0 {
        return Err(ObservationError::NothingHeld { tolerance }.into());
    }
    Ok(held)
}
