//! [`SolveDevice`] for [`GpuSolve`]: each call of the seam inside error
//! scopes of its own, and what those calls run.

use std::sync::Arc;

use glam::{Mat3, Vec3};
use tissue_core::field::SurfaceField;
use tissue_solve::coarse::{ElasticCoarse, SharedLaplacian};
use tissue_solve::stage2::Spring;
use tissue_solve::stage2::{DescentDots, Pairing, Pass, Plan, Potential};
use tissue_solve::{DeformParams, ForceModel, Iteration, RotationMethod, SolveDevice};

use super::{GpuDeformer, GpuSolve};
use crate::state::SLOTS;
use crate::support::Scopes;
use crate::{GpuError, Kernel, Params};

impl SolveDevice for GpuSolve {
    type Error = GpuError;

    /// One uniform slot and one row of step partials per iteration.
    fn batch(&self) -> usize {
        SLOTS as usize
    }

    fn coarse_rho(&self) -> Option<f32> {
        self.coarse_rho
    }

    fn elastic_rho(&self) -> Option<f32> {
        self.iteration
            .filter(|it| it.correct && it.force == ForceModel::Elastic)
            .and(self.elastic_coarse.as_deref())
            .map(ElasticCoarse::rho)
    }

    fn volume_smoother(&self) -> bool {
        self.elastic_host
            .as_ref()
            .is_some_and(|host| host.volume_smoother.is_some())
    }

    fn elastic_smoothed(&self) -> bool {
        self.elastic_rho().is_some()
            && self
                .elastic_coarse
                .as_ref()
                .is_some_and(|c| c.smoother().is_some())
    }

    /// Each particle's part (and held part) read back and summed on the
    /// host in `f64`.
    fn potential(&mut self) -> Result<Option<Potential>, GpuError> {
        self.scoped(|gpu| {
            let (parts, held) =
                gpu.state
                    .read_potential(&gpu.device, &gpu.queue, &gpu.pipelines)?;
            if parts.is_empty() {
                return Ok(None);
            }
            let parts = parts.iter().map(|&p| f64::from(p));
            Ok(Some(match held {
                Some(held) => {
                    let held: Vec<f64> = held.iter().map(|&p| f64::from(p)).collect();
                    Potential::paired(parts, &held)
                }
                None => Potential::of(parts),
            }))
        })
    }

    /// The iteration's kernels up to its combine and `descent_dots` in one
    /// submission, the parts read back and summed on the host in `f64`.
    fn descent_residual(&mut self) -> Result<Option<DescentDots>, GpuError> {
        if !self.elastic_smoothed() {
            return Ok(None);
        }
        self.scoped(Self::descent_residual_unscoped)
    }

    fn descent_direction(&mut self, beta: f32) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            gpu.descent_kernel(Kernel::DescentDirection, beta);
            Ok(())
        })
    }

    fn descent_move(&mut self, t: f32) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            gpu.descent_kernel(Kernel::DescentMove, t);
            Ok(())
        })
    }

    /// With a pairing, the springs held too ([`crate::DeformState::hold_springs`]).
    fn save(&mut self) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("save"),
                });
            for (from, to) in [
                (gpu.state.current.buffer(), &gpu.saved_current),
                (gpu.state.rotations.buffer(), &gpu.saved_rotations),
            ] {
                encoder.copy_buffer_to_buffer(from, 0, to, 0, None);
            }
            gpu.state.hold_springs(&mut encoder);
            gpu.queue.submit([encoder.finish()]);
            Ok(())
        })
    }

    fn restore(&mut self) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let state = &gpu.state;
            gpu.copy_all(
                "restore",
                [
                    (&gpu.saved_current, state.current.buffer()),
                    (&gpu.saved_rotations, state.rotations.buffer()),
                ],
            );
            Ok(())
        })
    }

    /// The coarse space, made for the CPU twin's parameters of `params`
    /// ([`GpuDeformer::cpu_twin`]).
    fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian {
        SharedLaplacian::new(
            plan.laplacian_key,
            plan,
            &GpuDeformer::cpu_twin(params),
            self.coarse.clone(),
            self.elastic_host
                .as_ref()
                .and_then(|host| host.volume_smoother),
        )
    }

    fn write_positions(&mut self, positions: &[Vec3], turn: Option<Mat3>) -> Result<(), GpuError> {
        self.scoped(|gpu| gpu.write_positions_unscoped(positions, turn))
    }

    /// Uploads them beside the loads; the correction is made again with
    /// them at the next elastic phase's start.
    fn set_springs(&mut self, springs: &[Spring]) -> Result<(), GpuError> {
        // Its operator holds the stiffness of the springs it was made with:
        // kept where only their points move.
        let same = self
            .elastic_host
            .as_ref()
            .is_some_and(|host| Spring::all_same_stiffness(springs, &host.springs));
        if !same {
            self.forget_elastic_correction(springs);
        }
        self.set_springs_keeping_correction(springs)
    }

    fn set_springs_keeping_correction(&mut self, springs: &[Spring]) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let device = gpu.device.clone();
            gpu.state
                .set_loads(&device, &gpu.pipelines, &gpu.loads, springs)?;
            match &mut gpu.elastic_host {
                Some(host) => springs.clone_into(&mut host.springs),
                None => gpu.forget_elastic_correction(springs),
            }
            Ok(())
        })
    }

    /// Written over the body forces' part of the loads buffer where it
    /// holds one per particle (the springs after them kept), the buffer
    /// made again where it does not.
    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let device = gpu.device.clone();
            loads.clone_into(&mut gpu.loads);
            gpu.state
                .write_loads(&device, &gpu.queue, &gpu.pipelines, loads)
        })
    }

    fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let device = gpu.device.clone();
            gpu.state.set_observation(&device, &gpu.pipelines, field)
        })
    }

    /// A pairing on a state without springs gives it zero springs first:
    /// the pairing writes them.
    fn set_pairing(&mut self, pairing: Option<&Pairing>) -> Result<(), GpuError> {
        self.scoped(|gpu| {
            let device = gpu.device.clone();
            if pairing.is_some() && !gpu.state.holds_springs() {
                let zero = vec![Spring::ZERO; gpu.state.len()];
                gpu.state
                    .set_loads(&device, &gpu.pipelines, &gpu.loads, &zero)?;
            }
            gpu.state.set_pairing(&device, &gpu.pipelines, pairing)
        })
    }

    fn begin(&mut self, iteration: Iteration) -> Result<(), GpuError> {
        self.scoped(|gpu| gpu.begin_unscoped(iteration))
    }

    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, GpuError> {
        self.scoped(|gpu| gpu.run_unscoped(omegas))
    }

    fn replay(&mut self, count: usize) -> Result<(), GpuError> {
        self.scoped(|gpu| gpu.replay_unscoped(count))
    }

    fn read_positions(&mut self) -> Result<Vec<Vec3>, GpuError> {
        self.scoped(Self::read_positions_unscoped)
    }

    fn read_rotations(&mut self) -> Result<Vec<Mat3>, GpuError> {
        self.scoped(|gpu| gpu.state.read_rotations(&gpu.device, &gpu.queue))
    }

    fn write_rotations(&mut self, rotations: &[Mat3]) -> Result<(), GpuError> {
        self.scoped(|gpu| gpu.state.write_rotations(&gpu.queue, rotations))
    }

    /// The host's copy, shared; the device's buffers are made from it.
    type Correction = Option<Arc<ElasticCoarse>>;

    fn correction(&self) -> Self::Correction {
        self.elastic_coarse.clone()
    }

    /// Uploaded again unless it is the correction in hand.
    fn put_correction(&mut self, correction: Self::Correction) -> Result<(), GpuError> {
        let same = match (&correction, &self.elastic_coarse) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        };
        if same {
            return Ok(());
        }
        self.scoped(|gpu| {
            let device = gpu.device.clone();
            match &correction {
                Some(coarse) => gpu
                    .state
                    .linearise_elastic(&device, &gpu.pipelines, coarse)?,
                None => gpu.state.forget_elastic_linearisation(),
            }
            gpu.elastic_coarse = correction;
            Ok(())
        })
    }

    fn reset(&mut self) -> Result<(), GpuError> {
        self.scoped(Self::reset_unscoped)
    }
}

/// What [`SolveDevice`] asks, each call inside error scopes of its own
/// ([`GpuSolve::scoped`]).
impl GpuSolve {
    /// `work`, with wgpu's validation and out-of-memory errors caught as
    /// [`GpuError`]s: every call the tracker makes fails with a typed
    /// error rather than wgpu's uncaptured-error handler.
    fn scoped<T>(
        &mut self,
        work: impl FnOnce(&mut Self) -> Result<T, GpuError>,
    ) -> Result<T, GpuError> {
        let scope = Scopes::push(&self.device);
        let done = work(self);
        scope.pop()?;
        done
    }

    /// Drops the elastic correction (made again at the next elastic
    /// phase's start) with the springs `springs` now in place.
    fn forget_elastic_correction(&mut self, springs: &[Spring]) {
        self.elastic_coarse = None;
        self.state.forget_elastic_linearisation();
        if let Some(host) = &mut self.elastic_host {
            springs.clone_into(&mut host.springs);
        }
    }

    /// Copies each pair's whole first buffer into its second, in one
    /// submission labelled `label`.
    fn copy_all<const N: usize>(&self, label: &str, pairs: [(&wgpu::Buffer, &wgpu::Buffer); N]) {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        for (from, to) in pairs {
            encoder.copy_buffer_to_buffer(from, 0, to, 0, None);
        }
        self.queue.submit([encoder.finish()]);
    }

    fn descent_residual_unscoped(&mut self) -> Result<Option<DescentDots>, GpuError> {
        let Some(it) = self.iteration.filter(|it| it.force == ForceModel::Elastic) else {
            return Ok(None);
        };
        let device = self.device.clone();
        self.state.ensure_descent(&device, &self.pipelines)?;
        let (device, queue) = (&self.device, &self.queue);
        let state = &self.state;
        // Undamped, whatever the phase's damping.
        let params = Params {
            volume_damping: 1.0,
            ..state.params(it.force, it.alpha, 1.0, 0)
        };
        state.write_params(queue, 0, params);
        let passes: Vec<Pass> = state
            .passes()
            .into_iter()
            .filter(|pass| !matches!(pass, Pass::StepNorms | Pass::Combine | Pass::UpdateNorms))
            .collect();
        let mut kernels = Kernel::of_passes(&passes);
        kernels.push(Kernel::DescentDots);
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("descent residual"),
        });
        self.pipelines
            .record_kernels(&mut encoder, state, &kernels, 0);
        queue.submit([encoder.finish()]);
        let parts = state
            .descent
            .dot_parts
            .read(device, queue, &state.readback)?;
        Ok(Some(DescentDots::of(
            parts.iter().map(|part| part.map(f64::from)),
        )))
    }

    /// One of `descent.wgsl`'s per-particle kernels with `value` (beta or
    /// t) as its parameter.
    fn descent_kernel(&self, kernel: Kernel, value: f32) {
        let state = &self.state;
        let it = self.iteration;
        let params = state.params(
            it.map_or(ForceModel::Elastic, |it| it.force),
            it.map_or(0.0, |it| it.alpha),
            value,
            0,
        );
        state.write_params(&self.queue, 0, params);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(kernel.name()),
            });
        self.pipelines
            .record_kernels(&mut encoder, state, &[kernel], 0);
        self.queue.submit([encoder.finish()]);
    }

    fn write_positions_unscoped(
        &mut self,
        positions: &[Vec3],
        turn: Option<Mat3>,
    ) -> Result<(), GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        self.state.write_current(queue, positions)?;
        if let Some(turn) = turn {
            // The warm-started rotations turn with the surface too, on the
            // GPU: one matrix up, one dispatch.
            self.state.write_turn(queue, turn)?;
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("turn rotations"),
            });
            self.pipelines
                .dispatch(&mut encoder, &self.state, crate::Kernel::TurnRotations, 0);
            queue.submit([encoder.finish()]);
        }
        Ok(())
    }

    fn begin_unscoped(&mut self, iteration: Iteration) -> Result<(), GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        if ElasticCoarse::is_needed_anew(self.elastic_coarse.as_deref(), &iteration) {
            self.linearise(iteration)?;
        }
        self.iteration = Some(iteration);
        self.state.set_phase(iteration.force, iteration.correct);
        self.state.set_rotations(iteration.rotations);
        let state = &self.state;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("solve start"),
        });
        encoder.copy_buffer_to_buffer(state.current.buffer(), 0, state.previous.buffer(), 0, None);
        queue.submit([encoder.finish()]);
        Ok(())
    }

    fn run_unscoped(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        let Some(it) = self.iteration else {
            return Ok(Vec::new());
        };
        let state = &self.state;
        let batch = omegas.len().min(SLOTS as usize) as u32;
        for (slot, &omega) in (0..batch).zip(omegas) {
            let params = Params {
                volume_damping: it.damping,
                ..state.params(it.force, it.alpha, omega, slot)
            };
            state.write_params(queue, slot, params);
        }
        self.slots = batch;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("solve batch"),
        });
        encoder.copy_buffer_to_buffer(state.current.buffer(), 0, &self.backup_current, 0, None);
        encoder.copy_buffer_to_buffer(state.previous.buffer(), 0, &self.backup_previous, 0, None);
        if it.rotations == RotationMethod::WarmPolar {
            encoder.copy_buffer_to_buffer(
                state.rotations.buffer(),
                0,
                &self.backup_rotations,
                0,
                None,
            );
        }
        self.pipelines.record_iterations(&mut encoder, state, batch);
        queue.submit([encoder.finish()]);
        let n = state.len() as f64;
        Ok(state
            .read_partials(device, queue, batch)?
            .iter()
            .map(|row| {
                let step = row.iter().map(|x| x[0]).fold(0.0f32, f32::max).sqrt();
                let sum: f64 = row.iter().map(|x| f64::from(x[1])).sum();
                (step, (sum / n).sqrt() as f32)
            })
            .collect())
    }

    fn replay_unscoped(&mut self, count: usize) -> Result<(), GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        let state = &self.state;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("solve replay"),
        });
        encoder.copy_buffer_to_buffer(&self.backup_current, 0, state.current.buffer(), 0, None);
        encoder.copy_buffer_to_buffer(&self.backup_previous, 0, state.previous.buffer(), 0, None);
        if self
            .iteration
            .is_some_and(|it| it.rotations == RotationMethod::WarmPolar)
        {
            encoder.copy_buffer_to_buffer(
                &self.backup_rotations,
                0,
                state.rotations.buffer(),
                0,
                None,
            );
        }
        let count = u32::try_from(count).map_or(self.slots, |c| c.min(self.slots));
        self.pipelines.record_iterations(&mut encoder, state, count);
        queue.submit([encoder.finish()]);
        crate::wait(device)
    }

    pub(super) fn read_positions_unscoped(&mut self) -> Result<Vec<Vec3>, GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        self.state.read_positions(device, queue)
    }

    fn reset_unscoped(&mut self) -> Result<(), GpuError> {
        let (device, queue) = (self.device.clone(), self.queue.clone());
        let (device, queue) = (&device, &queue);
        // The rotations start from the identity again, as the CPU path's.
        self.state
            .write_rotations(queue, &vec![Mat3::IDENTITY; self.state.len()])?;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("reset"),
        });
        encoder.copy_buffer_to_buffer(
            self.state.rest.buffer(),
            0,
            self.state.current.buffer(),
            0,
            None,
        );
        queue.submit([encoder.finish()]);
        crate::wait(device)
    }
}
