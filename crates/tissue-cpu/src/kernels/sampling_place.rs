//! Twin of `shaders/sampling_place.wgsl`: stage 1's surface placement,
//! `place_surface_particles`, written once in `tissue-solve`.

pub use tissue_solve::stage1::place_surface_particles;

/// The shader this module is the twin of.
pub const SHADER: &str = "sampling_place";
