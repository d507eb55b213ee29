//! How a stage-2 solve went.

use serde::{Deserialize, Serialize};

/// A rise of the potential of at most this many times the magnitude of its
/// parts ([`crate::stage2::device::Potential::magnitude`]) in an elastic phase
/// watched by the tracker (`phase::ENERGY_WATCH`) is rounding, not
/// a rise: `f32` parts round within about `6e-8` of it, so the CPU and the
/// GPU, on states that agree to rounding, accept the same ones.
pub const ENERGY_ROUNDING: f64 = 1e-6;
/// The largest error estimate (a fraction of the model's size) a solve
/// that stopped at the float floor ([`StopReason::FloatPrecision`]) is
/// taken to have converged with: `sqrt(ENERGY_ROUNDING)`. An elastic
/// conjugate-gradient phase stops there where the decrease a step asks is
/// below the potential's rounding; near the answer that decrease is the
/// error's energy, about the square of the error over the square of the
/// motion times the motion's energy, so rounding alone stops it at about
/// `sqrt(ENERGY_ROUNDING)` of the motion, at most that of the size. The
/// Chebyshev rule stops there where the RMS step is a few ulps; at the
/// positions' floor the largest step is a few ulps too, and its estimate
/// (the largest step over `1 - rho`) stays below this even at `rho` 0.999
/// (the phantom at 1,000,000 particles: 4.6e-4 and 9.0e-4). A larger
/// estimate is a solve short of its answer, not at its precision (a
/// sparse scan's skin still moving while the rest is still: breast_c's
/// scan thinned to every 16th point stopped at 0.13 of the size), and
/// not converged.
pub const FLOAT_FLOOR_ERROR: f32 = 1e-3;

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
    /// The state became non-finite, or an elastic phase's energy rose with
    /// no smaller step left (the state it kept is finite, not an answer).
    Diverged,
    /// The error estimate stopped falling in an iteration whose
    /// contraction was measured (the volume smoother's): the iteration no
    /// longer contracts where it runs (`acceleration::STALL_WINDOW`). The
    /// elastic solve then goes on from the state the phase accepted last
    /// (`phase::Next`).
    Stalled,
}

impl StopReason {
    /// Whether a solve it ended with the error estimate `residual` (a
    /// fraction of the model's size) converged: at the tolerance, or at
    /// the float floor with an estimate of at most [`FLOAT_FLOOR_ERROR`].
    pub fn converged_at(self, residual: f32) -> bool {
        match self {
            StopReason::Tolerance => true,
            StopReason::FloatPrecision => residual <= FLOAT_FLOOR_ERROR,
            StopReason::IterationCap | StopReason::Diverged | StopReason::Stalled => false,
        }
    }

    /// Whether the phase it ended stopped short of the tolerance: the
    /// state became non-finite, or the iteration stopped contracting.
    pub fn failed(self) -> bool {
        matches!(self, StopReason::Diverged | StopReason::Stalled)
    }
}

/// Where a stage-2 solve is: told to its progress callback after every
/// iteration (`Tracker::solve_observed`), in order, on every device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveStep {
    /// Iterations done in this solve, every phase counted (from 1); the
    /// report's `iterations` after the last.
    pub iteration: usize,
    /// The solve's iteration cap.
    pub max_iterations: usize,
    /// The error estimate after it, as a fraction of the model's size: the
    /// report's `residual_history` entry.
    pub residual: f32,
}

/// A stage of preparing stage 2 for a model, told to the preparation's
/// progress callback as it starts (`Tracker::new_observed`), in this order
/// where it runs. The stages a device skips are not told: the elastic ones
/// without the elastic force, the upload on the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum PrepareStage {
    /// The model and parameters checked, the control points found, the
    /// connection Laplacian's extreme eigenvalues estimated.
    Plan,
    /// The elastic force's rest data: the consistent gradients and the
    /// largest eigenvalue of its operator.
    ElasticModel,
    /// The GPU's kernels compiled and the model uploaded.
    Upload,
    /// The two-level solve's coarse space: aggregates, their matrix
    /// factored or its levels built.
    CoarseSpace,
    /// The elastic phase's aggregates and the volume smoother's
    /// contraction at rest.
    ElasticCoarse,
}

impl PrepareStage {
    /// A short name (`plan`, `elastic_model`, ...): the Python package's
    /// and the logs' spelling.
    pub fn name(self) -> &'static str {
        match self {
            Self::Plan => "plan",
            Self::ElasticModel => "elastic_model",
            Self::Upload => "upload",
            Self::CoarseSpace => "coarse_space",
            Self::ElasticCoarse => "elastic_coarse",
        }
    }
}

impl std::fmt::Display for PrepareStage {
    /// What the stage does, for a progress line.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Plan => "checking the model, estimating its spectrum",
            Self::ElasticModel => "the elastic model's consistent gradients",
            Self::Upload => "compiling the kernels, uploading the model",
            Self::CoarseSpace => "building the coarse space",
            Self::ElasticCoarse => "the elastic coarse space and smoother",
        })
    }
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
    /// How many times the elastic phase went on from the state it accepted
    /// last after it stopped short of the tolerance: linearised again there
    /// (`phase::MAX_RELINEARISATIONS` times at most), or without its
    /// correction after those (`phase::Next`); and a tracking frame's
    /// warm-started phase that failed and was solved again from a shear
    /// phase. The conjugate-gradient phase counts here the times it made
    /// its correction again because no step along its direction lowered
    /// the potential (not those it makes every
    /// `tracker::conjugate::DESCENT_RELINEARISE` steps;
    /// [`crate::stage2::params::ElasticSolve`]). 0
    /// for the other forces. Told here (and in the log at `info`), not as
    /// warnings: a solve that ends converged is a success.
    #[serde(default)]
    pub elastic_retries: usize,
    /// How many times an elastic phase went back to the last state it
    /// accepted and went on with half its step, because the potential had
    /// risen (or the iteration diverged) since
    /// (`phase::ENERGY_WATCH`); in the conjugate-gradient phase, how many
    /// times its line searches halved a step.
    #[serde(default)]
    pub backtracks: usize,
    /// Per elastic descent (a warm-started phase, or the elastic phases
    /// after a shear phase, each going on from the state the one before
    /// accepted last), the potential the elastic force descends where it
    /// started and at every state it accepted: each at most the one before,
    /// within the rounding of its parts ([`ENERGY_ROUNDING`]). Where the
    /// skin is paired with an observation each is the state's potential
    /// paired there; the watch compared it under the pairing of the state
    /// before ([`crate::stage2::Potential::held`]), where it fell, so the
    /// list itself may rise where the pairing moved.
    #[serde(default)]
    pub potentials: Vec<Vec<f64>>,
}

impl DeformReport {
    /// Whether every state an elastic descent accepted has a finite potential
    /// at most that of the state before, within
    /// [`ENERGY_ROUNDING`] of the larger potential's size
    /// (the tracker measures the rounding on its parts' magnitudes, which
    /// are at least that size: this is the stricter test).
    pub fn potentials_fell(&self) -> bool {
        let rounding = ENERGY_ROUNDING;
        self.potentials.iter().all(|phase| {
            phase.iter().all(|p| p.is_finite())
                && phase
                    .windows(2)
                    .all(|pair| pair[1] <= pair[0] + rounding * pair[0].abs().max(pair[1].abs()))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tolerance converges at any estimate it stops on; the float
    /// floor up to [`FLOAT_FLOOR_ERROR`] and not beyond; the cap, a
    /// divergence and a stall never.
    #[test]
    fn a_float_floor_converges_only_within_the_potentials_precision() {
        assert!(FLOAT_FLOOR_ERROR.to_bits() == (ENERGY_ROUNDING.sqrt() as f32).to_bits());
        assert!(StopReason::Tolerance.converged_at(1e-5));
        assert!(StopReason::FloatPrecision.converged_at(FLOAT_FLOOR_ERROR));
        assert!(StopReason::FloatPrecision.converged_at(5e-4));
        assert!(!StopReason::FloatPrecision.converged_at(2e-3));
        assert!(!StopReason::FloatPrecision.converged_at(0.48));
        assert!(!StopReason::FloatPrecision.converged_at(f32::NAN));
        for never in [
            StopReason::IterationCap,
            StopReason::Diverged,
            StopReason::Stalled,
        ] {
            assert!(!never.converged_at(0.0), "{never:?}");
        }
    }
}
