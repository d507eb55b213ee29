//! Observations without correspondence: a point cloud of the organ's
//! surface read from a file, its spacing and fitted normals, the grid
//! that finds a point's nearest observed point, the rigid motion that
//! puts a cloud on a surface, and the model's skin pulled onto a surface
//! of any triangulation or a cloud inside the elastic solve
//! ([`match_observation`]).

mod held;
mod matching;
mod observed;
mod region;

pub use matching::{
    CLOUD_EDGE_SPACINGS, CLOUD_NOISE, EARLY_TOLERANCE, FIELD_CELL_EDGES, FIELD_MARGIN,
    FRAME_STAGES, HELD_OFF, HELD_REACH, HELD_TOLERANCE, MATCH_STAGES, MAX_REACH, MAX_VOLUME_CHANGE,
    MatchParams, MatchReport, PREDICTION_ROUNDS, Residual, STAGE_GROWTH, SURFACE_FIRST_STAGE,
    SURFACE_NOISE, SURFACE_SMOOTHING, match_observation, match_observation_held, mean_edge,
};

pub use held::{HeldObservation, SAMPLE_CELLS};
pub use observed::{CleanedScan, Observation};
pub use region::{HeldRegion, held_on};
pub use tissue_core::ObservationError;
pub use tissue_core::io::cloud::{CLOUD_EXTENSIONS, load_cloud};
pub use tissue_solve::stage2::{
    Cleaned, Cloud, FIDUCIAL_MISFIT, FiducialFit, LINE_SPREAD, NORMAL_NEIGHBOURS, RigidFit,
    SCAN_SCALE, Spring, fiducial_fit, rigid_fit,
};

use crate::{Error, SurfaceMesh, field::SurfaceField};

/// [`rigid_fit`] of `points` onto a closed surface: its field in cells
/// of the surface's mean edge length, exact within two of them.
///
/// # Errors
///
/// [`Error::Observation`] where the surface has no triangles or too
/// small an edge for its size, a point is not finite, or fewer than
/// six points are within `reach`.
pub fn rigid_fit_to_surface(
    points: &[crate::Vec3],
    surface: &SurfaceMesh,
    reach: f32,
) -> Result<RigidFit, Error> {
    let cell = matching::mean_edge(surface);
    let field = SurfaceField::new(surface, cell, 2.0 * cell).map_err(ObservationError::from)?;
    Ok(rigid_fit(points, &field, reach)?)
}
