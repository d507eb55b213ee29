//! One stage-2 tracker for every device: the frame loop (the deformed
//! surface in, the prediction, the solve with its acceleration and stopping
//! rule, the history) written once, over [`SolveDevice`], which a device
//! implements with its kernels and buffers.

use std::time::Instant;

use glam::{Mat3, Vec3};
use tissue_core::field::SurfaceField;
use tissue_core::{Connections, Error, ParamError, ParticleModel, SurfaceMesh};

use crate::coarse::laplacian::SharedLaplacian;
use crate::model::svd3::rotation_of;
use crate::stage2::controls::check_same_topology;
use crate::stage2::pairing::Pairing;
use crate::stage2::params::{DeformParams, ForceModel};
use crate::stage2::phase::{PhaseRun, Steps, WARM_ITERATIONS};
use crate::stage2::plan::Plan;
use crate::stage2::predict::{FrameHistory, predict};
use crate::stage2::report::{DeformReport, PrepareStage, SolveStep, StopReason};

use crate::stage2::device::Potential;
pub use crate::stage2::device::SolveDevice;

pub(crate) mod conjugate;
mod descent;

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
    /// Each control particle (an observed surface particle) and its
    /// triangle and barycentric coordinates.
    attachments: Vec<(usize, u32, [f32; 3])>,
    /// Whether part of the skin is free (a surface particle that is no
    /// control point).
    free_skin: bool,
    rest: Vec<Vec3>,
    /// The positions at the last frame boundary.
    current: Vec<Vec3>,
    /// The last converged solutions, for the prediction.
    history: FrameHistory,
    /// The state is a converged solve's with the elastic force, so an
    /// elastic solve may start from it without the shear phase.
    elastic_warm: bool,
    /// The warm start is a caller's guess ([`Tracker::warm_start`]), not
    /// a converged solve's: its elastic phase is watched.
    guessed: bool,
    /// Whether that solve's elastic phase ran with the device's correction
    /// (a warm frame runs as it did).
    elastic_correct: bool,
    /// The model's connections, with the elastic force: the shear phase
    /// measures the volumes' misfit ([`crate::stage2::params::SolverTuning::shear_volume_share`]).
    connections: Option<Connections>,
}

/// A tracker's state at a frame boundary ([`Tracker::checkpoint`]), `C`
/// its device's [`SolveDevice::Correction`].
#[derive(Debug, Clone)]
pub(crate) struct Checkpoint<C> {
    current: Vec<Vec3>,
    /// The device's rotations there: points carried after
    /// [`Tracker::back_to`] move as they did at the checkpoint.
    rotations: Vec<Mat3>,
    /// The device's elastic correction there: the next frame's solve
    /// that keeps its correction keeps this one.
    correction: C,
    history: FrameHistory,
    load: Vec3,
    elastic_warm: bool,
    guessed: bool,
    elastic_correct: bool,
}

impl<D: SolveDevice> Tracker<D> {
    /// Checks `params` and `model`, works out the plan, and prepares the
    /// device by `prepare` from them.
    pub fn new<E: From<Error>>(
        model: &ParticleModel,
        params: DeformParams,
        prepare: impl FnOnce(&Plan, &DeformParams) -> Result<D, E>,
    ) -> Result<Self, E> {
        Self::new_observed(model, params, &mut |_| {}, |plan, params, _| {
            prepare(plan, params)
        })
    }

    /// [`Tracker::new`], telling `observe` as each stage of the
    /// preparation starts ([`PrepareStage`]): the plan's stages here, the
    /// device's from `prepare`, which is handed `observe` to tell them.
    pub fn new_observed<E: From<Error>>(
        model: &ParticleModel,
        params: DeformParams,
        observe: &mut dyn FnMut(PrepareStage),
        prepare: impl FnOnce(&Plan, &DeformParams, &mut dyn FnMut(PrepareStage)) -> Result<D, E>,
    ) -> Result<Self, E> {
        Self::new_shared(model, params, None, observe, prepare)
    }

    /// [`Tracker::new_observed`] with what another solver of the same
    /// connections and free particles prepared ([`SharedLaplacian`]): the
    /// plan takes its spectrum where it matches, and `prepare` is the
    /// device's to take its coarse space
    /// ([`coarse_space_shared`](crate::coarse::laplacian::coarse_space_shared)).
    pub fn new_shared<E: From<Error>>(
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
        observe: &mut dyn FnMut(PrepareStage),
        prepare: impl FnOnce(&Plan, &DeformParams, &mut dyn FnMut(PrepareStage)) -> Result<D, E>,
    ) -> Result<Self, E> {
        params.validate().map_err(Error::from)?;
        let plan = Plan::for_params_shared(
            model,
            &params,
            shared.map(SharedLaplacian::spectrum),
            shared.and_then(SharedLaplacian::elastic),
            observe,
        )?;
        let device = prepare(&plan, &params, observe)?;
        // The control points: the observed surface particles.
        let attachments = model
            .attachments
            .iter()
            .enumerate()
            .filter(|&(i, _)| plan.controls[i])
            .filter_map(|(i, a)| a.map(|a| (i, a.triangle, a.barycentric)))
            .collect();
        let connections = plan.elastic.is_some().then(|| model.connections.clone());
        let free_skin = model
            .attachments
            .iter()
            .zip(&plan.controls)
            .any(|(a, &control)| a.is_some() && !control);
        Ok(Self {
            free_skin,
            device,
            history: FrameHistory::at_rest(&model.positions, params.tuning.history),
            plan,
            params,
            surface: model.surface.clone(),
            attachments,
            rest: model.positions.clone(),
            current: model.positions.clone(),
            elastic_warm: false,
            guessed: false,
            elastic_correct: true,
            connections,
        })
    }

    /// What the solve prepared that another tracker of the same model may
    /// take ([`Tracker::new_shared`]): what depends only on the connections
    /// and the free particles (the Laplacian's spectrum and the device's
    /// coarse space), for any rest shape, and the elastic model, for the
    /// same rest shape at any Poisson ratio.
    pub fn shared_laplacian(&self) -> SharedLaplacian {
        self.device
            .shared_laplacian(&self.plan, &self.params)
            .with_elastic(&self.plan)
    }

    /// The potential the elastic force descends at the current positions
    /// ([`SolveDevice::potential`]); `None` without the elastic model.
    pub fn potential(&mut self) -> Result<Option<f64>, D::Error> {
        Ok(self.potential_parts()?.map(|p| p.value))
    }

    /// [`Tracker::potential`] with the magnitude of its parts, the scale
    /// of its rounding ([`Potential::magnitude`]).
    pub fn potential_parts(&mut self) -> Result<Option<Potential>, D::Error> {
        self.device.potential()
    }

    /// The device's kernels and buffers.
    pub fn device(&self) -> &D {
        &self.device
    }

    /// The device's kernels and buffers, to change (tests that make a
    /// device fail inside a solve).
    pub fn device_mut(&mut self) -> &mut D {
        &mut self.device
    }

    /// The solve's plan: free particles, spectrum, size, float floor.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Sets every particle's spring towards the observation
    /// ([`Plan::set_springs`]: one per particle, zero where none, or none
    /// at all to take them away) for the next solves; the state is kept.
    ///
    /// # Errors
    ///
    /// As [`Plan::set_springs`]; the device's error where it cannot take
    /// them.
    pub fn set_springs<E: From<Error> + From<D::Error>>(
        &mut self,
        springs: Vec<crate::stage2::springs::Spring>,
    ) -> Result<(), E> {
        self.plan.set_springs(springs)?;
        self.device.set_springs(&self.plan.springs)?;
        Ok(())
    }

    /// [`Tracker::set_springs`] with the device's elastic correction kept
    /// ([`SolveDevice::set_springs_keeping_correction`]): a tracking
    /// sequence's next scan, paired as the last one was.
    ///
    /// # Errors
    ///
    /// As [`Tracker::set_springs`].
    pub fn set_springs_keeping_correction<E: From<Error> + From<D::Error>>(
        &mut self,
        springs: Vec<crate::stage2::springs::Spring>,
    ) -> Result<(), E> {
        self.plan.set_springs(springs)?;
        self.device
            .set_springs_keeping_correction(&self.plan.springs)?;
        Ok(())
    }

    /// Changes the body force of the next solves ([`DeformParams::load`]):
    /// each particle's load made again at the rest shape
    /// ([`Plan::set_load`]) and given to the device; the state is kept.
    /// For solves near this one under a nearby load (the uncertainty's
    /// gravity columns).
    ///
    /// # Errors
    ///
    /// [`ParamError`] for a solve without the elastic force (its
    /// connections are not kept) or a load [`Plan::set_load`] refuses; the
    /// device's error where it cannot take it.
    pub fn set_load<E: From<Error> + From<D::Error>>(&mut self, load: Vec3) -> Result<(), E> {
        let Some(connections) = &self.connections else {
            ParamError::check(
                false,
                "load",
                load,
                "unchanged on a prepared solve without the elastic force",
            )
            .map_err(Error::from)?;
            return Ok(());
        };
        self.plan.set_load(&self.rest, connections, load)?;
        self.device.set_loads(&self.plan.loads)?;
        self.params.load = load;
        Ok(())
    }

    /// Holds the observation the skin is paired with (its nearest points'
    /// field), or none ([`SolveDevice::set_observation`]); the state is
    /// kept.
    ///
    /// # Errors
    ///
    /// The device's error where it cannot take it.
    pub fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), D::Error> {
        self.device.set_observation(field)
    }

    /// Sets how the elastic force's iterations pair the skin with the
    /// observation held ([`Plan::set_pairing`]), or stops pairing; the
    /// state is kept.
    ///
    /// # Errors
    ///
    /// As [`Plan::set_pairing`]; the device's error where it cannot take
    /// it.
    pub fn set_pairing<E: From<Error> + From<D::Error>>(
        &mut self,
        pairing: Option<Pairing>,
    ) -> Result<(), E> {
        self.plan.set_pairing(pairing)?;
        self.device.set_pairing(self.plan.pairing.as_ref())?;
        Ok(())
    }

    /// The model's rest surface, whose vertices [`Tracker::set_surface`]
    /// takes moved.
    pub fn rest_surface(&self) -> &SurfaceMesh {
        &self.surface
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        &self.params
    }

    /// Changes the parameters of the next solves (the tolerance between
    /// frames, say); the state is kept. What the device prepared once (the
    /// coarse space, the step) stays as it was prepared, so the
    /// force, (for the elastic force) the Poisson ratio, the observed
    /// vertices and the load cannot change.
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), Error> {
        params.validate()?;
        // The plan's step and the elastic weights were made for these two.
        ParamError::check(
            params.force == self.params.force,
            "force",
            format!("{:?}", params.force),
            format!(
                "{:?}, the force this solve was prepared for",
                self.params.force
            ),
        )?;
        ParamError::check(
            params.force != ForceModel::Elastic || params.poisson == self.params.poisson,
            "poisson",
            params.poisson,
            format!(
                "{}, the Poisson ratio this solve was prepared for",
                self.params.poisson
            ),
        )?;
        // The control points and the loads are in the plan and the device.
        ParamError::check(
            params.observed == self.params.observed,
            "observed",
            "a different mask",
            "the observed vertices this solve was prepared for",
        )?;
        ParamError::check(
            params.load == self.params.load,
            "load",
            params.load,
            format!("{}, the load this solve was prepared for", self.params.load),
        )?;
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

    /// The last frames' converged solutions, whose changes predict where
    /// the next frame starts ([`predict`], [`crate::stage2::predict_paired`]).
    pub fn history(&self) -> &FrameHistory {
        &self.history
    }

    /// Makes `from`, a converged state, and the positions now the
    /// history's only frames ([`FrameHistory::restart`]): after a match in
    /// several solves from `from`, whose solves' answers are no frames of
    /// their own. Nothing where the last solve did not converge (the
    /// history is then empty).
    pub fn restart_history(&mut self, from: &[Vec3]) {
        if !self.history.is_empty() {
            self.history
                .restart(from, &self.current, self.params.tuning.history);
        }
    }

    /// The contraction the Chebyshev weights and the stopping rule use (of
    /// the last phase, for the elastic force).
    pub fn rho(&self) -> f32 {
        self.plan.solve_rho(&self.params, self.device.coarse_rho())
    }

    /// Places the control points on `deformed`, which must be the rest
    /// surface with moved vertices (same vertex count, same triangles), and
    /// the free particles where the prediction puts them (unless
    /// `extrapolate` is off).
    pub fn set_surface<E: From<Error> + From<D::Error>>(
        &mut self,
        deformed: &SurfaceMesh,
    ) -> Result<(), E> {
        check_same_topology(&self.surface, deformed).map_err(Error::from)?;
        let controls: Vec<(usize, Vec3)> = self
            .attachments
            .iter()
            .map(|&(i, t, bary)| (i, deformed.point_on(t as usize, bary)))
            .collect();
        let mut turn = None;
        if self.params.tuning.extrapolate {
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
        Ok(self.device.write_positions(&self.current, turn)?)
    }

    /// Starts the next solve from `positions` (one per particle; the
    /// control points stay where [`Tracker::set_surface`] put them) as if a
    /// converged solve had left the free particles there: with the elastic
    /// force its elastic phase alone, and both phases from `positions` if
    /// that fails, as a tracking frame does. For a solve whose answer is
    /// known roughly: the next of a search over nearby loads or shapes.
    /// Unlike a tracking frame's, that elastic phase is watched (the
    /// potential measured; where it rises, the conjugate gradient goes on
    /// from the state accepted last, or with `ElasticSolve::Chebyshev` the
    /// phase steps back with half its step, as from rest): a guess is no
    /// converged state, and unwatched the posture's first round on a model
    /// diverged from one.
    pub fn warm_start<E: From<Error> + From<D::Error>>(
        &mut self,
        positions: &[Vec3],
    ) -> Result<(), E> {
        ParamError::check(
            positions.len() == self.current.len() && positions.iter().all(|p| p.is_finite()),
            "warm start",
            format!("{} positions", positions.len()),
            format!("{} finite positions, one per particle", self.current.len()),
        )
        .map_err(Error::from)?;
        for (i, &q) in positions.iter().enumerate() {
            if self.plan.free[i] {
                self.current[i] = q;
            }
        }
        self.device.write_positions(&self.current, None)?;
        self.elastic_warm = self.params.force == ForceModel::Elastic;
        self.guessed = true;
        self.elastic_correct = true;
        Ok(())
    }

    /// Iterates until the stopping rule holds or the cap is reached, then
    /// reads the positions back and records them for the next prediction.
    ///
    /// With the elastic force a solve from rest (or after a solve that did
    /// not converge) has two phases: the symmetric force (with the device's
    /// correction) to [`SHEAR_TOLERANCE`] times the tolerance (or, before a
    /// phase the volume smoother smooths, until its error is below
    /// [`crate::stage2::params::SolverTuning::shear_volume_share`] of the volumes' misfit), then
    /// the elastic force from there. The volume term's stiffness grows with
    /// `cof(F)`; from rest, particles next to a moved surface are stretched
    /// many times over and no step set at rest is stable for them, while
    /// the shear phase leaves every neighbourhood near its rest volume
    /// (docs/METHOD.md, "Elastic model"). A tracking frame after a
    /// converged elastic solve starts from the prediction with the elastic
    /// force alone (the shear phase would lead away from the last solution),
    /// and solves again with both phases from the frame's start if that
    /// diverges. The report counts every iteration run.
    pub fn solve(&mut self) -> Result<DeformReport, D::Error> {
        self.solve_observed(&mut |_| {})
    }

    /// [`Tracker::solve`], telling `observe` where it is after every
    /// iteration ([`SolveStep`]: the iterations so far, every phase
    /// counted, and the error estimate the report's history records).
    pub fn solve_observed(
        &mut self,
        observe: &mut dyn FnMut(&SolveStep),
    ) -> Result<DeformReport, D::Error> {
        let started = Instant::now();
        let params = self.params.clone();
        let mut steps = Steps {
            done: 0,
            max_iterations: params.max_iterations,
            observe,
        };
        let report = if params.force != ForceModel::Elastic {
            self.phase(
                &params,
                params.max_iterations,
                PhaseRun::corrected(false),
                &mut steps,
            )?
            .0
        } else if self.elastic_warm {
            let correct = self.elastic_correct;
            let cap = params.max_iterations.min(WARM_ITERATIONS);
            // A guess's watched phase turns to the conjugate gradient as a
            // phase from rest does.
            let turn = self.guessed && correct && self.turns_to_conjugate(&params);
            let mut warm = self
                .phase(
                    &params,
                    cap,
                    PhaseRun {
                        correct,
                        watch: self.guessed,
                        turn,
                        ..PhaseRun::corrected(false)
                    },
                    &mut steps,
                )?
                .0;
            if turn
                && self.device.elastic_smoothed()
                && matches!(warm.stopped_by, StopReason::Diverged | StopReason::Stalled)
                && warm.iterations < params.max_iterations
            {
                warm = match self.turn_to_conjugate(
                    &params,
                    params.max_iterations,
                    warm,
                    &mut steps,
                )? {
                    Ok(turned) | Err(turned) => turned,
                };
            }
            if warm.stopped_by == StopReason::IterationCap && cap < params.max_iterations {
                // It circles far from its answer: stalled.
                warm.stopped_by = StopReason::Stalled;
                warm.converged = false;
            }
            if warm.stopped_by.failed() {
                log::info!(
                    "the elastic solve {} from the predicted start after {} iterations; \
                     solving the frame again after a shear phase",
                    if warm.stopped_by == StopReason::Stalled {
                        "stalled"
                    } else {
                        "diverged"
                    },
                    warm.iterations
                );
                let budget = params.max_iterations.saturating_sub(warm.iterations);
                if budget == 0 {
                    return self.finish(warm, started, &params);
                }
                self.device.reset()?;
                self.device.write_positions(&self.current, None)?;
                let mut again = self.shear_then_elastic(&params, budget, &mut steps)?;
                again.iterations += warm.iterations;
                again.elastic_retries += 1;
                again.residual_history.splice(0..0, warm.residual_history);
                again.potentials.splice(0..0, warm.potentials);
                again.backtracks += warm.backtracks;
                again
            } else {
                warm
            }
        } else {
            self.shear_then_elastic(&params, params.max_iterations, &mut steps)?
        };
        self.finish(report, started, &params)
    }

    /// The end of a solve: its time, the positions read back and recorded,
    /// and whether the next frame starts warm.
    fn finish(
        &mut self,
        mut report: DeformReport,
        started: Instant,
        params: &DeformParams,
    ) -> Result<DeformReport, D::Error> {
        report.seconds = started.elapsed().as_secs_f64();
        log::debug!(
            "solve: {} iterations in {:.4} s",
            report.iterations,
            report.seconds
        );
        self.current = self.device.read_positions()?;
        self.history
            .record(&self.current, report.converged, self.params.tuning.history);
        self.elastic_warm = params.force == ForceModel::Elastic && report.converged;
        self.guessed = false;
        Ok(report)
    }

    /// What [`Tracker::back_to`] puts back: the positions, the device's
    /// rotations and elastic correction at the frame boundary, the
    /// history, the load and whether the next solve starts warm. For
    /// solves near the answer that must leave no trace on the answer or
    /// the next frames (the uncertainty's columns).
    ///
    /// # Errors
    ///
    /// The device's error where it cannot read its rotations back.
    pub(crate) fn checkpoint(&mut self) -> Result<Checkpoint<D::Correction>, D::Error> {
        Ok(Checkpoint {
            current: self.current.clone(),
            rotations: self.device.read_rotations()?,
            correction: self.device.correction(),
            history: self.history.clone(),
            load: self.params.load,
            elastic_warm: self.elastic_warm,
            guessed: self.guessed,
            elastic_correct: self.elastic_correct,
        })
    }

    /// A copy of the tracker in its state, on a copy of its device
    /// ([`SolveDevice::fork`]), that solves as this one would from here;
    /// `None` where the device cannot be copied.
    pub(crate) fn fork(&self) -> Option<Self> {
        Some(Self {
            device: self.device.fork()?,
            plan: self.plan.clone(),
            params: self.params.clone(),
            surface: self.surface.clone(),
            attachments: self.attachments.clone(),
            free_skin: self.free_skin,
            rest: self.rest.clone(),
            current: self.current.clone(),
            history: self.history.clone(),
            elastic_warm: self.elastic_warm,
            guessed: self.guessed,
            elastic_correct: self.elastic_correct,
            connections: self.connections.clone(),
        })
    }

    /// Back to `kept` ([`Tracker::checkpoint`]): its positions written to
    /// the device (the control points with them), its rotations and
    /// elastic correction, its history, load and warm start.
    pub(crate) fn back_to<E: From<Error> + From<D::Error>>(
        &mut self,
        kept: Checkpoint<D::Correction>,
    ) -> Result<(), E> {
        if self.params.load != kept.load {
            self.set_load::<E>(kept.load)?;
        }
        self.current = kept.current;
        self.history = kept.history;
        self.elastic_warm = kept.elastic_warm;
        self.guessed = kept.guessed;
        self.elastic_correct = kept.elastic_correct;
        self.device.write_positions(&self.current, None)?;
        self.device.write_rotations(&kept.rotations)?;
        self.device.put_correction(kept.correction)?;
        Ok(())
    }

    /// Back to the rest shape (no warm start, no history but the rest).
    pub fn reset(&mut self) -> Result<(), D::Error> {
        self.device.reset()?;
        self.elastic_warm = false;
        self.guessed = false;
        self.current.clone_from(&self.rest);
        self.history = FrameHistory::at_rest(&self.rest, self.params.tuning.history);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use std::convert::Infallible;

    use glam::Mat3;
    use tissue_core::{Attachment, Connections};

    use super::*;
    use crate::stage2::acceleration::StoppingRule;
    use crate::stage2::device::{DescentDots, Iteration, Potential};
    use crate::stage2::params::ElasticSolve;
    use crate::stage2::phase::FIRST_BATCH;
    use crate::stage2::phase::{ENERGY_WATCH, MAX_RELINEARISATIONS};

    /// The octahedron's six vertices as control points and one free
    /// particle at its centre, connected to all six.
    pub(super) fn star() -> ParticleModel {
        let (vertices, triangles) = tissue_testkit::octahedron();
        let mut attachments: Vec<Option<Attachment>> = (0..6u32)
            .map(|v| {
                let (triangle, corner) = triangles
                    .iter()
                    .enumerate()
                    .find_map(|(t, tri)| tri.iter().position(|&x| x == v).map(|c| (t, c)))
                    .unwrap();
                let mut barycentric = [0.0; 3];
                barycentric[corner] = 1.0;
                Some(Attachment {
                    triangle: triangle as u32,
                    barycentric,
                })
            })
            .collect();
        attachments.push(None);
        let mut positions = vertices.clone();
        positions.push(Vec3::ZERO);
        ParticleModel {
            positions,
            radii: vec![0.5; 7],
            attachments,
            connections: Connections::from_pairs(7, (0..6).map(|v| (v, 6))),
            surface: SurfaceMesh::new(vertices, triangles),
        }
    }

    /// A device whose step halves every iteration, whatever the weights;
    /// it records what the tracker asked of it.
    #[derive(Debug)]
    struct Halving {
        batch: usize,
        step: f32,
        batch_start: f32,
        positions: Vec<Vec3>,
        turn: Option<Mat3>,
        replays: Vec<usize>,
        /// Per phase begun, the Chebyshev weights asked for, in order.
        omegas: Vec<Vec<f32>>,
        begun: Vec<Iteration>,
        /// The next elastic iteration reports a non-finite step.
        diverge_once: bool,
        /// How many elastic phases in a row diverge.
        diverge_phases: usize,
        /// Whether the device corrects the elastic phase (its contraction).
        elastic_correction: Option<f32>,
        /// Whether its corrected elastic phase runs the volume smoother
        /// (the accelerated stopping rule).
        smoothed: bool,
        /// How many corrected elastic phases in a row keep their step
        /// (they stall).
        stall_phases: usize,
        /// The phase in hand keeps its step.
        stalling: bool,
        resets: usize,
        /// The Chebyshev weights of the iterations that stand, in order
        /// (a replay drops those of its batch past it).
        executed: Vec<f32>,
        /// Where the last batch's weights start in `executed`.
        batch_at: usize,
        /// The contraction of its two-level solve, where it has one.
        coarse: Option<f32>,
        /// Whether it measures a potential ([`SolveDevice::potential`]):
        /// halved by every elastic iteration, doubled by those of a full
        /// step (undamped, the first elastic phase's plain step) where
        /// `rising`.
        watched: bool,
        rising: bool,
        /// Whether the elastic iterations of a full step leave the step
        /// and the potential as they were (a particle stepping back and
        /// forth at a flat potential); a damped step still halves both.
        cycling: bool,
        energy: f64,
        /// The energy and the step [`SolveDevice::save`] kept.
        saved: (f64, f32),
        restores: usize,
    }

    impl Halving {
        fn new(batch: usize, model: &ParticleModel) -> Self {
            Self {
                batch,
                step: 1.0,
                batch_start: 1.0,
                positions: model.positions.clone(),
                turn: None,
                replays: Vec::new(),
                omegas: Vec::new(),
                begun: Vec::new(),
                diverge_once: false,
                diverge_phases: 0,
                elastic_correction: None,
                smoothed: false,
                stall_phases: 0,
                stalling: false,
                resets: 0,
                executed: Vec::new(),
                batch_at: 0,
                coarse: None,
                watched: false,
                rising: false,
                cycling: false,
                energy: 1.0,
                saved: (1.0, 1.0),
                restores: 0,
            }
        }
    }

    impl SolveDevice for Halving {
        type Error = Infallible;

        fn batch(&self) -> usize {
            self.batch
        }

        fn write_positions(
            &mut self,
            positions: &[Vec3],
            turn: Option<Mat3>,
        ) -> Result<(), Infallible> {
            self.positions = positions.to_vec();
            self.turn = turn;
            Ok(())
        }

        fn set_springs(
            &mut self,
            _springs: &[crate::stage2::springs::Spring],
        ) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_loads(&mut self, _loads: &[Vec3]) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_observation(&mut self, _field: Option<&SurfaceField>) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_pairing(&mut self, _pairing: Option<&Pairing>) -> Result<(), Infallible> {
            Ok(())
        }

        fn begin(&mut self, iteration: Iteration) -> Result<(), Infallible> {
            self.step = 1.0;
            self.begun.push(iteration);
            self.omegas.push(Vec::new());
            if iteration.force == ForceModel::Elastic && self.diverge_phases > 0 {
                self.diverge_phases -= 1;
                self.diverge_once = true;
            }
            self.stalling = iteration.force == ForceModel::Elastic
                && iteration.correct
                && self.stall_phases > 0;
            if self.stalling {
                self.stall_phases -= 1;
            }
            Ok(())
        }

        fn elastic_smoothed(&self) -> bool {
            self.smoothed && self.elastic_rho().is_some()
        }

        fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian {
            SharedLaplacian::new(plan.laplacian_key, plan, params, None, None)
        }

        fn potential(&mut self) -> Result<Option<Potential>, Infallible> {
            Ok(self.watched.then_some(Potential {
                value: self.energy,
                magnitude: self.energy,
                held: self.energy,
            }))
        }

        fn read_rotations(&mut self) -> Result<Vec<Mat3>, Infallible> {
            Ok(Vec::new())
        }

        fn write_rotations(&mut self, _rotations: &[Mat3]) -> Result<(), Infallible> {
            Ok(())
        }

        /// No correction kept.
        type Correction = ();

        fn correction(&self) {}

        fn put_correction(&mut self, (): ()) -> Result<(), Infallible> {
            Ok(())
        }

        /// No volume smoother to precondition with.
        fn descent_residual(&mut self) -> Result<Option<DescentDots>, Infallible> {
            Ok(None)
        }

        fn descent_direction(&mut self, _beta: f32) -> Result<(), Infallible> {
            Ok(())
        }

        fn descent_move(&mut self, _t: f32) -> Result<(), Infallible> {
            Ok(())
        }

        fn save(&mut self) -> Result<(), Infallible> {
            self.saved = (self.energy, self.step);
            Ok(())
        }

        fn restore(&mut self) -> Result<(), Infallible> {
            (self.energy, self.step) = self.saved;
            self.restores += 1;
            Ok(())
        }

        fn volume_smoother(&self) -> bool {
            self.smoothed
        }

        fn coarse_rho(&self) -> Option<f32> {
            self.coarse
        }

        fn elastic_rho(&self) -> Option<f32> {
            let corrected = self.begun.last().is_some_and(|it| it.correct);
            self.elastic_correction.filter(|_| corrected)
        }

        fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Infallible> {
            assert!(omegas.len() <= self.batch);
            if let Some(phase) = self.omegas.last_mut() {
                phase.extend_from_slice(omegas);
            }
            self.batch_at = self.executed.len();
            self.executed.extend_from_slice(omegas);
            let elastic = self.begun.last().map(|it| it.force) == Some(ForceModel::Elastic);
            if elastic && std::mem::take(&mut self.diverge_once) {
                return Ok(vec![(f32::NAN, f32::NAN)]);
            }
            self.batch_start = self.step;
            // The full step: undamped, at the first elastic phase's plain
            // step.
            let first = self
                .begun
                .iter()
                .find(|it| it.force == ForceModel::Elastic)
                .map(|it| it.alpha);
            let full = self
                .begun
                .last()
                .is_some_and(|it| it.damping >= 1.0 && Some(it.alpha) >= first);
            let factor = if elastic && self.rising && full {
                2.0
            } else {
                0.5
            };
            let cycling = elastic && self.cycling && full;
            Ok(omegas
                .iter()
                .map(|_| {
                    if !self.stalling && !cycling {
                        self.step *= 0.5;
                    }
                    if elastic && !cycling {
                        self.energy *= factor;
                    }
                    (self.step, self.step)
                })
                .collect())
        }

        fn replay(&mut self, count: usize) -> Result<(), Infallible> {
            self.step = self.batch_start * 0.5f32.powi(count as i32);
            self.replays.push(count);
            self.executed.truncate(self.batch_at + count);
            Ok(())
        }

        fn read_positions(&mut self) -> Result<Vec<Vec3>, Infallible> {
            Ok(self.positions.clone())
        }

        fn reset(&mut self) -> Result<(), Infallible> {
            self.step = 1.0;
            self.resets += 1;
            Ok(())
        }
    }

    /// A tracker of [`star`] with the elastic force on a [`Halving`]
    /// device running `batch` iterations at a time, set up by `setup`,
    /// descending by Chebyshev's phases (their steps back and retries are
    /// what the tests of it hold).
    fn elastic_tracker(batch: usize, setup: impl FnOnce(&mut Halving)) -> Tracker<Halving> {
        let model = star();
        let params = DeformParams {
            force: ForceModel::Elastic,
            ..DeformParams::default()
        }
        .with(|p| p.tuning.elastic_solve = ElasticSolve::Chebyshev);
        Tracker::new(&model, params, |_, _| {
            let mut device = Halving::new(batch, &model);
            setup(&mut device);
            Ok::<_, Error>(device)
        })
        .unwrap()
    }

    /// A one-phase solve (the symmetric force) of the star on a device
    /// running `batch` iterations at a time.
    fn solved(batch: usize) -> (DeformReport, Halving) {
        let model = star();
        let symmetric = DeformParams::default().with(|p| p.force = ForceModel::Symmetric);
        let mut tracker = Tracker::new(&model, symmetric, |_, _| {
            Ok::<_, Error>(Halving::new(batch, &model))
        })
        .unwrap();
        let Ok(report) = tracker.solve();
        (report, tracker.device)
    }

    /// The iteration cap holds for the whole elastic solve: its shear and
    /// elastic phases together, on devices running one iteration or eight
    /// at a time; a cap the shear phase takes whole ends the solve there,
    /// not converged.
    #[test]
    fn the_cap_holds_for_both_phases_of_an_elastic_solve() {
        let model = star();
        let free = Tracker::new(&model, DeformParams::default(), |_, _| {
            Ok::<_, Error>(Halving::new(1, &model))
        })
        .unwrap()
        .solve();
        let Ok(free) = free;
        assert!(free.converged, "{free:?}");
        for batch in [1, 8] {
            for cap in [1, 2, free.iterations - 1] {
                let capped = DeformParams::default().with(|p| p.max_iterations = cap);
                let mut tracker = Tracker::new(&model, capped, |_, _| {
                    Ok::<_, Error>(Halving::new(batch, &model))
                })
                .unwrap();
                let Ok(report) = tracker.solve();
                assert_eq!(
                    report.iterations, cap,
                    "cap {cap}, batch {batch}: {report:?}"
                );
                assert!(!report.converged, "cap {cap}, batch {batch}");
                assert_eq!(report.stopped_by, StopReason::IterationCap);
                assert_eq!(report.residual_history.len(), cap);
            }
        }
    }

    #[test]
    fn a_batch_the_rule_stops_inside_is_replayed_to_the_same_iteration() {
        let (one, single) = solved(1);
        assert!(one.converged, "{one:?}");
        assert!(single.replays.is_empty());
        for batch in [2, 5, 8, 64] {
            let (report, device) = solved(batch);
            assert_eq!(report.iterations, one.iterations, "batch {batch}");
            assert_eq!(
                report.residual_history, one.residual_history,
                "batch {batch}"
            );
            // The phase's batches: `FIRST_BATCH`, then each twice the last
            // up to `batch`; the one the rule held inside is replayed.
            let (mut start, mut size) = (0, FIRST_BATCH.min(batch));
            while start + size < one.iterations {
                start += size;
                size = (2 * size).min(batch);
            }
            let inside = one.iterations - start;
            let expected: Vec<usize> = (inside < size).then_some(inside).into_iter().collect();
            assert_eq!(device.replays, expected, "batch {batch}");
            // The device is left where the rule held, not at the batch's end.
            assert_eq!(device.step, single.step, "batch {batch}");
        }
    }

    /// The shear phase before a smoothed elastic phase pauses to measure
    /// the volumes' misfit (none on the star: one particle has a volume
    /// weight, so the misfit never stops it) and goes on as if it had
    /// not: the same iterations, estimates and Chebyshev weights, on a
    /// device that runs batches (replayed to the pause) as on one that
    /// runs one iteration at a time, and as without the measure.
    #[test]
    fn a_shear_phase_paused_to_measure_the_volumes_goes_on_as_before() {
        let model = star();
        let run = |batch: usize, share: f32| {
            let params = DeformParams::default().with(|p| {
                p.force = ForceModel::Elastic;
                p.tuning.shear_volume_share = share;
            });
            let mut tracker = Tracker::new(&model, params, |_, _| {
                let mut device = Halving::new(batch, &model);
                device.elastic_correction = Some(0.9);
                device.smoothed = true;
                // Chebyshev's weights in the shear phase change every
                // iteration.
                device.coarse = Some(0.75);
                Ok::<_, Error>(device)
            })
            .unwrap();
            let Ok(report) = tracker.solve();
            assert!(report.converged, "{report:?}");
            (report, tracker.device)
        };
        let (reference, unmeasured) = run(1, 0.0);
        for batch in [1, 8] {
            let (report, device) = run(batch, 0.25);
            assert_eq!(report.iterations, reference.iterations, "batch {batch}");
            assert_eq!(
                report.residual_history, reference.residual_history,
                "batch {batch}"
            );
            assert_eq!(device.executed, unmeasured.executed, "batch {batch}");
        }
        // With batches of 8 the pause fell inside one, which was replayed
        // to it.
        let (_, paused) = run(8, 0.25);
        let (_, unpaused) = run(8, 0.0);
        assert_eq!(paused.replays.len(), unpaused.replays.len() + 1);
    }

    #[test]
    fn an_elastic_solve_starts_with_a_corrected_shear_phase() {
        let model = star();
        let params = DeformParams {
            force: ForceModel::Elastic,
            ..DeformParams::default()
        };
        let mut tracker = Tracker::new(&model, params.clone(), |_, _| {
            Ok::<_, Error>(Halving::new(1, &model))
        })
        .unwrap();
        let Ok(report) = tracker.solve();
        let plan = tracker.plan().clone();
        let [shear, elastic] = tracker.device.begun[..] else {
            panic!("{:?}", tracker.device.begun);
        };
        assert_eq!((shear.force, shear.correct), (ForceModel::Symmetric, true));
        // The elastic phase with the device's own correction, made again
        // where it starts.
        assert_eq!(
            (elastic.force, elastic.correct, elastic.relinearise),
            (ForceModel::Elastic, true, true)
        );
        assert!(!shear.relinearise);
        // Each phase with its own step: the elastic operator is the stiffer.
        assert_eq!(shear.alpha, plan.alpha(&params.shear()));
        assert_eq!(elastic.alpha, plan.alpha(&params));
        assert!(elastic.alpha < shear.alpha);
        // The report counts both phases; the shear phase stops at a looser
        // tolerance, so sooner than the elastic one.
        let (one, _) = solved(1);
        assert!(report.converged);
        assert!(report.iterations > one.iterations, "{report:?} vs {one:?}");
        assert_eq!(report.residual_history.len(), report.iterations);
        // The next frame starts from a converged elastic solve: the elastic
        // phase alone. After a reset, both again.
        let Ok(next) = tracker.solve();
        assert!(next.converged);
        assert_eq!(tracker.device.begun.len(), 3);
        let warm = tracker.device.begun[2];
        assert_eq!(
            (warm.force, warm.correct, warm.relinearise),
            (ForceModel::Elastic, true, false)
        );
        let Ok(()) = tracker.reset();
        let Ok(_) = tracker.solve();
        let forces: Vec<ForceModel> = tracker.device.begun[3..]
            .iter()
            .map(|it| it.force)
            .collect();
        assert_eq!(forces, [ForceModel::Symmetric, ForceModel::Elastic]);
        // A warm frame that diverges is solved again from the frame's start,
        // the shear phase first; the report counts the lost iteration too,
        // and the phase run again.
        tracker.device.diverge_once = true;
        let resets = tracker.device.resets;
        let Ok(again) = tracker.solve();
        assert!(again.converged, "{again:?}");
        assert_eq!(tracker.device.resets, resets + 1);
        let forces: Vec<ForceModel> = tracker.device.begun[5..]
            .iter()
            .map(|it| it.force)
            .collect();
        assert_eq!(
            forces,
            [
                ForceModel::Elastic,
                ForceModel::Symmetric,
                ForceModel::Elastic
            ]
        );
        assert_eq!(again.residual_history.len(), again.iterations);
        assert!(again.iterations > report.iterations, "{again:?}");
        // The report tells it (the log at `info` only: the frame converged).
        assert_eq!(again.elastic_retries, 1, "{again:?}");
        assert_eq!(next.elastic_retries, 0, "{next:?}");
    }

    /// A state gone to NaN reads as a largest step of 0 where the maximum
    /// skips NaN (`f32::max`); its RMS step is NaN, and the rule says
    /// diverged, not converged.
    #[test]
    fn a_step_that_is_not_a_number_is_divergence() {
        let model = star();
        let params = DeformParams::default();
        let plan = Plan::for_params(&model, &params).unwrap();
        for (max, rms) in [(0.0, f32::NAN), (f32::NAN, 0.0), (f32::INFINITY, 1.0)] {
            let mut rule = StoppingRule::new(&plan, &params);
            assert_eq!(rule.after(1.0, 1.0), None);
            assert_eq!(
                rule.after(max, rms),
                Some(StopReason::Diverged),
                "{max} {rms}"
            );
        }
    }

    /// The accelerated rule stops an iteration whose steps stop falling,
    /// after two windows, and never one that contracts at the smoother's
    /// rate; the other rules never call a stall.
    #[test]
    fn a_stall_is_called_only_where_the_accelerated_steps_stop_falling() {
        let plan = Plan::new(&star()).unwrap();
        let params = DeformParams {
            tolerance: 1e-30,
            ..DeformParams::default()
        };
        let run = |mut rule: StoppingRule, step: &dyn Fn(usize) -> f32| {
            (1..=200).find_map(|k| rule.after(step(k), step(k)).map(|r| (k, r)))
        };
        let flat = |_: usize| 0.01 * plan.size;
        let stalled = run(
            crate::stage2::acceleration::StoppingRule::accelerated(&plan, &params, 0.9),
            &flat,
        );
        assert_eq!(
            stalled,
            Some((
                2 * crate::stage2::acceleration::STALL_WINDOW,
                StopReason::Stalled
            ))
        );
        assert_eq!(
            run(
                crate::stage2::acceleration::StoppingRule::with_rho(&plan, &params, 0.9),
                &flat
            ),
            None
        );
        // Contracting at 0.9 a step (slower than the smoother's 0.6-0.7):
        // never a stall, down to the float floor.
        let falling = |k: usize| 0.01 * plan.size * 0.9f32.powi(k as i32);
        let reason = run(
            crate::stage2::acceleration::StoppingRule::accelerated(&plan, &params, 0.9),
            &falling,
        );
        assert!(
            !matches!(reason, Some((_, StopReason::Stalled))),
            "{reason:?}"
        );
    }

    /// A smoothed elastic phase whose steps stop falling is stopped after
    /// two stall windows and goes on from where it stalled, its correction
    /// made again there, up to [`MAX_RELINEARISATIONS`] times; one stall
    /// more goes on from there without the correction. Nothing runs again
    /// from the end of the shear phase.
    #[test]
    fn a_stalled_smoothed_elastic_phase_is_linearised_again_where_it_stalled() {
        let most = MAX_RELINEARISATIONS;
        for stalls in [1, most, most + 1] {
            let mut tracker = elastic_tracker(1, |device| {
                device.elastic_correction = Some(0.5);
                device.smoothed = true;
                device.stall_phases = stalls;
            });
            let Ok(report) = tracker.solve();
            assert!(report.converged, "{stalls}: {report:?}");
            assert_eq!(report.elastic_retries, stalls, "{report:?}");
            let elastic: Vec<(bool, bool, f32)> = tracker.device.begun[1..]
                .iter()
                .map(|it| (it.correct, it.relinearise, it.damping))
                .collect();
            // Every phase made its correction where it started; the stall
            // past the last linearisation goes on without it.
            let mut expected = vec![(true, true, 1.0); stalls.min(most) + 1];
            if stalls > most {
                expected.push((false, true, 1.0));
            }
            assert_eq!(elastic, expected, "{stalls}");
            assert_eq!(tracker.device.resets, 0, "{stalls}");
            // The shear phase, each stalled phase cut at two windows, the
            // phase that converged.
            let shear = report.iterations - stalls * 2 * crate::stage2::acceleration::STALL_WINDOW;
            assert!(shear > 0 && shear < 40, "{report:?}");
        }
    }

    /// A smoothed elastic phase whose state diverges goes back to the state
    /// it accepted with half its step, Chebyshev's weights made for the
    /// damped contraction `1 - d (1 - rho)`; diverged again, with half
    /// that, and so on: steps back, never a run again from the end of the
    /// shear phase.
    #[test]
    fn a_diverged_smoothed_elastic_phase_steps_back_with_half_its_step() {
        let params = DeformParams {
            force: ForceModel::Elastic,
            ..DeformParams::default()
        };
        for diverging in [1, 2, 3] {
            let mut tracker = elastic_tracker(1, |device| {
                device.elastic_correction = Some(0.5);
                device.smoothed = true;
                device.watched = true;
                device.diverge_phases = diverging;
            });
            let Ok(report) = tracker.solve();
            assert!(report.converged, "{diverging}: {report:?}");
            assert_eq!(
                (report.elastic_retries, report.backtracks),
                (0, diverging),
                "{report:?}"
            );
            assert_eq!(tracker.device.resets, 0);
            let elastic: Vec<(bool, f32)> = tracker.device.begun[1..]
                .iter()
                .map(|it| (it.correct, it.damping))
                .collect();
            let expected = [(true, 1.0), (true, 0.5), (true, 0.25), (true, 0.125)];
            assert_eq!(elastic, &expected[..=diverging], "{diverging}");
            // The damped phase's first weight (after the shear phase and
            // the diverged one; no warm-up): 2 / (2 - rho^2) for its
            // contraction, the mock's 0.5 damped.
            assert_eq!(params.tuning.warm_up, 0);
            let rho = 1.0 - 0.5 * (1.0 - 0.5);
            let damped = tracker.device.omegas[2][0];
            assert!((damped - 2.0 / (2.0 - rho * rho)).abs() < 1e-6, "{damped}");
            assert!(report.potentials_fell(), "{report:?}");
        }
    }

    /// A corrected elastic phase that steps plainly (where the volume
    /// smoother does not reach) whose potential rose goes back to the state
    /// it kept with its correction linearised there and the same step;
    /// rising again from that state it ends there, and the solve goes on
    /// from it without the correction, watched: its full plain step rises
    /// too, and it goes back with half of it, which converges. One descent:
    /// every state accepted at most the one before.
    #[test]
    fn a_plain_elastic_phase_whose_potential_rose_is_linearised_again_once() {
        let mut tracker = elastic_tracker(1, |device| {
            device.elastic_correction = Some(0.5);
            device.watched = true;
            device.rising = true;
        });
        let params = tracker.params.clone();
        let Ok(report) = tracker.solve();
        let device = &tracker.device;
        assert!(report.converged, "{report:?}");
        // One step back in each phase; the plain one back once more to end
        // there.
        assert_eq!((report.backtracks, device.restores), (2, 3), "{report:?}");
        assert_eq!(report.elastic_retries, 1, "{report:?}");
        assert_eq!(device.resets, 0);
        let elastic: Vec<(bool, bool, f32)> = device.begun[1..]
            .iter()
            .map(|it| (it.correct, it.relinearise, it.alpha))
            .collect();
        let alpha = tracker.plan().alpha(&params);
        let halved = tracker
            .plan()
            .alpha(&params.clone().with(|p| p.tuning.step_fraction *= 0.5));
        assert_eq!(
            elastic,
            [
                (true, true, alpha),
                (true, true, alpha),
                (false, true, alpha),
                (false, false, halved)
            ]
        );
        // Each watched stretch ran its eight iterations before the rise.
        for phase in 1..=3 {
            assert_eq!(device.omegas[phase].len(), ENERGY_WATCH, "{phase}");
        }
        assert_eq!(report.potentials.len(), 1, "{report:?}");
        assert_eq!(report.potentials[0][..2], [1.0, 1.0], "{report:?}");
        assert!(report.potentials[0].len() >= 3, "{report:?}");
        assert!(report.potentials_fell(), "{report:?}");
    }

    /// A warm elastic phase (a tracking frame's, from the predicted start)
    /// that runs [`WARM_ITERATIONS`] without reaching the tolerance is
    /// taken for stalled: the frame is solved again from a shear phase,
    /// which converges, the retry counted.
    #[test]
    fn a_warm_phase_that_runs_too_long_is_solved_again_after_a_shear_phase() {
        let mut tracker = elastic_tracker(1, |device| {
            device.elastic_correction = Some(0.5);
        });
        let Ok(first) = tracker.solve();
        assert!(first.converged, "{first:?}");
        // The next frame's warm phase keeps its step: it never converges.
        tracker.device.stall_phases = 1;
        let phases = tracker.device.begun.len();
        let Ok(report) = tracker.solve();
        assert!(report.converged, "{report:?}");
        assert_eq!(report.elastic_retries, 1, "{report:?}");
        let device = &tracker.device;
        assert_eq!(device.omegas[phases].len(), WARM_ITERATIONS);
        assert!(report.iterations > WARM_ITERATIONS, "{report:?}");
        // Then a shear phase and an elastic one.
        let forces: Vec<ForceModel> = device.begun[phases..].iter().map(|it| it.force).collect();
        assert_eq!(
            forces,
            [
                ForceModel::Elastic,
                ForceModel::Symmetric,
                ForceModel::Elastic
            ]
        );
    }

    /// A smoothed elastic phase whose potential rose over its first
    /// [`ENERGY_WATCH`] iterations goes back to the state it started from
    /// and on from there with half its step, not linearised again, its
    /// Chebyshev weights started again for the damped contraction; it
    /// converges with no retry, each state it accepted lower than the one
    /// before. A device without a potential is not watched, nor is the
    /// next frame's warm phase; a warm start from a caller's guess is.
    #[test]
    fn a_smoothed_elastic_phase_whose_potential_rose_steps_back_with_half_its_step() {
        for (batch, watched) in [(1, true), (8, true), (1, false)] {
            let mut tracker = elastic_tracker(batch, |device| {
                device.elastic_correction = Some(0.5);
                device.smoothed = true;
                device.watched = watched;
                device.rising = true;
            });
            let Ok(report) = tracker.solve();
            let device = &tracker.device;
            assert!(report.converged, "{report:?}");
            assert_eq!(report.elastic_retries, 0, "{report:?}");
            let elastic: Vec<(bool, f32)> = device.begun[1..]
                .iter()
                .map(|it| (it.relinearise, it.damping))
                .collect();
            if !watched {
                assert_eq!((report.backtracks, device.restores), (0, 0));
                assert_eq!(elastic, [(true, 1.0)]);
                assert!(report.potentials.is_empty());
                continue;
            }
            assert_eq!((report.backtracks, device.restores), (1, 1), "{batch}");
            assert_eq!(elastic, [(true, 1.0), (false, 0.5)], "{batch}");
            // Eight iterations ran before the step back, all counted.
            assert_eq!(device.omegas[1].len(), ENERGY_WATCH, "{batch}");
            assert_eq!(
                report.residual_history.len(),
                report.iterations,
                "{report:?}"
            );
            let rho = 1.0 - 0.5 * (1.0 - 0.5);
            let first = device.omegas[2][0];
            assert!((first - 2.0 / (2.0 - rho * rho)).abs() < 1e-6, "{first}");
            assert_eq!(report.potentials.len(), 1, "{report:?}");
            let potentials = &report.potentials[0];
            assert_eq!(potentials[0], 1.0);
            assert!(potentials.len() >= 2, "{potentials:?}");
            assert!(report.potentials_fell(), "{potentials:?}");
            // The next frame starts warm: its phase is not watched.
            let Ok(warm) = tracker.solve();
            assert!(warm.converged, "{warm:?}");
            assert!(warm.potentials.is_empty(), "{warm:?}");
            assert_eq!(tracker.device.restores, 1);
            // A caller's guess is watched: the rise is stepped back from
            // with half the step, and the phase converges without running
            // again after a shear phase; the frame after it is not watched.
            let guess = tracker.current.clone();
            tracker.warm_start::<Error>(&guess).unwrap();
            let Ok(guessed) = tracker.solve();
            assert!(guessed.converged, "{guessed:?}");
            assert_eq!(guessed.elastic_retries, 0, "{guessed:?}");
            assert_eq!(guessed.backtracks, 1, "{guessed:?}");
            assert!(guessed.potentials_fell(), "{guessed:?}");
            let last = tracker.device.begun.last().unwrap();
            assert_eq!((last.relinearise, last.damping), (false, 0.5));
            let Ok(after) = tracker.solve();
            assert!(after.potentials.is_empty(), "{after:?}");
        }
    }

    /// Chebyshev then the conjugate gradient on a device without the
    /// conjugate gradient's calls: the phase whose potential rose ends at
    /// the state it accepted (no step back of its own), and the solve goes
    /// on as Chebyshev's does without it, its correction made again there
    /// and its rises stepped back from; it converges, each state it
    /// accepted lower than the one before.
    #[test]
    fn chebyshev_then_the_conjugate_gradient_goes_on_by_chebyshev_where_the_device_cannot_descend()
    {
        let mut tracker = elastic_tracker(8, |device| {
            device.elastic_correction = Some(0.5);
            device.smoothed = true;
            device.watched = true;
            device.rising = true;
        });
        tracker.params.tuning.elastic_solve = ElasticSolve::ChebyshevThenConjugateGradient;
        let Ok(report) = tracker.solve();
        assert!(report.converged, "{report:?}");
        assert!(report.potentials_fell(), "{report:?}");
        // Back where the first phase accepted, then went on from there as
        // a retry, whose own rise is stepped back from with half its step.
        assert_eq!(report.elastic_retries, 1, "{report:?}");
        assert_eq!(tracker.device.restores, 2, "{report:?}");
        let elastic: Vec<(bool, f32)> = tracker.device.begun[1..]
            .iter()
            .map(|it| (it.relinearise, it.damping))
            .collect();
        // The first phase, the conjugate gradient's attempt, the phase
        // linearised again where the first accepted, its step back.
        assert_eq!(
            elastic,
            [(true, 1.0), (true, 1.0), (true, 1.0), (false, 0.5)],
            "{report:?}"
        );
    }

    /// A smoothed elastic phase whose potential and error estimate both
    /// stay where they were over a watch's interval (a particle stepping
    /// back and forth, the potential flat, the stopping rule never met)
    /// made no progress: it goes back to the state it accepted with half
    /// its step, where it converges, with no retry. Where only a rise was
    /// stepped back from, the stall window caught it: linearised again, and
    /// then again at every stall.
    #[test]
    fn a_smoothed_elastic_phase_that_makes_no_progress_steps_back_with_half_its_step() {
        for batch in [1, 8] {
            let mut tracker = elastic_tracker(batch, |device| {
                device.elastic_correction = Some(0.5);
                device.smoothed = true;
                device.watched = true;
                device.cycling = true;
            });
            let Ok(report) = tracker.solve();
            assert!(report.converged, "{batch}: {report:?}");
            assert_eq!(report.elastic_retries, 0, "{batch}: {report:?}");
            assert_eq!(report.backtracks, 1, "{batch}: {report:?}");
            assert!(report.iterations < 100, "{batch}: {report:?}");
            let last = tracker.device.begun.last().unwrap();
            assert_eq!((last.relinearise, last.damping), (false, 0.5), "{batch}");
            assert!(report.potentials_fell(), "{batch}: {report:?}");
        }
    }

    /// A corrected plain elastic phase whose state diverges goes back to
    /// the state it accepted with its correction made there; diverged again,
    /// the solve goes on from that state without the correction. A device
    /// without one halves its plain step at each divergence instead. The
    /// next warm frame runs as the phase that converged did.
    #[test]
    fn a_diverged_elastic_phase_drops_the_correction_before_the_step() {
        let params = DeformParams {
            force: ForceModel::Elastic,
            ..DeformParams::default()
        };
        for correction in [Some(0.5), None] {
            let mut tracker = elastic_tracker(1, |device| {
                device.elastic_correction = correction;
                device.watched = true;
                device.diverge_phases = 2;
            });
            let Ok(report) = tracker.solve();
            assert!(report.converged, "{report:?}");
            let elastic: Vec<(bool, f32)> = tracker.device.begun[1..]
                .iter()
                .map(|it| (it.correct, it.alpha))
                .collect();
            let alpha = tracker.plan().alpha(&params);
            let step = |fraction: f32| {
                tracker
                    .plan()
                    .alpha(&params.clone().with(|p| p.tuning.step_fraction *= fraction))
            };
            let expected = if correction.is_some() {
                vec![(true, alpha), (true, alpha), (false, alpha)]
            } else {
                vec![(true, alpha), (true, step(0.5)), (true, step(0.25))]
            };
            assert_eq!(elastic, expected, "{correction:?}");
            let went_on = usize::from(correction.is_some());
            assert_eq!(
                (report.elastic_retries, report.backtracks),
                (went_on, 2 - went_on),
                "{report:?}"
            );
            assert_eq!(tracker.device.resets, 0);
            assert!(report.potentials_fell(), "{report:?}");
            let Ok(next) = tracker.solve();
            assert!(next.converged);
            let warm = tracker.device.begun[4];
            assert_eq!(warm.correct, correction.is_none(), "{correction:?}");
        }
    }

    #[test]
    fn a_new_surface_moves_the_controls_and_carries_the_rest_with_its_rotation() {
        let model = star();
        let mut tracker = Tracker::new(&model, DeformParams::default(), |_, _| {
            Ok::<_, Error>(Halving::new(8, &model))
        })
        .unwrap();
        let turn = Mat3::from_rotation_z(0.3);
        let shift = Vec3::new(1.0, -2.0, 0.5);
        let mut moved = model.surface.clone();
        moved
            .vertices
            .iter_mut()
            .for_each(|v| *v = turn * *v + shift);
        let Ok(()) = tracker
            .set_surface::<Error>(&moved)
            .map_err(|e| panic!("{e}"));
        let device = tracker.device();
        for (v, &want) in moved.vertices.iter().enumerate() {
            assert!((device.positions[v] - want).length() < 1e-5, "control {v}");
        }
        // The free centre is carried by the surface's affine move.
        assert!((device.positions[6] - shift).length() < 1e-5);
        let applied = device.turn.unwrap();
        assert!((applied - turn).abs_diff_eq(Mat3::ZERO, 1e-5), "{applied}");

        let mut other = model.surface.clone();
        other.vertices.pop();
        let err = tracker.set_surface::<Error>(&other).unwrap_err();
        assert!(err.to_string().contains("5 vertices"), "{err}");
    }
}
