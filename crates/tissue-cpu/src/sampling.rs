//! Stage 1, uniform sampling (the paper's Section 2), on the CPU.
//!
//! Every iteration is Jacobi-style: each particle's update reads only the
//! previous state, so the result does not depend on the thread count. The
//! stages are in [`crate::kernels`], each the twin of the GPU shader of its
//! name: `imf_force` (eqs. (4)-(6), with the surface force of eq. (3)),
//! `radius_update` (eqs. (7)-(8)), `sampling_integrate` (eq. (1) and the
//! surface constraint), `sampling_change`, `needs_rebuild`.

use std::time::Instant;

use tissue_core::{Error, SamplingParams, SurfaceMesh};
pub use tissue_solve::stage1::{
    FIELD_CELL_IN_R0, FIELD_MARGIN_IN_R0, ForceOut, Prepared, Progress, SKIN_IN_R0, Sampled,
    SamplingState, converged_after, finish, initial_positions, initial_radius,
    place_surface_particles, prepare,
};

pub use crate::kernels::imf_force::{ForceRows, imf_force, imf_force_near, imf_pair};
pub use crate::kernels::needs_rebuild::needs_rebuild;
pub use crate::kernels::radius_update::radius_update;
pub use crate::kernels::sampling_change::change;
pub use crate::kernels::sampling_integrate::{integrate, integrate_clear};
use crate::stage1::neighbour_rows;
use crate::stage1::quality_report;

/// Skin of the force's rows ([`ForceRows`]), in `r0`.
pub const FORCE_SKIN_IN_R0: f32 = 0.3;

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
    let force_skin = FORCE_SKIN_IN_R0 * r0;
    let mut near = ForceRows::default();
    near.filter(&state, &rows.0, &rows.1, params.force_cutoff, force_skin);
    let mut built_at = (state.positions.clone(), state.radii.clone());
    let mut near_at = built_at.clone();
    // How deep inside each particle surely is: its surface query is
    // skipped while its step is shorter ([`integrate_clear`]).
    let mut clearance = vec![0.0; state.positions.len()];
    let mut iterations = 0;
    let mut rebuilds = 0;
    let mut converged = false;
    while iterations < params.max_iterations {
        let forces = imf_force_near(&state, &near, &field, params);
        let radii = radius_update(&state.radii, &forces, params);
        let (positions, contact) =
            integrate_clear(&state, &forces, &field, params, r0, &mut clearance);
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
        let rebuild_rows = needs_rebuild(&state, &built_at, params.force_cutoff, skin);
        if rebuild_rows {
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
        if rebuild_rows || needs_rebuild(&state, &near_at, params.force_cutoff, force_skin) {
            near.filter(&state, &rows.0, &rows.1, params.force_cutoff, force_skin);
            near_at = (state.positions.clone(), state.radii.clone());
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
