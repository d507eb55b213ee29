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
/// at its end. `work` may say what it is doing through its [`Busy`]: the
/// spinner then reads `what: detail`.
pub fn busy<T>(quiet: bool, what: &str, work: impl FnOnce(&Busy) -> T) -> T {
    busy_told(quiet, what, work).0
}

/// What a [`busy`] work tells its spinner.
pub struct Busy {
    tell: Option<mpsc::Sender<Option<String>>>,
}

impl Busy {
    /// The spinner's line becomes `what: detail`.
    pub fn say(&self, detail: impl std::fmt::Display) {
        if let Some(tell) = &self.tell {
            // The spinner's thread outlives the work; a failed send is a
            // spinner already gone with it.
            let _sent = tell.send(Some(detail.to_string()));
        }
    }
}

/// [`busy`], and the spinner's last line (`what`, or `what: detail`).
fn busy_told<T>(quiet: bool, what: &str, work: impl FnOnce(&Busy) -> T) -> (T, String) {
    if quiet {
        return (work(&Busy { tell: None }), what.to_owned());
    }
    let (tell, told) = mpsc::channel::<Option<String>>();
    let line = |detail: Option<&str>| match detail {
        Some(detail) => format!("{what}: {detail}"),
        None => what.to_owned(),
    };
    std::thread::scope(|scope| {
        let spinner = scope.spawn(move || {
            let deadline = Instant::now() + SHOW_AFTER;
            let mut message = line(None);
            // Until the spinner is due: only the line changes.
            loop {
                match told.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                    Ok(Some(detail)) => message = line(Some(&detail)),
                    Ok(None) | Err(mpsc::RecvTimeoutError::Disconnected) => return message,
                    Err(mpsc::RecvTimeoutError::Timeout) => break,
                }
            }
            let spinner = bar("{spinner} {msg} ({elapsed})", None);
            spinner.set_message(message.clone());
            spinner.enable_steady_tick(Duration::from_millis(120));
            // Until `work` ends (its end, or the sender dropped by a panic).
            while let Ok(Some(detail)) = told.recv() {
                message = line(Some(&detail));
                spinner.set_message(message.clone());
            }
            spinner.finish_and_clear();
            message
        });
        let busy = Busy {
            tell: Some(tell.clone()),
        };
        let out = work(&busy);
        // The receiver may have gone (it never waits past the end).
        let _sent = tell.send(None);
        let message = spinner.join().unwrap_or_else(|_| line(None));
        (out, message)
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
        assert_eq!(busy(true, "quiet", |_| 1), 1);
        assert_eq!(busy(false, "quick", |_| 2), 2);
        let slow = busy(false, "slow", |_| {
            std::thread::sleep(SHOW_AFTER + Duration::from_millis(200));
            3
        });
        assert_eq!(slow, 3);
    }

    /// What the work says reaches the spinner's line, before the spinner
    /// is drawn and after.
    #[test]
    fn the_spinner_reads_what_the_work_says() {
        let (out, line) = busy_told(false, "preparing", |busy| {
            busy.say("the plan");
            4
        });
        assert_eq!((out, line.as_str()), (4, "preparing: the plan"));
        let (_, line) = busy_told(false, "preparing", |busy| {
            busy.say("the plan");
            std::thread::sleep(SHOW_AFTER + Duration::from_millis(200));
            busy.say("the coarse space");
        });
        assert_eq!(line, "preparing: the coarse space");
        let (_, line) = busy_told(false, "preparing", |_| ());
        assert_eq!(line, "preparing");
        let (_, line) = busy_told(true, "preparing", |busy| busy.say("unseen"));
        assert_eq!(line, "preparing");
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
