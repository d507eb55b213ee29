//! One stage-2 tracker for every device: the frame loop (the deformed
//! surface in, the prediction, the solve with its acceleration and stopping
//! rule, the history) written once, over [`SolveDevice`], which a device
//! implements with its kernels and buffers.

use std::time::Instant;

use glam::{Mat3, Vec3};
use tissue_core::{Error, ParticleModel, SurfaceMesh};

use crate::acceleration::{Chebyshev, StoppingRule};
use crate::controls::check_same_topology;
use crate::modes::LowModes;
use crate::params::{DeformParams, ForceModel, RotationMethod};
use crate::plan::Plan;
use crate::predict::{FrameHistory, predict};
use crate::report::{DeformReport, StopReason};
use crate::svd3::rotation_of;

/// What every iteration of one solve runs with, from the plan and the
/// parameters at its start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iteration {
    /// The force model.
    pub force: ForceModel,
    /// How the rotations are found.
    pub rotations: RotationMethod,
    /// The step `alpha = sigma / m` ([`Plan::alpha`]).
    pub alpha: f32,
    /// `c alpha`, what turns an error into the plain step ([`Plan::contraction`]).
    pub contraction: f32,
}

/// What a device does for a stage-2 solve: kernels and buffers, nothing
/// else. The iteration is the same on every device: rotations, force, the
/// plain step, the correction (deflation or the coarse space, if any), the
/// Chebyshev combine; its state is `current` and `previous` positions and
/// the rotations.
pub trait SolveDevice {
    /// The device's error (`std::convert::Infallible` where nothing can fail).
    type Error;
    /// What every call needs besides the device's own state (the GPU's
    /// `wgpu::Device` and `Queue`; nothing on the CPU).
    type Context<'a>: Copy;

    /// The most iterations one [`SolveDevice::run`] may be asked for.
    fn batch(&self) -> usize;

    /// The lowest Laplacian modes the device deflates every iteration, if any.
    fn modes(&self) -> Option<&LowModes> {
        None
    }

    /// The two-level iteration's contraction, where the device runs one.
    fn coarse_rho(&self) -> Option<f32> {
        None
    }

    /// Sets every particle's position at a frame boundary (the prediction
    /// and the control points). `turn`, when the positions were carried by
    /// the surface's linear move, is that move's rotation: warm-started
    /// rotations turn with it.
    fn write_positions(
        &mut self,
        cx: Self::Context<'_>,
        positions: &[Vec3],
        turn: Option<Mat3>,
    ) -> Result<(), Self::Error>;

    /// Starts a solve from the current positions (`previous = current`)
    /// whose iterations run with `iteration`.
    fn begin(&mut self, cx: Self::Context<'_>, iteration: Iteration) -> Result<(), Self::Error>;

    /// Runs one iteration per Chebyshev weight in `omegas` (at most
    /// [`SolveDevice::batch`]) and returns, per iteration, the largest and
    /// the RMS step the stopping rule measures. Keeps what
    /// [`SolveDevice::replay`] needs.
    fn run(
        &mut self,
        cx: Self::Context<'_>,
        omegas: &[f32],
    ) -> Result<Vec<(f32, f32)>, Self::Error>;

    /// Puts the state back where the last [`SolveDevice::run`] started and
    /// runs its first `count` iterations again, with the same weights: the
    /// stopping rule held inside the batch.
    fn replay(&mut self, cx: Self::Context<'_>, count: usize) -> Result<(), Self::Error>;

    /// The current positions.
    fn read_positions(&mut self, cx: Self::Context<'_>) -> Result<Vec<Vec3>, Self::Error>;

    /// Back to the rest shape, rotations included.
    fn reset(&mut self, cx: Self::Context<'_>) -> Result<(), Self::Error>;
}

/// Stage 2 for one particle model on one device: the control points follow
/// each deformed surface, the free particles start where [`predict`] puts
/// them and are solved until the stopping rule holds. The same iteration
/// count on every device: a batch in which the rule held is replayed up to
/// that iteration.
#[derive(Debug, Clone)]
pub struct Tracker<D> {
    device: D,
    plan: Plan,
    params: DeformParams,
    surface: SurfaceMesh,
    /// Each control particle and its triangle and barycentric coordinates.
    attachments: Vec<(usize, u32, [f32; 3])>,
    rest: Vec<Vec3>,
    /// The positions at the last frame boundary.
    current: Vec<Vec3>,
    /// The last converged solutions, for the prediction.
    history: FrameHistory,
}

impl<D: SolveDevice> Tracker<D> {
    /// Checks `params` and `model`, works out the plan, and prepares the
    /// device by `prepare` from them.
    pub fn new<E: From<Error>>(
        model: &ParticleModel,
        params: DeformParams,
        prepare: impl FnOnce(&Plan, &DeformParams) -> Result<D, E>,
    ) -> Result<Self, E> {
        params.validate()?;
        let plan = Plan::new(model)?;
        let device = prepare(&plan, &params)?;
        let attachments = model
            .attachments
            .iter()
            .enumerate()
            .filter_map(|(i, a)| a.map(|a| (i, a.triangle, a.barycentric)))
            .collect();
        Ok(Self {
            device,
            history: FrameHistory::at_rest(&model.positions, params.history),
            plan,
            params,
            surface: model.surface.clone(),
            attachments,
            rest: model.positions.clone(),
            current: model.positions.clone(),
        })
    }

    /// The device's kernels and buffers.
    pub fn device(&self) -> &D {
        &self.device
    }

    /// The solve's plan: free particles, spectrum, size, float floor.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        &self.params
    }

    /// Changes the parameters of the next solves (the tolerance between
    /// frames, say); the state is kept. What the device prepared once (the
    /// coarse space, the modes, the step) stays as it was prepared.
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), Error> {
        params.validate()?;
        self.params = params;
        Ok(())
    }

    /// Rest particle positions.
    pub fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// The positions at the last frame boundary: after the last solve, or
    /// the last `set_surface` or `reset`.
    pub fn positions(&self) -> &[Vec3] {
        &self.current
    }

    /// The contraction the Chebyshev weights and the stopping rule use.
    pub fn rho(&self) -> f32 {
        self.plan
            .solve_rho(&self.params, self.device.modes(), self.device.coarse_rho())
    }

    /// Places the control points on `deformed`, which must be the rest
    /// surface with moved vertices (same vertex count, same triangles), and
    /// the free particles where the prediction puts them (unless
    /// `extrapolate` is off).
    pub fn set_surface<E: From<Error> + From<D::Error>>(
        &mut self,
        cx: D::Context<'_>,
        deformed: &SurfaceMesh,
    ) -> Result<(), E> {
        check_same_topology(&self.surface, deformed)?;
        let controls: Vec<(usize, Vec3)> = self
            .attachments
            .iter()
            .map(|&(i, t, bary)| (i, deformed.point_on(t as usize, bary)))
            .collect();
        let mut turn = None;
        if self.params.extrapolate {
            let (prediction, linear) = predict(
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
            turn = Some(rotation_of(linear));
        }
        for (i, q) in controls {
            self.current[i] = q;
        }
        Ok(self.device.write_positions(cx, &self.current, turn)?)
    }

    /// Iterates until the stopping rule holds or the cap is reached, then
    /// reads the positions back and records them for the next prediction.
    pub fn solve(&mut self, cx: D::Context<'_>) -> Result<DeformReport, D::Error> {
        let started = Instant::now();
        let p = &self.params;
        let rho = self.rho();
        let (mut chebyshev, mut rule) = (
            Chebyshev::with_rho(p, rho),
            StoppingRule::with_rho(&self.plan, p, rho),
        );
        let mut stopped_by = StopReason::IterationCap;
        let mut iterations = 0;
        let iteration = Iteration {
            force: p.force,
            rotations: p.rotations,
            alpha: self.plan.alpha(p),
            contraction: self.plan.contraction(p),
        };
        self.device.begin(cx, iteration)?;
        while iterations < p.max_iterations {
            let batch = self.device.batch().clamp(1, p.max_iterations - iterations);
            // A batch replays exactly, so the weights may run ahead of the rule.
            let omegas: Vec<f32> = (1..=batch)
                .map(|k| chebyshev.omega(iterations + k))
                .collect();
            let steps = self.device.run(cx, &omegas)?;
            let mut stop_after = None;
            for (k, &(step, rms)) in steps.iter().enumerate() {
                iterations += 1;
                if let Some(reason) = rule.after(step, rms) {
                    stopped_by = reason;
                    stop_after = Some(k + 1);
                    break;
                }
            }
            if let Some(done) = stop_after {
                if done < batch {
                    self.device.replay(cx, done)?;
                }
                break;
            }
        }
        let report = rule.report(iterations, stopped_by, started.elapsed().as_secs_f64());
        self.current = self.device.read_positions(cx)?;
        self.history
            .record(&self.current, report.converged, self.params.history);
        Ok(report)
    }

    /// Back to the rest shape (no warm start, no history but the rest).
    pub fn reset(&mut self, cx: D::Context<'_>) -> Result<(), D::Error> {
        self.device.reset(cx)?;
        self.current.clone_from(&self.rest);
        self.history = FrameHistory::at_rest(&self.rest, self.params.history);
        Ok(())
    }
}
