//! Stage 1 (uniform sampling) on the GPU: `tissue_cpu::sample` with the
//! iteration loop on the device.
//!
//! - [`SamplingPipelines`]: the compiled stage-1 kernels, built once per device.
//! - [`SamplingBuffers`]: the buffers of one run: two particle states
//!   (`vec4`: xyz position, w radius) and two contact arrays used in turn,
//!   forces, the neighbour rows (CSR), the surface field, the convergence
//!   partials and the rebuild flag.
//! - [`sample`]: the whole stage. The field, the initial positions, `finish`
//!   and the quality report stay on the CPU (one upload, one readback); the
//!   iterations run on the GPU, [`BATCH`] to a command buffer, their change
//!   partials read back once per batch and finished in `f64`.
//!
//! The neighbour rows, and at the end the connections, are built on the GPU
//! by [`GridPipelines::neighbour_rows`]; the kernels only see CSR buffers
//! ([`SamplingBuffers::set_rows`] uploads rows built on the CPU instead).

mod buffers;
mod field;
mod kernels;

pub use buffers::{BATCH, SamplingBuffers, SamplingUniforms};
pub use field::{FieldBuffers, query_field};
pub use kernels::{SamplingKernel, SamplingPipelines};

use std::time::Instant;

use glam::Vec3;
use tissue_core::field::SurfaceField;
use tissue_core::{Connections, ParticleModel, SamplingParams, SurfaceMesh};
use tissue_solve::quality::quality_report;
use tissue_solve::sampling::{
    Prepared, Progress, SKIN_IN_R0, Sampled, SamplingState, converged_after,
    place_surface_particles, prepare,
};

use crate::support::{Scopes, scoped};
use crate::{GpuError, GridPipelines};
use buffers::{storage, vec4s};

/// The change of one iteration as `tissue_solve::sampling::change` finishes it:
/// RMS step of particles not held by the wall (in `r0`), RMS change of `ln r`.
fn finish_change(sums: [f64; 3], count: usize, r0: f32) -> (f32, f32) {
    let free = sums[1].round().max(1.0);
    let step_rms = (sums[0] / free).sqrt() as f32 / r0;
    let radius_rms = (sums[2] / count.max(1) as f64).sqrt() as f32;
    (step_rms, radius_rms)
}

/// Stage 1 on the GPU: `tissue_cpu::sample` with the iterations on `device`.
/// The same preparation, the same Jacobi iteration, the same convergence test
/// (partials finished in `f64`) and the same rebuild rule; rows and
/// connections by [`GridPipelines::neighbour_rows`]. When the
/// test holds inside a batch, the batch is replayed up to that iteration,
/// so the iteration count is the rule's.
pub fn sample(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mesh: &SurfaceMesh,
    params: &SamplingParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Sampled, GpuError> {
    let started = Instant::now();
    let Prepared {
        r0,
        field,
        state,
        mut stages,
    } = prepare(mesh, params)?;
    let pipelines = SamplingPipelines::new(device)?;
    let grid = GridPipelines::new(device)?;
    let clock = Instant::now();
    let scope = Scopes::push(device);
    let run = iterate(
        device, queue, &pipelines, &grid, &field, state, params, r0, progress,
    );
    scope.pop()?;
    let (state, iterations, converged, rebuilds, neighbour_seconds) = run?;
    stages.iterations += clock.elapsed().as_secs_f64() - neighbour_seconds;
    stages.neighbours += neighbour_seconds;

    // `tissue_solve::sampling::finish`, its connections (eq. (9)) on the GPU.
    let clock = Instant::now();
    let (positions, attachments) = place_surface_particles(&field, &state, params);
    let connections = connections(
        device,
        queue,
        &grid,
        &positions,
        &state.radii,
        params.connection_ratio,
    )?;
    let model = ParticleModel {
        positions,
        radii: state.radii,
        attachments,
        connections,
        surface: mesh.clone(),
    };
    stages.connections += clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let mut report = quality_report(&model, &field, iterations, converged, 0.0);
    stages.report += clock.elapsed().as_secs_f64();
    report.neighbour_rebuilds = rebuilds;
    report.stage_seconds = stages;
    report.seconds = started.elapsed().as_secs_f64();
    Ok(Sampled { model, report })
}

/// The iteration loop: `(final state, iterations, converged, rebuilds, seconds in rebuilds)`.
#[allow(clippy::too_many_arguments, reason = "the loop's inputs, named")]
fn iterate(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipelines: &SamplingPipelines,
    grid: &GridPipelines,
    field: &SurfaceField,
    state: SamplingState,
    params: &SamplingParams,
    r0: f32,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(SamplingState, usize, bool, usize, f64), GpuError> {
    let n = state.positions.len();
    let skin = SKIN_IN_R0 * r0;
    let mut buffers = SamplingBuffers::new(device, queue, pipelines, field, &state, params, r0)?;
    drop(state);
    // Rows from the state of `parity`, which becomes their build state.
    let build_rows = |buffers: &mut SamplingBuffers, parity: usize| -> Result<(), GpuError> {
        let rows = grid.neighbour_rows(
            device,
            queue,
            &buffers.states[parity],
            buffers.count,
            params.force_cutoff,
            skin,
            false,
        )?;
        buffers.set_row_buffers(device, pipelines, rows.offsets, rows.indices)?;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("sampling rows built"),
        });
        buffers.mark_built(&mut encoder, parity);
        queue.submit([encoder.finish()]);
        Ok(())
    };
    build_rows(&mut buffers, 0)?;
    let backup = |label| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: n as u64 * 16,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    };
    let backup_state = backup("backup state");
    let backup_contact = backup("backup contact");

    let mut parity = 0usize;
    let mut iterations = 0usize;
    let mut rebuilds = 0usize;
    let mut neighbour_seconds = 0.0;
    let mut converged = false;
    while iterations < params.max_iterations {
        let batch = BATCH.min((params.max_iterations - iterations) as u32);
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("sampling batch"),
        });
        encoder.copy_buffer_to_buffer(&buffers.states[parity], 0, &backup_state, 0, None);
        encoder.copy_buffer_to_buffer(&buffers.contacts[parity], 0, &backup_contact, 0, None);
        buffers.record_iterations(&mut encoder, pipelines, batch, parity);
        queue.submit([encoder.finish()]);
        let (sums, halt) = buffers.read_change(device, queue, batch)?;
        // A halt at slot s: iterations 0..=s ran, the rest did nothing.
        let ran = if halt == 0 { batch } else { halt.min(batch) };
        let mut stop_after = None;
        for (k, &row) in sums.iter().take(ran as usize).enumerate() {
            let (step_rms, radius_rms) = finish_change(row, n, r0);
            let done = converged_after(iterations, step_rms, radius_rms, params, progress)?;
            iterations += 1;
            if done {
                converged = true;
                stop_after = Some(k as u32 + 1);
                break;
            }
        }
        if let Some(done) = stop_after {
            if done < ran {
                // Replay the batch up to the iteration where the test held.
                let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("sampling replay"),
                });
                encoder.copy_buffer_to_buffer(&backup_state, 0, &buffers.states[parity], 0, None);
                encoder.copy_buffer_to_buffer(
                    &backup_contact,
                    0,
                    &buffers.contacts[parity],
                    0,
                    None,
                );
                buffers.record_iterations(&mut encoder, pipelines, done, parity);
                queue.submit([encoder.finish()]);
            }
            parity = (parity + done as usize) & 1;
            break;
        }
        parity = (parity + ran as usize) & 1;
        if halt != 0 && iterations < params.max_iterations {
            let clock = Instant::now();
            build_rows(&mut buffers, parity)?;
            rebuilds += 1;
            neighbour_seconds += clock.elapsed().as_secs_f64();
        }
    }
    let state = buffers.read_state(device, queue, parity)?;
    Ok((state, iterations, converged, rebuilds, neighbour_seconds))
}

/// Connections of eq. (9), `neighbour_rows(.., ratio, 0, sorted)`, on the GPU.
fn connections(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    grid: &GridPipelines,
    positions: &[Vec3],
    radii: &[f32],
    ratio: f32,
) -> Result<Connections, GpuError> {
    let n = positions.len();
    let count = u32::try_from(n).map_err(|_| GpuError::Length {
        what: "particles (below u32::MAX)",
        expected: u32::MAX as usize,
        got: n,
    })?;
    let what = || format!("{n} particles");
    let placed = scoped(device, || {
        storage(
            device,
            "placed",
            bytemuck::cast_slice(&vec4s(positions, radii)),
            &what,
        )
    })?;
    let rows = grid.neighbour_rows(device, queue, &placed, count, ratio, 0.0, true)?;
    let (offsets, indices) = rows.read(device, queue)?;
    Ok(Connections { offsets, indices })
}
