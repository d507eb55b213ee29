//! The parameters of stage 2 and their bounds; `docs/METHOD.md` explains
//! the defaults.

use glam::Vec3;
use serde::{Deserialize, Serialize};
use tissue_core::ParamError;

/// The largest Poisson ratio [`DeformParams::poisson`] accepts: at 0.5 the
/// volume term's weight is infinite.
pub const MAX_POISSON: f32 = 0.499;

/// Which force model stage 2 uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ForceModel {
    /// The paper's one-sided force (not the gradient of an energy).
    Paper,
    /// The symmetric variant, the exact gradient of the rotation-aware energy.
    Symmetric,
    /// The symmetric force plus a volume term weighted by
    /// [`DeformParams::poisson`] (the [`crate::model::Elastic`] model): resists
    /// volume change as soft tissue does.
    Elastic,
}

/// How each particle's rotation is found every iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
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

/// How an elastic solve's elastic phase descends the potential after its
/// shear phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ElasticSolve {
    /// The two-level iteration (volume smoother and elastic correction)
    /// accelerated by Chebyshev's weights, the potential watched every
    /// [`crate::stage2::phase::ENERGY_WATCH`] iterations, with steps back
    /// and new linearisations where it rises or stalls.
    Chebyshev,
    /// A nonlinear conjugate gradient preconditioned by the same two-level
    /// step: Polak-Ribiere directions, each step searched along its
    /// direction and accepted only where the potential fell by Armijo's
    /// margin (docs/METHOD.md, "Elastic model", *The conjugate-gradient
    /// phase*).
    ConjugateGradient,
    /// Chebyshev's phase, watched, until its potential first rises or it
    /// stalls; from the state it accepted last, the conjugate gradient's.
    /// Where the skin is paired with an observation, Chebyshev's phases
    /// alone, but for a surface's first match stage from rest, which the
    /// match runs by the conjugate gradient (`tissue::observation::SURFACE_FIRST_STAGE`;
    /// docs/METHOD.md, "Elastic model", *Chebyshev, then the conjugate
    /// gradient*). The default.
    ChebyshevThenConjugateGradient,
}

/// Parameters of stage 2 a user sets: the force and its Poisson ratio, the
/// tolerance and the iteration cap, the observed vertices and the load;
/// how the solver reaches the answer is [`SolverTuning`] (`tuning`).
/// `docs/METHOD.md` explains the defaults.
///
/// The struct is `#[non_exhaustive]`, so that a parameter can be added
/// without breaking callers: outside this crate, start from `default()`
/// and change fields with [`DeformParams::with`] or by assignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct DeformParams {
    /// Force model.
    pub force: ForceModel,
    /// Stop when the error estimate `step / (1 - rho)` of every free particle is
    /// below this fraction of the model's size. The default sits a little
    /// above where the estimate bottoms out at single precision
    /// (docs/METHOD.md).
    pub tolerance: f32,
    /// Iteration cap.
    pub max_iterations: usize,
    /// The Poisson ratio of the elastic force model (unused by the others):
    /// 0 is the symmetric force, 0.5 incompressible. docs/METHOD.md,
    /// "Elastic model", gives the measurements behind the default.
    pub poisson: f32,
    /// Which vertices of the surface were observed (the deformed surface
    /// is known there), one flag per rest-surface vertex; `None`: every
    /// one. A surface particle is a control point only where every vertex
    /// of its triangle is observed; the others move with the solve, as
    /// interior particles do (docs/METHOD.md, "Free surface and body
    /// forces"). Not written out with the parameters (it is as long as the
    /// surface).
    #[serde(skip)]
    pub observed: Option<Vec<bool>>,
    /// A body force on every particle per unit of its stiffness weight
    /// `a_i = tr(A_i) / 3` (the same weight the shear term carries), in
    /// reciprocal model units: gravity `g` on tissue of density `rho` and
    /// shear modulus `mu` is `rho g / (2 mu)` (docs/METHOD.md, "Free
    /// surface and body forces"). Zero: none.
    pub load: Vec3,
    /// How the solver reaches the answer (written flat beside the others).
    #[serde(flatten)]
    pub tuning: SolverTuning,
}

/// How the stage-2 solver reaches the answer: the rotations' method, the
/// step and its acceleration, the tracking prediction, the two-level
/// solves and the volume smoother. The defaults are measured
/// (`docs/METHOD.md`); a user changes them to compare, not to get a
/// right answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct SolverTuning {
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
    /// Tracking: start a new frame from the current state carried by the
    /// least-squares affine map of the surface's move, plus the combination
    /// of the last frames' non-affine changes that best matches the
    /// surface's own non-affine move (see [`crate::stage2::predict::predict`]).
    pub extrapolate: bool,
    /// Tracking: how many of the last frames' changes the prediction fits
    /// the new frame's surface move with (`0`: the affine map alone). Each
    /// costs a copy of the positions. 2 by default: see docs/METHOD.md.
    pub history: usize,
    /// Two-level solve: the edge of the grid cells whose free particles form
    /// one aggregate of the coarse space, in mean connection lengths; every
    /// iteration then removes the error's part in that space exactly
    /// ([`crate::coarse::CoarseSpace`]; the GPU's kernels in `shaders/coarse.wgsl`). 0
    /// turns it off. The default and what it saves: docs/METHOD.md,
    /// "Two-level solve".
    pub coarse: f32,
    /// The coarse space's cells grow (by factors of 1.25) until there are at
    /// most this many aggregates (at the default, cells of 2 spacings up to
    /// about two million particles).
    pub coarse_max_aggregates: usize,
    /// The coarse space's matrix is factored where it has at most this many
    /// aggregates (its factor takes about `n^(5/3)` numbers and a solve
    /// `n^(4/3)` multiply-adds an iteration); above, it is solved by
    /// two-grid cycles over groups of aggregates ([`crate::coarse::Multilevel`]),
    /// whose cost grows as the model. The default, 4,096, is the most one
    /// factor the GPU substitutes in one workgroup, so both devices solve
    /// every model's coarse space the same way (at 100,000 particles the
    /// cycles take 3 more iterations than the factor in the same time):
    /// docs/METHOD.md, "Two-level solve".
    pub coarse_direct_max_aggregates: usize,
    /// The elastic phase's two-level solve: where the CPU runs the
    /// two-level solve ([`SolverTuning::coarse`] on), the elastic operator,
    /// linearised where each elastic phase starts, is corrected over
    /// aggregates of the same cells, grown until there are at most this
    /// many (three unknowns each, made again every solve from rest). 0
    /// turns it off. The default and what it saves: docs/METHOD.md,
    /// "Elastic model".
    pub elastic_coarse_max_aggregates: usize,
    /// The elastic coarse matrix (three unknowns an aggregate) is factored
    /// where it has at most this many aggregates (its factor about
    /// `(3 n)^(5/3)` numbers, made every solve from rest); above, it is
    /// solved by two-grid cycles over groups of aggregates
    /// ([`crate::coarse::multilevel::BlockMultilevel`]), the groups at most this
    /// many. The default, 1,365, is the most whose 4,095 unknowns the GPU
    /// substitutes in one workgroup, so both devices solve every elastic
    /// correction the same way. What it saves: docs/METHOD.md, "Elastic
    /// model".
    pub elastic_coarse_direct_max_aggregates: usize,
    /// The elastic phase's two-level solve smooths with the volume term
    /// taken implicitly ([`crate::coarse::volume_smoother`]: the shear part stepped
    /// as the shear phase steps it, the volume part by a few sweeps on one
    /// pressure per particle) instead of the plain step, whose size the
    /// volume term's stiffness limits. Off: the plain step. What it saves:
    /// docs/METHOD.md, "The volume smoother".
    pub volume_smoother: bool,
    /// With the volume smoother, the shear phase that starts an elastic
    /// solve also stops where its error estimate (a fraction of the
    /// model's size) is below this share of the volumes' misfit at its
    /// state ([`crate::model::elastic::Elastic::volume_misfit`]): what is left of
    /// it then is less than what the elastic phase moves anyway. 0: only
    /// at its tolerance ([`crate::stage2::phase::SHEAR_TOLERANCE`]). Why 0.25:
    /// docs/METHOD.md, "Elastic model", *The shear phase's end*.
    pub shear_volume_share: f32,
    /// How the elastic phase descends the potential after the shear phase
    /// of an elastic solve from rest ([`ElasticSolve`]); a tracking
    /// frame's warm phase, a few iterations from its answer, steps by
    /// Chebyshev's weights either way. Where the device has no volume
    /// smoother for the phase, Chebyshev's. The default and why:
    /// docs/METHOD.md, "Elastic model", *Chebyshev, then the conjugate
    /// gradient*.
    pub elastic_solve: ElasticSolve,
}

impl Default for DeformParams {
    fn default() -> Self {
        Self {
            force: ForceModel::Elastic,
            tolerance: 3e-5,
            max_iterations: 5_000,
            poisson: 0.49,
            observed: None,
            load: Vec3::ZERO,
            tuning: SolverTuning::default(),
        }
    }
}

impl Default for SolverTuning {
    fn default() -> Self {
        Self {
            rotations: RotationMethod::WarmPolar,
            step_fraction: 0.9,
            chebyshev: true,
            warm_up: 0,
            extrapolate: true,
            history: 2,
            coarse: 2.0,
            coarse_max_aggregates: 200_000,
            coarse_direct_max_aggregates: 4_096,
            elastic_coarse_max_aggregates: 200_000,
            elastic_coarse_direct_max_aggregates: 1_365,
            volume_smoother: true,
            shear_volume_share: 0.25,
            elastic_solve: ElasticSolve::ChebyshevThenConjugateGradient,
        }
    }
}

impl DeformParams {
    /// These parameters as `change` leaves them:
    /// `DeformParams::default().with(|p| p.force = ForceModel::Elastic)`.
    #[must_use]
    pub fn with(mut self, change: impl FnOnce(&mut Self)) -> Self {
        change(&mut self);
        self
    }

    /// The parameters of the shear phase that starts every elastic solve
    /// (the symmetric force, whose coarse space a device prepares); `self` for the other forces.
    pub fn shear(&self) -> Self {
        let force = match self.force {
            ForceModel::Elastic => ForceModel::Symmetric,
            other => other,
        };
        Self {
            force,
            ..self.clone()
        }
    }

    /// Checks every parameter, naming the first that is out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        ParamError::check(
            self.tuning.step_fraction > 0.0 && self.tuning.step_fraction < 1.0,
            "step_fraction",
            self.tuning.step_fraction,
            "in (0, 1)",
        )?;
        ParamError::check(
            (0.0..=MAX_POISSON).contains(&self.poisson),
            "poisson",
            self.poisson,
            format!("in [0, {MAX_POISSON}] (0.5, incompressible, has no finite volume stiffness)"),
        )?;
        ParamError::check(
            self.tolerance > 0.0 && self.tolerance.is_finite(),
            "tolerance",
            self.tolerance,
            "a positive number",
        )?;
        ParamError::check(
            self.tuning.history <= MAX_HISTORY,
            "history",
            self.tuning.history,
            format!("0 to {MAX_HISTORY} frames"),
        )?;
        ParamError::check(
            self.tuning.coarse == 0.0 || (1.0..=1_000.0).contains(&self.tuning.coarse),
            "coarse",
            self.tuning.coarse,
            "0 (off) or a cell of 1 to 1000 mean connection lengths",
        )?;
        ParamError::check(
            (1..=MAX_COARSE_AGGREGATES).contains(&self.tuning.coarse_max_aggregates),
            "coarse_max_aggregates",
            self.tuning.coarse_max_aggregates,
            format!("1 to {MAX_COARSE_AGGREGATES}"),
        )?;
        ParamError::check(
            (1..=MAX_COARSE_DIRECT_AGGREGATES).contains(&self.tuning.coarse_direct_max_aggregates),
            "coarse_direct_max_aggregates",
            self.tuning.coarse_direct_max_aggregates,
            format!("1 to {MAX_COARSE_DIRECT_AGGREGATES}"),
        )?;
        ParamError::check(
            self.tuning.elastic_coarse_max_aggregates <= MAX_ELASTIC_COARSE_AGGREGATES,
            "elastic_coarse_max_aggregates",
            self.tuning.elastic_coarse_max_aggregates,
            format!("0 (off) to {MAX_ELASTIC_COARSE_AGGREGATES}"),
        )?;
        ParamError::check(
            (1..=MAX_ELASTIC_COARSE_DIRECT_AGGREGATES)
                .contains(&self.tuning.elastic_coarse_direct_max_aggregates),
            "elastic_coarse_direct_max_aggregates",
            self.tuning.elastic_coarse_direct_max_aggregates,
            format!("1 to {MAX_ELASTIC_COARSE_DIRECT_AGGREGATES}"),
        )?;
        ParamError::check(
            (0.0..=MAX_SHEAR_VOLUME_SHARE).contains(&self.tuning.shear_volume_share),
            "shear_volume_share",
            self.tuning.shear_volume_share,
            format!("0 (off) to {MAX_SHEAR_VOLUME_SHARE}"),
        )?;
        ParamError::check(self.load.is_finite(), "load", self.load, "a finite vector")?;
        ParamError::check(
            (1..=10_000_000).contains(&self.max_iterations),
            "max_iterations",
            self.max_iterations,
            "1 to 10,000,000",
        )
    }
}

/// The largest [`SolverTuning::shear_volume_share`]: at 2 the shear phase
/// of a 30-degree turn from rest stops before it has turned the interior
/// (its estimate is 1.2-1.7 times the misfit there), and the elastic phase
/// is slow to do that.
pub const MAX_SHEAR_VOLUME_SHARE: f32 = 1.0;

/// The most frames [`SolverTuning::history`] may keep: each is a copy of
/// the positions, and a fit with more columns than the surface's changes
/// have independent shapes only adds noise.
pub const MAX_HISTORY: usize = 16;

/// The most aggregates [`SolverTuning::coarse_max_aggregates`] may allow:
/// their matrix and the cycles' vectors take about 500 bytes each.
pub const MAX_COARSE_AGGREGATES: usize = 1_000_000;

/// The most aggregates [`SolverTuning::coarse_direct_max_aggregates`] may
/// allow: the factor of 50,000 holds about 70 million numbers (0.5 GB).
pub const MAX_COARSE_DIRECT_AGGREGATES: usize = 50_000;

/// The most aggregates [`SolverTuning::elastic_coarse_max_aggregates`] may
/// allow: their block matrix and the cycles' vectors take about 2 kB each.
pub const MAX_ELASTIC_COARSE_AGGREGATES: usize = 1_000_000;

/// The most aggregates [`SolverTuning::elastic_coarse_direct_max_aggregates`]
/// may allow: the factor of 15,000 unknowns holds about 40 million
/// numbers, and it is made again every solve from rest.
pub const MAX_ELASTIC_COARSE_DIRECT_AGGREGATES: usize = 5_000;

#[cfg(test)]
mod tests {
    use super::*;

    /// The message `validate` refuses `params` with.
    fn refusal(params: &DeformParams) -> String {
        match params.validate() {
            Err(err) => err.to_string(),
            Ok(()) => panic!("{params:?} was accepted"),
        }
    }

    /// The elastic force is the default, at a Poisson ratio of 0.49
    /// (docs/METHOD.md, "Elastic model", *Default*); its shear phase is
    /// the symmetric force.
    #[test]
    fn default_params_pin_the_elastic_force() {
        let defaults = DeformParams::default();
        assert_eq!(defaults.force, ForceModel::Elastic);
        assert_eq!(defaults.poisson, 0.49);
        assert_eq!(defaults.shear().force, ForceModel::Symmetric);
        assert!(defaults.validate().is_ok());
    }

    #[test]
    fn history_defaults_to_two_frames_and_is_bounded() {
        assert_eq!(DeformParams::default().tuning.history, 2);
        let err = refusal(&DeformParams::default().with(|p| p.tuning.history = MAX_HISTORY + 1));
        assert!(err.contains("history is 17"), "{err}");
        // A typed error, as the sampling parameters have: the field it names.
        let typed = DeformParams::default()
            .with(|p| p.tuning.history = MAX_HISTORY + 1)
            .validate();
        assert!(
            matches!(&typed, Err(ParamError { name: "history", value, .. }) if value == "17"),
            "{typed:?}"
        );
    }

    #[test]
    fn the_shear_phase_stops_at_a_quarter_of_the_volumes_misfit_by_default_and_is_bounded() {
        assert_eq!(DeformParams::default().tuning.shear_volume_share, 0.25);
        for (share, says) in [
            (-0.1, "shear_volume_share is -0.1"),
            (1.5, "shear_volume_share is 1.5"),
            (f32::NAN, "shear_volume_share is NaN"),
        ] {
            let err =
                refusal(&DeformParams::default().with(|p| p.tuning.shear_volume_share = share));
            assert!(err.contains(says), "{err}");
        }
        for share in [0.0, MAX_SHEAR_VOLUME_SHARE] {
            let params = DeformParams::default().with(|p| p.tuning.shear_volume_share = share);
            assert!(params.validate().is_ok(), "{share}");
        }
    }

    #[test]
    fn the_two_level_solve_defaults_to_cells_of_two_spacings_and_is_bounded() {
        let defaults = DeformParams::default();
        assert_eq!(defaults.tuning.coarse, 2.0);
        assert_eq!(defaults.tuning.coarse_max_aggregates, 200_000);
        assert_eq!(defaults.tuning.coarse_direct_max_aggregates, 4_096);
        assert_eq!(defaults.tuning.elastic_coarse_max_aggregates, 200_000);
        assert_eq!(defaults.tuning.elastic_coarse_direct_max_aggregates, 1_365);
        for (coarse, says) in [
            (0.5, "coarse is 0.5"),
            (-1.0, "coarse is -1"),
            (f32::NAN, "coarse is NaN"),
            (f32::INFINITY, "coarse is inf"),
        ] {
            let err = refusal(&DeformParams::default().with(|p| p.tuning.coarse = coarse));
            assert!(err.contains(says), "{err}");
        }
        let err = refusal(
            &DeformParams::default()
                .with(|p| p.tuning.coarse_max_aggregates = MAX_COARSE_AGGREGATES + 1),
        );
        assert!(err.contains("coarse_max_aggregates is 1000001"), "{err}");
        let err =
            refusal(&DeformParams::default().with(|p| {
                p.tuning.coarse_direct_max_aggregates = MAX_COARSE_DIRECT_AGGREGATES + 1
            }));
        assert!(
            err.contains("coarse_direct_max_aggregates is 50001"),
            "{err}"
        );
        let err =
            refusal(&DeformParams::default().with(|p| {
                p.tuning.elastic_coarse_max_aggregates = MAX_ELASTIC_COARSE_AGGREGATES + 1
            }));
        assert!(
            err.contains("elastic_coarse_max_aggregates is 1000001"),
            "{err}"
        );
        let err = refusal(
            &DeformParams::default().with(|p| p.tuning.elastic_coarse_direct_max_aggregates = 0),
        );
        assert!(
            err.contains("elastic_coarse_direct_max_aggregates is 0"),
            "{err}"
        );
        assert!(
            DeformParams::default()
                .with(|p| p.tuning.coarse = 0.0)
                .validate()
                .is_ok()
        );
    }

    /// An elastic solve from rest descends by Chebyshev's weights until its
    /// potential first rises, then by the conjugate gradient, unless told
    /// otherwise: the solves that never rise are Chebyshev's (the
    /// conjugate gradient alone measures the potential about 1.7 times an
    /// iteration, and the sag at 10k takes 1.2 times as long), and those
    /// that would step back or run again converge without (docs/METHOD.md,
    /// "Elastic model", *Chebyshev, then the conjugate gradient*).
    #[test]
    fn the_elastic_phase_turns_from_chebyshevs_weights_to_the_conjugate_gradient_by_default() {
        assert_eq!(
            DeformParams::default().tuning.elastic_solve,
            ElasticSolve::ChebyshevThenConjugateGradient
        );
    }
}
