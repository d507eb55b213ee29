//! How a solve ended: its status and exit code, and the words for it.

use glam::Vec3;
use serde::Serialize;
use tissue::deformation::StopReason;

/// How a solve ended, as `report.json` and `track.json` say and the exit
/// code tells a script: 0 converged, 2 not converged, 3 diverged, 4
/// converged but flagged, 130 a `track` stopped by Ctrl-C before its last
/// frame (1 is any other error: a refused input, a file that cannot be read
/// or written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The stopping rule held.
    Converged,
    /// The iteration cap came first, the iteration stalled, or it stopped
    /// at the float floor with an error estimate above
    /// [`tissue::deformation::FLOAT_FLOOR_ERROR`]: the result is written
    /// but not final.
    NotConverged,
    /// The state became non-finite: nothing is written.
    Diverged,
    /// The solve converged, but points or structures lie outside the
    /// organ (`outside` in the report) or particles are inverted
    /// (`inverted`): the results are written and flagged.
    Flagged,
    /// `track.json` of a run with frames still to solve: written after
    /// every frame but the last, and left so by a run that was stopped
    /// (Ctrl-C, or killed); `tissue track --resume` continues it.
    Incomplete,
}

impl Status {
    /// The status of a solve that stopped by `stopped_by`.
    pub fn of(converged: bool, stopped_by: StopReason) -> Self {
        match (converged, stopped_by) {
            (_, StopReason::Diverged) => Self::Diverged,
            (true, _) => Self::Converged,
            (false, _) => Self::NotConverged,
        }
    }

    /// The process's exit code for this status.
    pub fn exit_code(self) -> u8 {
        match self {
            Self::Converged => 0,
            Self::NotConverged => 2,
            Self::Diverged => 3,
            Self::Flagged => 4,
            Self::Incomplete => 130,
        }
    }
}

/// A run that finished its work but whose solve did not converge or
/// diverged: `main` prints it and exits with [`Status::exit_code`].
#[derive(Debug)]
pub struct Unfinished {
    /// How the solve ended.
    pub status: Status,
    /// What happened and where the results (if any) are.
    pub message: String,
}

impl std::fmt::Display for Unfinished {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Unfinished {}

/// Why a solve's results are not written, where it diverged: its state
/// turned non-finite, or it stopped by [`StopReason::Diverged`] (its energy
/// rose with no smaller step left; the state it kept is finite but not an
/// answer). `None` for any other end.
pub fn diverged(current: &[Vec3], iterations: usize, stopped_by: StopReason) -> Option<Unfinished> {
    let message = if let Some(i) = current.iter().position(|p| !p.is_finite()) {
        format!(
            "the solve diverged: particle {i} is at {} after {iterations} iterations; nothing was \
             written (try --force symmetric)",
            current[i]
        )
    } else if stopped_by == StopReason::Diverged {
        format!(
            "the solve diverged after {iterations} iterations: its energy rose and no smaller step \
             was left; nothing was written (try --force symmetric)"
        )
    } else {
        return None;
    };
    Some(Unfinished {
        status: Status::Diverged,
        message,
    })
}

/// What a user can do about a solve that stopped by `stopped_by` short
/// of converging: more iterations help only where the cap stopped it.
pub fn remedy(stopped_by: StopReason) -> &'static str {
    match stopped_by {
        StopReason::IterationCap => "raise --max-iterations",
        StopReason::Tolerance
        | StopReason::FloatPrecision
        | StopReason::Diverged
        | StopReason::Stalled => {
            "more iterations will not help: the iteration stopped short of the answer (the \
             input may ask what the tissue cannot do)"
        }
    }
}

/// `converged`, or how far and why not, of a solve that stopped by
/// `stopped_by` with the error estimate `residual`, `converged` or not.
pub fn convergence(converged: bool, stopped_by: StopReason, residual: f32) -> String {
    match stopped_by {
        StopReason::Tolerance => "converged".into(),
        StopReason::FloatPrecision if converged => format!(
            "converged to single precision (error estimate {residual:.1e} of the size, above --tolerance)"
        ),
        StopReason::FloatPrecision => format!(
            "NOT converged (error estimate {residual:.1e} of the size): it stopped at single \
             precision short of the answer"
        ),
        StopReason::IterationCap => format!(
            "NOT converged (error estimate {residual:.1e} of the size): raise --max-iterations"
        ),
        StopReason::Diverged => {
            "DIVERGED: the state became non-finite, or its energy rose with no smaller step left"
                .into()
        }
        StopReason::Stalled => format!(
            "NOT converged (error estimate {residual:.1e} of the size): the iteration stalled"
        ),
    }
}

#[cfg(test)]
mod status_tests {
    use super::*;

    #[test]
    fn each_way_a_solve_ends_has_its_status_and_exit_code() {
        let cases = [
            (true, StopReason::Tolerance, Status::Converged, 0),
            (true, StopReason::FloatPrecision, Status::Converged, 0),
            (false, StopReason::FloatPrecision, Status::NotConverged, 2),
            (false, StopReason::IterationCap, Status::NotConverged, 2),
            (false, StopReason::Diverged, Status::Diverged, 3),
            (false, StopReason::Stalled, Status::NotConverged, 2),
        ];
        for (converged, stopped_by, status, code) in cases {
            let more = remedy(stopped_by).contains("--max-iterations");
            assert_eq!(
                more,
                stopped_by == StopReason::IterationCap,
                "{stopped_by:?}"
            );
            assert_eq!(Status::of(converged, stopped_by), status);
            assert_eq!(status.exit_code(), code);
        }
        assert_eq!(
            serde_json::to_value(Status::NotConverged).ok(),
            Some(serde_json::json!("not_converged"))
        );
    }

    /// A stop at the float floor reads converged where the solve
    /// converged there and NOT converged where it stopped short, its
    /// estimate given either way.
    #[test]
    fn a_float_floor_short_of_the_answer_reads_not_converged() {
        let near = convergence(true, StopReason::FloatPrecision, 4e-4);
        assert!(near.starts_with("converged to single precision"), "{near}");
        let far = convergence(false, StopReason::FloatPrecision, 0.48);
        assert!(
            far.starts_with("NOT converged (error estimate 4.8e-1"),
            "{far}"
        );
    }

    /// A diverged solve writes nothing, whether its state turned
    /// non-finite or it kept a finite state when its energy rose with no
    /// step back left; every other end writes its results.
    #[test]
    fn a_diverged_solve_is_not_written_even_with_a_finite_state() {
        let finite = [Vec3::ZERO, Vec3::ONE];
        let unfinished = diverged(&finite, 40, StopReason::Diverged);
        assert!(
            unfinished
                .as_ref()
                .is_some_and(|u| u.status == Status::Diverged
                    && u.message.contains("energy rose")
                    && u.message.contains("40 iterations")),
            "{unfinished:?}"
        );
        let blown = [Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)];
        let unfinished = diverged(&blown, 7, StopReason::Tolerance);
        assert!(
            unfinished
                .as_ref()
                .is_some_and(|u| u.status == Status::Diverged && u.message.contains("particle 1")),
            "{unfinished:?}"
        );
        for stopped_by in [
            StopReason::Tolerance,
            StopReason::FloatPrecision,
            StopReason::IterationCap,
            StopReason::Stalled,
        ] {
            assert!(
                diverged(&finite, 40, stopped_by).is_none(),
                "{stopped_by:?}"
            );
        }
    }
}
