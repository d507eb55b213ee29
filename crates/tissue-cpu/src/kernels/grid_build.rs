//! Twin of `shaders/grid_build.wgsl`: the uniform grid's cells, written
//! once in `tissue-solve`: `grid_build`.

pub use tissue_solve::stage1::{Grid, grid_build};

/// The shader this module is the twin of.
pub const SHADER: &str = "grid_build";
