//! Twin of `shaders/imf_force.wgsl`: eqs. (2)-(6), the IMF pair forces over
//! a particle's neighbour row, the surface's force or reaction, and the
//! balloon's compression.

use glam::Vec3;
use rayon::prelude::*;
use tissue_core::field::{Side, SurfaceField};
use tissue_core::{SamplingParams, SurfaceMode};
use tissue_solve::stage1::{ForceOut, SamplingState};

/// The shader this module is the twin of.
pub const SHADER: &str = "imf_force";

/// Pair force of eqs. (4)-(5) on `i` from `j`, as a signed magnitude along the
/// unit vector from `j` to `i` (positive repels).
#[inline]
pub fn imf_pair(distance: f32, radius_sum: f32, alpha: f32) -> f32 {
    let h = 1.0 / (alpha * distance / radius_sum + (1.0 - alpha));
    let h3 = h * h * h;
    h3 * h3 - h3
}

/// Eqs. (2)-(6): the IMF pair forces over a particle's neighbour row, the
/// surface's force or reaction, and the balloon's compression.
pub fn imf_force(
    state: &SamplingState,
    offsets: &[u32],
    neighbours: &[u32],
    field: &SurfaceField,
    params: &SamplingParams,
) -> Vec<ForceOut> {
    let cutoff = params.force_cutoff;
    (0..state.positions.len())
        .into_par_iter()
        .map(|i| {
            let p = state.positions[i];
            let r = state.radii[i];
            let mut force = Vec3::ZERO;
            let mut magnitudes = 0.0f32;
            for &j in &neighbours[offsets[i] as usize..offsets[i + 1] as usize] {
                let offset = p - state.positions[j as usize];
                let radius_sum = r + state.radii[j as usize];
                let d2 = offset.length_squared();
                if d2 >= (cutoff * radius_sum) * (cutoff * radius_sum) || d2 == 0.0 {
                    continue;
                }
                let d = d2.sqrt();
                let f = imf_pair(d, radius_sum, params.alpha);
                force += offset * (f / d);
                magnitudes += f.abs();
            }
            // eq. (6): |F_compress| = sum |F_j| - |sum F_j|. When counted, the
            // surface's force is one more term on both sides.
            let (wall, moves) = match params.surface_mode {
                // The wall's reaction from the last move: it counts in the
                // compression, but the move itself is left to the projection.
                SurfaceMode::Projection => {
                    (-state.contact[i].w * state.contact[i].truncate(), false)
                }
                // eq. (3): -n while outside, weighted by mu in eq. (2).
                SurfaceMode::PaperForce { mu } => match field.query(p) {
                    Side::Near(nearest) if nearest.distance > 0.0 => (-mu * nearest.normal, true),
                    Side::DeepOutside => (-mu * field.nearest(p).normal, true),
                    _ => (Vec3::ZERO, true),
                },
            };
            let compression = if params.wall_in_compression {
                magnitudes + wall.length() - (force + wall).length()
            } else {
                magnitudes - force.length()
            };
            ForceOut {
                force: if moves { force + wall } else { force },
                compression: compression.max(0.0),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_force_is_zero_at_contact_repulsive_inside_attractive_outside() {
        let alpha = 0.5;
        assert!(imf_pair(1.0, 1.0, alpha).abs() < 1e-6);
        for d in [0.05, 0.3, 0.6, 0.75, 0.99] {
            assert!(imf_pair(d, 1.0, alpha) > 0.0, "d = {d} should repel");
        }
        for d in [1.01, 1.2, 2.0, 5.0] {
            assert!(imf_pair(d, 1.0, alpha) < 0.0, "d = {d} should attract");
        }
        // Decays towards zero far away (the attraction tail).
        assert!(imf_pair(50.0, 1.0, alpha).abs() < 1e-3);
        // At d = 0 it is 2^6 - 2^3 = 56 for alpha = 0.5.
        assert!((imf_pair(0.0, 1.0, alpha) - 56.0).abs() < 1e-4);
    }
}
