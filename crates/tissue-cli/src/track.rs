//! `tissue track`: a sequence of deformed surfaces, each solve starting from
//! the previous solution (warm start), one output folder per frame; every
//! frame checked before the first solve, the summary rewritten after every
//! frame, Ctrl-C honoured between frames, and a cut-off run resumable.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use serde_json::Value;
use tissue::SurfaceMesh;
use tissue::deformation::{DeformParams, ForceModel};
use tissue::io::space::Space;
use tissue::uncertainty::{Explorer, Priors, Refresh};

use crate::backend::{self, BackendArgs};
use crate::carry::{Carried, CarryArgs, StructureReport};
mod resume;
mod sequence;

use crate::frames::expand;
use crate::observe::{self, ObservationReport};
use crate::output::{
    Destination, Drawn, PARTICLES_FILE, Solved, Status, Unfinished, convergence, draw, file_name,
    planned_outputs, prepare_outputs, refuse_overwriting, remove_earlier_outputs, write_json,
    write_solution,
};
use crate::picture;
use crate::posture::{GravityArgs, PostureReport};
use crate::solve::{SolveArgs, Stage2, read_frame, read_model};
use crate::uncertain::{self, Answer, UncertaintyArgs};
use resume::{remove_stale, resumed};
use sequence::{Framed, Framing, Sequence, fixed_region_file};

/// The summary of a tracking run.
pub const TRACK_FILE: &str = "track.json";

/// The frames' particles as one ParaView collection (a time series).
pub const COLLECTION_FILE: &str = "track.pvd";

/// Options of `tissue track`.
#[derive(Debug, clap::Args)]
pub struct TrackArgs {
    /// The particle model (.vtp from `tissue sample`).
    #[arg(long)]
    pub model: PathBuf,
    /// The deformed surfaces, as a pattern (quote it: 'frames/*.obj'); solved
    /// in name order, numbers compared as numbers. Either each the model's
    /// rest surface with moved vertices, or each any closed surface of the
    /// organ (another segmentation's), matched without correspondence as
    /// `deform --surface` does (the held region: --fixed-region, or the rest
    /// vertices that lie on every frame).
    #[arg(long, required_unless_present = "clouds", conflicts_with = "clouds")]
    pub frames: Option<String>,
    /// Scans of part of the skin as points, as a pattern ('scans/*.ply';
    /// the formats of `deform --cloud`), each matched without
    /// correspondence; needs --fixed-region FILE.
    #[arg(long, value_name = "PATTERN")]
    pub clouds: Option<String>,
    /// The observations' noise scale, in the model's units (as `deform
    /// --noise`); only with observations without correspondence.
    #[arg(long, value_name = "MM")]
    pub noise: Option<f32>,
    /// How a surface of another triangulation is paired with the skin, in
    /// its mean edges: the plane smoothed over its vertices within this
    /// radius (default 1); 0 pairs each particle with the nearest point
    /// and the distance's curvature there (slower, its last stage ending at
    /// the float floor, but an uncertainty's re-solves of its answer are
    /// faster: docs/ACCURACY.md). Not for clouds.
    #[arg(long, value_name = "EDGES")]
    pub surface_smoothing: Option<f32>,
    /// Fiducials that put every observation in the model's frame first
    /// (as `deform --fiducials`): the same points in the model's frame,
    /// then in the observations' (one frame for the whole sequence).
    #[arg(long, num_args = 2, value_names = ["MODEL_POINTS", "OBSERVED_POINTS"])]
    pub fiducials: Option<Vec<PathBuf>>,
    #[command(flatten)]
    pub carry: CarryArgs,
    /// Folder for the results: `frame-0001/`, ... and `track.json`.
    #[arg(long, short = 'o')]
    pub output_dir: PathBuf,
    #[command(flatten)]
    pub solve: SolveArgs,
    #[command(flatten)]
    pub uncertainty: UncertaintyArgs,
    /// With --uncertainty: after the first frame, how many of the
    /// uncertainty's re-solves each frame makes anew, in turn (of 21 by
    /// default); the others are carried from the frame that made them
    /// last, their offsets put on the new answer (docs/METHOD.md,
    /// "Uncertainty", *Tracking*). `all`: every re-solve at every frame
    #[arg(long, value_name = "N|all", default_value = "2", value_parser = uncertain::parse_refresh)]
    pub uncertainty_refresh: Refresh,
    /// Start each frame from the fit of its surface move by this many of the
    /// last frames' changes (0: by the affine part of the move alone).
    #[arg(long, default_value_t = DeformParams::default().tuning.history)]
    pub history: usize,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Also draw the last frame as a PNG picture (as `deform --picture`
    /// does), beside the convergence of every frame this run solved.
    #[arg(long, value_name = "FILE.png")]
    pub picture: Option<PathBuf>,
    /// Continue a run into the same folder that was stopped before its last
    /// frame (Ctrl-C, or killed): the frames its `track.json` lists as done
    /// are kept, the first missing one starts from the rest shape. Refused
    /// unless the model, the frames, the carried files and the solve's
    /// parameters are those of that run.
    #[arg(long)]
    pub resume: bool,
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
    /// As in `report.json`: `flagged` when a check failed ([`Status`]).
    status: Status,
    /// Particles the solve turned inside out.
    inverted: usize,
    structures: Vec<StructureReport>,
    /// With observations without correspondence, how this one was matched
    /// (as in `report.json`).
    #[serde(skip_serializing_if = "Option::is_none")]
    observation: Option<ObservationReport>,
}

/// Totals over the frames done.
#[derive(Debug, Serialize)]
struct Totals {
    /// Frames solved and written.
    frames: usize,
    /// Frames the run was asked to solve.
    planned: usize,
    iterations: usize,
    /// Seconds in the solves.
    solve_seconds: f64,
    /// Seconds of this run (a resumed one's own): loading, checking,
    /// solving and writing.
    seconds: f64,
    /// Whether every frame done converged.
    converged: bool,
    /// `incomplete` until the last frame is written; then `converged` when
    /// every frame did, `not_converged` when one did not, `flagged` when
    /// carried points or structures lie outside the organ (the exit code's
    /// meaning).
    status: Status,
    /// The first frame (from 1) this run solved, when it resumed an earlier
    /// one; that frame started from the rest shape.
    #[serde(skip_serializing_if = "Option::is_none")]
    resumed_at: Option<usize>,
}

/// What a run was asked to do, kept in `track.json` so that `--resume`
/// continues only the same run.
#[derive(Debug, Serialize)]
struct Plan<'a> {
    model: &'a Path,
    frames: &'a [PathBuf],
    points: Option<&'a Path>,
    structures: &'a [PathBuf],
    rigid_structures: &'a [PathBuf],
    /// `--space`, left out when LPS (the default), so that the plans of
    /// runs made before the option compare equal.
    #[serde(skip_serializing_if = "is_lps")]
    space: Space,
    params: &'a DeformParams,
    /// The posture options, where given (a resume must give the same).
    #[serde(skip_serializing_if = "Option::is_none")]
    gravity: Option<&'a GravityArgs>,
    /// The held region of observations without correspondence given
    /// without the posture options.
    #[serde(skip_serializing_if = "Option::is_none")]
    fixed_region: Option<&'a str>,
    /// `--noise`, where given.
    #[serde(skip_serializing_if = "Option::is_none")]
    noise: Option<f32>,
    /// `--surface-smoothing`, where given.
    #[serde(skip_serializing_if = "Option::is_none")]
    surface_smoothing: Option<f32>,
    /// `--fiducials`, where given.
    #[serde(skip_serializing_if = "Option::is_none")]
    fiducials: Option<&'a [PathBuf]>,
    /// The uncertainty's priors, with `--uncertainty`.
    #[serde(skip_serializing_if = "Option::is_none")]
    uncertainty: Option<&'a Priors>,
    /// With `--uncertainty`, `--uncertainty-refresh` (`null`: all).
    #[serde(skip_serializing_if = "Option::is_none")]
    uncertainty_refresh: Option<Option<usize>>,
    /// Each input file's contents as a hash ([`input_hashes`]), by path: a
    /// resume must read the same files, not only the same names.
    inputs: BTreeMap<String, String>,
}

/// The contents of each of `paths` as a 64-bit XXH3 hash in hex, by path
/// as given.
fn input_hashes<'p>(paths: impl IntoIterator<Item = &'p Path>) -> Result<BTreeMap<String, String>> {
    paths
        .into_iter()
        .map(|path| {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            let hash = twox_hash::XxHash3_64::oneshot(&bytes);
            Ok((path.display().to_string(), format!("{hash:016x}")))
        })
        .collect()
}

fn is_lps(space: &Space) -> bool {
    *space == Space::Lps
}

/// `track.json`.
#[derive(Debug, Serialize)]
struct TrackReport<'a> {
    model: &'a str,
    /// Where stage 2 ran: `cpu`, or the GPU adapter's name and graphics backend.
    backend: String,
    /// The frames done, in order ([`FrameReport`]s; a resumed run keeps
    /// those of the run it continues as they were).
    frames: &'a [Value],
    totals: Totals,
    /// What the run was asked to do ([`Plan`]).
    plan: &'a Value,
    /// With the posture options: the postures, the stiffness and the
    /// unloaded shape, made once from the first frame (as in `report.json`).
    #[serde(flatten)]
    posture: Option<&'a PostureReport>,
}

/// Ctrl-C presses (SIGINT) and SIGTERMs so far: the first asks the run to
/// stop after the frame in hand, the second stops it at once (every file is
/// written to a temporary one and renamed, so none is left cut off). `None` when no handler could
/// be installed (another one is: the run cannot be stopped between frames).
fn interrupt_count() -> Option<Arc<AtomicUsize>> {
    let presses = Arc::new(AtomicUsize::new(0));
    let seen = Arc::clone(&presses);
    let installed = ctrlc::set_handler(move || {
        if seen.fetch_add(1, Ordering::SeqCst) == 0 {
            eprintln!("stopping after the frame in hand (Ctrl-C again to stop now)");
        } else {
            std::process::exit(i32::from(Status::Incomplete.exit_code()));
        }
    });
    match installed {
        Ok(()) => Some(presses),
        Err(e) => {
            log::warn!("Ctrl-C will stop the run at once, not between frames: {e}");
            None
        }
    }
}

/// The totals over the frames `done` (JSON [`FrameReport`]s).
fn totals(done: &[Value], planned: usize, status: Status, started: Instant) -> Totals {
    Totals {
        frames: done.len(),
        planned,
        iterations: done
            .iter()
            .filter_map(|f| f["iterations"].as_u64())
            .map(|i| i as usize)
            .sum(),
        solve_seconds: done.iter().filter_map(|f| f["seconds"].as_f64()).sum(),
        seconds: started.elapsed().as_secs_f64(),
        converged: done.iter().all(|f| f["converged"] == Value::Bool(true)),
        status,
        resumed_at: None,
    }
}

/// `tissue track`.
pub fn track(args: &TrackArgs) -> Result<()> {
    let started = Instant::now();
    let mut params = (args.solve.params()?).with(|p| {
        p.tuning.history = args.history;
    });
    params.validate()?;
    if let Some(path) = &args.picture {
        picture::check_name(path)?;
    }
    let frames = match (&args.frames, &args.clouds) {
        (Some(pattern), None) => expand("--frames", pattern)?,
        (None, Some(pattern)) => expand("--clouds", pattern)?,
        _ => bail!("give the deformed surfaces (--frames) or scans of the skin (--clouds)"),
    };
    let device = backend::pick(args.backend.backend, args.quiet)?;
    let model = read_model(&args.model, &mut params, args.solve.observed.as_deref())?;
    // Every frame read and checked before the first solve: a bad frame
    // stops the run before anything is written.
    for frame in &frames {
        crate::carry::check_space_tag(frame, args.carry.space)?;
    }
    let sequence = Sequence::read(args, &frames, &model)?;
    let priors = args.uncertainty.priors()?;
    if let Sequence::Matched {
        held, observations, ..
    } = &sequence
    {
        if !params.force.eq(&ForceModel::Elastic) {
            bail!("observations without correspondence are matched by the elastic force alone");
        }
        params.observed = Some(held.clone());
        if !args.quiet {
            println!(
                "{} {} without correspondence with the model's rest surface: each matched \
                 inside the elastic solve, {} of {} rest vertices held",
                observations.len(),
                if args.clouds.is_some() {
                    "scans"
                } else {
                    "surfaces"
                },
                held.iter().filter(|&&h| h).count(),
                held.len()
            );
        }
    }
    // The postures' unloaded shape and stiffness, once, from the first
    // frame; for an observation, from its match without gravity over the
    // skin it saw.
    let first_match = match (
        sequence.observation(0, &frames[0], &model, args.noise)?,
        args.solve.gravity.given(),
    ) {
        (Some(observation), true) => Some(
            observe::first_match(
                device.clone(),
                &model,
                &params,
                &observation,
                &observe::matching(args.noise, args.surface_smoothing),
                args.quiet,
            )
            .with_context(|| format!("{}: the match without gravity", frames[0].display()))?,
        ),
        _ => None,
    };
    let first_frame = match (&sequence, args.solve.gravity.given()) {
        (Sequence::Frames, true) => Some(read_frame(&frames[0], &model.surface)?),
        (Sequence::Matched { .. }, true) => first_match.as_ref().map(|(frame, _, _)| frame.clone()),
        _ => None,
    };
    let stage2 = Stage2 {
        path: &args.model,
        model: &model,
        deformed: first_frame.as_ref().unwrap_or(&model.surface),
        gravity: &args.solve.gravity,
        seen: first_match.as_ref().map(|(_, seen, _)| seen.as_slice()),
        quiet: args.quiet,
    };
    let (mut solver, mut posture) = stage2.solver(args.backend.backend, device, &mut params)?;
    if let (Some(posture), Some((_, _, short))) = (posture.as_mut(), &first_match) {
        posture.report.first_match_short = *short;
    }
    let posture_report = posture.as_ref().map(|p| &p.report);
    let carried = Carried::load(&args.carry, &solver, &model)?;
    let model_name = args.model.display().to_string();
    // Every frame's files and the summary, against every input, before any work.
    let mut inputs: Vec<(&str, &Path)> = vec![("model", args.model.as_path())];
    inputs.extend(frames.iter().map(|f| ("frame", f.as_path())));
    let fixed_region = fixed_region_file(args);
    inputs.extend(fixed_region.map(|p| ("fixed region", p)));
    for path in args.fiducials.iter().flatten() {
        inputs.push(("fiducials", path.as_path()));
    }
    inputs.extend(args.carry.inputs());
    let path = args.output_dir.join(TRACK_FILE);
    let mut outputs = vec![path.clone(), args.output_dir.join(COLLECTION_FILE)];
    outputs.extend(args.picture.clone());
    for k in 0..frames.len() {
        let dir = args.output_dir.join(format!("frame-{:04}", k + 1));
        let destination = Destination {
            dir: &dir,
            report: None,
            model: &model_name,
            surface: "",
            field: None,
            picture: None,
        };
        outputs.extend(planned_outputs(&destination, &carried));
    }
    refuse_overwriting(&outputs, &inputs)?;
    let plan = serde_json::from_str::<Value>(&serde_json::to_string(&Plan {
        model: &args.model,
        frames: &frames,
        points: args.carry.points.as_deref(),
        structures: &args.carry.structures,
        rigid_structures: &args.carry.rigid_structures,
        space: args.carry.space,
        params: &params,
        gravity: args.solve.gravity.given().then_some(&args.solve.gravity),
        fixed_region: (!args.solve.gravity.given())
            .then_some(args.solve.gravity.fixed_region.as_deref())
            .flatten(),
        noise: args.noise,
        surface_smoothing: args.surface_smoothing,
        fiducials: args.fiducials.as_deref(),
        uncertainty: priors.as_ref(),
        uncertainty_refresh: priors
            .as_ref()
            .map(|_| args.uncertainty_refresh.per_answer()),
        inputs: input_hashes(inputs.iter().map(|(_, path)| *path))?,
    })?)?;
    prepare_outputs(std::slice::from_ref(&path))?;
    let _lock = crate::folder::OutputLock::take(&args.output_dir)?;
    let mut done = if args.resume {
        resumed(&path, &plan, &args.output_dir, frames.len())?
    } else {
        Vec::new()
    };
    remove_stale(&args.output_dir, frames.len(), args.resume)?;
    let resumed_at = (args.resume && !done.is_empty()).then_some(done.len() + 1);
    if resumed_at.is_some() && !args.quiet {
        println!(
            "resuming at frame {} of {} (the frames before it are done; solving them again, \
             unwritten, to start where the stopped run was)",
            done.len() + 1,
            frames.len()
        );
    }
    // The solver's state at a frame (the warm start, the prediction from
    // the last frames) is what the frames before made it: solving them
    // again, as deterministic as the first time, makes the resumed run's
    // frames those of an uninterrupted run, to the bit. Their files stay.
    let framing = Framing {
        model: &model,
        frames: &frames,
        sequence: &sequence,
        first_frame: first_frame.as_ref(),
        posture: posture.as_ref(),
        noise: args.noise,
        surface_smoothing: args.surface_smoothing,
        held: std::cell::RefCell::new(None),
    };
    let unloaded = posture.as_ref().and_then(|p| p.unloaded.as_ref());
    // One explorer for the run: each frame's spread from the last one's.
    let refresh = args.uncertainty_refresh;
    let mut explorer = priors.clone().map(|p| Explorer::new(p).refreshing(refresh));
    for k in 0..done.len() {
        // With its spread, which leaves the device as the first run had it.
        let framed = framing.solve(k, &mut solver, true)?;
        let answer = Answer {
            converged: framed.solve.converged,
            deformed: &framed.deformed,
            unloaded,
            held_by: framed.held.as_ref(),
        };
        uncertain::spread_after(explorer.as_mut(), answer, &mut solver, &model, true)?;
    }
    let summary = Summary {
        path: &path,
        model: &model_name,
        plan: &plan,
        posture: posture_report,
        planned: frames.len(),
        started,
        resumed_at,
    };
    let presses = interrupt_count();
    let stop_asked = || {
        presses
            .as_ref()
            .is_some_and(|p| p.load(Ordering::SeqCst) > 0)
    };
    let first = done.len();
    let mut status = Status::Incomplete;
    // For the picture: this run's iterations, where each frame's begin,
    // and the last frame solved.
    let mut residuals: Vec<f32> = Vec::new();
    let mut frame_starts: Vec<usize> = Vec::new();
    let mut last_frame: Option<(SurfaceMesh, String)> = None;
    for (k, frame) in frames.iter().enumerate().skip(first) {
        let Framed {
            solve,
            deformed,
            observation,
            held,
        } = framing.solve(k, &mut solver, args.quiet)?;
        let answer = Answer {
            converged: solve.converged,
            deformed: &deformed,
            unloaded,
            held_by: held.as_ref(),
        };
        let uncertainty = uncertain::regions_after(
            explorer.as_mut(),
            answer,
            (&mut solver, &model),
            &carried,
            args.quiet,
        )?;
        if k > first {
            frame_starts.push(residuals.len());
        }
        residuals.extend(&solve.residual_history);
        let dir = args.output_dir.join(format!("frame-{:04}", k + 1));
        let surface = frame.display().to_string();
        let destination = Destination {
            dir: &dir,
            report: None,
            model: &model_name,
            surface: &surface,
            field: None,
            picture: None,
        };
        remove_earlier_outputs(
            &destination,
            &planned_outputs(&destination, &carried),
            &inputs,
        )?;
        let report = match write_solution(
            destination,
            &model,
            &solver,
            &deformed,
            &carried,
            Solved {
                params: &params,
                solve,
                posture: posture_report,
                observation: observation.clone(),
                uncertainty: uncertainty.as_ref(),
            },
        ) {
            Ok(report) => report,
            Err(err) => {
                // A diverged frame ends the run; the summary says so.
                if let Some(unfinished) = err.downcast_ref::<Unfinished>() {
                    summary.write(&solver, &done, unfinished.status)?;
                }
                return Err(err);
            }
        };
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
                convergence(report.converged, report.stopped_by, report.residual)
            );
            if !moved.is_empty() {
                line = format!("{line}; {}", moved.join(", "));
            }
            println!("{line}");
        }
        last_frame = Some((deformed, file_name(&surface)));
        done.push(serde_json::to_value(FrameReport {
            frame: surface,
            folder: dir.display().to_string(),
            iterations: report.iterations,
            seconds: report.seconds,
            converged: report.converged,
            residual: report.residual,
            status: report.status,
            inverted: report.inverted.count,
            structures: report.structures,
            observation,
        })?);
        let last = k + 1 == frames.len();
        if !last {
            summary.write(&solver, &done, status)?;
            if stop_asked() {
                break;
            }
        }
    }
    if done.len() == frames.len() {
        status = if !done.iter().all(|f| f["converged"] == Value::Bool(true)) {
            Status::NotConverged
        } else if done.iter().any(|f| f["status"] == "flagged") {
            Status::Flagged
        } else {
            Status::Converged
        };
    }
    if let (Some(path), Some((deformed, name))) = (&args.picture, &last_frame) {
        let (_, structures) = carried.moved(&solver)?;
        let moved: Vec<&SurfaceMesh> = structures.iter().map(|s| &s.mesh).collect();
        let solved = done.len() - first;
        let title = format!(
            "frame {} of {} ({name}): {} iterations over {solved} frame{}",
            done.len(),
            frames.len(),
            residuals.len(),
            if solved == 1 { "" } else { "s" }
        );
        draw(
            path,
            title,
            Drawn {
                model: &model,
                rest: solver.reference(),
                current: solver.positions(),
                deformed,
                carried: &carried,
                moved: &moved,
                residuals: &residuals,
                frame_starts,
                tolerance: params.tolerance,
                uncertainty: None,
            },
        )?;
        if !args.quiet {
            println!("drew {}", path.display());
        }
    }
    let totals = summary.write(&solver, &done, status)?;
    let count = totals.frames;
    let unconverged = done
        .iter()
        .filter(|f| f["converged"] != Value::Bool(true))
        .count();
    if !args.quiet && status != Status::Incomplete {
        println!(
            "tracked {} frames: {} iterations, {:.3} s solving, {:.3} s in all, {}",
            totals.frames,
            totals.iterations,
            totals.solve_seconds,
            totals.seconds,
            if totals.converged {
                "all converged"
            } else {
                "NOT all converged (each frame's `stopped_by`: more iterations help where it \
                 is `iteration_cap`)"
            }
        );
        println!(
            "  wrote {} (frame-0001 .. frame-{count:04}) and {}",
            args.output_dir.display(),
            path.display()
        );
    }
    let message = match status {
        Status::Converged => return Ok(()),
        Status::Incomplete => format!(
            "stopped by Ctrl-C after frame {count} of {}; {} says so, and the same command \
             with --resume continues from frame {}",
            frames.len(),
            path.display(),
            count + 1
        ),
        Status::Flagged => format!(
            "{} of {count} frames are flagged ({}, `status` of each frame): points or \
             structures outside the organ, or particles turned inside out",
            done.iter().filter(|f| f["status"] == "flagged").count(),
            path.display()
        ),
        _ => format!(
            "{unconverged} of {count} frames did NOT converge ({}; each frame's `stopped_by`: \
             raise --max-iterations where it is `iteration_cap`)",
            path.display()
        ),
    };
    Err(Unfinished { status, message }.into())
}

/// What `track.json` says besides the frames: written after every frame.
struct Summary<'a> {
    path: &'a Path,
    model: &'a str,
    plan: &'a Value,
    posture: Option<&'a PostureReport>,
    planned: usize,
    started: Instant,
    resumed_at: Option<usize>,
}

impl Summary<'_> {
    /// Writes `track.json` for the frames `done` so far; its totals.
    fn write(
        &self,
        solver: &crate::backend::Solver,
        done: &[Value],
        status: Status,
    ) -> Result<Totals> {
        let mut report = TrackReport {
            model: self.model,
            backend: solver.backend(),
            frames: done,
            totals: totals(done, self.planned, status, self.started),
            plan: self.plan,
            posture: self.posture,
        };
        report.totals.resumed_at = self.resumed_at;
        write_json(self.path, &report)?;
        write_collection(&self.path.with_file_name(COLLECTION_FILE), done.len())?;
        Ok(report.totals)
    }
}

/// Writes `track.pvd`: a ParaView collection of the first `frames` frames'
/// `particles.vtp`, frame k at time step k, so that the run opens as one
/// animation. Paths are relative to the collection's folder.
fn write_collection(path: &Path, frames: usize) -> Result<()> {
    tissue::io::write_atomically(path, |out| {
        writeln!(out, r#"<?xml version="1.0"?>"#)?;
        writeln!(
            out,
            r#"<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">"#
        )?;
        writeln!(out, "  <Collection>")?;
        for k in 1..=frames {
            writeln!(
                out,
                r#"    <DataSet timestep="{k}" group="" part="0" file="frame-{k:04}/{PARTICLES_FILE}"/>"#
            )?;
        }
        writeln!(out, "  </Collection>")?;
        writeln!(out, "</VTKFile>")
    })?;
    Ok(())
}
