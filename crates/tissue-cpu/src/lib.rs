//! The CPU reference path of tissue: rayon-parallel and Jacobi-style (each
//! particle's update reads only the previous state), so results do not depend
//! on the thread count. Each stage is the twin of a GPU shader of the same
//! name, in [`kernels`] under that name.
//!
//! What belongs to neither device (parameters, plan, acceleration, stopping,
//! prediction, modes, stage 1's preparation and finish) lives in
//! `tissue-solve`; the host algorithms both devices use (the grid, the 3x3
//! SVD, structures) are there too, re-exported here as this path's twins of
//! their shaders.

/// The two-level solve's coarse space, written once in `tissue-solve`
/// (its correction is the CPU's kernel).
pub use tissue_solve::coarse;
/// The elastic phase's two-level solve, written once in `tissue-solve`
/// (its correction is the CPU's kernel).
pub use tissue_solve::coarse_elastic;
pub mod deformation;
pub mod kernels;
pub mod sampling;

pub use sampling::{Progress, Sampled, sample};
pub use tissue_solve::{grid, quality, structures, svd3};
