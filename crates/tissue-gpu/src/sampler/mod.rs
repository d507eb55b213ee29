//! Stage 1 (uniform sampling) on the GPU: `tissue_cpu::sample` with the
//! iteration loop on the device.
//!
//! - [`SamplingPipelines`]: the compiled stage-1 kernels, built once per device.
//! - [`SamplingBuffers`]: the buffers of one run: two particle states
//!   (`vec4`: xyz position, w radius) and two contact arrays used in turn,
//!   forces, the neighbour rows (CSR), the surface field, the convergence
//!   partials and the rebuild flag.
//! - [`sample`]: the whole stage. The field, the initial positions and the
//!   quality report stay on the CPU (one upload, one readback); the
//!   iterations run on the GPU, [`BATCH`] to a command buffer, their change
//!   partials read back once per batch and finished in `f64`; so does
//!   `finish`: the surface placement ([`SamplingBuffers::placement`]) and
//!   the connections of the placed particles.
//!
//! The neighbour rows, and at the end the connections, are built on the GPU
//! by [`GridPipelines::neighbour_rows`]; the kernels only see CSR buffers
//! ([`SamplingBuffers::set_rows`] uploads rows built on the CPU instead).

mod buffers;
mod field;
mod kernels;

pub use buffers::{BATCH, Placement, SamplingBuffers, SamplingUniforms};
pub use field::{FieldBuffers, query_field};
pub use kernels::{SamplingKernel, SamplingPipelines};

use std::time::Instant;

use tissue_core::field::SurfaceField;
use tissue_core::{Connections, ParticleModel, SamplingParams, SurfaceMesh};
use tissue_solve::stage1::{
    Prepared, Progress, SKIN_IN_R0, Sampled, SamplingState, converged_after, prepare,
    quality_report,
};
use tissue_solve::stage2::{Batches, run_batched};

use crate::support::Scopes;
use crate::{GpuError, GridPipelines};

/// The change of one iteration as `tissue_solve::stage1::change` finishes it:
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
    let (buffers, parity, iterations, converged, rebuilds, neighbour_seconds) = run?;
    let state = buffers.read_state(device, queue, parity)?;
    let count = buffers.count;
    // As on the CPU: the iterations' time includes the rebuilds.
    stages.iterations += clock.elapsed().as_secs_f64();
    stages.neighbours += neighbour_seconds;

    // `tissue_solve::stage1::finish` on the GPU: the placement, then the
    // connections (eq. (9)) of the placed particles where they are.
    let clock = Instant::now();
    let placement = buffers.placement(device, queue, parity)?;
    // The run's buffers (the Verlet rows: 217 MB at 1M) go before the
    // connections' rows are built.
    drop(buffers);
    let rows = grid.neighbour_rows(
        device,
        queue,
        placement.placed.buffer(),
        count,
        params.connection_ratio,
        0.0,
        true,
    )?;
    let (offsets, indices) = rows.read(device, queue)?;
    let model = ParticleModel {
        positions: placement.positions,
        radii: state.radii,
        attachments: placement.attachments,
        connections: Connections { offsets, indices },
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
) -> Result<(SamplingBuffers, usize, usize, bool, usize, f64), GpuError> {
    let n = state.positions.len();
    let buffers = SamplingBuffers::new(device, queue, pipelines, field, &state, params, r0)?;
    drop(state);
    let backup = |label| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: n as u64 * 16,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    };
    let mut run = SamplingBatches {
        device,
        queue,
        pipelines,
        grid,
        params,
        skin: SKIN_IN_R0 * r0,
        r0,
        backup_state: backup("backup state"),
        backup_contact: backup("backup contact"),
        buffers,
        parity: 0,
        start_parity: 0,
        stale_rows: false,
        rebuilds: 0,
        neighbour_seconds: 0.0,
    };
    run.build_rows()?;
    let (iterations, converged) = run_batched(
        &mut run,
        params.max_iterations,
        BATCH as usize,
        |done, &(step_rms, radius_rms)| {
            Ok(converged_after(
                done, step_rms, radius_rms, params, progress,
            )?)
        },
    )?;
    Ok((
        run.buffers,
        run.parity,
        iterations,
        converged,
        run.rebuilds,
        run.neighbour_seconds,
    ))
}

/// Stage 1's batches on the GPU. The state alternates between two buffers
/// (`parity`); the Verlet check halts a batch when the rows may miss a
/// pair, and the next batch rebuilds them first.
struct SamplingBatches<'a> {
    device: &'a wgpu::Device,
    queue: &'a wgpu::Queue,
    pipelines: &'a SamplingPipelines,
    grid: &'a GridPipelines,
    params: &'a SamplingParams,
    skin: f32,
    r0: f32,
    buffers: SamplingBuffers,
    /// The current state at a batch's start, for a replay (a copy target
    /// that no kernel binds: raw).
    backup_state: wgpu::Buffer,
    /// The current contacts at a batch's start, likewise.
    backup_contact: wgpu::Buffer,
    /// Which of the two states is current.
    parity: usize,
    /// Which was current when the last batch started.
    start_parity: usize,
    /// The last batch was halted for a rebuild of the rows.
    stale_rows: bool,
    rebuilds: usize,
    neighbour_seconds: f64,
}

impl SamplingBatches<'_> {
    /// Rows from the current state, which becomes their build state.
    fn build_rows(&mut self) -> Result<(), GpuError> {
        let rows = self.grid.neighbour_rows(
            self.device,
            self.queue,
            self.buffers.states[self.parity].buffer(),
            self.buffers.count,
            self.params.force_cutoff,
            self.skin,
            false,
        )?;
        self.buffers
            .set_row_buffers(self.device, self.pipelines, rows)?;
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("sampling rows built"),
            });
        self.buffers.mark_built(&mut encoder, self.parity);
        self.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// Records `count` iterations from the current state, after copying it
    /// to the backups when `backup` (a batch's start) or from them (a replay).
    fn record(&self, count: usize, backup: bool) {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(if backup {
                    "sampling batch"
                } else {
                    "sampling replay"
                }),
            });
        let (state, contact) = (
            self.buffers.states[self.parity].buffer(),
            self.buffers.contacts[self.parity].buffer(),
        );
        if backup {
            encoder.copy_buffer_to_buffer(state, 0, &self.backup_state, 0, None);
            encoder.copy_buffer_to_buffer(contact, 0, &self.backup_contact, 0, None);
        } else {
            encoder.copy_buffer_to_buffer(&self.backup_state, 0, state, 0, None);
            encoder.copy_buffer_to_buffer(&self.backup_contact, 0, contact, 0, None);
        }
        let count = u32::try_from(count).unwrap_or(BATCH).min(BATCH);
        self.buffers
            .record_iterations(&mut encoder, self.pipelines, count, self.parity);
        self.queue.submit([encoder.finish()]);
    }
}

impl Batches for SamplingBatches<'_> {
    /// The RMS step of particles not held by the wall (in `r0`) and the RMS
    /// change of `ln r`.
    type Measure = (f32, f32);
    type Error = GpuError;

    fn run(&mut self, _: usize, count: usize) -> Result<Vec<(f32, f32)>, GpuError> {
        if self.stale_rows {
            let clock = Instant::now();
            self.build_rows()?;
            self.rebuilds += 1;
            self.neighbour_seconds += clock.elapsed().as_secs_f64();
        }
        self.start_parity = self.parity;
        self.record(count, true);
        let batch = u32::try_from(count).unwrap_or(BATCH).min(BATCH);
        let (sums, halt) = self.buffers.read_change(self.device, self.queue, batch)?;
        // A halt at slot s: iterations 0..=s ran, the rest did nothing.
        let ran = if halt == 0 { batch } else { halt.min(batch) } as usize;
        self.stale_rows = halt != 0;
        self.parity = (self.start_parity + ran) & 1;
        let n = self.buffers.len();
        Ok(sums
            .iter()
            .take(ran)
            .map(|&row| finish_change(row, n, self.r0))
            .collect())
    }

    fn replay(&mut self, count: usize) -> Result<(), GpuError> {
        self.parity = self.start_parity;
        self.record(count, false);
        self.parity = (self.start_parity + count) & 1;
        Ok(())
    }
}
