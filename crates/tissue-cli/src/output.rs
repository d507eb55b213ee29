//! What one solve writes: `particles.vtp`, `points.csv`, the moved
//! structures, and `report.json`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use serde::Serialize;
use tissue::deformation::{
    DeformParams, DeformReport, ForceModel, Inversions, StopReason, inversions,
};
use tissue::{ParticleModel, SurfaceMesh};

use crate::backend::Solver;
use crate::carry::{Carried, StructureReport};
use crate::folder::{Staging, remove_staged};
use crate::observe::ObservationReport;
use crate::picture;
use crate::posture::PostureReport;
use crate::uncertain::{RADIUS_NAME, Uncertainty, UncertaintyReport};

mod status;
pub use status::{Status, Unfinished, convergence, diverged, remedy};

/// The moved particles and the deformed surface.
pub const PARTICLES_FILE: &str = "particles.vtp";
/// The moved landmark points.
pub const POINTS_FILE: &str = "points.csv";
/// The moved landmark points, when they came from a 3D Slicer markups file.
pub const MARKUPS_FILE: &str = "points.mrk.json";
/// The JSON report of a solve.
pub const REPORT_FILE: &str = "report.json";

/// Landmark points in the report.
#[derive(Debug, Clone, Serialize)]
pub struct PointsReport {
    /// The file they were read from.
    pub source: String,
    /// How many.
    pub count: usize,
    /// Largest distance a point moved.
    pub max_displacement_mm: f32,
    /// The points outside the model's rest surface (flagged).
    pub outside: crate::carry::Outside,
}

/// The observed part of the surface (`--observed`).
#[derive(Debug, Clone, Serialize)]
pub struct ObservedReport {
    /// Observed vertices.
    pub vertices: usize,
    /// Vertices of the surface.
    pub of: usize,
}

/// The JSON report of one solve (`report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct SolveReport {
    /// The model file (or what the demo wrote).
    pub model: String,
    /// The deformed surface file.
    pub surface: String,
    /// Number of particles.
    pub particles: usize,
    /// Where stage 2 ran: `cpu`, or the GPU adapter's name and graphics backend.
    pub backend: String,
    /// The stage-2 parameters used.
    pub params: DeformParams,
    /// With `--observed`: how many of the surface's vertices were observed
    /// (the mask itself is not written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub observed: Option<ObservedReport>,
    /// With an observation without correspondence (another triangulation,
    /// or `--cloud`): how the skin was matched to it, and its residual.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub observation: Option<ObservationReport>,
    /// Iterations run.
    pub iterations: usize,
    /// The error estimate at the end, as a fraction of the model's size.
    pub residual: f32,
    /// Wall-clock seconds of the solve.
    pub seconds: f64,
    /// Whether the stopping rule held before the iteration cap.
    pub converged: bool,
    /// `converged`, `not_converged` or `diverged` (the exit code's meaning).
    pub status: Status,
    /// Which rule ended the solve.
    pub stopped_by: StopReason,
    /// How many times the elastic phase went on from the state it accepted
    /// last after it stalled or ran out of steps back, linearised again
    /// there or without its correction (0 for the other forces).
    pub elastic_retries: usize,
    /// How many times an elastic phase went back to the last state it
    /// accepted and on with half its step, the potential having risen.
    pub backtracks: usize,
    /// Largest distance a particle moved from rest.
    pub max_displacement_mm: f32,
    /// Where each structure went.
    pub structures: Vec<StructureReport>,
    /// The landmark points, when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub points: Option<PointsReport>,
    /// The displacement field, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub displacement_field: Option<FieldReport>,
    /// Particles the solve turned inside out (local volume ratio at or
    /// below 0; `tissue::deformation::inversions`): flagged.
    pub inverted: Inversions,
    /// The files written, report included.
    pub files: Vec<String>,
    /// With the posture options: the postures, the stiffness and the
    /// unloaded shape (top-level fields `gravity`, `stiffness_kpa`,
    /// `stiffness_fitted`, `fit_residual_mm`, `unloaded_residual_mm`, ...).
    #[serde(flatten)]
    pub posture: Option<PostureReport>,
    /// With `--uncertainty`, each target's 95 % region.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyReport>,
    /// The error estimate after every iteration.
    pub residual_history: Vec<f32>,
}

impl SolveReport {
    /// Whether the unloaded shape (with the posture options) was found:
    /// true without them.
    pub fn unloaded_converged(&self) -> bool {
        self.posture.as_ref().is_none_or(|p| p.unloaded_converged)
    }
}

/// A displacement field to write (`deform --displacement-field`).
#[derive(Debug, Clone, Copy)]
pub struct FieldRequest<'a> {
    /// The `.nrrd` file.
    pub path: &'a Path,
    /// The grid spacing, in the model's units.
    pub spacing: f32,
}

/// The displacement field in the report.
#[derive(Debug, Clone, Serialize)]
pub struct FieldReport {
    /// The file written.
    pub file: String,
    /// The grid spacing.
    pub spacing_mm: f32,
    /// Grid points along x, y, z.
    pub sizes: [usize; 3],
    /// The longest displacement on the grid.
    pub max_mm: f32,
}

/// Where a solve's files go, and what to call its inputs in the report.
#[derive(Debug, Clone, Copy)]
pub struct Destination<'a> {
    /// The folder for everything but (possibly) the report.
    pub dir: &'a Path,
    /// Where the report goes; `dir/report.json` when `None`.
    pub report: Option<&'a Path>,
    /// The model, as named in the report.
    pub model: &'a str,
    /// The deformed surface, as named in the report.
    pub surface: &'a str,
    /// The displacement field to write, if any.
    pub field: Option<FieldRequest<'a>>,
    /// The picture to draw (`--picture`), if any.
    pub picture: Option<&'a Path>,
}

/// The files a solve into `to` writes for `carried`, report included.
pub fn planned_outputs(to: &Destination<'_>, carried: &Carried) -> Vec<PathBuf> {
    let mut files = vec![to.dir.join(PARTICLES_FILE)];
    if let Some(points) = &carried.points {
        files.push(to.dir.join(points.output_name()));
    }
    files.extend(carried.structures.iter().map(|s| to.dir.join(&s.name)));
    files.extend(
        carried
            .structures
            .iter()
            .filter_map(|s| s.transform_file())
            .map(|name| to.dir.join(name)),
    );
    files.extend(to.field.map(|f| f.path.to_path_buf()));
    files.extend(to.picture.map(Path::to_path_buf));
    files.push(
        to.report
            .map_or_else(|| to.dir.join(REPORT_FILE), Path::to_path_buf),
    );
    files
}

/// Refuses, before any work, an output that is one of the `inputs` (as
/// `(what, path)`) or another output: a run must never replace the files it
/// reads, nor write two results to one file.
pub fn refuse_overwriting(outputs: &[PathBuf], inputs: &[(&str, &Path)]) -> Result<()> {
    let outputs: Vec<(&PathBuf, PathBuf)> = outputs.iter().map(|o| (o, resolved(o))).collect();
    for (k, (output, resolved_output)) in outputs.iter().enumerate() {
        for &(what, input) in inputs {
            if *resolved_output == resolved(input) {
                bail!(
                    "the output {} would overwrite the {what} {}: choose another output path \
                     (inputs are never replaced)",
                    output.display(),
                    input.display()
                );
            }
        }
        if let Some((other, _)) = outputs[..k].iter().find(|(_, r)| r == resolved_output) {
            bail!(
                "two outputs would be written to one file: {} and {}",
                other.display(),
                output.display()
            );
        }
    }
    Ok(())
}

/// Removes from `to.dir` what an earlier solve into it wrote (the `files`
/// of the report it left, `to`'s report or the folder's `report.json`) and
/// this one will not write again (`planned`), so that the folder holds
/// only this run's results: a rerun without `--points` leaves no old
/// `points.csv`. Never an input, and nothing a report of ours did not
/// list; a report that cannot be read as ours removes nothing.
pub fn remove_earlier_outputs(
    to: &Destination<'_>,
    planned: &[PathBuf],
    inputs: &[(&str, &Path)],
) -> Result<()> {
    remove_staged(to.dir)?;
    let reports = [
        to.report.map(Path::to_path_buf),
        Some(to.dir.join(REPORT_FILE)),
    ];
    let planned: Vec<PathBuf> = planned.iter().map(|p| resolved(p)).collect();
    let inputs: Vec<PathBuf> = inputs.iter().map(|(_, p)| resolved(p)).collect();
    for report in reports.iter().flatten() {
        let Ok(text) = std::fs::read_to_string(report) else {
            continue;
        };
        let Ok(earlier) = serde_json::from_str::<serde_json::Value>(&text) else {
            continue;
        };
        let Some(files) = earlier.get("files").and_then(|f| f.as_array()) else {
            continue;
        };
        for file in files.iter().filter_map(|f| f.as_str()) {
            // Only the name: the earlier run may have named the folder
            // from somewhere else.
            let Some(name) = Path::new(file).file_name() else {
                continue;
            };
            let path = to.dir.join(name);
            let full = resolved(&path);
            if path.is_file() && !planned.contains(&full) && !inputs.contains(&full) {
                log::info!("removing {}, written by an earlier run", path.display());
                std::fs::remove_file(&path)
                    .with_context(|| format!("removing the earlier {}", path.display()))?;
            }
        }
    }
    Ok(())
}

/// Makes sure, before any work, that each of `outputs` can be written: it
/// is not a folder, its folder is created if missing, and a file can be
/// made there (a probe, removed at once). A path under a regular file, a
/// folder's name, a read-only folder or a full disk then fails here,
/// naming the output, instead of after a sampling or a solve.
pub fn prepare_outputs(outputs: &[PathBuf]) -> Result<()> {
    for output in outputs {
        if output.is_dir() {
            bail!(
                "cannot write {}: it is a folder; name a file in it instead",
                output.display()
            );
        }
        let folder = match output.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent,
            _ => Path::new("."),
        };
        std::fs::create_dir_all(folder).with_context(|| {
            format!(
                "cannot write {}: creating its folder {}",
                output.display(),
                folder.display()
            )
        })?;
        tempfile::Builder::new()
            .prefix(".tissue-probe.")
            .tempfile_in(folder)
            .with_context(|| {
                format!(
                    "cannot write {}: its folder {} does not take new files",
                    output.display(),
                    folder.display()
                )
            })?;
    }
    Ok(())
}

/// `path` made absolute with its folder's links resolved (the file itself
/// need not exist), to compare outputs with inputs.
pub fn resolved(path: &Path) -> PathBuf {
    if let Ok(full) = path.canonicalize() {
        return full;
    }
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    match (absolute.parent(), absolute.file_name()) {
        (Some(parent), Some(name)) => parent
            .canonicalize()
            .map_or_else(|_| absolute.clone(), |p| p.join(name)),
        _ => absolute,
    }
}

/// What a solve was run with and how it went.
#[derive(Debug)]
pub struct Solved<'a> {
    /// The stage-2 parameters.
    pub params: &'a DeformParams,
    /// The solve's report.
    pub solve: DeformReport,
    /// With the posture options, what they gave.
    pub posture: Option<&'a PostureReport>,
    /// With an observation without correspondence, how it was matched.
    pub observation: Option<ObservationReport>,
    /// With `--uncertainty`, the regions.
    pub uncertainty: Option<&'a Uncertainty>,
}

/// Carries everything along with the solved particles and writes the results.
pub fn write_solution(
    to: Destination<'_>,
    model: &ParticleModel,
    solver: &Solver,
    deformed: &SurfaceMesh,
    carried: &Carried,
    solved: Solved<'_>,
) -> Result<SolveReport> {
    let Solved {
        params,
        solve,
        posture,
        observation,
        uncertainty,
    } = solved;
    let current = solver.positions();
    if let Some(unfinished) = diverged(current, solve.iterations, solve.stopped_by) {
        return Err(unfinished.into());
    }
    std::fs::create_dir_all(to.dir).with_context(|| format!("creating {}", to.dir.display()))?;
    // Every output is written under a staged name and renamed into place
    // with the others once all are written: a run that fails on the way
    // (a point that cannot be carried, a motion that cannot be written, a
    // full disk) leaves none of them.
    let mut staging = Staging::default();
    let mut files: Vec<PathBuf> = Vec::new();

    let particles = to.dir.join(PARTICLES_FILE);
    let radii = uncertainty.map(|u| (RADIUS_NAME, u.particle_radii.as_slice()));
    tissue::io::model::save_moved_particles_with(
        model,
        current,
        deformed,
        carried.space,
        radii.as_slice(),
        &staging.stage(&particles),
    )?;
    files.push(particles);

    let (points, structures) = carried.moved(solver)?;
    let points = match (points, &carried.points) {
        (Some(moved), Some(source)) => {
            let path = to.dir.join(source.output_name());
            let staged = staging.stage(&path);
            let radii = uncertainty.and_then(|u| u.point_radii.as_deref());
            match (&source.markups, radii) {
                (Some(markups), _) => tissue::io::markups::save_markups(markups, &moved, &staged)?,
                (None, Some(radii)) => {
                    tissue::io::points::save_points_with(&moved, RADIUS_NAME, radii, &staged)?;
                }
                (None, None) => tissue::save_points(&moved, &staged)?,
            }
            files.push(path);
            Some(PointsReport {
                source: source.source.clone(),
                count: moved.len(),
                max_displacement_mm: source
                    .rest()
                    .iter()
                    .zip(&moved)
                    .map(|(a, b)| a.distance(*b))
                    .fold(0.0, f32::max),
                outside: source.outside,
            })
        }
        _ => None,
    };
    for structure in &structures {
        let path = to.dir.join(&structure.report.name);
        tissue::save_surface_in(&structure.mesh, carried.space, &staging.stage(&path))?;
        files.push(path);
    }
    for structure in &structures {
        let report = &structure.report;
        if let (Some(transform), Some(name)) = (&report.transform, &report.transform_file) {
            let path = to.dir.join(name);
            let motion = tissue::io::itk::Affine::from_rows(transform);
            tissue::io::itk::save_motion_tfm(&motion, carried.space, &staging.stage(&path))?;
            files.push(path);
        }
    }
    let displacement_field = match to.field {
        Some(request) => {
            let field = tissue::resampling::resampling_field(
                solver.reference(),
                current,
                &solver.rotations()?,
                &model.connections,
                deformed,
                request.spacing,
            )
            .map_err(|e| anyhow::anyhow!("{}: {e}", request.path.display()))?;
            tissue::io::nrrd::save_displacement_field(
                &field,
                carried.space,
                &staging.stage(request.path),
            )?;
            files.push(request.path.to_path_buf());
            Some(FieldReport {
                file: request.path.display().to_string(),
                spacing_mm: field.spacing,
                sizes: field.dims,
                max_mm: field.values.iter().map(|v| v.length()).fold(0.0, f32::max),
            })
        }
        None => None,
    };
    if let Some(path) = to.picture {
        let title = format!(
            "{}: {} particles, {} iterations, {}",
            file_name(to.surface),
            model.len(),
            solve.iterations,
            if solve.converged {
                "converged"
            } else {
                "NOT converged"
            }
        );
        let moved: Vec<&SurfaceMesh> = structures.iter().map(|s| &s.mesh).collect();
        draw(
            &staging.stage(path),
            title,
            Drawn {
                model,
                rest: solver.reference(),
                current,
                deformed,
                carried,
                moved: &moved,
                residuals: &solve.residual_history,
                frame_starts: Vec::new(),
                tolerance: params.tolerance,
                uncertainty,
            },
        )?;
        files.push(path.to_path_buf());
    }
    let report_path = to
        .report
        .map_or_else(|| to.dir.join(REPORT_FILE), Path::to_path_buf);
    files.push(report_path.clone());

    let max_displacement_mm = current
        .iter()
        .zip(solver.reference())
        .map(|(q, p)| q.distance(*p))
        .fold(0.0, f32::max);
    let inverted = inversions(solver.reference(), current, &model.connections);
    let observation_flagged = observation.as_ref().is_some_and(|o| !o.flags().is_empty());
    let uncertainty = uncertainty.map(|u| u.report.clone());
    let uncertainty_flagged = uncertainty.as_ref().is_some_and(|u| !u.flags().is_empty());
    let report = SolveReport {
        model: to.model.to_owned(),
        surface: to.surface.to_owned(),
        particles: model.len(),
        backend: solver.backend(),
        params: params.clone(),
        observed: params.observed.as_ref().map(|mask| ObservedReport {
            vertices: mask.iter().filter(|&&o| o).count(),
            of: mask.len(),
        }),
        observation,
        iterations: solve.iterations,
        residual: solve.residual,
        seconds: solve.seconds,
        converged: solve.converged,
        status: match Status::of(solve.converged, solve.stopped_by) {
            // An unloaded shape that was not found leaves the result not final.
            Status::Converged if posture.is_some_and(|p| !p.unloaded_converged) => {
                Status::NotConverged
            }
            Status::Converged
                if carried.flagged()
                    || inverted.count > 0
                    || posture.is_some_and(|p| !p.flags().is_empty())
                    || observation_flagged
                    || uncertainty_flagged =>
            {
                Status::Flagged
            }
            status => status,
        },
        stopped_by: solve.stopped_by,
        elastic_retries: solve.elastic_retries,
        backtracks: solve.backtracks,
        max_displacement_mm,
        structures: structures.into_iter().map(|s| s.report).collect(),
        points,
        displacement_field,
        inverted,
        files: files.iter().map(|p| p.display().to_string()).collect(),
        posture: posture.cloned(),
        uncertainty,
        residual_history: solve.residual_history,
    };
    // The report last: it names the files, so it appears after them.
    write_json(&staging.stage(&report_path), &report)?;
    staging.commit()?;
    Ok(report)
}

/// What a picture shows of a solve (`picture::Scene`).
pub struct Drawn<'a> {
    /// The model solved.
    pub model: &'a ParticleModel,
    /// The particles where the solve measures displacement from (the
    /// solver's reference: the model's rest positions, or the unloaded
    /// shape with the posture options).
    pub rest: &'a [Vec3],
    /// The particles now.
    pub current: &'a [Vec3],
    /// The skin now.
    pub deformed: &'a SurfaceMesh,
    /// The structures at rest...
    pub carried: &'a Carried,
    /// ... and moved, in the same order.
    pub moved: &'a [&'a SurfaceMesh],
    /// The error estimate of every iteration drawn.
    pub residuals: &'a [f32],
    /// Where each frame after the first begins in `residuals`.
    pub frame_starts: Vec<usize>,
    /// The stopping tolerance.
    pub tolerance: f32,
    /// With `--uncertainty`, the regions.
    pub uncertainty: Option<&'a Uncertainty>,
}

/// Draws `what` into the PNG file `path` (`--picture`).
pub fn draw(path: &Path, title: String, what: Drawn<'_>) -> Result<()> {
    let scene = picture::Scene {
        title,
        rest: what.rest,
        current: what.current,
        radii: &what.model.radii,
        rest_surface: &what.model.surface,
        surface: what.deformed,
        structures: what
            .carried
            .structures
            .iter()
            .map(|s| s.rest_mesh())
            .zip(what.moved.iter().copied())
            .collect(),
        residuals: what.residuals,
        frame_starts: what.frame_starts,
        tolerance: what.tolerance,
        spread: what.uncertainty.map(|u| picture::Spread {
            radii: &u.particle_radii,
            centroids: u.centroids.clone(),
        }),
    };
    picture::save(&scene, path)
}

/// The last part of a path as written, for titles.
pub fn file_name(path: &str) -> String {
    Path::new(path)
        .file_name()
        .map_or_else(|| path.to_owned(), |n| n.to_string_lossy().into_owned())
}

/// Pretty JSON with a final newline.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let json = serde_json::to_string_pretty(value)?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    tissue::io::write_atomically(path, |out| writeln!(out, "{json}"))?;
    Ok(())
}

impl SolveReport {
    /// The solve in a few lines for the terminal, indented by `indent`.
    pub fn summary(&self, indent: &str) -> Vec<String> {
        let times = |n: usize| match n {
            1 => "once".to_owned(),
            n => format!("{n} times"),
        };
        let mut again = Vec::new();
        if self.backtracks > 0 {
            again.push(format!(
                "the elastic phase stepped back {}: `backtracks`",
                times(self.backtracks)
            ));
        }
        if self.elastic_retries > 0 {
            again.push(format!(
                "the elastic phase went on from where it stopped short {}: `elastic_retries`",
                times(self.elastic_retries)
            ));
        }
        let retried = match again.is_empty() {
            true => String::new(),
            false => format!(" ({})", again.join("; ")),
        };
        let mut lines = vec![format!(
            "{indent}{} iterations in {:.3} s, {}{retried}; particles moved up to {:.2} mm",
            self.iterations,
            self.seconds,
            convergence(self.converged, self.stopped_by, self.residual),
            self.max_displacement_mm
        )];
        if let Some(observation) = &self.observation {
            if let Some(alignment) = &observation.alignment {
                lines.push(format!("{indent}{}", alignment.line()));
            }
            lines.push(format!("{indent}{}", observation.line()));
        }
        for s in &self.structures {
            lines.push(format!("{indent}{}", s.line()));
        }
        if let Some(p) = &self.points {
            lines.push(format!(
                "{indent}{} points from {}: moved up to {:.2} mm",
                p.count, p.source, p.max_displacement_mm
            ));
        }
        if let Some(uncertainty) = &self.uncertainty {
            lines.extend(uncertainty.summary(indent));
        }
        lines.extend(
            self.flags()
                .into_iter()
                .map(|f| format!("{indent}FLAGGED: {f}")),
        );
        lines
    }

    /// What makes a converged solve implausible, one line each (empty when
    /// nothing does).
    pub fn flags(&self) -> Vec<String> {
        let mut flags = Vec::new();
        let outside = self.points.as_ref().map_or(0, |p| p.outside.count)
            + self
                .structures
                .iter()
                .map(|s| s.outside.count)
                .sum::<usize>();
        if outside > 0 {
            flags.push(format!(
                "{outside} points or structure vertices lie outside the model's rest surface \
                 (`outside` in the report): they are carried by extrapolation"
            ));
        }
        if let Some(posture) = &self.posture {
            flags.extend(posture.flags());
        }
        if let Some(observation) = &self.observation {
            flags.extend(observation.flags());
        }
        if let Some(uncertainty) = &self.uncertainty {
            flags.extend(uncertainty.flags());
        }
        if self.inverted.count > 0 {
            // The likely cause: the elastic force keeps every volume
            // positive under a deep indentation, so under it the input
            // asked for the fold.
            let cause = match (self.params.force, &self.observation) {
                (ForceModel::Elastic, Some(_)) => {
                    "the pull towards the observation folded the tissue: the points may be too \
                     sparse for the skin's curvature (each pulls the skin around it onto one \
                     plane), or lie where the skin cannot reach"
                }
                (ForceModel::Elastic, None) => {
                    "the surface has crossed or pushed-through vertices, or moved where the \
                     tissue cannot follow"
                }
                (ForceModel::Symmetric | ForceModel::Paper, _) => {
                    "the solve folded the tissue, as the symmetric force does under a deep, \
                     narrow indentation (try --force elastic), or the surface has crossed or \
                     pushed-through vertices"
                }
            };
            flags.push(format!(
                "{} particles are turned inside out (local volume ratio down to {:.2}, first \
                 particle {}; `inverted` in the report): {cause}",
                self.inverted.count,
                self.inverted.min_volume_ratio,
                self.inverted.first.unwrap_or_default()
            ));
        }
        flags
    }
}
