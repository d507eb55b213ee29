//! `tissue_cpu::deformation::Deformer::solve` on the GPU.

use std::time::Instant;

use glam::Vec3;
use tissue_core::{ParticleModel, SurfaceMesh};
use tissue_cpu::deformation::{
    Chebyshev, DeformParams, DeformReport, FrameHistory, LowModes, Plan, StopReason, StoppingRule,
    check_same_topology, deflation_modes, predict,
};

use crate::state::SLOTS;
use crate::{DeformState, GpuError, Pipelines};

/// Stage 2 on the GPU for one particle model: the same step `alpha` from
/// `lambda_max`, the same spectral Chebyshev `rho` and the same stopping rule
/// as the CPU [`tissue_cpu::deformation::Deformer`], with rotations always by
/// the SVD (`RotationMethod::Svd`; `params.rotations` is not consulted).
/// With `params.deflation`, the same modes as the CPU path's deflate the
/// plain step every iteration, with the same deflated `rho` and the same
/// step for the rule (the update made, after the combine). The two-level
/// solve (`params.coarse`) has no kernels yet: the GPU deflates where the
/// CPU path would use its coarse space. A
/// new frame starts where `tissue_cpu::deformation::predict` puts it, the
/// CPU path's own function: the positions are read back at the end of every
/// solve and the prediction is uploaded with the new control points (both
/// frame boundaries). The step norms are read back once per [`SLOTS`]
/// iterations; when the rule held inside a batch, the batch is replayed up
/// to that iteration, so the iteration count equals the CPU rule's.
#[derive(Debug)]
pub struct GpuDeformer {
    pipelines: Pipelines,
    state: DeformState,
    surface: SurfaceMesh,
    /// Triangle and barycentric coordinates of each control point, in particle order.
    attachments: Vec<(u32, [f32; 3])>,
    /// Free particles, spectrum, size and float floor, as the CPU path has them.
    plan: Plan,
    params: DeformParams,
    /// The modes deflated every iteration, as the CPU path computes them;
    /// `None` without deflation or when none came out.
    modes: Option<LowModes>,
    backup_current: wgpu::Buffer,
    backup_previous: wgpu::Buffer,
    /// The control particles, in the order of `attachments`.
    controls: Vec<usize>,
    /// The positions on the GPU at the last frame boundary.
    current: Vec<Vec3>,
    /// The last converged solutions, for the prediction.
    history: FrameHistory,
    rest: Vec<Vec3>,
}

impl GpuDeformer {
    /// The parameters under which the CPU path runs the solve the GPU runs
    /// under `params`, its twin: the same, without the two-level solve
    /// (`coarse`), which has no kernels yet (the GPU deflates instead).
    pub fn cpu_twin(params: &DeformParams) -> DeformParams {
        DeformParams {
            coarse: 0.0,
            ..params.clone()
        }
    }

    /// Checks `model` and `params`, estimates the Laplacian's extreme
    /// eigenvalues and, with `params.deflation`, its lowest modes (on the
    /// CPU, by the CPU path's own calls, so both deflate the same modes),
    /// compiles the kernels and uploads the model and the modes.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &ParticleModel,
        params: DeformParams,
    ) -> Result<Self, GpuError> {
        params.validate()?;
        let plan = Plan::new(model)?;
        let attachments: Vec<(u32, [f32; 3])> = model
            .attachments
            .iter()
            .flatten()
            .map(|a| (a.triangle, a.barycentric))
            .collect();
        let pipelines = Pipelines::new(device)?;
        let mut state = DeformState::new(device, queue, &pipelines, model, &plan.free)?;
        if params.coarse > 0.0 {
            log::info!(
                "the GPU path has no two-level solve yet (coarse {}): it deflates {} modes instead",
                params.coarse,
                params.deflation
            );
        }
        let modes = deflation_modes(model, &plan, &params);
        if let Some(m) = &modes {
            let scales: Vec<f32> = m
                .gain_scales(plan.contraction(&params))
                .map(|scale| scale as f32)
                .collect();
            state.set_modes(device, &pipelines, m.vectors(), &scales)?;
        }
        let backup = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: state.len() as u64 * 16,
                usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let history = FrameHistory::at_rest(&model.positions, params.history);
        let controls = model
            .attachments
            .iter()
            .enumerate()
            .filter_map(|(i, a)| a.map(|_| i))
            .collect();
        Ok(Self {
            backup_current: backup("backup current"),
            backup_previous: backup("backup previous"),
            pipelines,
            state,
            surface: model.surface.clone(),
            attachments,
            plan,
            params,
            modes,
            controls,
            current: model.positions.clone(),
            history,
            rest: model.positions.clone(),
        })
    }

    /// The kernels.
    pub fn pipelines(&self) -> &Pipelines {
        &self.pipelines
    }

    /// The buffers.
    pub fn state(&self) -> &DeformState {
        &self.state
    }

    /// The lowest Laplacian modes deflated every iteration, if any (the
    /// CPU path's `Deformer::modes`).
    pub fn modes(&self) -> Option<&LowModes> {
        self.modes.as_ref()
    }

    /// Bytes of every GPU buffer the deformer holds: the state's (with the
    /// modes, when deflated), and the two backups a batch is replayed from.
    pub fn buffer_bytes(&self) -> u64 {
        self.state.buffer_bytes() + self.backup_current.size() + self.backup_previous.size()
    }

    /// The model's size (bounding-box diagonal at rest).
    pub fn size(&self) -> f32 {
        self.plan.size
    }

    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_min(&self) -> f32 {
        self.plan.lambda_min
    }

    /// Largest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_max(&self) -> f32 {
        self.plan.lambda_max
    }

    /// Places the control points on `deformed`, the rest surface with moved
    /// vertices, predicts the free particles as the CPU path does (unless
    /// `extrapolate` is off) and uploads them (a frame boundary).
    pub fn set_surface(
        &mut self,
        queue: &wgpu::Queue,
        deformed: &SurfaceMesh,
    ) -> Result<(), GpuError> {
        check_same_topology(&self.surface, deformed)?;
        let points: Vec<Vec3> = self
            .attachments
            .iter()
            .map(|&(t, bary)| deformed.point_on(t as usize, bary))
            .collect();
        if !self.params.extrapolate {
            for (&i, &q) in self.controls.iter().zip(&points) {
                self.current[i] = q;
            }
            return self.state.set_control_points(queue, &points);
        }
        let controls: Vec<(usize, Vec3)> = self
            .controls
            .iter()
            .copied()
            .zip(points.iter().copied())
            .collect();
        let (prediction, _) = predict(
            &self.current,
            &self.history,
            &controls,
            self.params.tolerance * self.plan.size,
        );
        for (i, q) in prediction.into_iter().enumerate() {
            if self.plan.free[i] {
                self.current[i] = q;
            }
        }
        for (i, q) in controls {
            self.current[i] = q;
        }
        self.state.write_current(queue, &self.current)
    }

    /// The positions at the end of the last solve (read back by it), or
    /// after the last `set_surface` or `reset`.
    pub fn host_positions(&self) -> &[Vec3] {
        &self.current
    }

    /// Reads the current positions back (a frame boundary).
    pub fn positions(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<Vec3>, GpuError> {
        self.state.read_positions(device, queue)
    }

    /// Reads back each particle's rotation (rest offsets onto current
    /// offsets) from the last iteration, as
    /// `tissue_cpu::deformation::Deformer::rotations` has them: what
    /// `Embedding::moved` and `RigidBinding::motion` need. Stalls until the
    /// GPU is done: frame boundaries only.
    pub fn read_rotations(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<glam::Mat3>, GpuError> {
        self.state.read_rotations(device, queue)
    }

    /// Back to the rest shape.
    pub fn reset(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<(), GpuError> {
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("reset"),
        });
        encoder.copy_buffer_to_buffer(&self.state.rest, 0, &self.state.current, 0, None);
        queue.submit([encoder.finish()]);
        self.current.clone_from(&self.rest);
        self.history = FrameHistory::at_rest(&self.rest, self.params.history);
        crate::wait(device)
    }

    /// Iterates until the stopping rule of `Deformer::solve` holds or the cap
    /// is reached (see the type's doc for what differs).
    pub fn solve(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<DeformReport, GpuError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let report = self.iterate(device, queue);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(e.into());
        }
        let report = report?;
        self.current = self.state.read_positions(device, queue)?;
        self.history
            .record(&self.current, report.converged, self.params.history);
        Ok(report)
    }

    fn iterate(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<DeformReport, GpuError> {
        let started = Instant::now();
        let p = &self.params;
        let alpha = self.plan.alpha(p);
        // Deflated, the rest of the spectrum sets rho, and the state's
        // iteration measures the update made (`Deformer::solve`).
        let rho = self.plan.solve_rho(p, self.modes.as_ref(), None);
        let (mut chebyshev, mut rule) = (
            Chebyshev::with_rho(p, rho),
            StoppingRule::with_rho(&self.plan, p, rho),
        );
        let state = &self.state;
        let n = state.len() as f64;
        let mut stopped_by = StopReason::IterationCap;
        let mut iterations = 0;

        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("solve start"),
        });
        encoder.copy_buffer_to_buffer(&state.current, 0, &state.previous, 0, None);
        queue.submit([encoder.finish()]);

        while iterations < p.max_iterations {
            let batch = SLOTS.min((p.max_iterations - iterations) as u32);
            // The batch replays exactly, so omega may advance ahead of the rule.
            let mut lookahead = chebyshev.clone();
            for slot in 0..batch {
                let omega = lookahead.omega(iterations + slot as usize + 1);
                state.write_params(queue, slot, state.params(p.force, alpha, omega, slot));
            }
            chebyshev = lookahead;
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("solve batch"),
            });
            encoder.copy_buffer_to_buffer(&state.current, 0, &self.backup_current, 0, None);
            encoder.copy_buffer_to_buffer(&state.previous, 0, &self.backup_previous, 0, None);
            self.pipelines.record_iterations(&mut encoder, state, batch);
            queue.submit([encoder.finish()]);
            let partials = state.read_partials(device, queue, batch)?;

            let mut stop_after = None;
            for (k, row) in partials.iter().enumerate() {
                let step = row.iter().map(|x| x[0]).fold(0.0f32, f32::max).sqrt();
                let sum: f64 = row.iter().map(|x| f64::from(x[1])).sum();
                iterations += 1;
                if let Some(reason) = rule.after(step, (sum / n).sqrt() as f32) {
                    stopped_by = reason;
                    stop_after = Some(k as u32 + 1);
                    break;
                }
            }
            if let Some(done) = stop_after {
                if done < batch {
                    // Replay the batch up to the iteration where the rule held.
                    let mut encoder =
                        device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                            label: Some("solve replay"),
                        });
                    encoder.copy_buffer_to_buffer(&self.backup_current, 0, &state.current, 0, None);
                    encoder.copy_buffer_to_buffer(
                        &self.backup_previous,
                        0,
                        &state.previous,
                        0,
                        None,
                    );
                    self.pipelines.record_iterations(&mut encoder, state, done);
                    queue.submit([encoder.finish()]);
                    crate::wait(device)?;
                }
                break;
            }
        }
        Ok(rule.report(iterations, stopped_by, started.elapsed().as_secs_f64()))
    }
}
