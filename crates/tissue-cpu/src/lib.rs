//! The CPU reference path of tissue: rayon-parallel and Jacobi-style (each
//! particle's update reads only the previous state), so results do not depend
//! on the thread count. Each stage is the twin of a GPU shader of the same name.

pub mod coarse;
pub mod deformation;
pub mod grid;
pub mod quality;
pub mod sampling;
pub mod structures;
pub mod svd3;

pub use sampling::{Progress, Sampled, sample};
