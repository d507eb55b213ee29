//! Stage 1, uniform sampling (the paper's Section 2), on the CPU.
//!
//! Every iteration is Jacobi-style: each particle's update reads only the
//! previous state, so the result does not depend on the thread count. The
//! stages, each a function below with the GPU shader's name:
//! `imf_force` (eqs. (4)-(6), with the surface force of eq. (3)),
//! `radius_update` (eqs. (7)-(8)), `integrate` (eq. (1) and the surface constraint).

use std::time::Instant;

use glam::{Vec3, Vec4};
use rayon::prelude::*;
use tissue_core::field::{Nearest, Side, SurfaceField};
use tissue_core::{Error, SamplingParams, SurfaceMesh, SurfaceMode};
pub use tissue_solve::sampling::{
    FIELD_CELL_IN_R0, FIELD_MARGIN_IN_R0, ForceOut, Prepared, Progress, SKIN_IN_R0, Sampled,
    SamplingState, converged_after, finish, initial_positions, initial_radius,
    place_surface_particles, prepare,
};

use crate::grid::neighbour_rows;
use crate::quality::quality_report;

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

/// Stage 1: fills a closed, outward surface (validated by the caller) with
/// `params.particles` particles and relaxes them to the paper's uniform state.
pub fn sample(
    mesh: &SurfaceMesh,
    params: &SamplingParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Sampled, Error> {
    let started = Instant::now();
    let Prepared {
        r0,
        field,
        mut state,
        mut stages,
    } = prepare(mesh, params)?;
    let mut clock = Instant::now();
    let mut lap = |slot: &mut f64| {
        *slot += clock.elapsed().as_secs_f64();
        clock = Instant::now();
    };

    let skin = SKIN_IN_R0 * r0;
    let mut rows = neighbour_rows(
        &state.positions,
        &state.radii,
        params.force_cutoff,
        skin,
        false,
    );
    let mut built_at = (state.positions.clone(), state.radii.clone());
    let mut iterations = 0;
    let mut rebuilds = 0;
    let mut converged = false;
    while iterations < params.max_iterations {
        let forces = imf_force(&state, &rows.0, &rows.1, &field, params);
        let radii = radius_update(&state.radii, &forces, params);
        let (positions, contact) = integrate(&state, &forces, &field, params, r0);
        let (step_rms, radius_rms) = change(&state, &positions, &contact, &radii, r0);
        let done = converged_after(iterations, step_rms, radius_rms, params, progress)?;
        state = SamplingState {
            positions,
            radii,
            contact,
        };
        iterations += 1;
        if done {
            converged = true;
            break;
        }
        if needs_rebuild(&state, &built_at, params.force_cutoff, skin) {
            let rebuild = Instant::now();
            rows = neighbour_rows(
                &state.positions,
                &state.radii,
                params.force_cutoff,
                skin,
                false,
            );
            built_at = (state.positions.clone(), state.radii.clone());
            rebuilds += 1;
            stages.neighbours += rebuild.elapsed().as_secs_f64();
        }
    }
    lap(&mut stages.iterations);

    let model = finish(mesh, &field, state, params);
    lap(&mut stages.connections);
    let mut report = quality_report(&model, &field, iterations, converged, 0.0);
    lap(&mut stages.report);
    report.neighbour_rebuilds = rebuilds;
    report.stage_seconds = stages;
    report.seconds = started.elapsed().as_secs_f64();
    Ok(Sampled { model, report })
}

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
