//! Twin of `shaders/sampling_change.wgsl`: stage 1's convergence measure.

use glam::{Vec3, Vec4};
use tissue_solve::stage1::SamplingState;

/// The shader this module is the twin of.
pub const SHADER: &str = "sampling_change";

/// RMS step of particles not held by the wall (in `r0`) and RMS change of `ln r`.
/// Summed in index order, so the result does not depend on threads.
pub fn change(
    old: &SamplingState,
    positions: &[Vec3],
    contact: &[Vec4],
    radii: &[f32],
    r0: f32,
) -> (f32, f32) {
    let mut steps = 0.0f64;
    let mut free = 0usize;
    let mut logs = 0.0f64;
    for i in 0..positions.len() {
        if contact[i].w == 0.0 && old.contact[i].w == 0.0 {
            // Particles the wall holds slide along it; their steps are not the
            // interior's relaxation.
            steps += f64::from((positions[i] - old.positions[i]).length_squared());
            free += 1;
        }
        logs += f64::from((radii[i] / old.radii[i]).ln()).powi(2);
    }
    let step_rms = (steps / free.max(1) as f64).sqrt() as f32 / r0;
    let radius_rms = (logs / positions.len().max(1) as f64).sqrt() as f32;
    (step_rms, radius_rms)
}
