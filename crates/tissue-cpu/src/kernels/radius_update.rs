//! Twin of `shaders/radius_update.wgsl`: eqs. (7)-(8), each balloon's radius.

use rayon::prelude::*;
use tissue_core::SamplingParams;
use tissue_solve::stage1::ForceOut;

/// The shader this module is the twin of.
pub const SHADER: &str = "radius_update";

/// Eqs. (7)-(8): each balloon inflates when under-compressed and deflates when
/// over-compressed. `dr` of eq. (8) is read as a change of `ln r`, its `ln`
/// argument clamped to `[exp(-x), exp(x)]`, `x = max_log_radius_step`.
pub fn radius_update(radii: &[f32], forces: &[ForceOut], params: &SamplingParams) -> Vec<f32> {
    let ideal = params.ideal_compression();
    let bound = params.max_log_radius_step.exp();
    radii
        .par_iter()
        .zip(forces)
        .map(|(&r, out)| {
            let argument = (1.0 + params.eta * (out.compression - ideal)).clamp(1.0 / bound, bound);
            r / argument
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn forces_with(compression: f32) -> Vec<ForceOut> {
        vec![ForceOut {
            force: Vec3::ZERO,
            compression,
        }]
    }

    #[test]
    fn radius_grows_when_under_compressed_and_shrinks_when_over_compressed() {
        let params = SamplingParams::default();
        let ideal = params.ideal_compression();
        let r = [1.0f32];
        assert!(radius_update(&r, &forces_with(ideal - 3.0), &params)[0] > 1.0);
        assert!(radius_update(&r, &forces_with(ideal + 3.0), &params)[0] < 1.0);
        assert!((radius_update(&r, &forces_with(ideal), &params)[0] - 1.0).abs() < 1e-6);
        // A huge compression cannot make the ln argument non-positive: the
        // change is clamped to max_log_radius_step.
        let squeezed = radius_update(&r, &forces_with(1e9), &params)[0];
        assert!((squeezed.ln() + params.max_log_radius_step).abs() < 1e-5);
        let freed = radius_update(&r, &forces_with(-1e9), &params)[0];
        assert!((freed.ln() - params.max_log_radius_step).abs() < 1e-5);
    }
}
