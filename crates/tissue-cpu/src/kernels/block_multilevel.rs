//! Twin of `shaders/block_multilevel.wgsl`: the two-grid cycles over blocks
//! of three unknowns that solve an elastic coarse matrix too large for one
//! factor, `BlockMultilevel::solve`, written once in `tissue-solve`.

pub use tissue_solve::coarse::BlockMultilevel;

/// The shader this module is the twin of.
pub const SHADER: &str = "block_multilevel";
