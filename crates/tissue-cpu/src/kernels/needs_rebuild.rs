//! Twin of `shaders/needs_rebuild.wgsl`: the Verlet check of the neighbour
//! rows.

use glam::Vec3;
use rayon::prelude::*;
use tissue_solve::stage1::SamplingState;

/// The shader this module is the twin of.
pub const SHADER: &str = "needs_rebuild";

/// True when the neighbour rows may miss a pair within the force cutoff: some
/// particle moved, or its radius grew, by more than half the skin since they were built.
pub fn needs_rebuild(
    state: &SamplingState,
    built_at: &(Vec<Vec3>, Vec<f32>),
    cutoff: f32,
    skin: f32,
) -> bool {
    let drift = state
        .positions
        .par_iter()
        .zip(&state.radii)
        .zip(built_at.0.par_iter().zip(&built_at.1))
        .map(|((&p, &r), (&p0, &r0))| (p - p0).length() + cutoff * (r - r0).max(0.0))
        .reduce(|| 0.0, f32::max);
    drift > 0.5 * skin
}
