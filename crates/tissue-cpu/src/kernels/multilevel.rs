//! Twin of `shaders/multilevel.wgsl`: the two-grid cycles that solve a
//! coarse Laplacian too large for one factor, `Multilevel::solve`, written
//! once in `tissue-solve`.

pub use tissue_solve::coarse::Multilevel;

/// The shader this module is the twin of.
pub const SHADER: &str = "multilevel";
