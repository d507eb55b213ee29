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

/// One line search: what it found and what it took.
struct Searched {
    found: Search,
    /// Times the step was halved.
    halved: usize,
    /// Potentials measured.
    measured: usize,
}

impl<D: SolveDevice> Tracker<D> {
    /// The elastic phase by the preconditioned conjugate gradient, from the
    /// state the shear phase left, within `cap` iterations; `None` where the
    /// device has no smoothed elastic phase to precondition it with, or no
    /// [`SolveDevice::descent_residual`] (the phase made its correction;
    /// the caller runs the Chebyshev phase).
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
        // `r . z` of the last step since the last linearisation (beta's
        // denominator); none: the direction starts afresh.
        let mut last_rz: Option<f64> = None;
        // How many steps' errors the history holds: each step's is read
        // at the next residual, the state it left.
        let mut recorded = 0;
        let (mut iterations, mut since_linearised) = (0, 0);
        let (mut halvings, mut relinearisations, mut retries, mut measured) = (0, 0, 0, 0);
        // The error estimate at the state the phase ends on (read there
        // whether or not a step followed it).
        let mut latest = 0.0;
        let stopped_by = loop {
            let Some(dots) = self.device.descent_residual()? else {
                if iterations == 0 && measured == 0 {
                    // The device has no conjugate-gradient calls.
                    return Ok(None);
                }
                // The device left its smoothed phase: nothing to descend by.
                break StopReason::Stalled;
            };
            let error = DESCENT_ERROR_BOUND * dots.step_largest / size;
            latest = error;
            if recorded < iterations {
                history.push(error);
                steps.told(error);
                recorded = iterations;
            }
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
            let searched = self.line_search(at, slope)?;
            halvings += searched.halved;
            measured += searched.measured;
            match searched.found {
                Search::Accepted(now) => {
                    at = now;
                    potentials.push(now.value);
                    iterations += 1;
                    since_linearised += 1;
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
            "conjugate-gradient elastic phase: {iterations} iterations, {measured} potentials \
             measured, {halvings} halved steps, {relinearisations} new linearisations ({retries} \
             after a failed search) in {seconds:.4} s, {stopped_by:?}"
        );
        Ok(Some(DeformReport {
            iterations,
            residual: latest,
            residual_history: history,
            converged: stopped_by.converged_at(latest),
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
    /// Leaves the state at the step accepted (or at the base).
    fn line_search(&mut self, at: Potential, slope: f64) -> Result<Searched, D::Error> {
        let mut measured = 0;
        let mut measure = |device: &mut D, t: f32| -> Result<Potential, D::Error> {
            measured += 1;
            device.descent_move(t)?;
            Ok(device.potential()?.unwrap_or(Potential {
                value: f64::NAN,
                magnitude: f64::NAN,
                held: f64::NAN,
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
        let found = if !enough(t, now) && !in_the_rounding {
            self.device.descent_move(0.0)?;
            Search::Failed
        } else {
            if moved_to != t {
                self.device.descent_move(t)?;
            }
            Search::Accepted(now)
        };
        Ok(Searched {
            found,
            halved,
            measured,
        })
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
    use std::convert::Infallible;

    use glam::{Mat3, Vec3};
    use tissue_core::Error;
    use tissue_core::field::SurfaceField;

    use super::*;
    use crate::coarse::laplacian::SharedLaplacian;
    use crate::stage2::device::Iteration;
    use crate::stage2::pairing::Pairing;
    use crate::stage2::params::ForceModel;
    use crate::stage2::plan::Plan;
    use crate::stage2::report::FLOAT_FLOOR_ERROR;
    use crate::stage2::report::SolveStep;
    use crate::stage2::springs::Spring;
    use crate::stage2::tracker::tests::star;

    /// A device whose potential is `x^T A x - 2 b^T x + offset` over
    /// unknowns `x` (`A` diagonal, its entries spread over two orders, so
    /// its two-level step stands in by a preconditioner that is only
    /// roughly right: `A`'s diagonal scaled by `mismatch`), each particle's
    /// part in index order plus `offset` split into a positive and a
    /// negative part (`offset` widens the parts' magnitude, not the value),
    /// its value rounded to a multiple of `quantum` where that is not zero
    /// (as a sum of `f32` parts rounds).
    /// `bump` raises the potential by that much at every state other than
    /// the base the line search starts from, from the `bump_from`th
    /// direction on (a potential the search cannot lower).
    struct Quadratic {
        a: Vec<f64>,
        b: Vec<f64>,
        x: Vec<f64>,
        mismatch: Vec<f64>,
        offset: f64,
        quantum: f64,
        bump: f64,
        bump_from: usize,
        directions: usize,
        z: Vec<f64>,
        last_residual: Vec<f64>,
        direction: Vec<f64>,
        base: Vec<f64>,
        linearisations: usize,
    }

    impl Quadratic {
        fn new(n: usize) -> Self {
            let a: Vec<f64> = (0..n).map(|i| 1.0 + 99.0 * i as f64 / n as f64).collect();
            Self {
                b: (0..n).map(|i| (i as f64 * 0.7).sin() * a[i]).collect(),
                mismatch: (0..n).map(|i| 1.0 + 0.5 * (i as f64 * 1.3).cos()).collect(),
                a,
                x: vec![0.0; n],
                offset: 0.0,
                quantum: 0.0,
                bump: 0.0,
                bump_from: 0,
                directions: 0,
                z: vec![0.0; n],
                last_residual: vec![0.0; n],
                direction: vec![0.0; n],
                base: vec![0.0; n],
                linearisations: 0,
            }
        }

        /// The unknowns that minimise the potential.
        fn answer(&self) -> Vec<f64> {
            self.b.iter().zip(&self.a).map(|(b, a)| b / a).collect()
        }
    }

    impl SolveDevice for Quadratic {
        type Error = Infallible;

        fn batch(&self) -> usize {
            1
        }

        fn elastic_rho(&self) -> Option<f32> {
            Some(0.5)
        }

        fn elastic_smoothed(&self) -> bool {
            true
        }

        fn write_positions(&mut self, _: &[Vec3], _: Option<Mat3>) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_springs(&mut self, _: &[Spring]) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_loads(&mut self, _: &[Vec3]) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_observation(&mut self, _: Option<&SurfaceField>) -> Result<(), Infallible> {
            Ok(())
        }

        fn set_pairing(&mut self, _: Option<&Pairing>) -> Result<(), Infallible> {
            Ok(())
        }

        fn begin(&mut self, _: Iteration) -> Result<(), Infallible> {
            self.linearisations += 1;
            Ok(())
        }

        fn run(&mut self, _: &[f32]) -> Result<Vec<(f32, f32)>, Infallible> {
            Ok(Vec::new())
        }

        fn replay(&mut self, _: usize) -> Result<(), Infallible> {
            Ok(())
        }

        fn read_positions(&mut self) -> Result<Vec<Vec3>, Infallible> {
            Ok(Vec::new())
        }

        fn reset(&mut self) -> Result<(), Infallible> {
            Ok(())
        }

        fn read_rotations(&mut self) -> Result<Vec<Mat3>, Infallible> {
            Ok(Vec::new())
        }

        fn write_rotations(&mut self, _: &[Mat3]) -> Result<(), Infallible> {
            Ok(())
        }

        /// No correction kept.
        type Correction = ();

        fn correction(&self) {}

        fn put_correction(&mut self, (): ()) -> Result<(), Infallible> {
            Ok(())
        }

        fn potential(&mut self) -> Result<Option<Potential>, Infallible> {
            let parts = self
                .x
                .iter()
                .zip(self.a.iter().zip(&self.b))
                .map(|(x, (a, b))| a * x * x - 2.0 * b * x);
            let bumped = self.x != self.base && self.directions > self.bump_from;
            let bump = if bumped { self.bump } else { 0.0 };
            let split = [0.5 * self.offset + self.offset, -self.offset, bump];
            let mut potential = Potential::of(parts.chain(split));
            if self.quantum > 0.0 {
                potential.value = (potential.value / self.quantum).round() * self.quantum;
            }
            Ok(Some(potential))
        }

        fn save(&mut self) -> Result<(), Infallible> {
            Ok(())
        }

        fn restore(&mut self) -> Result<(), Infallible> {
            Ok(())
        }

        fn shared_laplacian(&self, _: &Plan, _: &DeformParams) -> SharedLaplacian {
            unreachable!("not asked of the conjugate-gradient phase")
        }

        /// `r = b - A x`, `z = r / (A's diagonal times the mismatch)`.
        fn descent_residual(&mut self) -> Result<Option<DescentDots>, Infallible> {
            let mut parts = Vec::new();
            for i in 0..self.x.len() {
                let r = self.b[i] - self.a[i] * self.x[i];
                let z = r / (self.a[i] * self.mismatch[i]);
                parts.push([
                    r * z,
                    z * self.last_residual[i],
                    r * self.direction[i],
                    z.abs(),
                ]);
                self.last_residual[i] = r;
                self.z[i] = z;
            }
            Ok(Some(DescentDots::of(parts)))
        }

        fn descent_direction(&mut self, beta: f32) -> Result<(), Infallible> {
            for i in 0..self.x.len() {
                self.direction[i] = self.z[i] + f64::from(beta) * self.direction[i];
            }
            self.base.clone_from(&self.x);
            self.directions += 1;
            Ok(())
        }

        fn descent_move(&mut self, t: f32) -> Result<(), Infallible> {
            for i in 0..self.x.len() {
                self.x[i] = self.base[i] + f64::from(t) * self.direction[i];
            }
            Ok(())
        }
    }

    /// The conjugate-gradient phase of `device` within `cap` iterations,
    /// and the device after it.
    fn descend(device: Quadratic, cap: usize) -> (DeformReport, Quadratic) {
        let model = star();
        let params = DeformParams::default().with(|p| p.force = ForceModel::Elastic);
        let mut tracker = Tracker::new(&model, params.clone(), |_, _| Ok::<_, Error>(device))
            .unwrap_or_else(|e| panic!("{e}"));
        let mut observe = |_: &SolveStep| {};
        let mut steps = Steps {
            done: 0,
            max_iterations: cap,
            observe: &mut observe,
        };
        let Ok(report) = tracker.conjugate_phase(&params, cap, &mut steps);
        let report = report.unwrap_or_else(|| panic!("the device smooths its elastic phase"));
        (report, tracker.device)
    }

    /// On a quadratic potential with a preconditioner only roughly right,
    /// the phase converges to the tolerance well within as many
    /// iterations as unknowns, every accepted state strictly below the
    /// one before, with no step halved, no retry and no new linearisation
    /// before its twentieth step, at the minimiser.
    #[test]
    fn a_quadratic_is_descended_at_every_step_to_its_minimum() {
        let (report, device) = descend(Quadratic::new(60), 500);
        assert_eq!(report.stopped_by, StopReason::Tolerance, "{report:?}");
        assert!(report.converged);
        assert!(report.iterations < 60, "{report:?}");
        assert_eq!((report.backtracks, report.elastic_retries), (0, 0));
        assert_eq!(report.residual_history.len(), report.iterations);
        assert!(
            report.residual < DeformParams::default().tolerance,
            "{report:?}"
        );
        let potentials = &report.potentials[0];
        assert_eq!(potentials.len(), report.iterations + 1);
        assert!(
            potentials.windows(2).all(|pair| pair[1] < pair[0]),
            "{potentials:?}"
        );
        assert_eq!(
            device.linearisations,
            1 + report.iterations.saturating_sub(1) / DESCENT_RELINEARISE
        );
        let worst = device
            .x
            .iter()
            .zip(device.answer())
            .map(|(x, best)| (x - best).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-3, "{worst}");
    }

    /// Where the potential rounds (to 1e-7 of its parts' magnitude, as
    /// `f32` parts do) and its last decreases are below that, the phase
    /// still reaches the tolerance: its steps there are taken where the
    /// potential did not rise beyond its rounding, and the report's
    /// potentials fall within it. Some accepted states are no lower than
    /// the one before: those steps were taken in the rounding.
    #[test]
    fn decreases_below_the_rounding_are_taken_where_the_potential_did_not_rise() {
        let mut device = Quadratic::new(60);
        (device.offset, device.quantum) = (1e6, 0.25);
        let (report, _) = descend(device, 500);
        assert_eq!(report.stopped_by, StopReason::Tolerance, "{report:?}");
        assert!(report.potentials_fell(), "{:?}", report.potentials);
        let level = report.potentials[0]
            .windows(2)
            .filter(|p| p[1] >= p[0])
            .count();
        assert!(level > 0, "{:?}", report.potentials);
    }

    /// A potential no step along the direction lowers (raised at every
    /// state but the base): right where the phase made its correction the
    /// search fails and the phase ends there, stalled and not converged,
    /// never having accepted a step; after three accepted steps the first
    /// failure makes the correction again (a retry) and the second ends
    /// the phase, stalled, at the third step's state.
    #[test]
    fn a_potential_no_step_lowers_ends_the_phase_stalled() {
        let mut device = Quadratic::new(10);
        device.bump = 1e6;
        let (report, device) = descend(device, 500);
        assert_eq!(report.stopped_by, StopReason::Stalled, "{report:?}");
        assert!(!report.converged);
        assert_eq!((report.iterations, report.elastic_retries), (0, 0));
        assert_eq!(device.linearisations, 1);
        assert!(device.x.iter().all(|&x| x == 0.0));

        let mut device = Quadratic::new(10);
        (device.bump, device.bump_from) = (1e6, 3);
        let (report, device) = descend(device, 500);
        assert_eq!(report.stopped_by, StopReason::Stalled, "{report:?}");
        assert!(!report.converged);
        assert_eq!((report.iterations, report.elastic_retries), (3, 1));
        assert_eq!(device.linearisations, 2);
        assert_eq!(device.x, device.base);
    }

    /// Where the potential's parts are so large that no decrease a step
    /// asks is told apart from their rounding, and every step after the
    /// third raises it beyond that rounding, the phase stops there at the
    /// float floor with an error estimate of about 0.6 of the size: short
    /// of the answer, not at its precision ([`FLOAT_FLOOR_ERROR`]), and
    /// not converged.
    #[test]
    fn a_float_floor_far_from_the_answer_is_not_converged() {
        let mut device = Quadratic::new(60);
        (device.offset, device.bump, device.bump_from) = (1e14, 1e10, 3);
        let (report, _) = descend(device, 500);
        let (stopped_by, iterations, residual) =
            (report.stopped_by, report.iterations, report.residual);
        assert_eq!(
            (stopped_by, iterations),
            (StopReason::FloatPrecision, 3),
            "{residual}"
        );
        assert!(residual > 100.0 * FLOAT_FLOOR_ERROR, "{residual}");
        assert!(!report.converged);
    }

    /// The cap ends the phase not converged, after exactly that many
    /// accepted steps.
    #[test]
    fn the_cap_ends_the_phase() {
        let (report, _) = descend(Quadratic::new(60), 3);
        assert_eq!(report.stopped_by, StopReason::IterationCap);
        assert!(!report.converged);
        assert_eq!(report.iterations, 3);
    }

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
