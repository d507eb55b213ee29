//! The algorithm of tissue, written once for every device: what belongs to
//! neither the CPU nor the GPU path.
//!
//! - Stage 2: the parameters ([`params`]), the elastic model's
//!   mathematics ([`elastic`], its consistent gradients [`consistent`]), what a solve knows before it
//!   starts ([`plan`], with the Laplacian's spectrum from [`spectrum`]),
//!   Chebyshev acceleration and the stopping rule ([`acceleration`]), the
//!   tracking prediction and its history ([`predict`]), the deformed surface's checks and control points
//!   ([`controls`]), what one iteration runs ([`passes`]), how a solve went ([`report`]), and the one tracker
//!   that runs frames on any device ([`tracker`], over [`SolveDevice`]);
//!   batches of iterations with the replay that stops every device at the
//!   same iteration ([`batches`], stage 1's GPU loop too).
//! - Stage 1: the initial radius and placement, the state the iterations
//!   work on and the finish ([`sampling`]), and the quality report
//!   ([`quality`]).
//! - Host algorithms both devices use on the host: the uniform grid and
//!   neighbour rows ([`grid`]), the 3x3 SVD and polar rotation ([`svd3`]),
//!   and structures bound to particles ([`structures`]), and the
//!   displacement field they carry back to rest ([`resampling`]). The CPU path takes
//!   these as its twins of the shaders of the same name.
//!
//! The devices (`tissue-cpu`, `tissue-gpu`) implement kernels and buffers.

pub mod acceleration;
pub mod aggregates;
pub mod batches;
pub mod cholesky;
pub mod coarse;
pub mod coarse_elastic;
pub mod consistent;
pub mod controls;
pub mod device;
pub mod elastic;
mod entries;
pub mod envelope;
pub mod gravity;
pub mod grid;
pub mod inversion;
pub mod multilevel;
pub mod params;
pub mod passes;
pub mod plan;
pub mod posture;
pub mod predict;
pub mod quality;
pub mod report;
pub mod resampling;
pub mod sampling;
pub mod spectrum;
pub mod stiffness;
pub mod structures;
pub mod svd3;
pub mod tracker;
pub mod volume_smoother;

pub use acceleration::{Chebyshev, StoppingRule};
pub use controls::check_same_topology;
pub use inversion::{Inversions, inversions};
pub use params::{DeformParams, ForceModel, RotationMethod, SolverTuning};
pub use passes::{Choices, Correction, Holds, Pass};
pub use plan::Plan;
pub use predict::{FrameHistory, predict};
pub use report::{DeformReport, PrepareStage, SolveStep, StopReason};
pub use tracker::{Iteration, SolveDevice, Tracker};
