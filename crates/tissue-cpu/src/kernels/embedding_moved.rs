//! Twin of `shaders/embedding_moved.wgsl`: where each embedded point of a
//! structure goes, `embedding_moved` (`Embedding::moved`), written once in
//! `tissue-solve`.

pub use tissue_solve::model::{Embedding, embedding_moved};

/// The shader this module is the twin of.
pub const SHADER: &str = "embedding_moved";
