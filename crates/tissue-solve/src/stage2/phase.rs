//! What one phase of a stage-2 solve runs with and the rules of the
//! elastic phase the tracker ([`crate::stage2::tracker::Tracker`]) follows:
//! where the shear phase stops, the energy watch, and how an elastic phase
//! that stopped short of the tolerance goes on.

use crate::stage2::acceleration::Chebyshev;
use crate::stage2::batches::Batches;
use crate::stage2::device::{Potential, SolveDevice};
use crate::stage2::report::{ENERGY_ROUNDING, SolveStep, StopReason};

/// The shear phase of an elastic solve stops at this many times the
/// solve's tolerance: it only has to bring every neighbourhood near its
/// rest volume.
pub const SHEAR_TOLERANCE: f32 = 10.0;

/// The shear phase measures the volumes' misfit
/// ([`crate::stage2::params::SolverTuning::shear_volume_share`]) first where its estimate falls
/// below this many times its tolerance (so [`SHEAR_TOLERANCE`] times this
/// many times the solve's), then each time it falls below its share of the
/// last misfit measured.
pub const SHEAR_CHECK: f32 = 100.0;

/// How many times in one solve an elastic phase that stopped short of the
/// tolerance (stalled, or out of steps back) goes on from the state it
/// accepted last with its correction made there, before the solve goes on
/// without the correction ([`Next`]). A corrected phase's steps are set
/// from a linearisation at its start; under a deep probe the particles it
/// compresses stiffen as the phase moves away from it, and its steps
/// settle at a size that no longer falls. The deepest of the bench's probes
/// at 10k (30 mm deep, 15 mm wide) is linearised three times
/// (docs/METHOD.md, "Elastic model", *The energy watch*).
pub const MAX_RELINEARISATIONS: usize = 8;

/// What an elastic solve does after a phase that stopped short of the
/// tolerance: the device holds the state the phase accepted last (whose
/// potential is at most that of every state before it), and the solve goes
/// on from there; nothing is run again from an earlier state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Next {
    /// The solve ends there.
    End,
    /// The next phase makes its correction at that state and starts with
    /// the fraction of its step the last one ended with.
    Relinearise,
    /// The next phase steps plainly (the device's correction dropped),
    /// halving its step from each rise ([`MAX_BACKTRACKS`] times).
    Uncorrected,
}

impl Next {
    /// After a phase that stopped by `stopped_by`, ran `corrected` (with the
    /// device's correction), `smoothed` (with the volume smoother), after
    /// `relinearised` linearisations of the solve's, with iterations left
    /// or not. A smoothed phase out of steps back, or any corrected phase
    /// that stalled, is linearised again at the state it accepted; a plain
    /// one out of steps back made its correction at that state already, and
    /// goes on without it, as every corrected phase does past
    /// [`MAX_RELINEARISATIONS`].
    pub(crate) fn after(
        stopped_by: StopReason,
        corrected: bool,
        smoothed: bool,
        relinearised: usize,
        left: bool,
    ) -> Self {
        if !stopped_by.failed() || !left || !corrected {
            return Self::End;
        }
        let linearise_again = stopped_by == StopReason::Stalled || smoothed;
        if linearise_again && relinearised < MAX_RELINEARISATIONS {
            Self::Relinearise
        } else {
            Self::Uncorrected
        }
    }
}

/// The most iterations an elastic solve's warm phase (from the predicted
/// start) runs before it is taken for stalled and the frame is solved
/// again from a shear phase. A warm phase starts near its answer: the
/// unloaded shape's warm rounds and the deformed postures take 20-120
/// iterations at 10k, tracking frames 2-60; one that runs this long
/// circles a state far from the one its correction was made at, and left
/// alone it ran to the 5,000-iteration cap (the first round of breast_e's
/// rest surface taken as an unloaded shape at 1.3 kPa).
pub const WARM_ITERATIONS: usize = 500;

/// An elastic phase measures the potential its force descends every this
/// many iterations (the GPU's batch): a phase that fails raises it within
/// its first five iterations, a healthy one never does (docs/METHOD.md,
/// "Elastic model", *The energy watch*).
pub const ENERGY_WATCH: usize = 8;

/// A phase that does not watch the potential, other than an elastic
/// solve's shear phase (a tracking frame's warm phase, a solve with the
/// symmetric force), runs its first batch of this many iterations on a
/// device that batches, each next batch twice the last up to the device's:
/// a tracking frame takes 2-4 iterations, which a first batch of 8 ran past
/// and replayed (10 iterations for 2).
pub const FIRST_BATCH: usize = 2;

/// How many times one smoothed elastic phase goes back to the state it
/// accepted with half its step before it ends, diverged: the step is then
/// `1 / 64` of the first; so does an uncorrected one, halving its plain
/// step. A plain corrected one goes back once from each state it accepted,
/// its correction linearised there, at most as many times.
pub const MAX_BACKTRACKS: usize = 6;

/// Below this many tolerances of its error estimate a watched smoothed
/// phase is settling: it neither keeps nor steps back from a finite rise
/// (it goes on) and makes no verdict of no progress. It is then far
/// from the steps with which a failing phase raises the potential, and on
/// lavapipe the potential rises there by about `1e-5` of itself where the
/// CPU's does not. Without it the test column
/// lying at 60 kPa went back 24 times on lavapipe in one warm trial, ran
/// again 3 times and stopped at the float floor short of the minimum (the
/// fit 65 kPa against 60); the probe sweep's steps back are as they were
/// (docs/METHOD.md, *The energy watch*).
pub const WATCH_SETTLED: f32 = 100.0;

/// Whether the potential rose from `last` to `now` by more than its
/// rounding ([`ENERGY_ROUNDING`]); a potential that is not finite rose (on
/// the GPU a diverging state's parts overflow `f32`).
pub(crate) fn rose(last: Potential, now: Potential) -> bool {
    if !(now.value.is_finite() && now.magnitude.is_finite()) {
        return true;
    }
    let rounding = ENERGY_ROUNDING * last.magnitude.max(now.magnitude);
    now.value > last.value + rounding
}

/// Whether the potential fell from `last` to `now` by more than its
/// rounding ([`ENERGY_ROUNDING`]).
fn fell(last: Potential, now: Potential) -> bool {
    let rounding = ENERGY_ROUNDING * last.magnitude.max(now.magnitude);
    now.value < last.value - rounding
}

/// What a watched phase knows at the end of an interval.
pub(crate) struct Watched {
    /// The potential of the state it accepted last.
    pub(crate) last: Potential,
    /// The potential now; `None` where the iteration diverged.
    pub(crate) now: Option<Potential>,
    /// The stopping rule's error estimate at the state accepted last (none
    /// since the phase's last step back), and now.
    pub(crate) accepted_error: Option<f32>,
    pub(crate) error_now: Option<f32>,
    /// Whether the phase is smoothed (its step back halves the step).
    pub(crate) smoothed: bool,
    /// Whether its error estimate is below [`WATCH_SETTLED`] tolerances.
    pub(crate) settling: bool,
    /// Whether it has a step back left.
    pub(crate) may_step_back: bool,
}

/// What the energy watch makes of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Verdict {
    /// The state is kept: the potential did not rise.
    Keep(Potential),
    /// Neither kept nor stepped back from: a smoothed phase settling whose
    /// potential rose, which goes on, the state it kept last still the one
    /// to go back to.
    Pass,
    /// Back to the state kept last: the potential rose (the reason's
    /// words), or a smoothed phase made no progress.
    StepBack(&'static str),
    /// The phase ends there, diverged: no step back left.
    Diverged,
}

impl Watched {
    /// A rise (or a divergence) is stepped back from while there are steps
    /// back left; so is no progress in a smoothed phase that is not
    /// settling (neither the potential nor the error estimate fell: a
    /// particle stepping back and forth at a flat potential). A smoothed
    /// phase settling passes over a finite rise (docs/METHOD.md, *The
    /// energy watch*).
    ///
    /// Where the skin is paired, the state now is measured under the
    /// pairing of the state kept last as well ([`Potential::held`]): the
    /// pairing moves the springs' planes as the skin slides, and the
    /// potential paired at each state is not quite the one the iterations
    /// descend (their springs' planes held while they step), so it may
    /// rise a little as they converge. A state whose potential paired
    /// where it is rose is still kept where it fell under the kept
    /// pairing while the error estimate fell (the iteration contracting);
    /// with the error estimate up, such a rise is a cycle of the pairing,
    /// stepped back from as any rise.
    pub(crate) fn verdict(&self) -> Verdict {
        let settling = self.smoothed && self.settling;
        let held = |now: Potential| Potential {
            value: now.held,
            ..now
        };
        let contracting = matches!(
            (self.accepted_error, self.error_now),
            (Some(a), Some(e)) if e < a
        );
        let rise = |now: Potential| {
            // Fell under the kept pairing while the iteration contracts:
            // the skin slid.
            let slid = contracting && !rose(self.last, held(now));
            rose(self.last, now) && !slid
        };
        match self.now {
            Some(now) if settling && now.value.is_finite() && rise(now) => Verdict::Pass,
            Some(now) if !rise(now) => {
                let stuck = self.smoothed
                    && !settling
                    && self.may_step_back
                    && !fell(self.last, now)
                    && matches!(
                        (self.accepted_error, self.error_now),
                        (Some(a), Some(e)) if e >= a
                    );
                if stuck {
                    Verdict::StepBack("made no progress")
                } else {
                    Verdict::Keep(now)
                }
            }
            _ if self.may_step_back => Verdict::StepBack("rose"),
            _ => Verdict::Diverged,
        }
    }
}

/// How a phase runs ([`Iteration`]'s `correct`, `relinearise` and
/// `damping`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PhaseRun {
    pub(crate) correct: bool,
    pub(crate) relinearise: bool,
    pub(crate) damping: f32,
    /// The shear phase of an elastic solve: it also stops on the volumes'
    /// misfit ([`crate::stage2::params::SolverTuning::shear_volume_share`]).
    pub(crate) volume_check: bool,
    /// A corrected elastic phase watches its potential ([`ENERGY_WATCH`]);
    /// a tracking frame's warm phase does not (it takes 2-10 iterations,
    /// the watch's first measure would cost it a third of an iteration's
    /// time or more, and where it fails the frame is solved again from a
    /// shear phase, watched).
    pub(crate) watch: bool,
    /// A watched smoothed phase takes no step back: its first rise ends it
    /// at the state it accepted, diverged, for the conjugate gradient to go
    /// on from ([`crate::stage2::params::ElasticSolve::ChebyshevThenConjugateGradient`]).
    /// Otherwise it goes back there up to [`MAX_BACKTRACKS`] times.
    pub(crate) turn: bool,
}

impl PhaseRun {
    /// Corrected, the full step, linearised where it starts if `relinearise`.
    pub(crate) fn corrected(relinearise: bool) -> Self {
        Self {
            correct: true,
            relinearise,
            damping: 1.0,
            volume_check: false,
            watch: true,
            turn: false,
        }
    }
}

/// A solve's progress callback and the iterations it was told of.
pub(crate) struct Steps<'a> {
    pub(crate) done: usize,
    pub(crate) max_iterations: usize,
    pub(crate) observe: &'a mut dyn FnMut(&SolveStep),
}

impl Steps<'_> {
    /// One more iteration, ending with error estimate `residual`.
    pub(crate) fn told(&mut self, residual: f32) {
        self.done += 1;
        (self.observe)(&SolveStep {
            iteration: self.done,
            max_iterations: self.max_iterations,
            residual,
        });
    }
}

/// A solve's batches on a device: the Chebyshev weights of each batch, which
/// may run ahead of the stopping rule because a replay repeats them exactly.
pub(crate) struct SolveBatches<'a, D: SolveDevice> {
    pub(crate) device: &'a mut D,
    pub(crate) chebyshev: Chebyshev,
    /// Iterations of the phase run before these batches.
    pub(crate) done: usize,
}

impl<D: SolveDevice> Batches for SolveBatches<'_, D> {
    type Measure = (f32, f32);
    type Error = D::Error;

    fn run(&mut self, done: usize, count: usize) -> Result<Vec<(f32, f32)>, D::Error> {
        let omegas: Vec<f32> = (1..=count)
            .map(|k| self.chebyshev.omega(self.done + done + k))
            .collect();
        self.device.run(&omegas)
    }

    fn replay(&mut self, count: usize) -> Result<(), D::Error> {
        self.device.replay(count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A potential above the last by more than its rounding rose; one
    /// within it did not; one that is not finite rose whatever its
    /// magnitude (an infinite magnitude would make any rounding infinite).
    #[test]
    fn a_potential_that_is_not_finite_rose() {
        let at = |value: f64, magnitude: f64| Potential {
            value,
            magnitude,
            held: value,
        };
        let last = at(100.0, 200.0);
        assert!(!rose(last, at(99.0, 200.0)));
        assert!(!rose(last, at(100.0 + 1e-4, 200.0)));
        assert!(rose(last, at(100.01, 200.0)));
        assert!(rose(last, at(f64::INFINITY, f64::INFINITY)));
        assert!(rose(last, at(f64::NAN, 200.0)));
        assert!(rose(last, at(50.0, f64::INFINITY)));
    }

    /// After a phase that stopped short of the tolerance: a stall, or a
    /// smoothed phase out of steps back, is linearised again while
    /// linearisations are left; a plain corrected phase out of steps back
    /// (linearised again at that state already), or any past the last
    /// linearisation, goes on without its correction; an uncorrected one,
    /// or one with no iteration left, ends; a phase that converged ends.
    #[test]
    fn a_phase_short_of_the_tolerance_goes_on_from_where_it_accepted() {
        use StopReason::{Diverged, FloatPrecision, IterationCap, Stalled, Tolerance};
        let most = MAX_RELINEARISATIONS;
        let after = |stopped, corrected, smoothed, relinearised| {
            Next::after(stopped, corrected, smoothed, relinearised, true)
        };
        assert_eq!(after(Stalled, true, true, 0), Next::Relinearise);
        assert_eq!(after(Stalled, true, false, most - 1), Next::Relinearise);
        assert_eq!(after(Diverged, true, true, 0), Next::Relinearise);
        assert_eq!(after(Diverged, true, false, 0), Next::Uncorrected);
        assert_eq!(after(Stalled, true, true, most), Next::Uncorrected);
        assert_eq!(after(Diverged, true, true, most), Next::Uncorrected);
        assert_eq!(after(Stalled, false, false, 0), Next::End);
        assert_eq!(after(Diverged, false, false, 0), Next::End);
        for done in [Tolerance, FloatPrecision, IterationCap] {
            assert_eq!(after(done, true, true, 0), Next::End, "{done:?}");
        }
        assert_eq!(Next::after(Stalled, true, true, 0, false), Next::End);
    }

    /// The watch's verdicts: a fall is kept; a rise stepped back from, or
    /// the end, diverged, with no step back left; a smoothed phase whose
    /// potential and error estimate both stayed made no progress (kept
    /// with no step back left, or in a plain phase); settling, it passes
    /// over a finite rise but not over a divergence.
    #[test]
    fn the_watch_keeps_falls_and_steps_back_from_rises_and_no_progress() {
        let at = |value: f64| Potential {
            value,
            magnitude: 200.0,
            held: value,
        };
        let watched = |now: Option<f64>, error_now: f32| Watched {
            last: at(100.0),
            now: now.map(at),
            accepted_error: Some(1.0),
            error_now: Some(error_now),
            smoothed: true,
            settling: false,
            may_step_back: true,
        };
        assert_eq!(watched(Some(99.0), 2.0).verdict(), Verdict::Keep(at(99.0)));
        assert_eq!(
            watched(Some(101.0), 0.5).verdict(),
            Verdict::StepBack("rose")
        );
        assert_eq!(watched(None, 0.5).verdict(), Verdict::StepBack("rose"));
        let flat = watched(Some(100.0), 1.0);
        assert_eq!(flat.verdict(), Verdict::StepBack("made no progress"));
        // The error estimate fell: progress.
        assert_eq!(
            watched(Some(100.0), 0.9).verdict(),
            Verdict::Keep(at(100.0))
        );
        let plain = Watched {
            smoothed: false,
            ..watched(Some(100.0), 1.0)
        };
        assert_eq!(plain.verdict(), Verdict::Keep(at(100.0)));
        let no_steps_left = |w: Watched| Watched {
            may_step_back: false,
            ..w
        };
        assert_eq!(no_steps_left(flat).verdict(), Verdict::Keep(at(100.0)));
        assert_eq!(
            no_steps_left(watched(Some(101.0), 0.5)).verdict(),
            Verdict::Diverged
        );
        let settling = |w: Watched| Watched {
            settling: true,
            ..w
        };
        assert_eq!(settling(watched(Some(101.0), 0.5)).verdict(), Verdict::Pass);
        assert_eq!(
            settling(watched(Some(100.0), 1.0)).verdict(),
            Verdict::Keep(at(100.0))
        );
        assert_eq!(
            settling(watched(Some(f64::NAN), 0.5)).verdict(),
            Verdict::StepBack("rose")
        );
        assert_eq!(
            settling(watched(None, 0.5)).verdict(),
            Verdict::StepBack("rose")
        );
        // A plain phase does not settle.
        let plain_settling = Watched {
            smoothed: false,
            ..settling(watched(Some(101.0), 0.5))
        };
        assert_eq!(plain_settling.verdict(), Verdict::StepBack("rose"));
    }

    /// Where the skin is paired the watch also compares the state now
    /// under the kept state's pairing (`held`) with the kept state's
    /// potential: a state whose potential paired where it is rose, but fell
    /// under the kept pairing, is kept (its own potential the next
    /// reference) while the error estimate falls, and stepped back from
    /// where it rose (a cycle of the pairing); one whose potential paired
    /// where it is fell is kept whatever the kept pairing says.
    #[test]
    fn a_paired_watch_compares_under_the_kept_states_pairing() {
        let paired = |value: f64, held: f64| Potential {
            value,
            magnitude: 200.0,
            held,
        };
        let watched = |now: Potential| Watched {
            last: paired(100.0, 100.0),
            now: Some(now),
            accepted_error: Some(1.0),
            error_now: Some(0.5),
            smoothed: true,
            settling: false,
            may_step_back: true,
        };
        let slid = paired(101.0, 99.0);
        assert_eq!(watched(slid).verdict(), Verdict::Keep(slid));
        let cycling = Watched {
            error_now: Some(2.0),
            ..watched(slid)
        };
        assert_eq!(cycling.verdict(), Verdict::StepBack("rose"));
        // Right after a step back there is no estimate to compare.
        let after_a_step_back = Watched {
            accepted_error: None,
            ..watched(slid)
        };
        assert_eq!(after_a_step_back.verdict(), Verdict::StepBack("rose"));
        let fell_here = paired(99.0, 101.0);
        assert_eq!(watched(fell_here).verdict(), Verdict::Keep(fell_here));
        // Rose both ways: a rise, contracting or not.
        assert_eq!(
            watched(paired(101.0, 100.5)).verdict(),
            Verdict::StepBack("rose")
        );
    }
}
