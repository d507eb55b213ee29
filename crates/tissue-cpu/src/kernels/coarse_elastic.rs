//! Twin of `shaders/coarse_elastic.wgsl`: the elastic phase's correction
//! over the elastic aggregates, `ElasticCoarse::correct`, written once in
//! `tissue-solve`.

pub use tissue_solve::coarse::ElasticCoarse;

/// The shader this module is the twin of.
pub const SHADER: &str = "coarse_elastic";
