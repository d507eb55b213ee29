//! Twin of `shaders/coarse.wgsl`: the two-level solve's correction over the
//! Laplacian's aggregates, `CoarseSpace::correct`, written once in
//! `tissue-solve` (the coarse space is made on the host for both devices).

pub use tissue_solve::coarse::CoarseSpace;

/// The shader this module is the twin of.
pub const SHADER: &str = "coarse";
