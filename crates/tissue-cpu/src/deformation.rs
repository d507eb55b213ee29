//! Stage 2, deformation (the paper's Section 3), on the CPU.
//!
//! Surface particles (control points) follow the deformed surface through
//! their triangle + barycentric attachment; every other particle moves by
//! `q += F / m` until the residual force vanishes. Stage functions, each the
//! twin of a GPU shader of the same name:
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

use std::time::Instant;

use glam::{DMat3, DVec3, Mat3, Vec3, Vec3A};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tissue_core::{Connections, Error, ParticleModel, SurfaceMesh};

use crate::coarse::CoarseSpace;
use crate::svd3::rotation_of;

/// Which force model stage 2 uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ForceModel {
    /// The paper's one-sided force (not the gradient of an energy).
    Paper,
    /// The symmetric variant, the exact gradient of the rotation-aware energy.
    Symmetric,
}

/// How each particle's rotation is found every iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RotationMethod {
    /// A full 3x3 SVD of `M_i` (`svd3::rotation_of`) every iteration.
    Svd,
    /// The polar rotation of `M_i` by Müller et al. 2016 ("A Robust Method to
    /// Extract the Rotational Part of Deformations"), warm-started from the
    /// last iteration's rotation: the same rotation at convergence, a few
    /// cross products instead of an SVD.
    WarmPolar,
}

/// Parameters of stage 2; `docs/METHOD.md` explains the defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DeformParams {
    /// Force model.
    pub force: ForceModel,
    /// How rotations are found.
    pub rotations: RotationMethod,
    /// Step as a fraction of the largest stable step (`2 / lambda_max` for the
    /// paper's force, `1 / lambda_max` for the symmetric one).
    pub step_fraction: f32,
    /// Chebyshev semi-iterative acceleration (Wang 2015).
    pub chebyshev: bool,
    /// Plain iterations before Chebyshev starts. `rho` comes from the
    /// Laplacian's spectrum, so none are needed; 0 measured best.
    pub warm_up: usize,
    /// Stop when the error estimate `step / (1 - rho)` of every free particle is
    /// below this fraction of the model's size. 3e-5: at 10k particles on the
    /// phantom the estimate bottoms out near 1.5e-5 at single precision.
    pub tolerance: f32,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Tracking: start a new frame from the current state carried by the
    /// least-squares affine map of the surface's move, plus the combination
    /// of the last frames' non-affine changes that best matches the
    /// surface's own non-affine move (see [`predict`]).
    pub extrapolate: bool,
    /// Tracking: how many of the last frames' changes the prediction fits
    /// the new frame's surface move with (`0`: the affine map alone). Each
    /// costs a copy of the positions. 2 by default: see docs/METHOD.md.
    pub history: usize,
    /// Deflation: the number of lowest eigenvectors of the Dirichlet
    /// Laplacian over free particles (computed once per model) whose error
    /// every iteration removes exactly; Chebyshev and the stopping rule then
    /// use the next eigenvalue instead of the smallest (see [`LowModes`]).
    /// 32 by default: it halves the iterations of a solve from rest and
    /// brings tracking frames of up to 2 % of the size to at most 10
    /// iterations, where 0 (off) takes up to 29 (docs/METHOD.md); it costs
    /// 0.2 s of preparation at 10k particles, 4 s at 100k, and 10-40 % more
    /// time per iteration. One frame alone does not repay the preparation
    /// at 100k: `tissue deform` turns it off unless asked.
    ///
    /// Models with more free particles than [`DeformParams::deflation_max_particles`]
    /// are solved without it, and the CPU path does not deflate where the
    /// two-level solve ([`DeformParams::coarse`], on by default) runs.
    pub deflation: usize,
    /// Deflation is left out (with a log warning) for models with more free
    /// particles than this: the modes' preparation grows faster than the
    /// model (0.2 s at 10k, 4.4 s at 100k, 153 s and 1.8 GB of memory at
    /// 1M), and a solve from rest at 1M takes less than that. 200,000 by
    /// default; raise it to deflate larger models.
    pub deflation_max_particles: usize,
    /// Two-level solve (CPU): the edge of the grid cells whose free
    /// particles form one aggregate of the coarse space, in mean connection
    /// lengths; every iteration then removes the error's part in that space
    /// exactly (see [`crate::coarse`]). 0 turns it off. 2 by default: at 10k
    /// and 100k particles a solve from rest takes 12-18 iterations instead
    /// of 22-39 deflated and 50-186 plain, and every tracking frame of at
    /// most 2 % of the size, the first change away from rest included, at
    /// most 10 (docs/METHOD.md, "Two-level solve"). It costs 0.03 s of
    /// preparation at 10k particles and about as much per iteration as
    /// deflation. Where it is on, the CPU path does not deflate; the GPU
    /// path has no coarse correction yet and deflates instead.
    pub coarse: f32,
    /// The coarse space's cells grow (by factors of 1.25) until there are at
    /// most this many aggregates: its factor takes about `n^(5/3)` numbers
    /// and a solve as many multiply-adds per iteration, so it must stay
    /// small beside the model. 10,000 by default (about 8,000 aggregates at
    /// 100k particles, where a coarse solve costs a third of an iteration).
    pub coarse_max_aggregates: usize,
}

impl Default for DeformParams {
    fn default() -> Self {
        Self {
            force: ForceModel::Symmetric,
            rotations: RotationMethod::WarmPolar,
            step_fraction: 0.9,
            chebyshev: true,
            warm_up: 0,
            tolerance: 3e-5,
            max_iterations: 5_000,
            extrapolate: true,
            history: 2,
            deflation: 32,
            deflation_max_particles: 200_000,
            coarse: 2.0,
            coarse_max_aggregates: 10_000,
        }
    }
}

impl DeformParams {
    /// Checks every parameter, naming the first that is out of range.
    pub fn validate(&self) -> Result<(), Error> {
        let bad = |what: &str| Err(Error::Deformation(format!("deformation parameter {what}")));
        if !(self.step_fraction > 0.0 && self.step_fraction < 1.0) {
            return bad(&format!(
                "step_fraction is {}, expected in (0, 1)",
                self.step_fraction
            ));
        }
        if !(self.tolerance > 0.0 && self.tolerance.is_finite()) {
            return bad(&format!(
                "tolerance is {}, expected a positive number",
                self.tolerance
            ));
        }
        if self.history > MAX_HISTORY {
            return bad(&format!(
                "history is {}, expected 0 to {MAX_HISTORY} frames",
                self.history
            ));
        }
        if self.deflation > MAX_DEFLATION {
            return bad(&format!(
                "deflation is {}, expected 0 to {MAX_DEFLATION} modes",
                self.deflation
            ));
        }
        if !(self.coarse == 0.0 || (1.0..=1_000.0).contains(&self.coarse)) {
            return bad(&format!(
                "coarse is {}, expected 0 (off) or a cell of 1 to 1000 mean connection lengths",
                self.coarse
            ));
        }
        if !(1..=MAX_COARSE_AGGREGATES).contains(&self.coarse_max_aggregates) {
            return bad(&format!(
                "coarse_max_aggregates is {}, expected 1 to {MAX_COARSE_AGGREGATES}",
                self.coarse_max_aggregates
            ));
        }
        if self.max_iterations == 0 || self.max_iterations > 10_000_000 {
            return bad(&format!(
                "max_iterations is {}, expected 1 to 10,000,000",
                self.max_iterations
            ));
        }
        Ok(())
    }
}

/// Which rule ended a solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The error estimate fell below the tolerance.
    Tolerance,
    /// The steps fell to what `f32` resolves at the model's coordinates: the
    /// tolerance is finer than single precision can reach for this model.
    FloatPrecision,
    /// The iteration cap.
    IterationCap,
    /// The state became non-finite.
    Diverged,
}

/// How a solve went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeformReport {
    /// Iterations run.
    pub iterations: usize,
    /// The error estimate at the end, as a fraction of the model's size.
    pub residual: f32,
    /// The error estimate after every iteration.
    pub residual_history: Vec<f32>,
    /// Whether the stopping rule held before the cap.
    pub converged: bool,
    /// Which rule ended the solve.
    pub stopped_by: StopReason,
    /// Wall-clock seconds of the solve.
    pub seconds: f64,
}

/// What a stage-2 solve needs to know about a model before it starts, the
/// same for the CPU and the GPU path: which particles move, the spectrum
/// that sets the step and the Chebyshev rate, the model's size and the
/// finest step `f32` resolves at its coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Per particle: moved by the solve (not a control point, and connected
    /// to one through some path of connections).
    pub free: Vec<bool>,
    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub lambda_min: f32,
    /// Largest one, with a 2 % margin.
    pub lambda_max: f32,
    /// The model's bounding-box diagonal at rest.
    pub size: f32,
    /// An RMS step below this is `f32` rounding at the model's coordinates.
    pub floor: f32,
}

impl Plan {
    /// Checks `model` and works out its plan.
    pub fn new(model: &ParticleModel) -> Result<Self, Error> {
        let n = model.len();
        if n == 0 {
            return Err(Error::Deformation("the model has no particles".into()));
        }
        if model.connections.particles() != n {
            return Err(Error::Deformation(format!(
                "the model's connections describe {} particles, it has {n}",
                model.connections.particles()
            )));
        }
        if model.attachments.iter().all(Option::is_none) {
            return Err(Error::Deformation(
                "the model has no surface particles to follow the surface".into(),
            ));
        }
        if let Some(bad) = model
            .attachments
            .iter()
            .flatten()
            .find(|a| a.triangle as usize >= model.surface.triangles.len())
        {
            return Err(Error::Deformation(format!(
                "a surface particle is attached to triangle {}, the surface has {}",
                bad.triangle,
                model.surface.triangles.len()
            )));
        }
        let mut free: Vec<bool> = model.attachments.iter().map(Option::is_none).collect();
        // A free particle with no path of connections to a control point has
        // nothing to follow: it would stay put anyway, and its zero Laplacian
        // eigenvalue would stall the acceleration for everyone. Hold it.
        let anchored = anchored(&model.connections, &free);
        let floating = free
            .iter()
            .zip(&anchored)
            .filter(|(f, a)| **f && !**a)
            .count();
        if floating > 0 {
            log::warn!(
                "{floating} particles are not connected to the surface through any path of connections; \
                 they stay where they are"
            );
        }
        for (f, a) in free.iter_mut().zip(&anchored) {
            *f = *f && *a;
        }
        let (lambda_min, lambda_max) = laplacian_extremes(&model.connections, &free);
        let (lo, hi) = model.positions.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        // f32 resolves about EPSILON * |x|: at single precision most particles
        // no longer move and a few flip by an ulp, so the RMS step (unlike the
        // largest, which grows with the particle count) settles below one ulp.
        let largest = model
            .positions
            .iter()
            .map(|q| q.abs().max_element())
            .fold(0.0, f32::max);
        Ok(Self {
            free,
            lambda_min,
            lambda_max,
            size: (hi - lo).length(),
            floor: FLOOR_ULPS * f32::EPSILON * largest,
        })
    }

    /// The step `alpha = sigma / m`: `step_fraction` of the largest stable
    /// step, `2 / lambda_max` for the paper's force, `1 / lambda_max` for the
    /// symmetric one.
    pub fn alpha(&self, params: &DeformParams) -> f32 {
        let limit = match params.force {
            ForceModel::Paper => 2.0,
            ForceModel::Symmetric => 1.0,
        };
        params.step_fraction * limit / self.lambda_max.max(f32::MIN_POSITIVE)
    }

    /// `c alpha`: the plain step is `-c alpha L e` for the error `e` while the
    /// rotations are fixed (`c = 2` for the symmetric force, 1 for the paper's).
    pub fn contraction(&self, params: &DeformParams) -> f32 {
        let c = match params.force {
            ForceModel::Paper => 1.0,
            ForceModel::Symmetric => 2.0,
        };
        c * self.alpha(params)
    }

    /// The plain iteration `q <- (I - c alpha L) q + b` (`c = 2` symmetric, 1
    /// paper) contracts at `1 - 2 step_fraction lambda_min / lambda_max` for both.
    pub fn rho(&self, params: &DeformParams) -> f32 {
        (1.0 - 2.0 * params.step_fraction * self.lambda_min / self.lambda_max).clamp(0.0, 0.9999)
    }

    /// The contraction a solve's Chebyshev weights and stopping rule use:
    /// [`Plan::rho`]; with a coarse space, the two-level iteration's
    /// ([`CoarseSpace::rho`]); with deflation, what the modes leave
    /// ([`LowModes::rho`]).
    pub fn solve_rho(
        &self,
        params: &DeformParams,
        modes: Option<&LowModes>,
        coarse: Option<&CoarseSpace>,
    ) -> f32 {
        match (coarse, modes) {
            (Some(c), _) => c.rho(),
            (None, Some(m)) => m.rho(self, params),
            (None, None) => self.rho(params),
        }
    }
}

/// The RMS step, in ulps of the largest coordinate, below which a solve has
/// reached single precision.
const FLOOR_ULPS: f32 = 2.0;

/// The Chebyshev weights of Wang 2015, iteration by iteration:
/// `omega_2 = 2 / (2 - rho^2)`, `omega_{k+1} = 4 / (4 - rho^2 omega_k)`, and 1
/// (a plain step) during the warm-up or without acceleration.
#[derive(Debug, Clone)]
pub struct Chebyshev {
    rho: f32,
    enabled: bool,
    warm_up: usize,
    omega: f32,
}

impl Chebyshev {
    /// The sequence for one solve.
    pub fn new(plan: &Plan, params: &DeformParams) -> Self {
        Self {
            rho: plan.rho(params),
            enabled: params.chebyshev,
            warm_up: params.warm_up,
            omega: 1.0,
        }
    }

    /// The sequence for one solve with contraction `rho` (a deflated one, say).
    pub fn with_rho(params: &DeformParams, rho: f32) -> Self {
        Self {
            rho,
            enabled: params.chebyshev,
            warm_up: params.warm_up,
            omega: 1.0,
        }
    }

    /// The weight of iteration `iteration` (counted from 1).
    pub fn omega(&mut self, iteration: usize) -> f32 {
        if !self.enabled || iteration <= self.warm_up {
            return 1.0;
        }
        let rho2 = self.rho * self.rho;
        self.omega = if self.omega == 1.0 {
            2.0 / (2.0 - rho2)
        } else {
            4.0 / (4.0 - rho2 * self.omega)
        };
        self.omega
    }
}

/// The stopping rule of a solve, never on a small step alone: for fixed
/// rotations the plain step is `(B - I) e` for the error `e`, so
/// `|e| <= |step| / (1 - rho)`, Chebyshev or not. Re-fitting the rotations
/// adds slower modes (a twist of the interior against its surface); the
/// contraction observed over the last five iterations catches them. Stop when
/// `max step / (1 - rate)` is below `tolerance` times the size, or when the
/// RMS step is below what `f32` resolves.
#[derive(Debug, Clone)]
pub struct StoppingRule {
    tolerance: f32,
    size: f32,
    floor: f32,
    rho: f32,
    rms_steps: Vec<f32>,
    history: Vec<f32>,
}

impl StoppingRule {
    /// The rule for one solve.
    pub fn new(plan: &Plan, params: &DeformParams) -> Self {
        Self {
            tolerance: params.tolerance,
            size: plan.size,
            floor: plan.floor,
            rho: plan.rho(params),
            rms_steps: Vec::new(),
            history: Vec::new(),
        }
    }

    /// The rule for one solve with contraction `rho` (a deflated one, say).
    pub fn with_rho(plan: &Plan, params: &DeformParams, rho: f32) -> Self {
        Self {
            rho,
            ..Self::new(plan, params)
        }
    }

    /// Records an iteration's largest and RMS plain step; `Some` when the
    /// solve should stop after it.
    pub fn after(&mut self, max_step: f32, rms_step: f32) -> Option<StopReason> {
        self.rms_steps.push(rms_step);
        let n = self.rms_steps.len();
        let observed = if n > 5 {
            geometric_rate(self.rms_steps[n - 6], self.rms_steps[n - 1], 5)
        } else {
            0.0
        };
        let rate = self.rho.max(observed.min(0.999));
        let error = max_step / (1.0 - rate) / self.size;
        self.history.push(error);
        if !error.is_finite() {
            Some(StopReason::Diverged)
        } else if n > 1 && error < self.tolerance {
            Some(StopReason::Tolerance)
        } else if n > 1 && rms_step < self.floor {
            // Rounding noise: most particles no longer move, a few flip by an ulp.
            Some(StopReason::FloatPrecision)
        } else {
            None
        }
    }

    /// The report of the solve, ended by `stopped_by` after `iterations`.
    pub fn report(self, iterations: usize, stopped_by: StopReason, seconds: f64) -> DeformReport {
        DeformReport {
            iterations,
            residual: self.history.last().copied().unwrap_or(0.0),
            residual_history: self.history,
            converged: matches!(
                stopped_by,
                StopReason::Tolerance | StopReason::FloatPrecision
            ),
            stopped_by,
            seconds,
        }
    }
}

/// Stage 2 state for one particle model: rest shape, connections, control
/// points, and the current positions, kept between frames (warm start).
#[derive(Debug, Clone)]
pub struct Deformer {
    rest: Vec<Vec3>,
    connections: Connections,
    surface: SurfaceMesh,
    /// The attachment of each control point (`None` for other particles).
    attachments: Vec<Option<(u32, [f32; 3])>>,
    plan: Plan,
    current: Vec<Vec3>,
    /// The last converged solutions, for the prediction.
    history: FrameHistory,
    rotations: Vec<Mat3>,
    params: DeformParams,
    /// The lowest Laplacian modes removed exactly every iteration (not
    /// with a coarse space).
    modes: Option<std::sync::Arc<LowModes>>,
    /// The coarse space of the two-level solve.
    coarse: Option<std::sync::Arc<CoarseSpace>>,
}

impl Deformer {
    /// Prepares stage 2 for `model`: checks it, and estimates the largest
    /// eigenvalue of the connection-graph Laplacian over free particles.
    pub fn new(model: &ParticleModel, params: DeformParams) -> Result<Self, Error> {
        params.validate()?;
        let plan = Plan::new(model)?;
        let coarse = coarse_space(model, &plan, &params).map(std::sync::Arc::new);
        let modes = if coarse.is_some() {
            None
        } else {
            deflation_modes(model, &plan, &params).map(std::sync::Arc::new)
        };
        Ok(Self {
            coarse,
            rest: model.positions.clone(),
            connections: model.connections.clone(),
            surface: model.surface.clone(),
            attachments: model
                .attachments
                .iter()
                .map(|a| a.map(|a| (a.triangle, a.barycentric)))
                .collect(),
            plan,
            current: model.positions.clone(),
            history: FrameHistory::at_rest(&model.positions, params.history),
            rotations: vec![Mat3::IDENTITY; model.len()],
            params,
            modes,
        })
    }

    /// Current particle positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.current
    }

    /// Rest particle positions.
    pub fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// Each particle's rotation (rest offsets onto current offsets) from the last iteration.
    pub fn rotations(&self) -> &[Mat3] {
        &self.rotations
    }

    /// The model's size (bounding-box diagonal at rest).
    pub fn size(&self) -> f32 {
        self.plan.size
    }

    /// The solve's plan: free particles, spectrum, size, float floor.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_min(&self) -> f32 {
        self.plan.lambda_min
    }

    /// Largest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_max(&self) -> f32 {
        self.plan.lambda_max
    }

    /// The lowest Laplacian modes deflated every iteration, if any.
    pub fn modes(&self) -> Option<&LowModes> {
        self.modes.as_deref()
    }

    /// The coarse space of the two-level solve, if any.
    pub fn coarse(&self) -> Option<&CoarseSpace> {
        self.coarse.as_deref()
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        &self.params
    }

    /// Changes the parameters of the next solves (the tolerance between
    /// frames, say); the current state is kept. The coarse space and the
    /// deflated modes are prepared once, by [`Deformer::new`], for its
    /// `coarse`, `coarse_max_aggregates`, `deflation` and `step_fraction`:
    /// build a new deformer to change those.
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), Error> {
        params.validate()?;
        self.params = params;
        Ok(())
    }

    /// Back to the rest shape (no warm start).
    pub fn reset(&mut self) {
        self.current.clone_from(&self.rest);
        self.rotations.fill(Mat3::IDENTITY);
        self.history = FrameHistory::at_rest(&self.rest, self.params.history);
    }

    /// Places the control points on `deformed`, which must be the rest surface
    /// with moved vertices (same vertex count, same triangles).
    pub fn set_surface(&mut self, deformed: &SurfaceMesh) -> Result<(), Error> {
        check_same_topology(&self.surface, deformed)?;
        let controls: Vec<(usize, Vec3)> = self
            .attachments
            .iter()
            .enumerate()
            .filter_map(|(i, a)| a.map(|(t, bary)| (i, deformed.point_on(t as usize, bary))))
            .collect();
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
            // The warm-started rotations turn with the surface too.
            let turn = rotation_of(linear);
            self.rotations.par_iter_mut().for_each(|r| *r = turn * *r);
        }
        for (i, q) in controls {
            self.current[i] = q;
        }
        Ok(())
    }

    /// Iterates until the stopping rule holds or the cap is reached.
    ///
    /// Stopping rule: the error estimate `max step / (1 - rho)`, with `rho` the
    /// plain iteration's contraction rate from the Laplacian's spectrum, is
    /// below `tolerance` times the model's size; or the step is below what
    /// `f32` can resolve at the model's coordinates.
    pub fn solve(&mut self) -> DeformReport {
        let started = Instant::now();
        let p = &self.params;
        let alpha = self.plan.alpha(p);
        let modes = self.modes.clone();
        let coarse = self.coarse.clone();
        let rho = self.plan.solve_rho(p, modes.as_deref(), coarse.as_deref());
        let (mut chebyshev, mut rule) = (
            Chebyshev::with_rho(p, rho),
            StoppingRule::with_rho(&self.plan, p, rho),
        );
        let contraction = self.plan.contraction(p);
        let mut previous = self.current.clone();
        let mut stopped_by = StopReason::IterationCap;
        let mut iterations = 0;
        while iterations < p.max_iterations {
            self.rotations = match p.rotations {
                RotationMethod::Svd => {
                    local_rotations(&self.rest, &self.current, &self.connections)
                }
                RotationMethod::WarmPolar => local_rotations_warm(
                    &self.rest,
                    &self.current,
                    &self.connections,
                    &self.rotations,
                ),
            };
            let force = deformation_force(
                &self.rest,
                &self.current,
                &self.rotations,
                &self.connections,
                p.force,
            );
            let mut plain = integrate(&self.current, &force, &self.plan.free, alpha);
            if let Some(m) = &modes {
                m.deflate(&self.current, &mut plain, contraction);
            }
            if let Some(c) = &coarse {
                c.correct(&self.current, &mut plain, &self.connections, contraction);
            }
            // Deflated or two-level, the plain step no longer bounds the error of the
            // modes coupled to the rotations (re-fitting them lowers the
            // curvature below the Laplacian's, so the exact correction for
            // fixed rotations under-corrects them): the error is bounded by
            // the geometric tail of the updates actually made instead.
            let plain_steps =
                (modes.is_none() && coarse.is_none()).then(|| steps(&self.current, &plain));
            iterations += 1;
            let omega = chebyshev.omega(iterations);
            let next = if omega == 1.0 {
                plain
            } else {
                chebyshev_combine(&plain, &previous, omega)
            };
            let (step, rms) = plain_steps.unwrap_or_else(|| steps(&self.current, &next));
            previous = std::mem::replace(&mut self.current, next);
            if let Some(reason) = rule.after(step, rms) {
                stopped_by = reason;
                break;
            }
        }
        let report = rule.report(iterations, stopped_by, started.elapsed().as_secs_f64());
        self.history
            .record(&self.current, report.converged, self.params.history);
        report
    }
}

/// The most frames [`DeformParams::history`] may keep: each is a copy of
/// the positions, and a fit with more columns than the surface's changes
/// have independent shapes only adds noise.
pub const MAX_HISTORY: usize = 16;

/// The converged solutions of the last frames, oldest first, from which
/// [`predict`] takes the changes it fits a new frame's surface move with.
/// A solve that did not converge clears it: its state is no change worth
/// repeating.
#[derive(Debug, Clone, Default)]
pub struct FrameHistory {
    solutions: std::collections::VecDeque<Vec<Vec3>>,
}

impl FrameHistory {
    /// The history of a model at rest: the rest shape is a solved frame
    /// (the exact answer for the rest surface), so the first solve's change
    /// from it already gives the second frame a shape to fit (a sag grown
    /// by 2 % of itself after a first frame of half of it: 2 iterations
    /// instead of 11, deflated at 10k).
    pub fn at_rest(rest: &[Vec3], depth: usize) -> Self {
        let mut history = Self::default();
        history.record(rest, true, depth);
        history
    }

    /// Keeps `solution` (when `converged`) and the `depth` solutions
    /// before it, which give `depth` changes.
    pub fn record(&mut self, solution: &[Vec3], converged: bool, depth: usize) {
        if !converged || depth == 0 {
            self.solutions.clear();
            return;
        }
        let mut kept = Vec::new();
        while self.solutions.len() > depth {
            kept = self.solutions.pop_front().unwrap_or_default();
        }
        kept.clear();
        kept.extend_from_slice(solution);
        self.solutions.push_back(kept);
    }

    /// Forgets every frame (a reset, or a new model state).
    pub fn clear(&mut self) {
        self.solutions.clear();
    }

    /// The number of frame-to-frame changes kept.
    pub fn changes(&self) -> usize {
        self.solutions.len().saturating_sub(1)
    }

    /// `(earlier, later)` solution pairs, newest first.
    fn pairs(&self) -> impl Iterator<Item = (&[Vec3], &[Vec3])> {
        let s = &self.solutions;
        (1..s.len())
            .rev()
            .map(move |k| (s[k - 1].as_slice(), s[k].as_slice()))
    }
}

/// Where a new frame's solve starts: the current state carried along by the
/// surface's move, plus what the last frames' changes say about its
/// non-affine part. `controls` are the control particles' new positions;
/// `current` is the last solution (the newest in `history`, if any).
///
/// - `A`, the least-squares affine map of the control points from where
///   they are in `current` to where they go, carries every particle:
///   `A(q)`. Exact for a rigid or affine move, of the sequence or of the frame.
/// - The rest of the control points' move, `r = controls - A(current)`, is
///   fitted in least squares by the non-affine parts of the last frames'
///   changes at the control points: `r ~ sum_k beta_k d_k`, where `d_k` is
///   change `k` less the least-squares affine function of the *current*
///   control positions closest to it. One base for every change and for
///   `r` keeps the fit exact for moves in the span of the changes: with
///   fitted each on its own base (the positions the change started from),
///   the affine parts of a sag and an indentation mixed at two rhythms left
///   3-7 % of the move unfitted. With the rotations fixed the interior's
///   answer is linear in the surface's move, so every particle gets
///   `sum_k beta_k d_k` too. A sag growing by the same step gets `beta = 1`
///   (constant velocity); a breathing one the ratio of this step to the
///   last, negative where it turns.
/// - A change whose control part is below `noise` (the solve's tolerance,
///   as a length) everywhere is left out: it is affine, and its interior is
///   what the last solves left undone; extrapolating that made the error
///   grow frame after frame. So is a change the ones before it (newer)
///   nearly explain already (a hundredth of its length left), which would
///   otherwise amplify their noise. A tenth, as before the common base,
///   dropped the older change of a sag and an indentation mixed at two
///   rhythms (their changes differ by a few degrees at the surface); a
///   floor from the solve's tolerance dropped the single change of a slow
///   sag (docs/METHOD.md).
///
/// Returns the predicted positions and `L` (the identity when the control
/// points do not determine `A`, and nothing moves).
pub fn predict(
    current: &[Vec3],
    history: &FrameHistory,
    controls: &[(usize, Vec3)],
    noise: f32,
) -> (Vec<Vec3>, Mat3) {
    let from: Vec<Vec3> = controls.iter().map(|&(i, _)| current[i]).collect();
    let to: Vec<Vec3> = controls.iter().map(|&(_, q)| q).collect();
    let Some((linear, shift)) = affine_fit(&from, &to) else {
        return (current.to_vec(), Mat3::IDENTITY);
    };
    let carried = |q: Vec3| linear * q + shift;
    let changes: Vec<Vec<Vec3>> = history
        .pairs()
        .filter_map(|(earlier, later)| {
            let moved: Vec<Vec3> = controls
                .iter()
                .map(|&(i, _)| current[i] + (later[i] - earlier[i]))
                .collect();
            let (l, t) = affine_fit(&from, &moved)?;
            let d: Vec<Vec3> = earlier
                .par_iter()
                .zip(later)
                .zip(current)
                .map(|((&e, &q), &c)| (q - e) - (l * c + t - c))
                .collect();
            controls
                .iter()
                .any(|&(i, _)| d[i].length() >= noise)
                .then_some(d)
        })
        .collect();
    let flat = |points: &mut dyn Iterator<Item = Vec3>| -> Vec<f64> {
        points
            .flat_map(|p| p.as_dvec3().to_array())
            .collect::<Vec<f64>>()
    };
    let target = flat(&mut from.iter().zip(&to).map(|(&f, &t)| t - carried(f)));
    let columns: Vec<Vec<f64>> = changes
        .iter()
        .map(|d| flat(&mut controls.iter().map(|&(i, _)| d[i])))
        .collect();
    let beta = least_squares(&columns, &target, 0.01);
    let predicted = current
        .par_iter()
        .enumerate()
        .map(|(i, &q)| {
            let fitted: Vec3 = changes
                .iter()
                .zip(&beta)
                .map(|(d, &b)| b as f32 * d[i])
                .sum();
            carried(q) + fitted
        })
        .collect();
    (predicted, linear)
}

/// The coefficients `beta` minimising `|target - sum_k beta_k columns_k|`,
/// by modified Gram-Schmidt. A column with less than `keep` of its length
/// outside the span of the columns before it gets `beta = 0`: nearly
/// dependent columns would only amplify their noise.
fn least_squares(columns: &[Vec<f64>], target: &[f64], keep: f64) -> Vec<f64> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    // The kept columns' orthonormal basis, their column of R, and index.
    let mut basis: Vec<Vec<f64>> = Vec::new();
    let mut r: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    for (k, column) in columns.iter().enumerate() {
        let length = dot(column, column).sqrt();
        let mut v = column.clone();
        let mut coefficients = Vec::with_capacity(basis.len() + 1);
        for q in &basis {
            let c = dot(q, &v);
            v.iter_mut().zip(q).for_each(|(v, q)| *v -= c * q);
            coefficients.push(c);
        }
        let rest = dot(&v, &v).sqrt();
        if !(length > 0.0 && rest > keep * length) {
            continue;
        }
        v.iter_mut().for_each(|v| *v /= rest);
        coefficients.push(rest);
        basis.push(v);
        r.push(coefficients);
        kept.push(k);
    }
    let y: Vec<f64> = basis.iter().map(|q| dot(q, target)).collect();
    let mut solved = vec![0.0; kept.len()];
    for i in (0..kept.len()).rev() {
        let later: f64 = (i + 1..kept.len()).map(|j| r[j][i] * solved[j]).sum();
        solved[i] = (y[i] - later) / r[i][i];
    }
    let mut beta = vec![0.0; columns.len()];
    for (k, b) in kept.into_iter().zip(solved) {
        beta[k] = b;
    }
    beta
}

/// The affine map `x -> L x + t` that moves the points `from` closest to
/// `to` in least squares, in `f64`; `None` when the points do not span 3D
/// well enough to determine it (fewer than four, or nearly coplanar).
pub fn affine_fit(from: &[Vec3], to: &[Vec3]) -> Option<(Mat3, Vec3)> {
    if from.len() != to.len() || from.len() < 4 {
        return None;
    }
    let count = from.len() as f64;
    let mean = |points: &[Vec3]| points.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / count;
    let (from_mean, to_mean) = (mean(from), mean(to));
    let mut spread = DMat3::ZERO;
    let mut cross = DMat3::ZERO;
    for (a, b) in from.iter().zip(to) {
        let a = a.as_dvec3() - from_mean;
        let b = b.as_dvec3() - to_mean;
        spread += outer(a, a);
        cross += outer(b, a);
    }
    // Nearly coplanar points leave the map along the normal undetermined:
    // a condition number of 1e8 in the spread is about 1e4 in distances.
    let trace = spread.x_axis.x + spread.y_axis.y + spread.z_axis.z;
    let determinant = spread.determinant();
    if !(trace > 0.0 && determinant > 1e-24 * trace * trace * trace) {
        return None;
    }
    let linear = cross * spread.inverse();
    let shift = to_mean - linear * from_mean;
    let linear = linear.as_mat3();
    let shift = shift.as_vec3();
    (linear.is_finite() && shift.is_finite()).then_some((linear, shift))
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The Chebyshev step: `omega (q_hat - q_old) + q_old`.
pub fn chebyshev_combine(plain: &[Vec3], previous: &[Vec3], omega: f32) -> Vec<Vec3> {
    plain
        .par_iter()
        .zip(previous)
        .map(|(&q_hat, &q_old)| omega * (q_hat - q_old) + q_old)
        .collect()
}

/// `(last / first)^(1 / count)`: the mean contraction per iteration.
fn geometric_rate(first: f32, last: f32, count: usize) -> f32 {
    if first <= 0.0 || count == 0 {
        return 0.0;
    }
    (last / first).powf(1.0 / count as f32)
}

/// Largest and RMS plain step over all particles (`old` to `new`), as
/// [`Deformer::solve`] measures each iteration.
pub fn steps(old: &[Vec3], new: &[Vec3]) -> (f32, f32) {
    let squares: Vec<f32> = old
        .par_iter()
        .zip(new)
        .map(|(a, b)| (*b - *a).length_squared())
        .collect();
    let max = squares.iter().copied().fold(0.0, f32::max).sqrt();
    let mean = squares.iter().map(|&x| f64::from(x)).sum::<f64>() / squares.len().max(1) as f64;
    (max, mean.sqrt() as f32)
}

/// Per particle: reachable from a control point through connections.
fn anchored(connections: &Connections, free: &[bool]) -> Vec<bool> {
    let mut reached: Vec<bool> = free.iter().map(|f| !f).collect();
    let mut stack: Vec<usize> = (0..free.len()).filter(|&i| reached[i]).collect();
    while let Some(i) = stack.pop() {
        for &j in connections.of(i) {
            if !reached[j as usize] {
                reached[j as usize] = true;
                stack.push(j as usize);
            }
        }
    }
    reached
}

/// The deformed surface must be the rest surface with moved vertices.
pub fn check_same_topology(rest: &SurfaceMesh, deformed: &SurfaceMesh) -> Result<(), Error> {
    if deformed.vertices.len() != rest.vertices.len()
        || deformed.triangles.len() != rest.triangles.len()
    {
        return Err(Error::Deformation(format!(
            "the deformed surface has {} vertices and {} triangles; the model's rest surface has {} and {} \
             (it must be the same mesh with moved vertices)",
            deformed.vertices.len(),
            deformed.triangles.len(),
            rest.vertices.len(),
            rest.triangles.len()
        )));
    }
    if let Some(t) = (0..rest.triangles.len()).find(|&t| rest.triangles[t] != deformed.triangles[t])
    {
        return Err(Error::Deformation(format!(
            "triangle {t} of the deformed surface is {:?}, in the rest surface {:?} \
             (it must be the same mesh with moved vertices)",
            deformed.triangles[t], rest.triangles[t]
        )));
    }
    if let Some(v) = deformed.vertices.iter().position(|v| !v.is_finite()) {
        return Err(Error::Deformation(format!(
            "vertex {v} of the deformed surface is not finite: {}",
            deformed.vertices[v]
        )));
    }
    Ok(())
}

/// Per particle, the rotation that best maps rest offsets onto current
/// offsets: the polar rotation of `M_i = sum_j (q_j - q_i)(p_j - p_i)^T`.
pub fn local_rotations(rest: &[Vec3], current: &[Vec3], connections: &Connections) -> Vec<Mat3> {
    (0..rest.len())
        .into_par_iter()
        .map(|i| rotation_of(offsets_product(rest, current, connections, i)))
        .collect()
}

/// `M_i = sum_j (q_j - q_i)(p_j - p_i)^T` over particle `i`'s connections:
/// the matrix whose polar rotation maps its rest offsets onto its current ones.
fn offsets_product(rest: &[Vec3], current: &[Vec3], connections: &Connections, i: usize) -> Mat3 {
    let mut m = Mat3::ZERO;
    for &j in connections.of(i) {
        let d = rest[j as usize] - rest[i];
        let c = current[j as usize] - current[i];
        m += Mat3::from_cols(c * d.x, c * d.y, c * d.z);
    }
    m
}

/// Iterations of the warm-started polar update per solver iteration; the
/// solver's own iterations refine it further.
const POLAR_ITERATIONS: usize = 3;

/// [`local_rotations`] by Müller et al.'s polar iteration, warm-started
/// from `previous` (rest offsets onto current offsets, like `local_rotations`).
pub fn local_rotations_warm(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    previous: &[Mat3],
) -> Vec<Mat3> {
    (0..rest.len())
        .into_par_iter()
        .map(|i| warm_rotation(offsets_product(rest, current, connections, i), previous[i]))
        .collect()
}

/// The polar rotation of `m` from `start` by the warm update; where that has
/// not settled (far from `start`, or near a saddle of `trace(R^T m)`), the SVD.
pub fn warm_rotation(m: Mat3, start: Mat3) -> Mat3 {
    match polar_rotation(m, start, POLAR_ITERATIONS) {
        (r, true) => r,
        (_, false) => rotation_of(m),
    }
}

/// The last turn of a settled polar update is below this (radians).
const POLAR_SETTLED: f32 = 1e-3;

/// Rotates `start` towards the polar rotation of `m` (the rotation `R`
/// maximising `trace(R^T m)`): each step turns `R` about
/// `sum_c r_c x m_c / |sum_c r_c . m_c|` (Müller et al. 2016, eq. 13).
/// Returns the rotation and whether it settled: its last turn was below
/// `POLAR_SETTLED` while `trace(R^T m) > 0` (so not at a saddle).
pub fn polar_rotation(m: Mat3, start: Mat3, iterations: usize) -> (Mat3, bool) {
    let scale = m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return (start, true);
    }
    let m = m * (1.0 / scale);
    let mut q = glam::Quat::from_mat3(&start).normalize();
    let mut settled = false;
    for _ in 0..iterations {
        let r = Mat3::from_quat(q);
        let cross = r.x_axis.cross(m.x_axis) + r.y_axis.cross(m.y_axis) + r.z_axis.cross(m.z_axis);
        let dot = r.x_axis.dot(m.x_axis) + r.y_axis.dot(m.y_axis) + r.z_axis.dot(m.z_axis);
        let omega = cross * (1.0 / (dot.abs() + 1e-9));
        let angle = omega.length();
        settled = dot > 0.0 && angle < POLAR_SETTLED;
        if angle < 1e-9 {
            break;
        }
        q = (glam::Quat::from_axis_angle(omega / angle, angle) * q).normalize();
    }
    (Mat3::from_quat(q), settled)
}

/// The force on every particle, gathered over its connections.
pub fn deformation_force(
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
    connections: &Connections,
    model: ForceModel,
) -> Vec<Vec3> {
    (0..rest.len())
        .into_par_iter()
        .map(|j| {
            let mut f = Vec3::ZERO;
            for &i in connections.of(j) {
                let i = i as usize;
                let d = rest[j] - rest[i];
                let c = current[j] - current[i];
                f += match model {
                    ForceModel::Paper => rotations[i] * d - c,
                    ForceModel::Symmetric => (rotations[i] + rotations[j]) * d - 2.0 * c,
                };
            }
            f
        })
        .collect()
}

/// `q += alpha F` for free particles (the stiffness `sigma` and mass `m`
/// fold into `alpha = sigma / m`); control points stay where the surface put them.
pub fn integrate(current: &[Vec3], force: &[Vec3], free: &[bool], alpha: f32) -> Vec<Vec3> {
    current
        .par_iter()
        .zip(force)
        .zip(free)
        .map(|((&q, &f), &free)| if free { q + alpha * f } else { q })
        .collect()
}

/// The lowest eigenpairs of the connection-graph Laplacian over free
/// particles (control points fixed: Dirichlet rows), for deflation. For fixed
/// rotations the plain step is `-c alpha L e` for the error `e` (`c = 2` for
/// the symmetric force, 1 for the paper's), so the error along an
/// eigenvector `v` with eigenvalue `lambda` is `-(v . step) / (c alpha lambda)`:
/// [`LowModes::deflate`] removes it exactly, and what is left of the error
/// lies in modes with eigenvalues from `next` up.
#[derive(Debug, Clone, PartialEq)]
pub struct LowModes {
    /// Particle-major: `vectors[i * count + k]` is eigenvector `k` at particle `i`
    /// (0 at particles that are not free).
    vectors: Vec<f32>,
    /// The eigenvalues, ascending.
    values: Vec<f64>,
    /// A lower estimate of the next eigenvalue, the smallest left to Chebyshev.
    next: f32,
    /// The largest relative residual `|L v - lambda v| / lambda` of the vectors.
    residual: f64,
    /// Seconds spent computing them.
    seconds: f64,
}

impl LowModes {
    /// Number of modes.
    pub fn count(&self) -> usize {
        self.values.len()
    }

    /// The eigenvalues, ascending.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The eigenvectors, particle-major (`vectors()[i * count() + k]` is
    /// mode `k` at particle `i`, 0 where the particle is not free), so the
    /// GPU deflates with the very modes the CPU path does.
    pub fn vectors(&self) -> &[f32] {
        &self.vectors
    }

    /// The smallest eigenvalue left after deflation (estimated from below).
    pub fn next(&self) -> f32 {
        self.next
    }

    /// The largest relative residual of the eigenvectors.
    pub fn residual(&self) -> f64 {
        self.residual
    }

    /// Seconds it took to compute them.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    /// The plain iteration's contraction on what deflation leaves:
    /// `1 - 2 step_fraction next / lambda_max`.
    pub fn rho(&self, plan: &Plan, params: &DeformParams) -> f32 {
        (1.0 - 2.0 * params.step_fraction * self.next / plan.lambda_max).clamp(0.0, 0.9999)
    }

    /// Per mode, `1 / (contraction lambda_k) - 1` in `f64`: what turns the
    /// plain step's component along mode `k` into the correction that
    /// removes its error ([`LowModes::deflate`]; the GPU uploads them).
    pub fn gain_scales(&self, contraction: f32) -> impl Iterator<Item = f64> + '_ {
        let c = f64::from(contraction);
        self.values
            .iter()
            .map(move |&lambda| 1.0 / (c * lambda) - 1.0)
    }

    /// Turns the plain step `plain - current` into one that also removes the
    /// error along every mode: the step's component `s_k` along mode `k` is
    /// `c alpha lambda_k` times the error there (`contraction = c alpha`),
    /// so the mode moves by `s_k / (c alpha lambda_k)` instead of `s_k`.
    pub fn deflate(&self, current: &[Vec3], plain: &mut [Vec3], contraction: f32) {
        let m = self.count();
        const CHUNK: usize = 1024;
        // Per particle, one 4-lane multiply-add per mode (`Vec3A`), summed in
        // `f32` within a chunk and in `f64` across chunks.
        let projections = current
            .par_chunks(CHUNK)
            .zip(plain.par_chunks(CHUNK))
            .zip(self.vectors.par_chunks(CHUNK * m))
            .map(|((q, p), v)| {
                let mut c = vec![Vec3A::ZERO; m];
                for ((q, p), v) in q.iter().zip(p).zip(v.chunks_exact(m)) {
                    let s = Vec3A::from(*p - *q);
                    for (c, &v) in c.iter_mut().zip(v) {
                        *c += s * v;
                    }
                }
                c.into_iter().map(|c| c.as_dvec3()).collect::<Vec<_>>()
            })
            .reduce(|| vec![DVec3::ZERO; m], add_entries);
        let gains: Vec<Vec3A> = projections
            .iter()
            .zip(self.gain_scales(contraction))
            .map(|(c, scale)| Vec3A::from((*c * scale).as_vec3()))
            .collect();
        plain
            .par_chunks_mut(CHUNK)
            .zip(self.vectors.par_chunks(CHUNK * m))
            .for_each(|(p, v)| {
                for (p, v) in p.iter_mut().zip(v.chunks_exact(m)) {
                    let mut d = Vec3A::ZERO;
                    for (&g, &v) in gains.iter().zip(v) {
                        d += g * v;
                    }
                    *p += Vec3::from(d);
                }
            });
    }
}

/// The modes a solve of `model` deflates under `params`, as both backends
/// compute them: none without deflation, where none came out (`low_modes`
/// warned), or (with a warning) for a model with more free particles than
/// `deflation_max_particles`.
pub fn deflation_modes(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<LowModes> {
    if params.deflation == 0 {
        return None;
    }
    let free = plan.free.iter().filter(|&&f| f).count();
    if free > params.deflation_max_particles {
        log::warn!(
            "no deflation: {free} free particles, more than deflation_max_particles \
             ({}); preparing {} modes would take minutes",
            params.deflation_max_particles,
            params.deflation
        );
        return None;
    }
    Some(low_modes(
        &model.connections,
        &plan.free,
        params.deflation,
        plan.lambda_min,
        plan.lambda_max,
    ))
    .filter(|m| m.count() > 0)
}

/// The coarse space a CPU solve of `model` uses under `params`: none with
/// `coarse` 0, or (with a warning) where it cannot be built.
pub fn coarse_space(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<CoarseSpace> {
    if params.coarse == 0.0 {
        return None;
    }
    let space = CoarseSpace::new(
        &model.positions,
        &model.connections,
        &plan.free,
        params.coarse * model.mean_connection_length(),
        params.coarse_max_aggregates,
        plan.contraction(params),
    );
    match space {
        Ok(space) => {
            log::info!(
                "two-level solve: {} aggregates in cells of {:.3}, contraction {:.3}, prepared in {:.3} s",
                space.count(),
                space.cell(),
                space.rho(),
                space.seconds()
            );
            Some(space)
        }
        Err(e) => {
            log::warn!("no two-level solve: {e}");
            None
        }
    }
}

/// The most aggregates [`DeformParams::coarse_max_aggregates`] may allow:
/// the factor of 50,000 holds about 70 million numbers (0.5 GB).
pub const MAX_COARSE_AGGREGATES: usize = 50_000;

/// The most modes [`DeformParams::deflation`] may ask for: each costs a
/// pass over the particles per iteration and `4 n` bytes.
pub const MAX_DEFLATION: usize = 256;

/// Guard vectors carried beyond the modes wanted, so that the last wanted
/// one and the next eigenvalue converge.
const MODE_GUARDS: usize = 8;
/// Degree of the Chebyshev filter of each subspace iteration, per
/// `sqrt(lambda_max / cut)` (what separates the wanted modes by a fixed factor).
const MODE_FILTER_DEGREE: f64 = 4.0;
/// Subspace iterations at most.
const MODE_ITERATIONS: usize = 60;
/// Seed of the random start block (any fixed value: the modes do not depend on it).
const MODE_SEED: u64 = 0x9e37_79b9_7f4a_7c15;
/// Relative eigenvector residual at which the modes are taken as converged.
const MODE_RESIDUAL: f64 = 1e-5;

/// The `count` lowest eigenpairs of the Laplacian over free particles by
/// Chebyshev-filtered subspace iteration (Zhou and Saad 2007) in `f64`:
/// each round applies a Chebyshev polynomial of the Laplacian that
/// damps `[cut, lambda_max]` to a block of `count + 8` vectors,
/// orthonormalises it and takes the Ritz vectors; `cut`, the block's largest
/// Ritz value, falls as they converge. `lambda_max` must bound the spectrum
/// from above.
pub fn low_modes(
    connections: &Connections,
    free: &[bool],
    count: usize,
    lambda_min: f32,
    lambda_max: f32,
) -> LowModes {
    let started = Instant::now();
    let index: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
    let n = index.len();
    let count = count.min(n.saturating_sub(1));
    let empty = || LowModes {
        vectors: vec![0.0; free.len() * count.max(1)],
        values: vec![],
        next: lambda_min,
        residual: 0.0,
        seconds: started.elapsed().as_secs_f64(),
    };
    if count == 0 {
        return empty();
    }
    let block = (count + MODE_GUARDS).min(n);
    // Free-only rows: diagonal (all connections) and free neighbours.
    let mut local = vec![usize::MAX; free.len()];
    for (k, &i) in index.iter().enumerate() {
        local[i] = k;
    }
    // Free-only rows in compressed form: diagonal, and free neighbours.
    let diagonal: Vec<f64> = index
        .iter()
        .map(|&i| connections.of(i).len() as f64)
        .collect();
    let mut offsets = Vec::with_capacity(n + 1);
    let mut columns = Vec::new();
    offsets.push(0);
    for &i in &index {
        columns.extend(
            connections
                .of(i)
                .iter()
                .filter(|&&j| free[j as usize])
                .map(|&j| local[j as usize] as u32),
        );
        offsets.push(columns.len());
    }
    // `L X` for the block `X` held particle-major (`x[i * block + a]`), so
    // one pass over the rows serves every vector and the inner loops run
    // over contiguous vector entries.
    let apply = |x: &[f64]| -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        y.par_chunks_mut(block).enumerate().for_each(|(i, y)| {
            let own = &x[i * block..(i + 1) * block];
            y.iter_mut()
                .zip(own)
                .for_each(|(y, v)| *y = diagonal[i] * v);
            for &j in &columns[offsets[i]..offsets[i + 1]] {
                let j = j as usize;
                y.iter_mut()
                    .zip(&x[j * block..(j + 1) * block])
                    .for_each(|(y, v)| *y -= v);
            }
        });
        y
    };
    // A deterministic random start.
    let mut rng = Pcg64::seed_from_u64(MODE_SEED);
    let mut x: Vec<f64> = (0..n * block).map(|_| rng.random::<f64>() - 0.5).collect();
    let upper = f64::from(lambda_max);
    // The first cut: a guess of where the block's spectrum ends, lowered to
    // the block's largest Ritz value after every round.
    let mut cut = (f64::from(lambda_min) * (block as f64).powf(2.0 / 3.0) * 2.0).min(upper * 0.5);
    let mut values = vec![0.0; block];
    let mut residual = f64::INFINITY;
    for _ in 0..MODE_ITERATIONS {
        // Filter: T_d((L - c) / e) with [cut, upper] mapped onto [-1, 1].
        let (c, e) = (0.5 * (upper + cut), 0.5 * (upper - cut));
        let degree = (MODE_FILTER_DEGREE * (upper / cut).sqrt()).clamp(8.0, 400.0) as usize;
        let mut previous = x;
        let mut current: Vec<f64> = apply(&previous)
            .par_iter()
            .zip(&previous)
            .map(|(l, v)| (l - c * v) / e)
            .collect();
        for _ in 1..degree {
            let next: Vec<f64> = apply(&current)
                .par_iter()
                .zip(&current)
                .zip(&previous)
                .map(|((l, v), p)| 2.0 * (l - c * v) / e - p)
                .collect();
            previous = std::mem::replace(&mut current, next);
            // Keep the scale in range.
            let largest = current.par_iter().map(|x| x.abs()).reduce(|| 0.0, f64::max);
            if largest > 1e100 {
                current.par_iter_mut().for_each(|x| *x /= largest);
                previous.par_iter_mut().for_each(|x| *x /= largest);
            }
        }
        // Orthonormalise (Cholesky QR, twice: Fukaya et al. 2014).
        x = current;
        for _ in 0..2 {
            if !orthonormalise_rows(&mut x, block) {
                log::warn!("the Laplacian's low modes did not come out; no deflation");
                return LowModes {
                    vectors: vec![],
                    ..empty()
                };
            }
        }
        // Rayleigh-Ritz.
        let lx = apply(&x);
        let (theta, z) = symmetric_eigen(&mut row_gram(&x, &lx, block), block);
        x = times_rows(&x, &z, block);
        let lx = times_rows(&lx, &z, block);
        values = theta;
        // Per vector, |L v - theta v|, relative to theta.
        let checked = (count + 1).min(block);
        let squares = lx
            .par_chunks(block)
            .zip(x.par_chunks(block))
            .fold(
                || vec![0.0; checked],
                |mut sums, (l, v)| {
                    for k in 0..checked {
                        sums[k] += (l[k] - values[k] * v[k]).powi(2);
                    }
                    sums
                },
            )
            .reduce(|| vec![0.0; checked], add_entries);
        residual = squares
            .iter()
            .zip(&values)
            .map(|(r, v)| r.sqrt() / v.abs().max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max);
        cut = values[block - 1];
        if residual < MODE_RESIDUAL {
            break;
        }
    }
    if !values.iter().all(|v| v.is_finite() && *v > 0.0) {
        log::warn!("the Laplacian's low modes did not come out; no deflation");
        return LowModes {
            vectors: vec![],
            ..empty()
        };
    }
    let mut vectors = vec![0.0f32; free.len() * count];
    for (k, &i) in index.iter().enumerate() {
        for m in 0..count {
            vectors[i * count + m] = x[k * block + m] as f32;
        }
    }
    LowModes {
        vectors,
        values: values[..count].to_vec(),
        // Ritz values bound eigenvalues from above; a little margin for a
        // next eigenvalue not fully converged.
        next: (values[count] * 0.97) as f32,
        residual,
        seconds: started.elapsed().as_secs_f64(),
    }
}

/// `a + b`, entry by entry: how partial sums from parallel chunks combine.
fn add_entries<T: std::ops::AddAssign>(mut a: Vec<T>, b: Vec<T>) -> Vec<T> {
    a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
    a
}

/// `A^T B` for two blocks held particle-major (`a[i * block + k]`): a
/// `block x block` matrix, row-major.
fn row_gram(a: &[f64], b: &[f64], block: usize) -> Vec<f64> {
    a.par_chunks(block)
        .zip(b.par_chunks(block))
        .fold(
            || vec![0.0; block * block],
            |mut sum, (a, b)| {
                for (k, &a) in a.iter().enumerate() {
                    sum[k * block..(k + 1) * block]
                        .iter_mut()
                        .zip(b)
                        .for_each(|(s, b)| *s += a * b);
                }
                sum
            },
        )
        .reduce(|| vec![0.0; block * block], add_entries)
}

/// `X Z` for a block held particle-major and a `block x block` row-major `Z`.
fn times_rows(x: &[f64], z: &[f64], block: usize) -> Vec<f64> {
    let mut out = vec![0.0; x.len()];
    out.par_chunks_mut(block)
        .zip(x.par_chunks(block))
        .for_each(|(out, row)| {
            for (a, &r) in row.iter().enumerate() {
                out.iter_mut()
                    .zip(&z[a * block..(a + 1) * block])
                    .for_each(|(o, z)| *o += r * z);
            }
        });
    out
}

/// Makes the columns of the particle-major block `x` orthonormal by one
/// Cholesky QR step: `X^T X = R^T R`, `X <- X R^-1`. False when the Gram
/// matrix is not numerically positive definite (dependent columns).
fn orthonormalise_rows(x: &mut [f64], block: usize) -> bool {
    let mut r = row_gram(x, x, block);
    // Cholesky, upper: r = R^T R, R stored in r's upper triangle.
    for k in 0..block {
        let pivot = r[k * block + k] - (0..k).map(|a| r[a * block + k].powi(2)).sum::<f64>();
        if !(pivot > 0.0 && pivot.is_finite()) {
            return false;
        }
        let pivot = pivot.sqrt();
        r[k * block + k] = pivot;
        for j in k + 1..block {
            let dot: f64 = (0..k).map(|a| r[a * block + k] * r[a * block + j]).sum();
            r[k * block + j] = (r[k * block + j] - dot) / pivot;
        }
    }
    // Each row y of the result solves y R = x (forward substitution).
    x.par_chunks_mut(block).for_each(|row| {
        for k in 0..block {
            let dot: f64 = (0..k).map(|a| row[a] * r[a * block + k]).sum();
            row[k] = (row[k] - dot) / r[k * block + k];
        }
    });
    true
}

/// Eigenvalues (ascending) and eigenvectors (columns of the row-major
/// `size x size` result) of the symmetric matrix `a`, by cyclic Jacobi.
fn symmetric_eigen(a: &mut [f64], size: usize) -> (Vec<f64>, Vec<f64>) {
    let mut v = vec![0.0; size * size];
    for i in 0..size {
        v[i * size + i] = 1.0;
    }
    for _ in 0..100 {
        let off: f64 = (0..size)
            .flat_map(|i| (0..size).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i * size + j].powi(2))
            .sum();
        let diagonal: f64 = (0..size).map(|i| a[i * size + i].powi(2)).sum();
        if off <= 1e-30 * diagonal {
            break;
        }
        for p in 0..size {
            for q in p + 1..size {
                let apq = a[p * size + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q * size + q] - a[p * size + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..size {
                    let akp = a[k * size + p];
                    let akq = a[k * size + q];
                    a[k * size + p] = c * akp - s * akq;
                    a[k * size + q] = s * akp + c * akq;
                }
                for k in 0..size {
                    let apk = a[p * size + k];
                    let aqk = a[q * size + k];
                    a[p * size + k] = c * apk - s * aqk;
                    a[q * size + k] = s * apk + c * aqk;
                }
                for k in 0..size {
                    let vkp = v[k * size + p];
                    let vkq = v[k * size + q];
                    v[k * size + p] = c * vkp - s * vkq;
                    v[k * size + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..size).collect();
    order.sort_by(|&i, &j| a[i * size + i].total_cmp(&a[j * size + j]));
    let values = order.iter().map(|&i| a[i * size + i]).collect();
    let mut vectors = vec![0.0; size * size];
    for (new, &old) in order.iter().enumerate() {
        for k in 0..size {
            vectors[k * size + new] = v[k * size + old];
        }
    }
    (values, vectors)
}

/// Lanczos steps for the Laplacian's extreme eigenvalues.
const LANCZOS_STEPS: usize = 40;

/// The smallest and largest eigenvalues of the graph Laplacian restricted to
/// free particles (control points fixed: Dirichlet rows), by 40 Lanczos steps
/// in `f64`. The Ritz values bracket the spectrum from inside: `lambda_min`
/// comes out slightly high (so the Chebyshev `rho` slightly low, which still
/// converges) and `lambda_max` slightly low (so it gets a 2% margin).
pub fn laplacian_extremes(connections: &Connections, free: &[bool]) -> (f32, f32) {
    laplacian_extremes_with(connections, free, LANCZOS_STEPS)
}

/// [`laplacian_extremes`] with `steps` Lanczos steps.
pub fn laplacian_extremes_with(
    connections: &Connections,
    free: &[bool],
    steps: usize,
) -> (f32, f32) {
    let n = free.len();
    let apply = |v: &[f64]| -> Vec<f64> {
        (0..n)
            .into_par_iter()
            .map(|i| {
                if !free[i] {
                    return 0.0;
                }
                let row = connections.of(i);
                let mut s = row.len() as f64 * v[i];
                for &j in row {
                    if free[j as usize] {
                        s -= v[j as usize];
                    }
                }
                s
            })
            .collect()
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    // A deterministic start with every mode in it.
    let mut v: Vec<f64> = (0..n)
        .map(|i| {
            if free[i] {
                1.0 + 0.5 * ((i as f64) * 0.618_033_988_7).fract()
            } else {
                0.0
            }
        })
        .collect();
    let norm = dot(&v, &v).sqrt();
    if norm == 0.0 {
        return (1.0, 1.0);
    }
    v.iter_mut().for_each(|x| *x /= norm);
    let mut previous = vec![0.0; n];
    let (mut alphas, mut betas) = (Vec::new(), Vec::new());
    let mut beta = 0.0f64;
    for _ in 0..steps.max(2) {
        let mut w = apply(&v);
        for i in 0..n {
            w[i] -= beta * previous[i];
        }
        let alpha = dot(&w, &v);
        for i in 0..n {
            w[i] -= alpha * v[i];
        }
        alphas.push(alpha);
        beta = dot(&w, &w).sqrt();
        if beta < 1e-10 {
            break;
        }
        betas.push(beta);
        previous = std::mem::replace(&mut v, w.iter().map(|x| x / beta).collect());
    }
    betas.truncate(alphas.len().saturating_sub(1));
    let lo = tridiagonal_eigenvalue(&alphas, &betas, 0);
    let hi = tridiagonal_eigenvalue(&alphas, &betas, alphas.len() - 1);
    (lo as f32, (hi * 1.02) as f32)
}

/// The `k`-th smallest eigenvalue of the symmetric tridiagonal matrix with
/// diagonal `a` and off-diagonal `b`, by bisection on Sturm counts.
fn tridiagonal_eigenvalue(a: &[f64], b: &[f64], k: usize) -> f64 {
    // Gershgorin bounds.
    let mut lo = f64::MAX;
    let mut hi = f64::MIN;
    for i in 0..a.len() {
        let r = b.get(i).map_or(0.0, |x| x.abs()) + if i > 0 { b[i - 1].abs() } else { 0.0 };
        lo = lo.min(a[i] - r);
        hi = hi.max(a[i] + r);
    }
    // Number of eigenvalues below x.
    let below = |x: f64| {
        let mut count = 0;
        let mut d = 1.0f64;
        for i in 0..a.len() {
            let off = if i > 0 { b[i - 1] * b[i - 1] } else { 0.0 };
            d = a[i] - x - if i > 0 { off / d } else { 0.0 };
            if d == 0.0 {
                d = -1e-300;
            }
            if d < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if below(mid) > k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svd3::rotation_of;

    /// Deterministic matrices with entries in [-1, 1].
    fn matrices(count: usize) -> Vec<Mat3> {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        };
        (0..count)
            .map(|_| Mat3::from_cols_array(&[(); 9].map(|_| next())))
            .collect()
    }

    #[test]
    fn a_warm_rotation_is_the_svd_rotation_from_any_start() {
        let mut checked = 0;
        let starts = [
            Mat3::IDENTITY,
            Mat3::from_rotation_x(3.1),
            Mat3::from_axis_angle(Vec3::new(1.0, 1.0, 0.0).normalize(), 1.5),
        ];
        for (k, m) in matrices(3_000).into_iter().enumerate() {
            let svd = crate::svd3::svd3(m);
            // Where the two smallest singular values nearly cancel the
            // maximum is nearly flat and any nearby rotation is as good.
            if (svd.sigma.y + svd.sigma.z).abs() < 0.05 {
                continue;
            }
            let r = warm_rotation(m, starts[k % 3]);
            let exact = rotation_of(m);
            let off = (r - exact)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            assert!(off < 1e-3, "{m:?}: off by {off}");
            assert!((r.determinant() - 1.0).abs() < 1e-5);
            checked += 1;
        }
        assert!(checked > 1_000);
    }

    #[test]
    fn the_warm_polar_update_keeps_a_rotation_that_is_already_right() {
        for m in matrices(500) {
            let exact = rotation_of(m);
            let (r, settled) = polar_rotation(m, exact, 3);
            assert!(settled);
            let off = (r - exact)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            assert!(off < 1e-4, "drifted by {off}");
        }
        assert_eq!(
            polar_rotation(Mat3::ZERO, Mat3::IDENTITY, 3).0,
            Mat3::IDENTITY
        );
    }

    /// A path of `n` free nodes between two fixed ends: eigenvalues
    /// `2 - 2 cos(k pi / (n + 1))`, k = 1..n.
    #[test]
    fn an_affine_fit_recovers_an_affine_map_and_refuses_flat_points() {
        let linear = Mat3::from_cols(
            Vec3::new(1.1, 0.2, -0.1),
            Vec3::new(-0.3, 0.9, 0.05),
            Vec3::new(0.0, 0.4, 1.3),
        );
        let shift = Vec3::new(5.0, -2.0, 30.0);
        let from: Vec<Vec3> = (0..50)
            .map(|k| {
                let k = k as f32;
                Vec3::new((k * 1.3).sin(), (k * 0.7).cos(), (k * 0.37).sin()) * 40.0
            })
            .collect();
        let to: Vec<Vec3> = from.iter().map(|&p| linear * p + shift).collect();
        let Some((l, t)) = affine_fit(&from, &to) else {
            panic!("no fit through 50 points in general position");
        };
        assert!(l.abs_diff_eq(linear, 1e-5), "{l} vs {linear}");
        assert!(t.abs_diff_eq(shift, 1e-3), "{t} vs {shift}");
        let flat: Vec<Vec3> = from.iter().map(|p| Vec3::new(p.x, p.y, 0.0)).collect();
        assert_eq!(affine_fit(&flat, &to), None);
        assert_eq!(affine_fit(&from[..3], &to[..3]), None);
    }

    /// Eight control points on a unit cube's corners and two free particles
    /// inside; `bulge` and `dent` are two non-affine moves (a corner pulled
    /// out, another pushed in) with what they do to the free particles.
    fn cube() -> (Vec<Vec3>, [Vec<Vec3>; 2]) {
        let mut rest: Vec<Vec3> = (0..8)
            .map(|k| Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32))
            .collect();
        rest.extend([Vec3::splat(0.3), Vec3::splat(0.7)]);
        let mut bulge = vec![Vec3::ZERO; 10];
        bulge[7] = Vec3::splat(0.02);
        bulge[9] = Vec3::splat(0.01);
        let mut dent = vec![Vec3::ZERO; 10];
        dent[0] = Vec3::new(0.0, 0.0, 0.03);
        dent[8] = Vec3::new(0.0, 0.0, 0.012);
        (rest, [bulge, dent])
    }

    /// `rest + a bulge + b dent`, then translated by `shift`.
    fn cube_state(a: f32, b: f32, shift: Vec3) -> Vec<Vec3> {
        let (rest, [bulge, dent]) = cube();
        (0..rest.len())
            .map(|i| rest[i] + a * bulge[i] + b * dent[i] + shift)
            .collect()
    }

    fn history_of(states: &[Vec<Vec3>]) -> FrameHistory {
        let mut history = FrameHistory::default();
        for state in states {
            history.record(state, true, states.len() - 1);
        }
        history
    }

    fn controls_of(state: &[Vec3]) -> Vec<(usize, Vec3)> {
        (0..8).map(|i| (i, state[i])).collect()
    }

    #[test]
    fn a_prediction_fits_the_surface_move_with_the_last_changes() {
        // A bulge growing by 1, then by 0.5, then turning back by 0.75, with
        // a translation on top: the free particles follow by the same
        // fraction of the last change (constant velocity would say +1),
        // exactly (to rounding): every change is fitted on the same base.
        let shift = Vec3::new(0.5, -0.2, 0.1);
        let states = [
            cube_state(0.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 0.0, Vec3::ZERO),
        ];
        let history = history_of(&states);
        assert_eq!(history.changes(), 1);
        for step in [1.0, 0.5, -0.75] {
            let next = cube_state(1.0 + step, 0.0, shift);
            let (predicted, _) = predict(&states[1], &history, &controls_of(&next), 1e-4);
            for i in 8..10 {
                assert!(
                    predicted[i].distance(next[i]) < 1e-6,
                    "step {step}, particle {i}: {} vs {}",
                    predicted[i],
                    next[i]
                );
            }
        }
        // Two changes of two shapes (a bulge, then a dent) fit a move of both.
        let states = [
            cube_state(0.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 1.0, Vec3::ZERO),
        ];
        let history = history_of(&states);
        assert_eq!(history.changes(), 2);
        let next = cube_state(0.6, 1.5, shift);
        let (predicted, _) = predict(&states[2], &history, &controls_of(&next), 1e-4);
        for i in 8..10 {
            assert!(
                predicted[i].distance(next[i]) < 1e-6,
                "particle {i}: {} vs {}",
                predicted[i],
                next[i]
            );
        }
    }

    #[test]
    fn a_prediction_leaves_out_changes_affine_on_the_surface() {
        // The control points only translate from frame to frame while a free
        // particle drifts (what a solve leaves undone): the drift is not
        // extrapolated, however large, and the next frame is carried by the
        // affine map alone.
        let mut earlier = cube_state(0.0, 0.0, Vec3::ZERO);
        let mut last = cube_state(0.0, 0.0, Vec3::X);
        earlier[8] += Vec3::Y * 0.1;
        last[8] += Vec3::Y * 0.2;
        let history = history_of(&[earlier, last.clone()]);
        let next = cube_state(0.0, 0.0, 2.0 * Vec3::X);
        let (predicted, _) = predict(&last, &history, &controls_of(&next), 1e-3);
        assert!(
            predicted[8].abs_diff_eq(last[8] + Vec3::X, 1e-5),
            "{} vs {}",
            predicted[8],
            last[8] + Vec3::X
        );
    }

    #[test]
    fn frame_history_keeps_depth_changes_and_forgets_on_divergence() {
        let state = |k: f32| vec![Vec3::splat(k); 3];
        let mut history = FrameHistory::default();
        for k in 0..5 {
            history.record(&state(k as f32), true, 2);
        }
        assert_eq!(history.changes(), 2);
        let newest: Vec<f32> = history.pairs().map(|(_, later)| later[0].x).collect();
        assert_eq!(newest, [4.0, 3.0]);
        history.record(&state(5.0), true, 1);
        assert_eq!(history.changes(), 1);
        history.record(&state(6.0), false, 2);
        assert_eq!(history.changes(), 0);
        history.record(&state(7.0), true, 0);
        assert_eq!(history.changes(), 0);
        // At rest, the rest shape is the first solved frame.
        let mut history = FrameHistory::at_rest(&state(0.0), 2);
        assert_eq!(history.changes(), 0);
        history.record(&state(1.0), true, 2);
        let firsts: Vec<f32> = history.pairs().map(|(e, l)| l[0].x - e[0].x).collect();
        assert_eq!(firsts, [1.0]);
        assert_eq!(FrameHistory::at_rest(&state(0.0), 0).changes(), 0);
    }

    /// The message `validate` refuses `params` with.
    fn refusal(params: &DeformParams) -> String {
        match params.validate() {
            Err(err) => err.to_string(),
            Ok(()) => panic!("{params:?} was accepted"),
        }
    }

    #[test]
    fn history_defaults_to_two_frames_and_is_bounded() {
        assert_eq!(DeformParams::default().history, 2);
        let err = refusal(&DeformParams {
            history: MAX_HISTORY + 1,
            ..DeformParams::default()
        });
        assert!(err.contains("history is 17"), "{err}");
    }

    /// A path of `n` free particles between two fixed ends, whose Laplacian
    /// has the eigenpairs `2 - 2 cos(k pi / (n + 1))`, `sin(k pi i / (n + 1))`.
    fn dirichlet_path(n: usize) -> (Connections, Vec<bool>) {
        let total = n + 2;
        let pairs = (0..total - 1).map(|i| (i as u32, i as u32 + 1));
        let free = (0..total).map(|i| i != 0 && i != total - 1).collect();
        (Connections::from_pairs(total, pairs), free)
    }

    #[test]
    fn low_modes_of_a_dirichlet_path_are_its_exact_eigenpairs() {
        let n = 60;
        let (connections, free) = dirichlet_path(n);
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let modes = low_modes(&connections, &free, 6, lo, hi);
        let exact =
            |k: usize| 2.0 - 2.0 * (k as f64 * std::f64::consts::PI / (n as f64 + 1.0)).cos();
        assert_eq!(modes.count(), 6);
        for (k, &value) in modes.values().iter().enumerate() {
            let want = exact(k + 1);
            assert!(
                (value - want).abs() <= 1e-6 * want,
                "mode {k}: {value} vs {want}"
            );
        }
        let next = f64::from(modes.next());
        assert!(
            next <= exact(7) && next >= 0.9 * exact(7),
            "next {next} vs {}",
            exact(7)
        );
        assert!(modes.residual() < 1e-4, "{}", modes.residual());
        // Orthonormal over the free particles, zero at the fixed ends.
        let m = modes.count();
        let vectors = &modes.vectors;
        let column = |k: usize| (0..n + 2).map(move |i| vectors[i * m + k]);
        for a in 0..m {
            assert_eq!(column(a).next(), Some(0.0));
            assert_eq!(column(a).next_back(), Some(0.0));
            for b in 0..m {
                let dot: f32 = column(a).zip(column(b)).map(|(x, y)| x * y).sum();
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-5, "v{a} . v{b} = {dot}");
            }
        }
    }

    #[test]
    fn deflation_removes_the_error_of_a_deflated_mode_in_one_step() {
        let n = 60;
        let (connections, free) = dirichlet_path(n);
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let modes = low_modes(&connections, &free, 4, lo, hi);
        let m = modes.count();
        let contraction = 0.9 / hi;
        // An error along one mode, and one along a mode left to Chebyshev.
        for (k, deflated) in [(1, true), (9, false)] {
            let angle = |i: usize| (k * i) as f32 * std::f32::consts::PI / (n as f32 + 1.0);
            let lambda = 2.0 - 2.0 * angle(1).cos();
            let direction = Vec3::new(0.3, -1.0, 0.5);
            let error: Vec<Vec3> = (0..n + 2)
                .map(|i| {
                    if free[i] {
                        angle(i).sin() * direction
                    } else {
                        Vec3::ZERO
                    }
                })
                .collect();
            // The plain step for fixed rotations: -contraction L e.
            let mut plain: Vec<Vec3> = error
                .iter()
                .map(|&e| e - contraction * lambda * e)
                .collect();
            modes.deflate(&error, &mut plain, contraction);
            for i in 0..n + 2 {
                let step = plain[i] - error[i];
                let want = if deflated {
                    -error[i]
                } else {
                    -contraction * lambda * error[i]
                };
                assert!(
                    (step - want).length() < 1e-4 * direction.length(),
                    "mode {k} (m = {m}), particle {i}: step {step} vs {want}"
                );
            }
        }
    }

    #[test]
    fn deflation_defaults_to_32_modes_and_is_bounded() {
        assert_eq!(DeformParams::default().deflation, 32);
        assert_eq!(DeformParams::default().deflation_max_particles, 200_000);
        let err = refusal(&DeformParams {
            deflation: MAX_DEFLATION + 1,
            ..DeformParams::default()
        });
        assert!(err.contains("deflation is 257"), "{err}");
    }

    #[test]
    fn the_two_level_solve_defaults_to_cells_of_two_spacings_and_is_bounded() {
        let defaults = DeformParams::default();
        assert_eq!(defaults.coarse, 2.0);
        assert_eq!(defaults.coarse_max_aggregates, 10_000);
        for (coarse, says) in [
            (0.5, "coarse is 0.5"),
            (-1.0, "coarse is -1"),
            (f32::NAN, "coarse is NaN"),
            (f32::INFINITY, "coarse is inf"),
        ] {
            let err = refusal(&DeformParams {
                coarse,
                ..DeformParams::default()
            });
            assert!(err.contains(says), "{err}");
        }
        let err = refusal(&DeformParams {
            coarse_max_aggregates: MAX_COARSE_AGGREGATES + 1,
            ..DeformParams::default()
        });
        assert!(err.contains("coarse_max_aggregates is 50001"), "{err}");
        assert!(
            DeformParams {
                coarse: 0.0,
                ..DeformParams::default()
            }
            .validate()
            .is_ok()
        );
    }

    #[test]
    fn lanczos_finds_the_extreme_eigenvalues_of_a_dirichlet_path() {
        let n = 30;
        let total = n + 2;
        let pairs = (0..total - 1).map(|i| (i as u32, i as u32 + 1));
        let connections = Connections::from_pairs(total, pairs);
        let free: Vec<bool> = (0..total).map(|i| i != 0 && i != total - 1).collect();
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let exact = |k: f64| 2.0 - 2.0 * (k * std::f64::consts::PI / (n as f64 + 1.0)).cos();
        assert!(
            (f64::from(lo) - exact(1.0)).abs() < 1e-4,
            "{lo} vs {}",
            exact(1.0)
        );
        assert!(
            (f64::from(hi) / 1.02 - exact(n as f64)).abs() < 1e-3,
            "{hi} vs {}",
            exact(n as f64)
        );
    }
}
