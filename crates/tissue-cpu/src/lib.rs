//! The CPU reference path of tissue: rayon-parallel and Jacobi-style (each
//! particle's update reads only the previous state), so results do not depend
//! on the thread count. Each stage is the twin of a GPU shader of the same
//! name, in [`kernels`] under that name.
//!
//! What belongs to neither device (parameters, plan, acceleration, stopping,
//! prediction, stage 1's preparation and finish) lives in `tissue-solve`;
//! the host algorithms both devices use (the grid, the 3x3 SVD, structures)
//! are there too, re-exported here as this path's twins of their shaders.

/// The two-level solves' coarse spaces, written once in `tissue-solve`
/// (their corrections are the CPU's kernels).
pub use tissue_solve::coarse;
/// The elastic model, the 3x3 SVD and structures bound to particles,
/// written once in `tissue-solve`.
pub use tissue_solve::model;
/// Stage 1's grid, neighbour rows and quality report, written once in
/// `tissue-solve`.
pub use tissue_solve::stage1;
pub mod deformation;
pub mod kernels;
pub mod sampling;

pub use sampling::{Progress, Sampled, sample};
