//! Chebyshev acceleration and the stopping rule of a stage-2 solve.

use crate::stage2::params::DeformParams;
use crate::stage2::plan::Plan;
use crate::stage2::report::{DeformReport, StopReason};

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
            enabled: params.tuning.chebyshev,
            warm_up: params.tuning.warm_up,
            omega: 1.0,
        }
    }

    /// The sequence for one solve with contraction `rho` (a two-level one, say).
    pub fn with_rho(params: &DeformParams, rho: f32) -> Self {
        Self {
            rho,
            enabled: params.tuning.chebyshev,
            warm_up: params.tuning.warm_up,
            omega: 1.0,
        }
    }

    /// The sequence after its first `done` weights were taken: a phase
    /// that went on after a pause.
    #[must_use]
    pub fn advanced(mut self, done: usize) -> Self {
        for iteration in 1..=done {
            self.omega(iteration);
        }
        self
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
/// `|e| <= |step| / (1 - rho)`. Where `rho` is the measured contraction of
/// the volume smoother's two-level iteration ([`StoppingRule::accelerated`]),
/// Chebyshev's steps and error fall together at the accelerated rate
/// `sigma` ([`accelerated_rate`]) inside an envelope twice its geometric
/// tail, and `|e| <= 2 |step| / (1 - sigma)`; not where `rho` is near 1
/// and the iteration takes long to reach that rate (the plain step on the
/// Laplacian stopped with errors above the tolerance). Re-fitting the
/// rotations adds slower modes (a twist of the interior against its
/// surface); the contraction observed over the last five iterations
/// catches them, `|step| / (1 - observed)`. Stop when the larger bound is
/// below `tolerance` times the size, or when the RMS step is below what
/// `f32` resolves.
#[derive(Debug, Clone)]
pub struct StoppingRule {
    tolerance: f32,
    size: f32,
    floor: f32,
    /// How many times its step the error is at most, from the contraction.
    bound: f32,
    rms_steps: Vec<f32>,
    history: Vec<f32>,
    /// The largest steps, where the rule watches for a stall.
    max_steps: Option<Vec<f32>>,
}

/// Iterations of the window an accelerated iteration must make progress
/// in: stalled when the smallest largest step of the last `STALL_WINDOW`
/// iterations is above [`STALL_FACTOR`] times that of the
/// `STALL_WINDOW` before. At the volume smoother's rate (`sigma` about
/// 0.6-0.7) a window takes a healthy phase down by a factor of 200 or
/// more; on the bench's phantom indented at 300,000 particles the
/// corrected phase kept steps of the same size for 5,000 iterations
/// (docs/METHOD.md, "The volume smoother").
pub const STALL_WINDOW: usize = 15;

/// See [`STALL_WINDOW`].
pub const STALL_FACTOR: f32 = 0.5;

/// Chebyshev's error stays within this many times the geometric tail of
/// its rate (`2 sigma^k / (1 + sigma^(2k))` of the start).
pub const CHEBYSHEV_ENVELOPE: f32 = 2.0;

impl StoppingRule {
    /// The rule for one solve.
    pub fn new(plan: &Plan, params: &DeformParams) -> Self {
        Self {
            tolerance: params.tolerance,
            size: plan.size,
            floor: plan.floor,
            bound: 1.0 / (1.0 - plan.rho(params)),
            rms_steps: Vec::new(),
            history: Vec::new(),
            max_steps: None,
        }
    }

    /// The rule for one solve with contraction `rho` (a two-level one, say).
    pub fn with_rho(plan: &Plan, params: &DeformParams, rho: f32) -> Self {
        Self {
            bound: 1.0 / (1.0 - rho),
            ..Self::new(plan, params)
        }
    }

    /// The rule for an iteration whose contraction `rho` was measured
    /// closely (the volume smoother's two-level iteration): with
    /// Chebyshev's weights the error is bounded by its accelerated rate
    /// ([`error_bound`]).
    /// It also stops an iteration that stalls ([`STALL_WINDOW`]), whose
    /// measured contraction no longer holds.
    pub fn accelerated(plan: &Plan, params: &DeformParams, rho: f32) -> Self {
        Self {
            bound: error_bound(rho, params.tuning.chebyshev),
            max_steps: Some(Vec::new()),
            ..Self::new(plan, params)
        }
    }

    /// Whether the largest steps in `steps` stopped falling.
    fn stalled(steps: &[f32]) -> bool {
        let n = steps.len();
        if n < 2 * STALL_WINDOW {
            return false;
        }
        let least = |window: &[f32]| window.iter().copied().fold(f32::INFINITY, f32::min);
        let (before, recent) = (
            least(&steps[n - 2 * STALL_WINDOW..n - STALL_WINDOW]),
            least(&steps[n - STALL_WINDOW..]),
        );
        recent > STALL_FACTOR * before
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
        let bound = self.bound.max(1.0 / (1.0 - observed.min(0.999)));
        let error = max_step * bound / self.size;
        self.history.push(error);
        if !(error.is_finite() && rms_step.is_finite()) {
            Some(StopReason::Diverged)
        } else if n > 1 && error < self.tolerance {
            Some(StopReason::Tolerance)
        } else if n > 1 && rms_step < self.floor {
            // Rounding noise: most particles no longer move, a few flip by an ulp.
            Some(StopReason::FloatPrecision)
        } else if let Some(steps) = self.max_steps.as_mut() {
            steps.push(max_step);
            Self::stalled(steps).then_some(StopReason::Stalled)
        } else {
            None
        }
    }

    /// The error estimate after the last iteration recorded, as a fraction
    /// of the size.
    pub fn last_error(&self) -> Option<f32> {
        self.history.last().copied()
    }

    /// The error estimates recorded so far, one per iteration.
    pub fn history(&self) -> &[f32] {
        &self.history
    }

    /// The report of the solve, ended by `stopped_by` after `iterations`.
    pub fn report(self, iterations: usize, stopped_by: StopReason, seconds: f64) -> DeformReport {
        let residual = self.history.last().copied().unwrap_or(0.0);
        DeformReport {
            iterations,
            residual,
            residual_history: self.history,
            converged: stopped_by.converged_at(residual),
            stopped_by,
            seconds,
            elastic_retries: 0,
            backtracks: 0,
            potentials: Vec::new(),
        }
    }
}

/// `(last / first)^(1 / count)`: the mean contraction per iteration.
fn geometric_rate(first: f32, last: f32, count: usize) -> f32 {
    if first <= 0.0 || count == 0 {
        return 0.0;
    }
    (last / first).powf(1.0 / count as f32)
}

/// The rate at which a Chebyshev-accelerated iteration of contraction `rho`
/// converges: `rho / (1 + sqrt(1 - rho^2))`.
pub fn accelerated_rate(rho: f32) -> f32 {
    rho / (1.0 + (1.0 - rho * rho).max(0.0).sqrt())
}

/// How many times its step the error of an iteration of contraction `rho`
/// is at most: `2 / (1 - sigma)` with Chebyshev's weights, `1 / (1 - rho)`
/// without.
pub fn error_bound(rho: f32, chebyshev: bool) -> f32 {
    if chebyshev {
        CHEBYSHEV_ENVELOPE / (1.0 - accelerated_rate(rho))
    } else {
        1.0 / (1.0 - rho)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A phase that went on after a pause takes the weights it would have
    /// taken without one.
    #[test]
    fn an_advanced_sequence_goes_on_with_the_same_weights() {
        let params = DeformParams::default();
        for done in [0, 1, 2, 7] {
            let mut whole = Chebyshev::with_rho(&params, 0.9);
            for k in 1..=done {
                whole.omega(k);
            }
            let mut advanced = Chebyshev::with_rho(&params, 0.9).advanced(done);
            for k in done + 1..done + 5 {
                assert_eq!(
                    advanced.omega(k),
                    whole.omega(k),
                    "after {done}, weight {k}"
                );
            }
        }
    }
}
