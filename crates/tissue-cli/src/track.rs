//! `tissue track`: a sequence of deformed surfaces, each solve starting from
//! the previous solution (warm start), one output folder per frame.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;
use tissue::deformation::DeformParams;

use crate::backend::{self, BackendArgs};
use crate::carry::{Carried, CarryArgs, StructureReport};
use crate::frames::expand;
use crate::output::{
    Destination, REPORT_FILE, Status, Unfinished, convergence, planned_outputs, refuse_overwriting,
    write_json, write_solution,
};
use crate::solve::{Frames, SolveArgs, load_deformed, load_model};

/// The summary of a tracking run.
pub const TRACK_FILE: &str = "track.json";

/// Options of `tissue track`.
#[derive(Debug, clap::Args)]
pub struct TrackArgs {
    /// The particle model (.vtp from `tissue sample`).
    #[arg(long)]
    pub model: PathBuf,
    /// The deformed surfaces, as a pattern (quote it: 'frames/*.obj'); solved
    /// in name order, numbers compared as numbers.
    #[arg(long)]
    pub frames: String,
    #[command(flatten)]
    pub carry: CarryArgs,
    /// Folder for the results: `frame-0001/`, ... and `track.json`.
    #[arg(long, short = 'o')]
    pub output_dir: PathBuf,
    #[command(flatten)]
    pub solve: SolveArgs,
    /// Start each frame from the fit of its surface move by this many of the
    /// last frames' changes (0: by the affine part of the move alone).
    #[arg(long, default_value_t = DeformParams::default().history)]
    pub history: usize,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Print nothing but errors.
    #[arg(long, short)]
    pub quiet: bool,
}

/// One frame in `track.json`.
#[derive(Debug, Serialize)]
struct FrameReport {
    /// The deformed surface.
    frame: String,
    /// Its output folder.
    folder: String,
    iterations: usize,
    seconds: f64,
    converged: bool,
    residual: f32,
    structures: Vec<StructureReport>,
}

/// Totals over all frames.
#[derive(Debug, Serialize)]
struct Totals {
    frames: usize,
    iterations: usize,
    /// Seconds in the solves.
    solve_seconds: f64,
    /// Seconds of the whole run: loading, solving and writing.
    seconds: f64,
    /// Whether every frame converged.
    converged: bool,
    /// `converged` when every frame did, else `not_converged` (the exit code's meaning).
    status: Status,
}

/// `track.json`.
#[derive(Debug, Serialize)]
struct TrackReport {
    model: String,
    /// Where stage 2 ran: `cpu`, or the GPU adapter's name and graphics backend.
    backend: String,
    frames: Vec<FrameReport>,
    totals: Totals,
}

/// Removes what an earlier `track` into `dir` left that this run of
/// `frames` frames would not replace: its `track.json` (rewritten only at
/// the end, so a cut-off run must not leave the old summary beside the new
/// frames) and its frame folders past this run's last (`frame-NNNN` holding
/// a `report.json`: nothing else is touched).
fn remove_stale(dir: &Path, frames: usize) -> Result<()> {
    let summary = dir.join(TRACK_FILE);
    if summary.exists() {
        std::fs::remove_file(&summary)
            .with_context(|| format!("removing the earlier {}", summary.display()))?;
    }
    let entries = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(number) = name
            .to_str()
            .and_then(|n| n.strip_prefix("frame-"))
            .filter(|n| n.len() == 4)
            .and_then(|n| n.parse::<usize>().ok())
        else {
            continue;
        };
        let folder = entry.path();
        if number > frames && folder.join(REPORT_FILE).is_file() {
            log::info!("removing {}, left by an earlier run", folder.display());
            std::fs::remove_dir_all(&folder)
                .with_context(|| format!("removing the earlier {}", folder.display()))?;
        }
    }
    Ok(())
}

/// `tissue track`.
pub fn track(args: &TrackArgs) -> Result<()> {
    let started = Instant::now();
    let params = DeformParams {
        history: args.history,
        ..args.solve.params(Frames::Sequence)?
    };
    params.validate()?;
    let frames = expand(&args.frames)?;
    let device = backend::pick(args.backend.backend, args.quiet)?;
    let (model, mut solver) = load_model(&args.model, params.clone(), device)?;
    let carried = Carried::load(&args.carry, &solver, &model)?;
    let model_name = args.model.display().to_string();
    // Every frame's files and the summary, against every input, before any work.
    let mut inputs: Vec<(&str, &Path)> = vec![("model", args.model.as_path())];
    inputs.extend(frames.iter().map(|f| ("frame", f.as_path())));
    inputs.extend(args.carry.inputs());
    let mut outputs = vec![args.output_dir.join(TRACK_FILE)];
    for k in 0..frames.len() {
        let dir = args.output_dir.join(format!("frame-{:04}", k + 1));
        let destination = Destination {
            dir: &dir,
            report: None,
            model: &model_name,
            surface: "",
        };
        outputs.extend(planned_outputs(&destination, &carried));
    }
    refuse_overwriting(&outputs, &inputs)?;
    std::fs::create_dir_all(&args.output_dir)
        .with_context(|| format!("creating {}", args.output_dir.display()))?;
    remove_stale(&args.output_dir, frames.len())?;
    let mut reports = Vec::new();
    for (k, frame) in frames.iter().enumerate() {
        let deformed = load_deformed(frame, &mut solver, &model.surface)?;
        let solve = solver.solve()?;
        let dir = args.output_dir.join(format!("frame-{:04}", k + 1));
        let surface = frame.display().to_string();
        let destination = Destination {
            dir: &dir,
            report: None,
            model: &model_name,
            surface: &surface,
        };
        let report = write_solution(
            destination,
            &model,
            &solver,
            &deformed,
            &carried,
            &params,
            solve,
        )?;
        if !args.quiet {
            let moved: Vec<String> = report
                .structures
                .iter()
                .map(|s| format!("{} moved {:.2} mm", s.name, s.displacement_mm))
                .collect();
            let mut line = format!(
                "frame {}/{} {}: {} iterations, {:.1} ms, {}",
                k + 1,
                frames.len(),
                surface,
                report.iterations,
                1e3 * report.seconds,
                convergence(report.stopped_by, report.residual)
            );
            if !moved.is_empty() {
                line = format!("{line}; {}", moved.join(", "));
            }
            println!("{line}");
        }
        reports.push(FrameReport {
            frame: surface,
            folder: dir.display().to_string(),
            iterations: report.iterations,
            seconds: report.seconds,
            converged: report.converged,
            residual: report.residual,
            structures: report.structures,
        });
    }
    let totals = Totals {
        frames: reports.len(),
        iterations: reports.iter().map(|f| f.iterations).sum(),
        solve_seconds: reports.iter().map(|f| f.seconds).sum(),
        seconds: started.elapsed().as_secs_f64(),
        converged: reports.iter().all(|f| f.converged),
        status: if !reports.iter().all(|f| f.converged) {
            Status::NotConverged
        } else if carried.flagged() {
            Status::Flagged
        } else {
            Status::Converged
        },
    };
    let path = args.output_dir.join(TRACK_FILE);
    let summary = format!(
        "tracked {} frames: {} iterations, {:.3} s solving, {:.3} s in all, {}",
        totals.frames,
        totals.iterations,
        totals.solve_seconds,
        totals.seconds,
        if totals.converged {
            "all converged"
        } else {
            "NOT all converged: raise --max-iterations"
        }
    );
    let count = totals.frames;
    let status = totals.status;
    let unconverged = reports.iter().filter(|f| !f.converged).count();
    write_json(
        &path,
        &TrackReport {
            model: model_name,
            backend: solver.backend(),
            frames: reports,
            totals,
        },
    )?;
    if !args.quiet {
        println!("{summary}");
        println!(
            "  wrote {} (frame-0001 .. frame-{count:04}) and {}",
            args.output_dir.display(),
            path.display()
        );
    }
    let message = match status {
        Status::Converged => return Ok(()),
        Status::Flagged => format!(
            "points or structures lie outside the model's rest surface ({}): \
             they are carried by extrapolation",
            path.display()
        ),
        _ => format!(
            "{unconverged} of {count} frames did NOT converge ({}): raise --max-iterations",
            path.display()
        ),
    };
    Err(Unfinished { status, message }.into())
}
