//! Twin of `shaders/sampling_integrate.wgsl`: eq. (1) and the surface
//! constraint.

use glam::{Vec3, Vec4};
use rayon::prelude::*;
use tissue_core::field::{Nearest, Side, SurfaceField};
use tissue_core::{SamplingParams, SurfaceMode};
use tissue_solve::stage1::{ForceOut, SamplingState};

/// The shader this module is the twin of.
pub const SHADER: &str = "sampling_integrate";

/// Eq. (1), `dp = F / m` with `m = m~ / r0` and the step capped at
/// `max_step r0`; in projection mode a particle that ends outside is moved
/// back onto the surface by its penetration depth. Returns the new positions
/// and the wall's reactions.
pub fn integrate(
    state: &SamplingState,
    forces: &[ForceOut],
    field: &SurfaceField,
    params: &SamplingParams,
    r0: f32,
) -> (Vec<Vec3>, Vec<Vec4>) {
    let max_step = params.max_step * r0;
    state
        .positions
        .par_iter()
        .zip(forces)
        .map(|(&p, out)| {
            let step = (out.force * (r0 / params.mass)).clamp_length_max(max_step);
            let moved = p + step;
            if params.surface_mode != SurfaceMode::Projection {
                return (moved, Vec4::ZERO);
            }
            // What the projection takes away is the wall's reaction, in force
            // units (dp = F r0 / m): zero as soon as the particle stays inside.
            let held = |n: Nearest| {
                let reaction = n.distance * params.mass / r0;
                (n.point, n.normal.extend(reaction))
            };
            match field.query(moved) {
                Side::DeepOutside => held(field.nearest(moved)),
                Side::Near(n) if n.distance > 0.0 => held(n),
                _ => (moved, Vec4::ZERO),
            }
        })
        .unzip()
}
