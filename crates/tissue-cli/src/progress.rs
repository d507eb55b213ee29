//! The terminal's progress display, shared by the long commands. indicatif
//! draws on stderr only where it is a terminal; callers leave it out when
//! `--quiet`. Work that ends within [`SHOW_AFTER`] draws nothing, so fast
//! runs print as they did.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use tissue::deformation::SolveStep;

/// How long work runs before its bar or spinner appears.
pub const SHOW_AFTER: Duration = Duration::from_millis(500);

/// A bar of `length` steps, or a spinner without one, drawn by indicatif's
/// `template`.
pub fn bar(template: &str, length: Option<u64>) -> ProgressBar {
    let bar = match length {
        Some(n) => ProgressBar::new(n),
        None => ProgressBar::new_spinner(),
    };
    bar.set_style(
        ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar
}

/// Runs `work`; unless `quiet`, a spinner saying `what` (and the time
/// taken) turns while it runs longer than [`SHOW_AFTER`], and is cleared
/// at its end.
pub fn busy<T>(quiet: bool, what: &str, work: impl FnOnce() -> T) -> T {
    if quiet {
        return work();
    }
    let (done, finished) = mpsc::channel::<()>();
    let what = what.to_owned();
    std::thread::scope(|scope| {
        scope.spawn(move || {
            if !matches!(
                finished.recv_timeout(SHOW_AFTER),
                Err(mpsc::RecvTimeoutError::Timeout)
            ) {
                return;
            }
            let spinner = bar("{spinner} {msg} ({elapsed})", None);
            spinner.set_message(what);
            spinner.enable_steady_tick(Duration::from_millis(120));
            // Until `work` ends (a message, or the sender dropped by a panic).
            let _ended = finished.recv();
            spinner.finish_and_clear();
        });
        let out = work();
        // The receiver may have gone (it never waits past a message).
        let _sent = done.send(());
        out
    })
}

/// A stage-2 solve's progress line: the iterations and the error
/// estimate, drawn once the solve has run [`SHOW_AFTER`].
pub struct SolveBar {
    what: String,
    quiet: bool,
    started: Instant,
    bar: Option<ProgressBar>,
}

impl SolveBar {
    /// A bar for the solve named `what` ("solving", "frame 3/10"), silent
    /// when `quiet`.
    pub fn new(what: impl Into<String>, quiet: bool) -> Self {
        Self {
            what: what.into(),
            quiet,
            started: Instant::now(),
            bar: None,
        }
    }

    /// The solve's callback: where it is after an iteration.
    pub fn step(&mut self, step: &SolveStep) {
        if self.quiet || (self.bar.is_none() && self.started.elapsed() < SHOW_AFTER) {
            return;
        }
        let what = &self.what;
        let bar = self.bar.get_or_insert_with(|| {
            // No bar: the cap is far above the iterations a solve takes.
            let bar = bar(
                "{spinner} {prefix}: iteration {pos} ({elapsed}), {msg}",
                None,
            );
            bar.set_prefix(what.clone());
            bar
        });
        bar.set_position(step.iteration as u64);
        bar.set_message(format!("error {:.1e} of the size", step.residual));
    }

    /// Clears the bar, if one was drawn.
    pub fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The work's value comes back whether or not the spinner appeared,
    /// and the spinner's thread ends with the work (the scope joins it).
    #[test]
    fn busy_returns_the_works_value_and_ends_its_spinner() {
        assert_eq!(busy(true, "quiet", || 1), 1);
        assert_eq!(busy(false, "quick", || 2), 2);
        let slow = busy(false, "slow", || {
            std::thread::sleep(SHOW_AFTER + Duration::from_millis(200));
            3
        });
        assert_eq!(slow, 3);
    }

    /// A solve's line stays silent when quiet and for a solve faster than
    /// [`SHOW_AFTER`], and appears for a slow one.
    #[test]
    fn a_solve_bar_appears_only_for_slow_solves() {
        let step = SolveStep {
            iteration: 1,
            max_iterations: 100,
            residual: 1e-3,
        };
        let mut quiet = SolveBar::new("quiet", true);
        quiet.started -= 2 * SHOW_AFTER;
        quiet.step(&step);
        assert!(quiet.bar.is_none());
        let mut fast = SolveBar::new("fast", false);
        fast.step(&step);
        assert!(fast.bar.is_none());
        let mut slow = SolveBar::new("slow", false);
        slow.started -= 2 * SHOW_AFTER;
        slow.step(&step);
        assert!(slow.bar.as_ref().is_some_and(|b| b.position() == 1));
        slow.finish();
    }
}
