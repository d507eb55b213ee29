//! Twin of `shaders/neighbour_rows.wgsl`: each particle's neighbours within
//! a cutoff, `neighbour_rows`, written once in `tissue-solve`.

pub use tissue_solve::stage1::neighbour_rows;

/// The shader this module is the twin of.
pub const SHADER: &str = "neighbour_rows";
