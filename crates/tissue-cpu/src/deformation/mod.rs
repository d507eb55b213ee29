//! Stage 2, deformation (the paper's Section 3), on the CPU.
//!
//! Surface particles (control points) follow the deformed surface through
//! their triangle + barycentric attachment; every other particle moves by
//! `q += F / m` until the residual force vanishes. The stage functions are
//! in [`crate::kernels`], each the twin of a GPU shader of the same name:
//! - `local_rotations`: per particle, the rotation `R_i` that best maps its
//!   rest offsets `p_j - p_i` onto its current ones `q_j - q_i` (Procrustes
//!   through a 3x3 SVD). The paper writes `R_i^T (p_j - p_i)` for the rotated
//!   rest offset because its `R_i = U V^T` comes from `svd(A_relax^T A_current)`;
//!   our `R_i` is that matrix's transpose, so the offset is `R_i (p_j - p_i)`.
//! - `deformation_force`: the force on each particle, gathered over its
//!   connections (no atomics), in one of two forms:
//!   - **paper**: `F_j = sigma sum_i [R_i (p_j - p_i) - (q_j - q_i)]`, the
//!     paper's one-sided `F_{i->j}` summed over `j`'s connections;
//!   - **symmetric**: `F_j = sigma sum_i [(R_i + R_j)(p_j - p_i) - 2 (q_j - q_i)]`,
//!     exactly `-1/2` the gradient of `E = sum_i sum_j |q_j - q_i - R_i (p_j - p_i)|^2`.
//! - `integrate`: `q += alpha F` for free particles, optionally Chebyshev-accelerated.

//!
//! The frame loop (prediction, acceleration, stopping, history) is
//! `tissue_solve::Tracker`'s, the same as the GPU path's; [`CpuSolve`] is
//! this path's [`SolveDevice`]: the kernels and the state they work on.

use std::sync::Arc;
use std::time::Instant;

use glam::{DVec3, Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::field::SurfaceField;
use tissue_core::{Connections, Error, ParticleModel, SurfaceMesh};
pub use tissue_solve::coarse::SharedLaplacian;
pub use tissue_solve::model::Elastic;
use tissue_solve::model::ElasticTerms;
pub use tissue_solve::stage2::Pass;
pub use tissue_solve::stage2::Plan;
use tissue_solve::stage2::Spring;
pub use tissue_solve::stage2::check_same_topology;
pub use tissue_solve::stage2::{Chebyshev, StoppingRule};
use tissue_solve::stage2::{Choices, Holds, Pairing, Tracker};
pub use tissue_solve::stage2::{
    DeformParams, ElasticSolve, ForceModel, MAX_COARSE_AGGREGATES, MAX_HISTORY, RotationMethod,
    SolverTuning,
};
pub use tissue_solve::stage2::{DeformReport, PrepareStage, StopReason};
pub use tissue_solve::stage2::{FrameHistory, affine_fit, predict};
pub use tissue_solve::stage2::{Iteration, SolveDevice};
pub use tissue_solve::stage2::{laplacian_extremes, laplacian_extremes_with};

mod solve_device;

pub use crate::kernels::deformation_force::deformation_force;
pub use crate::kernels::elastic_targets::{
    elastic_force, elastic_potential, elastic_terms, elastic_terms_into,
};
pub use crate::kernels::integrate::{chebyshev_combine, integrate};
pub use crate::kernels::local_rotations::{local_rotations, local_rotations_warm};
pub use crate::kernels::pair::pair;
pub use crate::kernels::polar::{
    POLAR_ITERATIONS, POLAR_MOST_ITERATIONS, polar_rotation, polar_update, warm_rotation,
};
pub use crate::kernels::step_norms::step_norms;
pub use crate::kernels::volume_smoother::elastic_residual;

use tissue_solve::coarse::{
    Aggregates, CoarseSpace, CorrectionFor, ElasticCoarse, Smoothing, coarse_space_shared,
    elastic_aggregates, volume_smoother,
};

/// Stage 2 on the CPU for one particle model: the tracker (rest shape,
/// control points, prediction, history) over [`CpuSolve`], kept between
/// frames (warm start).
#[derive(Debug, Clone)]
pub struct Deformer {
    tracker: Tracker<CpuSolve>,
}

impl Deformer {
    /// Prepares stage 2 for `model`: checks it, estimates the extreme
    /// eigenvalues of the connection-graph Laplacian over free particles,
    /// and builds the coarse space.
    pub fn new(model: &ParticleModel, params: DeformParams) -> Result<Self, Error> {
        Self::new_observed(model, params, &mut |_| {})
    }

    /// [`Deformer::new`], telling `observe` as each stage of the
    /// preparation starts.
    pub fn new_observed(
        model: &ParticleModel,
        params: DeformParams,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        Self::new_shared(model, params, None, observe)
    }

    /// [`Deformer::new_observed`], taking what another solver of the same
    /// connections and free particles prepared where it matches
    /// ([`SharedLaplacian`]; [`Deformer::shared_laplacian`] of that one).
    pub fn new_shared(
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        let tracker =
            Tracker::new_shared(model, params, shared, observe, |plan, params, observe| {
                Ok::<_, Error>(CpuSolve::new_shared(model, plan, params, shared, observe))
            })?;
        Ok(Self { tracker })
    }

    /// What this solver prepared that depends only on the connections and
    /// the free particles, for another solver of the same model in another
    /// rest shape ([`Deformer::new_shared`]).
    pub fn shared_laplacian(&self) -> SharedLaplacian {
        self.tracker.shared_laplacian()
    }

    /// Current particle positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.tracker.device().current
    }

    /// Rest particle positions.
    pub fn rest(&self) -> &[Vec3] {
        self.tracker.rest()
    }

    /// The state and kernels the solves run on.
    pub fn device(&self) -> &CpuSolve {
        self.tracker.device()
    }

    /// The state and kernels, to drive through their
    /// [`tissue_solve::SolveDevice`] calls (tests that compare devices one
    /// call at a time).
    pub fn device_mut(&mut self) -> &mut CpuSolve {
        self.tracker.device_mut()
    }

    /// The passes every iteration of the last solve ran, in order (the GPU
    /// path's `GpuDeformer::passes`).
    pub fn passes(&self) -> Vec<Pass> {
        self.tracker.device().passes()
    }

    /// Each particle's rotation (rest offsets onto current offsets) from the last iteration.
    pub fn rotations(&self) -> &[Mat3] {
        &self.tracker.device().rotations
    }

    /// The model's size (bounding-box diagonal at rest).
    pub fn size(&self) -> f32 {
        self.tracker.plan().size
    }

    /// The solve's plan: free particles, spectrum, size, float floor.
    pub fn plan(&self) -> &Plan {
        self.tracker.plan()
    }

    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_min(&self) -> f32 {
        self.tracker.plan().lambda_min
    }

    /// Largest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_max(&self) -> f32 {
        self.tracker.plan().lambda_max
    }

    /// The coarse space of the two-level solve, if any.
    pub fn coarse(&self) -> Option<&CoarseSpace> {
        self.tracker.device().coarse.as_deref()
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        self.tracker.params()
    }

    /// Changes the parameters of the next solves (the tolerance between
    /// frames, say); the current state is kept. The coarse space is
    /// prepared once, by [`Deformer::new`], for its `coarse`,
    /// `coarse_max_aggregates` and `step_fraction`:
    /// build a new deformer to change those.
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), Error> {
        self.tracker.set_params(params)
    }

    /// Back to the rest shape (no warm start).
    pub fn reset(&mut self) {
        let Ok(()) = self.tracker.reset();
    }

    /// Places the control points on `deformed`, which must be the rest surface
    /// with moved vertices (same vertex count, same triangles).
    pub fn set_surface(&mut self, deformed: &SurfaceMesh) -> Result<(), Error> {
        self.tracker.set_surface(deformed)
    }

    /// Sets every particle's spring towards the observation for the next
    /// solves (`Tracker::set_springs`: one per particle, or none).
    pub fn set_springs(&mut self, springs: Vec<Spring>) -> Result<(), Error> {
        self.tracker.set_springs(springs)
    }

    /// Holds the observation the skin is paired with, or none
    /// (`Tracker::set_observation`).
    pub fn set_observation(&mut self, field: Option<&SurfaceField>) {
        let Ok(()) = self.tracker.set_observation(field);
    }

    /// Sets how the elastic iterations pair the skin with the observation
    /// (`Tracker::set_pairing`), or stops pairing.
    pub fn set_pairing(&mut self, pairing: Option<Pairing>) -> Result<(), Error> {
        self.tracker.set_pairing(pairing)
    }

    /// The next solve starts from `positions` (`Tracker::warm_start`).
    pub fn warm_start(&mut self, positions: &[Vec3]) -> Result<(), Error> {
        self.tracker.warm_start(positions)
    }

    /// The potential the elastic force descends at the current positions
    /// (`SolveDevice::potential`); `None` for the other forces.
    pub fn potential(&mut self) -> Option<f64> {
        let Ok(potential) = self.tracker.potential();
        potential
    }

    /// Iterates until the stopping rule holds or the cap is reached.
    ///
    /// Stopping rule: the error estimate `max step / (1 - rho)`, with `rho` the
    /// plain iteration's contraction rate from the Laplacian's spectrum, is
    /// below `tolerance` times the model's size; or the step is below what
    /// `f32` can resolve at the model's coordinates.
    pub fn solve(&mut self) -> DeformReport {
        self.solve_observed(&mut |_| {})
    }

    /// [`Deformer::solve`], telling `observe` where it is after every
    /// iteration.
    pub fn solve_observed(
        &mut self,
        observe: &mut dyn FnMut(&tissue_solve::SolveStep),
    ) -> DeformReport {
        let Ok(report) = self.tracker.solve_observed(observe);
        report
    }
}

/// The CPU's stage-2 state and kernels: the positions, the rotations, and
/// the correction (the coarse space of the two-level solve).
#[derive(Debug, Clone)]
pub struct CpuSolve {
    rest: Vec<Vec3>,
    connections: Connections,
    free: Vec<bool>,
    /// Per particle its body force (empty without a load).
    loads: Vec<Vec3>,
    /// Per particle its spring towards the observation as the plan set
    /// it (empty without: [`Plan::springs`]): what the elastic phase's
    /// correction is made with.
    springs: Vec<Spring>,
    /// The springs the elastic force's iterations apply: the plan's, or
    /// where the skin is paired with an observation, as the last
    /// [`Pass::Pair`] set them.
    pulls: Vec<Spring>,
    /// The observation the skin is paired with (its nearest points).
    observation: Option<Arc<SurfaceField>>,
    /// How the skin is paired with it ([`Plan::pairing`]).
    pairing: Option<Pairing>,
    current: Vec<Vec3>,
    previous: Vec<Vec3>,
    rotations: Vec<Mat3>,
    /// The coarse space of the two-level solve.
    coarse: Option<Arc<CoarseSpace>>,
    /// The elastic model's rest data, with the elastic force.
    elastic: Option<Arc<Elastic>>,
    /// The aggregates of the elastic phase's two-level solve.
    elastic_aggregates: Option<Arc<Aggregates>>,
    /// The elastic phase's coarse correction, linearised where the last
    /// elastic phase after a shear phase started.
    elastic_coarse: Option<Arc<ElasticCoarse>>,
    /// Up to how many aggregates the elastic coarse matrix is factored
    /// (`SolverTuning::elastic_coarse_direct_max_aggregates`).
    elastic_direct_max: usize,
    /// How the volume smoother is made and its two-level iteration's
    /// contraction, estimated once at rest, where the elastic phase's
    /// correction smooths with it.
    volume_smoother: Option<(Smoothing, f32)>,
    /// What the iterations of the solve in hand run with.
    iteration: Option<Iteration>,
    /// Where the last batch of more than one iteration started, for a replay.
    batch_start: Option<BatchStart>,
    /// The positions and rotations [`SolveDevice::save`] kept.
    saved: Option<(Vec<Vec3>, Vec<Mat3>)>,
    /// Where the skin is paired, the pulls as they were when
    /// [`SolveDevice::save`] kept a state (paired there by the
    /// [`SolveDevice::potential`] before it): what
    /// [`tissue_solve::stage2::Potential::held`] is measured with.
    held_pulls: Vec<Spring>,
    /// The elastic terms of the last iteration ([`Pass::ElasticTerms`]),
    /// and the buffer its rotations are made in before they replace
    /// `rotations`: kept from iteration to iteration.
    terms: Vec<ElasticTerms>,
    turned: Vec<Mat3>,
    /// The conjugate-gradient elastic phase's vectors (empty until its
    /// first [`SolveDevice::descent_residual`]).
    descent: Descent,
}

/// The conjugate-gradient elastic phase's vectors, one per particle.
#[derive(Debug, Clone, Default)]
struct Descent {
    /// The two-level step `z` the last residual call made.
    step: Vec<Vec3>,
    /// The residual `r'` it kept.
    last_residual: Vec<Vec3>,
    /// The direction `d`.
    direction: Vec<Vec3>,
    /// The positions the line search moves from.
    base: Vec<Vec3>,
}

/// The state and the weights a batch started from.
#[derive(Debug, Clone)]
struct BatchStart {
    current: Vec<Vec3>,
    previous: Vec<Vec3>,
    rotations: Vec<Mat3>,
    omegas: Vec<f32>,
}

impl CpuSolve {
    /// The state of `model` at rest, with its coarse space.
    pub fn new(model: &ParticleModel, plan: &Plan, params: &DeformParams) -> Self {
        Self::new_observed(model, plan, params, &mut |_| {})
    }

    /// [`CpuSolve::new`], telling `observe` as each stage starts.
    pub fn new_observed(
        model: &ParticleModel,
        plan: &Plan,
        params: &DeformParams,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Self {
        Self::new_shared(model, plan, params, None, observe)
    }

    /// [`CpuSolve::new_observed`], the coarse space taken from `shared`
    /// where it was made for the same Laplacian and parameters.
    pub fn new_shared(
        model: &ParticleModel,
        plan: &Plan,
        params: &DeformParams,
        shared: Option<&SharedLaplacian>,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Self {
        if params.tuning.coarse != 0.0 {
            observe(PrepareStage::CoarseSpace);
        }
        let coarse = coarse_space_shared(
            model,
            plan,
            params,
            shared.map(|shared| (shared, plan.laplacian_key)),
        );
        if plan.elastic.is_some() {
            observe(PrepareStage::ElasticCoarse);
        }
        let elastic_aggregates = elastic_aggregates(model, plan, params).map(Arc::new);
        let direct_max = params.tuning.elastic_coarse_direct_max_aggregates;
        let volume_smoother = volume_smoother(
            model,
            plan,
            params,
            elastic_aggregates.as_deref(),
            direct_max,
            shared.and_then(|shared| shared.smoother_for(plan.laplacian_key, params)),
        );
        Self {
            rest: model.positions.clone(),
            connections: model.connections.clone(),
            free: plan.free.clone(),
            loads: plan.loads.clone(),
            springs: plan.springs.clone(),
            pulls: plan.springs.clone(),
            observation: None,
            pairing: plan.pairing.clone(),
            current: model.positions.clone(),
            previous: model.positions.clone(),
            rotations: vec![Mat3::IDENTITY; model.len()],
            coarse,
            elastic: plan.elastic.clone(),
            elastic_aggregates,
            elastic_coarse: None,
            elastic_direct_max: direct_max,
            volume_smoother,
            iteration: None,
            batch_start: None,
            saved: None,
            held_pulls: Vec::new(),
            terms: Vec::new(),
            turned: Vec::new(),
            descent: Descent::default(),
        }
    }

    /// Current particle positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.current
    }

    /// Each particle's rotation (rest offsets onto current offsets) from
    /// the last iteration.
    pub fn rotations(&self) -> &[Mat3] {
        &self.rotations
    }

    /// The coarse space of the two-level solve, if any.
    pub fn coarse(&self) -> Option<&CoarseSpace> {
        self.coarse.as_deref()
    }

    /// The elastic phase's coarse correction made where the last corrected
    /// elastic phase started, if any.
    pub fn elastic_coarse(&self) -> Option<&ElasticCoarse> {
        self.elastic_coarse.as_deref()
    }

    /// How the volume smoother is made and its iteration's contraction at
    /// rest, where the elastic phase smooths with it
    /// (`tissue_solve::coarse::volume_smoother`).
    pub fn volume_smoother(&self) -> Option<(Smoothing, f32)> {
        self.volume_smoother
    }

    /// Makes the elastic phase's coarse correction at the current state
    /// where `iteration` starts an elastic phase of its own, or none was
    /// made for its step; a warm-started phase keeps the last one. A
    /// failure leaves the phase uncorrected, with a warning.
    fn linearise(&mut self, iteration: Iteration) {
        let (Some(aggregates), Some(elastic)) =
            (self.elastic_aggregates.as_deref(), self.elastic.as_deref())
        else {
            return;
        };
        if !ElasticCoarse::is_needed_anew(self.elastic_coarse.as_deref(), &iteration) {
            return;
        }
        let made_for = CorrectionFor {
            contraction: iteration.contraction,
            smoothing: self.volume_smoother.map(|(smoothing, _)| smoothing),
            rho: self.volume_smoother.map(|(_, rho)| rho),
            direct_max_aggregates: self.elastic_direct_max,
            envelope: false,
        };
        self.elastic_coarse = ElasticCoarse::at_phase_start(
            aggregates,
            &self.rest,
            &self.current,
            &self.connections,
            elastic,
            made_for,
            &self.springs,
            self.elastic_coarse.as_deref(),
        )
        .map(|mut coarse| {
            if self.pairing.is_some() {
                coarse.set_pulls(&self.pulls);
            }
            Arc::new(coarse)
        });
    }

    /// One iteration with Chebyshev weight `omega`: the largest and RMS
    /// step the stopping rule measures.
    fn iterate(&mut self, it: Iteration, omega: f32) -> (f32, f32) {
        self.iterate_with(it, omega, &mut Laps::off())
    }

    /// [`SolveDevice::run`]'s iteration, one at a time, telling `clock` how
    /// many seconds each pass took (the benchmark's breakdown; the solve
    /// runs the same passes untimed).
    pub fn iterate_timed(
        &mut self,
        it: Iteration,
        omega: f32,
        clock: &mut dyn FnMut(Pass, f64),
    ) -> (f32, f32) {
        self.iterate_with(it, omega, &mut Laps::on(clock))
    }

    /// What this device holds for its iterations, for the rule that picks
    /// their passes ([`Choices::of`]).
    fn holds(&self) -> Holds {
        let elastic_correction = self
            .elastic_coarse
            .as_deref()
            .filter(|_| self.elastic_aggregates.is_some())
            .map(|c| (c.multilevel().is_some(), c.smoother().map(|s| s.sweeps())));
        Holds {
            elastic: self.elastic.is_some(),
            coarse: self.coarse.as_deref().map(|c| c.multilevel().is_some()),
            elastic_correction,
            pairs: self.pairs(),
        }
    }

    /// The passes every iteration of the solve in hand runs, in order
    /// (empty before a solve's [`SolveDevice::begin`]).
    pub fn passes(&self) -> Vec<Pass> {
        self.iteration
            .map(|it| Choices::of_iteration(&it, self.holds()).passes())
            .unwrap_or_default()
    }

    /// One iteration: the passes of [`CpuSolve::passes`], each by its twin.
    fn iterate_with(&mut self, it: Iteration, omega: f32, laps: &mut Laps<'_>) -> (f32, f32) {
        let mut work = Work::default();
        for pass in Choices::of_iteration(&it, self.holds()).passes() {
            self.run_pass(pass, it, omega, &mut work);
            laps.lap(pass);
        }
        let next = work.next.unwrap_or_else(|| self.current.clone());
        self.previous = std::mem::replace(&mut self.current, next);
        work.measured
    }

    /// At the current positions, left where they are, the smoothed elastic
    /// phase's residual `r = (f + b) / 2` and its two-level step (smoothed
    /// and corrected, undamped): a preconditioned direction of descent
    /// for a method that searches along it (`examples/ncg_trial.rs`).
    /// `None` outside an elastic phase that smooths with the volume
    /// smoother. The warm rotations and terms are those of the current
    /// positions afterwards, as after an iteration.
    pub fn residual_and_step(&mut self) -> Option<(Vec<Vec3>, Vec<Vec3>)> {
        let mut it = self
            .iteration
            .filter(|it| it.force == ForceModel::Elastic)?;
        it.damping = 1.0;
        let mut work = Work::default();
        for pass in Choices::of_iteration(&it, self.holds()).passes() {
            if !matches!(pass, Pass::StepNorms | Pass::Combine | Pass::UpdateNorms) {
                self.run_pass(pass, it, 1.0, &mut work);
            }
        }
        if work.residual.is_empty() {
            return None;
        }
        let step = work
            .plain
            .iter()
            .zip(&self.current)
            .map(|(&next, &now)| next - now)
            .collect();
        let residual = work.residual.iter().map(|r| r.as_vec3()).collect();
        Some((residual, step))
    }

    /// The springs an iteration with `it` applies: the pulls with the
    /// elastic force, none with the others (whose corrections are made
    /// for the Laplacian without them).
    fn springs_for(&self, it: Iteration) -> &[Spring] {
        if it.force == ForceModel::Elastic {
            &self.pulls
        } else {
            &[]
        }
    }

    /// Whether the skin is paired with an observation: one is held, and a
    /// pairing.
    fn pairs(&self) -> bool {
        self.observation.is_some() && self.pairing.is_some()
    }

    /// [`Pass::Pair`]: the pulls paired at the current positions, where an
    /// observation and a pairing are held.
    fn pair_at_current(&mut self) {
        if let (Some(field), Some(pairing)) = (&self.observation, &self.pairing) {
            pair(field, pairing, &self.current, &mut self.pulls);
            if let Some(coarse) = &mut self.elastic_coarse {
                Arc::make_mut(coarse).set_pulls(&self.pulls);
            }
        }
    }

    /// One pass of an iteration, on what the passes before it left in `work`.
    fn run_pass(&mut self, pass: Pass, it: Iteration, omega: f32, work: &mut Work) {
        let elastic_coarse = self
            .elastic_coarse
            .as_deref()
            .zip(self.elastic_aggregates.as_deref());
        match pass {
            Pass::Pair => self.pair_at_current(),
            Pass::Rotations(RotationMethod::Svd) => {
                self.rotations = local_rotations(&self.rest, &self.current, &self.connections);
            }
            Pass::Rotations(RotationMethod::WarmPolar) => {
                self.rotations = local_rotations_warm(
                    &self.rest,
                    &self.current,
                    &self.connections,
                    &self.rotations,
                );
            }
            Pass::ElasticTerms(method) => {
                if let Some(elastic) = self.elastic.as_deref() {
                    elastic_terms_into(
                        &self.rest,
                        &self.current,
                        &self.connections,
                        &self.rotations,
                        elastic,
                        method,
                        (&mut self.terms, &mut self.turned),
                    );
                    std::mem::swap(&mut self.rotations, &mut self.turned);
                }
            }
            Pass::Force => {
                work.force = deformation_force(
                    &self.rest,
                    &self.current,
                    &self.rotations,
                    &self.connections,
                    it.force,
                );
            }
            Pass::ElasticForce => {
                if let Some(elastic) = self.elastic.as_deref() {
                    work.force = elastic_force(
                        &self.rest,
                        &self.current,
                        &self.connections,
                        &self.terms,
                        elastic,
                    );
                }
            }
            Pass::PlainStep => {
                work.plain = integrate(
                    &self.current,
                    &work.force,
                    &self.loads,
                    self.springs_for(it),
                    &self.free,
                    it.alpha,
                );
            }
            Pass::SmoothedStep { .. } => {
                // The corrected elastic step made whole from the residual.
                let step = elastic_coarse.and_then(|(c, aggregates)| {
                    let mut residual = elastic_residual(
                        &work.force,
                        &self.current,
                        &self.loads,
                        &self.pulls,
                        &aggregates.aggregate,
                    );
                    // The two-level step is linear in the residual: a
                    // damped step is the step of the residual scaled.
                    if it.damping != 1.0 {
                        let damping = f64::from(it.damping);
                        residual.par_iter_mut().for_each(|r| *r *= damping);
                    }
                    let step = c.smoothed_step(aggregates, &self.connections, &residual);
                    work.residual = residual;
                    step
                });
                work.plain = match step {
                    Some(step) => self
                        .current
                        .par_iter()
                        .zip(&step)
                        .map(|(&q, s)| q + s.as_vec3())
                        .collect(),
                    None => integrate(
                        &self.current,
                        &work.force,
                        &self.loads,
                        self.springs_for(it),
                        &self.free,
                        it.alpha,
                    ),
                };
            }
            Pass::CoarseCorrection { .. } => {
                if let Some(coarse) = self.coarse.as_deref() {
                    coarse.correct(
                        &self.current,
                        &mut work.plain,
                        &self.connections,
                        it.contraction,
                    );
                }
            }
            Pass::ElasticCorrection { .. } => {
                if let Some((c, aggregates)) = elastic_coarse {
                    c.correct(
                        aggregates,
                        &self.current,
                        &mut work.plain,
                        &self.connections,
                    );
                }
            }
            Pass::StepNorms => work.measured = step_norms(&self.current, &work.plain),
            Pass::Combine => {
                let plain = std::mem::take(&mut work.plain);
                work.next = Some(if omega == 1.0 {
                    plain
                } else {
                    chebyshev_combine(&plain, &self.previous, omega)
                });
            }
            Pass::UpdateNorms => {
                if let Some(next) = &work.next {
                    work.measured = step_norms(&self.current, next);
                }
            }
        }
    }
}

/// What one iteration's passes hand on to the next ones.
#[derive(Default)]
struct Work {
    /// The force on each particle.
    force: Vec<Vec3>,
    /// The step's positions, plain or corrected.
    plain: Vec<Vec3>,
    /// The positions after the combine.
    next: Option<Vec<Vec3>>,
    /// The largest and RMS step the stopping rule measures.
    measured: (f32, f32),
    /// The residual the smoothed step read, `(f + b) / 2` scaled by the
    /// iteration's damping (empty where the iteration has none).
    residual: Vec<DVec3>,
}

/// The clock of a timed iteration: each lap's seconds to `clock`; off, no
/// clock is read.
struct Laps<'a> {
    clock: Option<&'a mut dyn FnMut(Pass, f64)>,
    since: Option<Instant>,
}

impl<'a> Laps<'a> {
    fn off() -> Self {
        Self {
            clock: None,
            since: None,
        }
    }

    fn on(clock: &'a mut dyn FnMut(Pass, f64)) -> Self {
        Self {
            clock: Some(clock),
            since: Some(Instant::now()),
        }
    }

    fn lap(&mut self, pass: Pass) {
        if let (Some(clock), Some(since)) = (self.clock.as_mut(), self.since.as_mut()) {
            clock(pass, since.elapsed().as_secs_f64());
            *since = Instant::now();
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;
    use tissue_core::deform::sagged_breast;
    use tissue_core::{SamplingParams, phantom};

    /// The residual and step a descent method reads are those of an
    /// undamped iteration at the current positions, which stay where they
    /// were; outside an elastic phase there are none.
    /// A tracker of the phantom at 1,500 particles (`before` run on it
    /// first) solved to the sagged breast.
    fn sagged_tracker(before: impl FnOnce(&mut Tracker<CpuSolve>)) -> Tracker<CpuSolve> {
        let model = crate::sampling::sample(
            &phantom::default_breast(),
            &SamplingParams::with_particles(1_500),
            &mut |_| {},
        )
        .unwrap()
        .model;
        let mut tracker = Tracker::new(&model, DeformParams::default(), |plan, params| {
            Ok::<_, Error>(CpuSolve::new(&model, plan, params))
        })
        .unwrap();
        before(&mut tracker);
        tracker.set_surface::<Error>(&sagged_breast()).unwrap();
        let Ok(report) = tracker.solve();
        assert!(report.converged, "{report:?}");
        tracker
    }

    #[test]
    fn the_residual_and_step_are_an_undamped_iterations_at_the_current_positions() {
        let mut tracker = sagged_tracker(|tracker| {
            assert!(tracker.device_mut().residual_and_step().is_none());
        });
        let solve = tracker.device_mut();
        assert!(solve.elastic_smoothed());
        // Off the answer, where the step is not small.
        let moved: Vec<Vec3> = solve
            .current
            .iter()
            .zip(&solve.free)
            .map(|(&p, &free)| {
                if free {
                    p + Vec3::new(0.3, -0.2, 0.1)
                } else {
                    p
                }
            })
            .collect();
        let Ok(()) = solve.write_positions(&moved, None);
        // The iteration compared with starts from the same warm rotations.
        let rotations = solve.rotations.clone();
        let (residual, step) = solve.residual_and_step().unwrap();
        assert_eq!(solve.current, moved);
        assert_eq!((residual.len(), step.len()), (moved.len(), moved.len()));
        let largest = step.iter().map(|s| s.length()).fold(0.0, f32::max);
        assert!(largest > 0.05, "step {largest}");
        solve.rotations = rotations;
        let Ok(_) = solve.run(&[1.0]);
        let off = moved
            .iter()
            .zip(&step)
            .zip(&solve.current)
            .map(|((&p, &s), &q)| (p + s).distance(q))
            .fold(0.0, f32::max);
        assert!(
            off < 1e-5 * largest.max(1.0),
            "{off} from the iteration's step"
        );
    }
    #[test]
    fn springs_set_keeping_the_correction_keep_it_where_others_make_it_again() {
        let mut tracker = sagged_tracker(|_| {});
        assert!(tracker.device().elastic_coarse().is_some());
        // Springs on every seventh free particle, of weight `w`, across z.
        let free = tracker.plan().free.clone();
        let springs = |w: f32, tracker: &Tracker<CpuSolve>| -> Vec<Spring> {
            (0..free.len())
                .map(|i| {
                    if free[i] && i % 7 == 0 {
                        Spring::plane(tracker.positions()[i], Vec3::Z, w)
                    } else {
                        Spring::ZERO
                    }
                })
                .collect()
        };
        let first = springs(0.5, &tracker);
        tracker
            .set_springs_keeping_correction::<Error>(first)
            .unwrap();
        assert!(
            tracker.device().elastic_coarse().is_some(),
            "kept for springs"
        );
        tracker
            .set_springs_keeping_correction::<Error>(Vec::new())
            .unwrap();
        assert!(
            tracker.device().elastic_coarse().is_some(),
            "kept without springs"
        );
        let other = springs(2.0, &tracker);
        tracker.set_springs::<Error>(other).unwrap();
        assert!(
            tracker.device().elastic_coarse().is_none(),
            "made again for other springs"
        );
    }
}
