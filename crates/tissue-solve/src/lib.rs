//! The algorithm of tissue, written once for every device: what belongs to
//! neither the CPU nor the GPU path, in four folders.
//!
//! - [`stage1`]: uniform sampling of a closed surface's interior (the
//!   initial radius and placement, the state the iterations work on, the
//!   finish, the grid and neighbour rows, the quality report).
//! - [`stage2`]: the deformation (the parameters, the plan, Chebyshev
//!   acceleration and the stopping rule, the tracking prediction, what one
//!   iteration runs, the [`SolveDevice`] seam and the one [`Tracker`] over
//!   it, the report, and the posture search).
//! - [`coarse`]: the two-level solves' coarse spaces, factors and cycles.
//! - [`model`]: the elastic model, the 3x3 SVD, structures bound to
//!   particles, gravity and the stiffness fit.
//!
//! Each folder's modules are the crate's own; each folder re-exports the
//! items the devices and the facade use. The devices (`tissue-cpu`,
//! `tissue-gpu`) implement kernels and buffers.

pub mod coarse;
pub mod model;
pub mod stage1;
pub mod stage2;

pub use stage2::{
    Chebyshev, Choices, Correction, DeformParams, DeformReport, ElasticSolve, FLOAT_FLOOR_ERROR,
    ForceModel, FrameHistory, Holds, Inversions, Iteration, Pass, Plan, PrepareStage,
    RotationMethod, SolveDevice, SolveStep, SolverTuning, StopReason, StoppingRule, Tracker,
    check_same_topology, inversions, predict,
};
