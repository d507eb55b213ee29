//! The elastic phase as a nonlinear conjugate gradient preconditioned by
//! the two-level step (docs/METHOD.md, "Elastic model", *The
//! conjugate-gradient phase*): every accepted step lowers the potential the
//! elastic force descends by Armijo's margin, so the phase cannot diverge
//! and needs no step back.

use std::time::Instant;

use crate::stage2::device::{DescentDots, Potential, SolveDevice};
use crate::stage2::params::DeformParams;
use crate::stage2::phase::{Steps, rose};
use crate::stage2::report::{DeformReport, ENERGY_ROUNDING, StopReason};
use crate::stage2::tracker::Tracker;

/// The error of the conjugate-gradient phase is taken as at most this many
/// times the two-level step's largest move (`max |z_i|`): near its answer
/// that step underestimated the distance to the converged answer by up to
/// 6 times on the bench's cases and probes at 10k (docs/METHOD.md, *The
/// conjugate-gradient phase*).
pub const DESCENT_ERROR_BOUND: f32 = 10.0;

/// Armijo's margin: a step `t` along `d` is accepted where it lowers the
/// potential by at least this fraction of its first-order decrease
/// `t (2 r . d)`.
pub const ARMIJO: f64 = 1e-4;

/// The phase makes its correction again at the current state every this
/// many accepted steps (and starts its directions afresh): the two-level
/// step is linearised where it was made, and under a deep probe the
/// particles it compresses stiffen as the phase moves on.
pub const DESCENT_RELINEARISE: usize = 20;

/// The line search halves its step at most until it is this small; below,
/// no step along the direction lowers the potential enough.
pub const SMALLEST_STEP: f32 = 1e-4;

/// The line search measures the parabola's vertex where it lies further
/// than this from the full step, and takes it at most this many full steps
/// long ([`LONGEST_STEP`]).
const VERTEX_MARGIN: f32 = 0.25;

/// See [`VERTEX_MARGIN`].
pub const LONGEST_STEP: f32 = 4.0;

/// A decrease asked of a step, `t (2 r . d)`, below this many times the
/// potential's rounding ([`ENERGY_ROUNDING`] of its parts' magnitude) is
/// below what the potential tells apart: the line search halves no further,
/// and takes a step there where the potential did not rise beyond that
/// rounding.
const MEASURABLE: f64 = 1.0;

/// What one line search found.
enum Search {
    /// A step was taken; the potential there.
    Accepted(Potential),
    /// No step along the direction lowered the potential enough: the state
    /// is back at its base.
    Failed,
}

impl<D: SolveDevice> Tracker<D> {
    /// The elastic phase by the preconditioned conjugate gradient, from the
    /// state the shear phase left, within `cap` iterations; `None` where the
    /// device has no smoothed elastic phase to precondition it with (the
    /// phase made its correction; the caller runs the Chebyshev phase).
    ///
    /// Each iteration reads the residual `r` and the two-level step `z`
    /// at the current state ([`SolveDevice::descent_residual`]), stops where
    /// `DESCENT_ERROR_BOUND max |z|` is below the tolerance, takes
    /// Polak-Ribiere's `beta = max(0, z . (r - r') / (z' . r'))` (`0` where
    /// `d = z + beta d'` would be no descent) and searches along `d`
    /// ([`Tracker::line_search`]). Every [`DESCENT_RELINEARISE`] steps, and
    /// once where no step is accepted, the correction is made again at the
    /// current state; a failure right after that ends the phase, at the
    /// float floor (converged) where the decrease is below what the
    /// potential tells apart, stalled otherwise.
    pub(super) fn conjugate_phase(
        &mut self,
        p: &DeformParams,
        cap: usize,
        steps: &mut Steps<'_>,
    ) -> Result<Option<DeformReport>, D::Error> {
        let started = Instant::now();
        self.device.begin(self.iteration(p, true, true, 1.0))?;
        if !self.device.elastic_smoothed() {
            return Ok(None);
        }
        let Some(mut at) = self.device.potential()? else {
            return Ok(None);
        };
        let size = self.plan.size;
        let mut potentials = vec![at.value];
        let mut history = Vec::new();
        // `(r . z, beta's denominator)` of the last iteration since the
        // last linearisation: none, the direction starts afresh.
        let mut last_rz: Option<f64> = None;
        let (mut iterations, mut since_linearised) = (0, 0);
        let (mut halvings, mut relinearisations, mut retries) = (0, 0, 0);
        let stopped_by = loop {
            let Some(dots) = self.device.descent_residual()? else {
                // The device left its smoothed phase: nothing to descend by.
                break StopReason::Stalled;
            };
            let error = DESCENT_ERROR_BOUND * dots.step_largest / size;
            if !(error.is_finite() && dots.residual_step.is_finite()) {
                break StopReason::Diverged;
            }
            if error < p.tolerance {
                break StopReason::Tolerance;
            }
            if iterations >= cap {
                break StopReason::IterationCap;
            }
            let (beta, slope) = direction(&dots, last_rz);
            if slope <= 0.0 {
                // No descent along the two-level step: none left where the
                // residual vanished, none to take where the step is not a
                // descent direction.
                break if slope == 0.0 {
                    StopReason::FloatPrecision
                } else {
                    StopReason::Stalled
                };
            }
            self.device.descent_direction(beta as f32)?;
            let (search, halved) = self.line_search(at, slope)?;
            halvings += halved;
            match search {
                Search::Accepted(now) => {
                    at = now;
                    potentials.push(now.value);
                    iterations += 1;
                    since_linearised += 1;
                    history.push(error);
                    steps.told(error);
                    last_rz = Some(dots.residual_step);
                }
                Search::Failed if since_linearised == 0 => {
                    break if unmeasurable(at, slope) {
                        StopReason::FloatPrecision
                    } else {
                        StopReason::Stalled
                    };
                }
                Search::Failed => {
                    since_linearised = DESCENT_RELINEARISE;
                    retries += 1;
                }
            }
            if since_linearised >= DESCENT_RELINEARISE {
                self.device.begin(self.iteration(p, true, true, 1.0))?;
                relinearisations += 1;
                since_linearised = 0;
                last_rz = None;
            }
        };
        let seconds = started.elapsed().as_secs_f64();
        log::debug!(
            "conjugate-gradient elastic phase: {iterations} iterations, {halvings} halved \
             steps, {relinearisations} new linearisations ({retries} after a failed search) in \
             {seconds:.4} s, {stopped_by:?}"
        );
        Ok(Some(DeformReport {
            iterations,
            residual: history.last().copied().unwrap_or(0.0),
            residual_history: history,
            converged: matches!(
                stopped_by,
                StopReason::Tolerance | StopReason::FloatPrecision
            ),
            stopped_by,
            seconds,
            elastic_retries: retries,
            backtracks: halvings,
            potentials: vec![potentials],
        }))
    }

    /// Searches along the direction from the state at potential `at`
    /// whose first-order decrease per unit step is `slope` (`2 r . d`):
    /// the full step; the vertex of the parabola through the potential at
    /// 0 and 1 and the slope, where it lies more than [`VERTEX_MARGIN`]
    /// from it; halving until Armijo's margin holds, or until the decrease
    /// asked for is below the potential's rounding ([`MEASURABLE`]), where
    /// a step that did not raise it beyond that rounding is taken.
    /// Leaves the state at the step accepted (or at the base). Also returns
    /// how many times the step was halved.
    fn line_search(&mut self, at: Potential, slope: f64) -> Result<(Search, usize), D::Error> {
        let measure = |device: &mut D, t: f32| -> Result<Potential, D::Error> {
            device.descent_move(t)?;
            Ok(device.potential()?.unwrap_or(Potential {
                value: f64::NAN,
                magnitude: f64::NAN,
            }))
        };
        let enough = |t: f32, now: Potential| now.value <= at.value - ARMIJO * f64::from(t) * slope;
        let (mut t, mut now) = (1.0f32, measure(&mut self.device, 1.0)?);
        let mut moved_to = t;
        // phi(t) ~ phi(0) - slope t + curvature t^2 / 2.
        let curvature = 2.0 * (now.value - at.value + slope);
        if curvature > 0.0 {
            let vertex = ((slope / curvature) as f32).min(LONGEST_STEP);
            if (vertex - 1.0).abs() > VERTEX_MARGIN {
                let there = measure(&mut self.device, vertex)?;
                moved_to = vertex;
                if there.value < now.value || !now.value.is_finite() {
                    (t, now) = (vertex, there);
                }
            }
        }
        let mut halved = 0;
        // Halved while the decrease asked for is one the potential tells
        // apart from its rounding.
        while !enough(t, now) && t > SMALLEST_STEP && !unmeasurable(at, f64::from(t) * slope) {
            t *= 0.5;
            now = measure(&mut self.device, t)?;
            moved_to = t;
            halved += 1;
        }
        // Below that, a step where the potential did not rise beyond its
        // rounding is taken.
        let in_the_rounding = unmeasurable(at, f64::from(t) * slope) && !rose(at, now);
        if !enough(t, now) && !in_the_rounding {
            self.device.descent_move(0.0)?;
            return Ok((Search::Failed, halved));
        }
        if moved_to != t {
            self.device.descent_move(t)?;
        }
        Ok((Search::Accepted(now), halved))
    }
}

/// Whether a first-order decrease `slope` from the state at potential `at`
/// is below what the potential tells apart ([`MEASURABLE`]).
fn unmeasurable(at: Potential, slope: f64) -> bool {
    slope < MEASURABLE * ENERGY_ROUNDING * at.magnitude
}

/// Polak-Ribiere's `beta` (0 without a last iteration, or where it is
/// negative) and the first-order decrease `2 r . d` along `d = z + beta d'`;
/// where that is no descent, `d = z` (`beta = 0`).
fn direction(dots: &DescentDots, last_rz: Option<f64>) -> (f64, f64) {
    let beta = match last_rz {
        Some(last) if last > 0.0 => {
            ((dots.residual_step - dots.step_last_residual) / last).max(0.0)
        }
        _ => 0.0,
    };
    let along = dots.residual_step + beta * dots.residual_last_direction;
    if beta > 0.0 && along > 0.0 {
        (beta, 2.0 * along)
    } else {
        (0.0, 2.0 * dots.residual_step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dots(rz: f64, zr_last: f64, rd_last: f64) -> DescentDots {
        DescentDots {
            residual_step: rz,
            step_last_residual: zr_last,
            residual_last_direction: rd_last,
            step_largest: 1.0,
        }
    }

    /// The first direction, and one after a new linearisation, is the
    /// two-level step; after that Polak-Ribiere's, never below zero; a
    /// conjugate direction that would climb is dropped for the step.
    #[test]
    fn the_direction_is_polak_ribieres_and_always_descends() {
        assert_eq!(direction(&dots(4.0, 1.0, 3.0), None), (0.0, 8.0));
        let (beta, slope) = direction(&dots(4.0, 1.0, 3.0), Some(6.0));
        assert_eq!(beta, 0.5);
        assert_eq!(slope, 2.0 * (4.0 + 0.5 * 3.0));
        // z . (r - r') < 0: beta is 0, the step alone.
        assert_eq!(direction(&dots(4.0, 5.0, 3.0), Some(6.0)), (0.0, 8.0));
        // r . d' so negative that r . d < 0: the step alone.
        assert_eq!(direction(&dots(4.0, 1.0, -20.0), Some(6.0)), (0.0, 8.0));
    }
}
