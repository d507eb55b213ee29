//! The elastic solve's descent: the shear phase, then elastic phases that
//! go on from the state the one before accepted last, each watching the
//! potential its force descends (docs/METHOD.md, "Elastic model", *The
//! energy watch*).

use std::time::Instant;

use crate::stage2::acceleration::{Chebyshev, StoppingRule};
use crate::stage2::batches::run_batched_from;
use crate::stage2::device::{Iteration, SolveDevice};
use crate::stage2::params::{DeformParams, ElasticSolve, ForceModel};
use crate::stage2::phase::{
    ENERGY_WATCH, FIRST_BATCH, MAX_BACKTRACKS, Next, PhaseRun, SHEAR_CHECK, SHEAR_TOLERANCE,
    SolveBatches, Steps, Verdict, WATCH_SETTLED, Watched,
};
use crate::stage2::report::{DeformReport, StopReason};
use crate::stage2::tracker::Tracker;

impl<D: SolveDevice> Tracker<D> {
    /// The elastic force's two phases: the shear phase, then the elastic
    /// one. An elastic phase that stops short of the tolerance (stalled, or
    /// out of steps back) leaves the state it accepted last, and the solve
    /// goes on from there as [`Next`] says: its correction linearised again
    /// there (the stall is the iteration taken away from the state its
    /// correction was made for: under a deep probe the particles it
    /// compresses stiffen, and the steps settle at a size that no longer
    /// falls; docs/METHOD.md, "Elastic model", *The energy watch*), with
    /// the fraction of its step the phase ended with; past
    /// [`crate::stage2::phase::MAX_RELINEARISATIONS`], without the
    /// correction. Nothing is run again from an earlier state: every state
    /// the elastic phases accept has a potential at most that of the one
    /// before. Both phases together take at most `budget` iterations: a
    /// shear phase that takes them all ends the solve, not converged.
    pub(super) fn shear_then_elastic(
        &mut self,
        params: &DeformParams,
        budget: usize,
        steps: &mut Steps<'_>,
    ) -> Result<DeformReport, D::Error> {
        let shear = DeformParams {
            tolerance: params.tolerance * SHEAR_TOLERANCE,
            ..params.shear()
        };
        let (first, _) = self.phase(
            &shear,
            budget,
            PhaseRun {
                volume_check: self.device.volume_smoother(),
                ..PhaseRun::corrected(false)
            },
            steps,
        )?;
        if first.stopped_by.failed() {
            return Ok(first);
        }
        if first.iterations >= budget {
            // The elastic phase has no iteration left: the solve stops at
            // the cap, whatever the shear phase's own rule said.
            return Ok(DeformReport {
                converged: false,
                stopped_by: StopReason::IterationCap,
                ..first
            });
        }
        if params.tuning.elastic_solve == ElasticSolve::ConjugateGradient
            && let Some(mut second) =
                self.conjugate_phase(params, budget - first.iterations, steps)?
        {
            second.iterations += first.iterations;
            second.residual_history.splice(0..0, first.residual_history);
            self.elastic_correct = true;
            return Ok(second);
        }
        let (mut used, mut history) = (first.iterations, first.residual_history);
        let (mut potentials, mut backtracks) = (Vec::new(), 0);
        let mut turn = self.turns_to_conjugate(params);
        let mut run = PhaseRun {
            turn,
            ..PhaseRun::corrected(true)
        };
        let (mut relinearised, mut went_on) = (0, 0);
        loop {
            let left = budget.saturating_sub(used);
            let (mut second, damping) = self.phase(params, left, run, steps)?;
            let corrected = run.correct && self.device.elastic_rho().is_some();
            let smoothed = corrected && self.device.elastic_smoothed();
            used += second.iterations;
            history.append(&mut second.residual_history);
            // The phases go on from one another: one descent.
            potentials.extend(second.potentials.concat());
            backtracks += second.backtracks;
            let failed = matches!(
                second.stopped_by,
                StopReason::Diverged | StopReason::Stalled
            );
            if turn && smoothed && failed && used < budget {
                let before = DeformReport {
                    iterations: used,
                    residual_history: std::mem::take(&mut history),
                    potentials: vec![std::mem::take(&mut potentials)],
                    backtracks,
                    elastic_retries: went_on,
                    ..second.clone()
                };
                match self.turn_to_conjugate(params, budget, before, steps)? {
                    Ok(turned) => return Ok(turned),
                    Err(before) => {
                        // The device cannot descend by it: Chebyshev's
                        // phases go on as they do without it.
                        history = before.residual_history;
                        potentials = before.potentials.concat();
                        turn = false;
                    }
                }
            }
            let next = Next::after(
                second.stopped_by,
                corrected,
                smoothed,
                relinearised,
                used < budget,
            );
            let how = match second.stopped_by {
                StopReason::Stalled => "stalled",
                _ => "ran out of steps back",
            };
            match next {
                Next::End => {
                    second.iterations = used;
                    second.residual_history = history;
                    second.potentials = if potentials.is_empty() {
                        Vec::new()
                    } else {
                        vec![potentials]
                    };
                    second.backtracks = backtracks;
                    second.elastic_retries = went_on;
                    self.elastic_correct = run.correct;
                    return Ok(second);
                }
                Next::Relinearise => {
                    relinearised += 1;
                    run = PhaseRun {
                        damping,
                        ..PhaseRun::corrected(true)
                    };
                    log::info!(
                        "the elastic phase {how} after {} iterations with its two-level solve; \
                         linearising it again where it accepted last",
                        second.iterations
                    );
                }
                Next::Uncorrected => {
                    run = PhaseRun {
                        correct: false,
                        ..PhaseRun::corrected(true)
                    };
                    log::info!(
                        "the elastic phase {how} after {} iterations with its two-level solve; \
                         going on without it from where it accepted last",
                        second.iterations
                    );
                }
            }
            went_on += 1;
        }
    }

    /// Whether `params`' watched Chebyshev phases turn to the conjugate
    /// gradient where their potential first rises or they stall
    /// ([`ElasticSolve::ChebyshevThenConjugateGradient`]): not where the
    /// skin is paired with an observation, whose potential changes with the
    /// pairing (paired with the nearest points of the sag's surface
    /// subdivided, at 3,000 particles, the conjugate gradient circled to
    /// the cap where Chebyshev's phases converge).
    pub(super) fn turns_to_conjugate(&self, params: &DeformParams) -> bool {
        params.tuning.elastic_solve == ElasticSolve::ChebyshevThenConjugateGradient
            && self.plan.pairing.is_none()
    }

    /// Where a Chebyshev phase run with [`PhaseRun::turn`] first rose,
    /// diverged or stalled (`before`: every phase so far, ended at the
    /// state it accepted last), the conjugate-gradient phase goes on from
    /// there within what is left of `budget`: the whole descent's report,
    /// the turn counted as a step back. `Err(before)` where the device
    /// cannot descend by the conjugate gradient (nothing was run).
    pub(super) fn turn_to_conjugate(
        &mut self,
        params: &DeformParams,
        budget: usize,
        before: DeformReport,
        steps: &mut Steps<'_>,
    ) -> Result<Result<DeformReport, DeformReport>, D::Error> {
        log::debug!(
            "the elastic phase {} ({} iterations into the solve); the conjugate gradient goes on \
             from the state it accepted last",
            if before.stopped_by == StopReason::Stalled {
                "stalled"
            } else {
                "rose"
            },
            before.iterations
        );
        let left = budget.saturating_sub(before.iterations);
        let Some(mut third) = self.conjugate_phase(params, left, steps)? else {
            return Ok(Err(before));
        };
        // The state accepted last: its potential is the conjugate
        // gradient's first.
        let mut potentials = before.potentials.concat();
        potentials.extend(third.potentials.concat().into_iter().skip(1));
        let mut history = before.residual_history;
        history.append(&mut third.residual_history);
        self.elastic_correct = true;
        Ok(Ok(DeformReport {
            iterations: before.iterations + third.iterations,
            residual_history: history,
            potentials: vec![potentials],
            // Back to the state Chebyshev's phase accepted last.
            backtracks: before.backtracks + 1 + third.backtracks,
            elastic_retries: before.elastic_retries + third.elastic_retries,
            ..third
        }))
    }

    /// One phase of a solve: `p`'s force from the current state until its
    /// stopping rule holds or `cap` iterations; `correct` and `relinearise`
    /// as in [`Iteration`]; every iteration told to `steps`.
    ///
    /// An elastic phase (but a tracking frame's warm one) watches the
    /// potential its force descends ([`SolveDevice::potential`]) every
    /// [`ENERGY_WATCH`] iterations and where it stalls: a state where it
    /// did not rise (within [`crate::stage2::report::ENERGY_ROUNDING`]) is
    /// kept ([`SolveDevice::save`]); where it rose, or the iteration
    /// diverged, the phase goes back to the state it kept
    /// ([`SolveDevice::restore`]) and on from there, Chebyshev started
    /// again. A smoothed phase goes on with half its smoothed step, an
    /// uncorrected one with half its plain step, up to [`MAX_BACKTRACKS`]
    /// times; a plain corrected one (where the smoother does not reach) with
    /// its correction linearised there, once from each state it kept. After
    /// those the phase ends there, diverged; a watched phase that stalls
    /// ends at the state it kept last (docs/METHOD.md, "Elastic model",
    /// *The energy watch*). Also returns the fraction of the smoothed step
    /// the phase ended with.
    pub(super) fn phase(
        &mut self,
        p: &DeformParams,
        cap: usize,
        run: PhaseRun,
        steps: &mut Steps<'_>,
    ) -> Result<(DeformReport, f32), D::Error> {
        let started = Instant::now();
        // An uncorrected elastic phase halves its step on a step back.
        let mut p = p.clone();
        let p = &mut p;
        let mut damping = run.damping;
        self.device
            .begin(self.iteration(p, run.correct, run.relinearise, damping))?;
        let begun = started.elapsed().as_secs_f64();
        let smoothed = p.force == ForceModel::Elastic && self.device.elastic_smoothed();
        let mut rho = self.phase_rho(p, damping, smoothed);
        let mut rule = self.phase_rule(p, rho, smoothed);
        let mut stopped_by = StopReason::IterationCap;
        let batch = self.device.batch();
        // A corrected elastic phase that steps plainly (where the volume
        // smoother does not reach), and one without the device's correction.
        let elastic = p.force == ForceModel::Elastic;
        let corrected = elastic && run.correct && self.device.elastic_rho().is_some();
        let plain = corrected && !smoothed;
        // The state the phase last accepted, where it watches the potential.
        let mut accepted = if elastic && run.watch {
            self.device.potential()?
        } else {
            None
        };
        if accepted.is_some() {
            self.device.save()?;
        }
        let mut potentials: Vec<f64> = accepted.iter().map(|a| a.value).collect();
        let (mut backtracks, mut earlier) = (0, Vec::new());
        // Whether the plain phase went back to the state it accepted last.
        let mut back_there = false;
        // The stopping rule's error estimate where the phase last accepted
        // (none since its last step back).
        let mut accepted_error: Option<f32> = None;
        // Where Chebyshev's weights started: the phase's start, or its last
        // step back.
        let mut restart = 0;
        // Where the shear phase next measures the volumes' misfit.
        let share = p.tuning.shear_volume_share;
        let mut check = (run.volume_check && share > 0.0 && self.connections.is_some())
            .then_some(p.tolerance * SHEAR_CHECK);
        let mut iterations = 0;
        loop {
            let limit = match accepted {
                Some(_) => ENERGY_WATCH.min(cap - iterations),
                None => cap - iterations,
            };
            // After a pause, Chebyshev goes on where it was.
            let mut batches = SolveBatches {
                device: &mut self.device,
                chebyshev: Chebyshev::with_rho(p, rho).advanced(iterations - restart),
                done: iterations - restart,
            };
            let mut paused = false;
            // Unwatched, a phase may stop after a few iterations: its
            // first batch is short (not an elastic solve's shear phase,
            // which runs on to the volumes' misfit).
            let first = if accepted.is_none() && !run.volume_check && iterations == 0 {
                FIRST_BATCH
            } else {
                batch
            };
            let (ran, held) =
                run_batched_from(&mut batches, limit, first, batch, |_, &(step, rms)| {
                    let reason = rule.after(step, rms);
                    if let Some(reason) = reason {
                        stopped_by = reason;
                    }
                    let error = rule.last_error().unwrap_or(f32::NAN);
                    steps.told(error);
                    paused = reason.is_none() && check.is_some_and(|at| error < at);
                    Ok(reason.is_some() || paused)
                })?;
            iterations += ran;
            let ended = held && !paused;
            if let Some(last) = accepted
                && ran > 0
                && (!ended || stopped_by.failed())
            {
                let now = match stopped_by {
                    StopReason::Diverged => None,
                    _ => self.device.potential()?,
                };
                let error_now = rule.last_error();
                // A stall ends the phase at the state it kept last: a new
                // linearisation, not a shorter step, is what it lacks.
                let stalled = stopped_by == StopReason::Stalled;
                let steps_back = if run.turn && smoothed {
                    0
                } else {
                    MAX_BACKTRACKS
                };
                let may_step_back = backtracks < steps_back
                    && iterations < cap
                    && (!plain || !back_there)
                    && !stalled;
                let verdict = Watched {
                    last,
                    now,
                    accepted_error,
                    error_now,
                    smoothed,
                    settling: error_now.is_some_and(|e| e < WATCH_SETTLED * p.tolerance),
                    may_step_back,
                }
                .verdict();
                log::trace!(
                    "the energy watch after {iterations} iterations (step {damping}): the \
                     potential {:.6} kept, now {:?} (paired here, under the kept pairing), the \
                     error estimate {accepted_error:?} kept, now {error_now:?}: {verdict:?}",
                    last.value,
                    now.map(|n| (n.value, n.held))
                );
                if let Verdict::Keep(now) = verdict {
                    self.device.save()?;
                    potentials.push(now.value);
                    accepted = Some(now);
                    accepted_error = error_now;
                    back_there = false;
                } else if let Verdict::StepBack(why) = verdict {
                    backtracks += 1;
                    self.device.restore()?;
                    back_there = true;
                    // The next rule's estimates, on another contraction,
                    // are not this one's.
                    accepted_error = None;
                    if smoothed {
                        damping *= 0.5;
                    } else if !plain {
                        p.tuning.step_fraction *= 0.5;
                    }
                    log::debug!(
                        "the elastic phase's potential {why} after {iterations} iterations; back \
                         to the state it accepted {}",
                        if plain {
                            "with its correction made there"
                        } else {
                            "with half its step"
                        }
                    );
                    self.device
                        .begin(self.iteration(p, run.correct, plain, damping))?;
                    rho = self.phase_rho(p, damping, smoothed);
                    earlier.extend_from_slice(rule.history());
                    rule = self.phase_rule(p, rho, smoothed);
                    restart = iterations;
                    stopped_by = StopReason::IterationCap;
                    continue;
                } else {
                    // Out of steps back, or stalled above the state it
                    // kept last (or settling, passing over a rise).
                    if verdict == Verdict::Diverged || stalled {
                        self.device.restore()?;
                    }
                    if verdict == Verdict::Diverged && !stalled {
                        stopped_by = StopReason::Diverged;
                        break;
                    }
                }
            }
            if ended || iterations >= cap {
                break;
            }
            if !paused {
                // The watch's interval ended.
                continue;
            }
            let error = rule.last_error().unwrap_or(f32::NAN);
            let misfit = self.volume_misfit()?;
            let at = share * misfit;
            log::trace!(
                "the shear phase after {iterations} iterations: error {error:.1e}, the volumes' \
                 misfit {misfit:.1e}"
            );
            if error < at {
                log::debug!(
                    "the shear phase stops at an error of {error:.1e} of the size: below \
                     {share} of the volumes' misfit {misfit:.1e}, which the elastic phase moves"
                );
                stopped_by = StopReason::Tolerance;
                break;
            }
            check = Some(at);
        }
        let seconds = started.elapsed().as_secs_f64();
        log::debug!(
            "{:?} phase: begun in {begun:.4} s, {iterations} iterations in {:.4} s, {stopped_by:?}",
            p.force,
            seconds - begun
        );
        let mut report = rule.report(iterations, stopped_by, seconds);
        report.residual_history.splice(0..0, earlier);
        report.backtracks = backtracks;
        if !potentials.is_empty() {
            report.potentials = vec![potentials];
        }
        Ok((report, damping))
    }

    /// What a phase's iterations run with: `p`'s step and force, corrected
    /// where `correct`, the smoothed step scaled by `damping`.
    pub(super) fn iteration(
        &self,
        p: &DeformParams,
        correct: bool,
        relinearise: bool,
        damping: f32,
    ) -> Iteration {
        Iteration {
            force: p.force,
            rotations: p.tuning.rotations,
            alpha: self.plan.alpha(p),
            contraction: self.plan.contraction(p),
            correct,
            relinearise,
            damping,
        }
    }

    /// The contraction a phase of `p` runs on (asked after its
    /// [`SolveDevice::begin`]).
    fn phase_rho(&self, p: &DeformParams, damping: f32, smoothed: bool) -> f32 {
        match (p.force, self.device.elastic_rho()) {
            // A damped step contracts the error by `1 - d (1 - lambda)`
            // where the full one does by `lambda`.
            (ForceModel::Elastic, Some(rho)) if smoothed => 1.0 - damping * (1.0 - rho),
            (ForceModel::Elastic, Some(rho)) => rho,
            _ => self.plan.solve_rho(p, self.device.coarse_rho()),
        }
    }

    /// The stopping rule of a phase of `p` on contraction `rho`: the
    /// accelerated one (with its stall window) for a smoothed phase over a
    /// whole observed skin, where the smoother's contraction at rest holds.
    /// Over a free skin the smoother's slowest modes (a column bending
    /// under its weight) lie below that estimate, and the accelerated rule
    /// calls a phase that is still converging there stalled; stopped by
    /// the plain rule the test column converges with no retry
    /// (docs/METHOD.md, "The volume smoother").
    fn phase_rule(&self, p: &DeformParams, rho: f32, smoothed: bool) -> StoppingRule {
        if smoothed && !self.free_skin {
            StoppingRule::accelerated(&self.plan, p, rho)
        } else {
            StoppingRule::with_rho(&self.plan, p, rho)
        }
    }

    /// The volumes' misfit at the device's state
    /// ([`crate::model::elastic::Elastic::volume_misfit`]); zero without the
    /// elastic model.
    fn volume_misfit(&mut self) -> Result<f32, D::Error> {
        let (Some(elastic), Some(connections)) = (self.plan.elastic.clone(), &self.connections)
        else {
            return Ok(0.0);
        };
        let positions = self.device.read_positions()?;
        Ok(elastic.volume_misfit(&self.rest, &positions, connections))
    }
}
