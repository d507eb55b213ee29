//! `tissue deform`: one deformed surface, one solve; and what `track` and
//! `demo` share with it (parameters, loading, error wording).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use glam::{IVec3, Vec3};
use tissue::backend::with_cpu_fallback;
use tissue::deformation::{DeformParams, ForceModel};
use tissue::observation::{FiducialFit, MatchParams, MatchReport, Observation, match_observation};
use tissue::{ParticleModel, SurfaceMesh};

use crate::backend::{self, BackendArgs, Device, Solver};
use crate::carry::{Carried, CarryArgs};
use crate::observe;
use crate::output::{
    Destination, FieldRequest, Solved, Status, Unfinished, planned_outputs, prepare_outputs,
    refuse_overwriting, remedy, remove_earlier_outputs, write_solution,
};
use crate::picture;
use crate::posture::{self, GravityArgs, Posture};

mod args;

use crate::progress::{self, SolveBar};
use crate::uncertain::{self, UncertaintyArgs};
pub use args::SolveArgs;
use tissue::uncertainty::Explorer;

/// What the spinner says while a solver is prepared (the plan, the coarse
/// levels' factors, the device's buffers).
pub const PREPARING: &str = "preparing the solver";

/// Options of `tissue deform`.
#[derive(Debug, clap::Args)]
pub struct DeformArgs {
    /// The particle model (.vtp from `tissue sample`).
    #[arg(long)]
    pub model: PathBuf,
    /// The deformed surface: the model's rest surface with moved vertices
    /// (same vertices in the same order, same triangles: the skin follows
    /// it vertex by vertex), or any closed surface of the organ (another
    /// segmentation's: the skin is matched to it without correspondence,
    /// docs/METHOD.md, "Observations without correspondence").
    #[arg(long, required_unless_present = "cloud", conflicts_with = "cloud")]
    pub surface: Option<PathBuf>,
    /// A scan of part of the skin as points (.csv, .ply, .vtk, .vtp,
    /// .mrk.json; docs/FORMATS.md), matched without correspondence; needs
    /// --fixed-region FILE.
    #[arg(long, value_name = "FILE")]
    pub cloud: Option<PathBuf>,
    /// The observation's noise scale, in the model's units (default: a
    /// tenth of the model's mean connection length for a surface; for a
    /// cloud the larger of a fifth of its spacing and its points' scatter
    /// about their neighbours' planes): a cloud's pairs farther off than 3 times it
    /// and the pairs' robust spread are pulled with the force they would
    /// have there (Huber's), so an outlier moves the skin little and skin
    /// with far to go is pulled all the way. At most a quarter of the
    /// organ's size.
    #[arg(long, value_name = "MM")]
    pub noise: Option<f32>,
    /// How a surface of another triangulation is paired with the skin, in
    /// its mean edges: the plane smoothed over its vertices within this
    /// radius (default 1); 0 pairs each particle with the nearest point
    /// and the distance's curvature there (slower, its last stage ending at
    /// the float floor, but an uncertainty's re-solves of its answer are
    /// faster: docs/ACCURACY.md). Not for a cloud.
    #[arg(long, value_name = "EDGES")]
    pub surface_smoothing: Option<f32>,
    /// Fiducials that put an observation without correspondence (--cloud,
    /// or --surface of another triangulation) in the model's frame first:
    /// the same points in the model's frame, then in the observation's, in
    /// the same order (.csv, .ply, .mrk.json; at least three, not on one
    /// line). The rigid motion fitted to them moves the observation before
    /// it is matched; the motion and the fiducials' residual are reported.
    #[arg(long, num_args = 2, value_names = ["MODEL_POINTS", "OBSERVED_POINTS"])]
    pub fiducials: Option<Vec<PathBuf>>,

    #[command(flatten)]
    pub carry: CarryArgs,
    /// Folder for the results (created if missing).
    #[arg(long, short = 'o')]
    pub output_dir: PathBuf,
    /// Write the JSON report here instead of `<output-dir>/report.json`.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Also write the interior's displacement on a regular grid as a NRRD
    /// file, which 3D Slicer loads as a grid transform: in LPS, at each point
    /// of the deformed configuration the vector to where that tissue is at
    /// rest (the resampling direction; docs/FORMATS.md).
    #[arg(long, value_name = "FILE.nrrd")]
    pub displacement_field: Option<PathBuf>,
    /// Grid spacing of `--displacement-field`, in the model's units
    /// (default: half the model's mean connection length).
    #[arg(long, value_name = "MM", requires = "displacement_field")]
    pub field_spacing: Option<f32>,
    /// Also draw the result as a PNG picture: a cut through the organ
    /// coloured by displacement, the skin and the structures at rest and
    /// moved, beside the solve's convergence (docs/FORMATS.md, "Pictures").
    #[arg(long, value_name = "FILE.png")]
    pub picture: Option<PathBuf>,
    #[command(flatten)]
    pub solve: SolveArgs,
    #[command(flatten)]
    pub uncertainty: UncertaintyArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Print nothing but errors.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Reads a model for stage 2 and checks it; with `observed`, `params`
/// gains its mask.
pub fn read_model(
    path: &Path,
    params: &mut DeformParams,
    observed: Option<&Path>,
) -> Result<ParticleModel> {
    let vtp = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vtp"));
    if !vtp {
        bail!(
            "{}: a model is the .vtp file `tissue sample --output model.vtp` writes",
            path.display()
        );
    }
    let model = tissue::load_model(path)?;
    tissue::io::model::check_placement(&model).with_context(|| format!("{}", path.display()))?;
    if let Some(file) = observed {
        params.observed = Some(read_observed(file, &model.surface)?);
    }
    Ok(model)
}

/// What stage 2 is prepared for: the model (read from `path`), the
/// deformed surface, the posture options; `quiet` prints nothing.
pub struct Stage2<'a> {
    pub path: &'a Path,
    pub model: &'a ParticleModel,
    pub deformed: &'a SurfaceMesh,
    pub gravity: &'a GravityArgs,
    /// With an observation without correspondence, the surface vertices
    /// it saw: the skin the posture options fit the stiffness to (`None`:
    /// `params.observed`'s).
    pub seen: Option<&'a [bool]>,
    pub quiet: bool,
}

impl Stage2<'_> {
    /// [`Stage2::solver_on`] `device`; where `backend` is `auto` and the
    /// GPU it picked has no room for the model (out of memory, or a limit
    /// it exceeds), on the CPU instead, saying so unless `quiet`
    /// (`tissue::backend::with_cpu_fallback`).
    pub fn solver(
        &self,
        backend: crate::backend::Backend,
        device: Device,
        params: &mut DeformParams,
    ) -> Result<(Solver, Option<Posture>)> {
        let asked = params.clone();
        let (solver, fell_back) =
            with_cpu_fallback(backend.into(), device, ran_out_on_gpu, |device| {
                *params = asked.clone();
                self.solver_on(device, params)
            })?;
        if let (Some(why), false) = (fell_back, self.quiet) {
            println!("backend: cpu ({why})");
        }
        Ok(solver)
    }

    /// Stage 2 on `device` under `params`: with the posture options, the
    /// organ's unloaded shape (and stiffness) first, from the rest scan and
    /// the deformed surface, and the solver then stress-free in it with the
    /// deformed posture's gravity inside (`params` gains that load; unless
    /// `quiet`, what was found is printed).
    fn solver_on(
        &self,
        device: Device,
        params: &mut DeformParams,
    ) -> Result<(Solver, Option<Posture>)> {
        let Self {
            path,
            model,
            deformed,
            gravity,
            seen,
            quiet,
        } = *self;
        let context = || format!("{}: cannot deform this model", path.display());
        let fit_params = match seen {
            Some(seen) => params.clone().with(|p| p.observed = Some(seen.to_vec())),
            None => params.clone(),
        };
        let Some(posture) =
            posture::prepare(gravity, &device, model, deformed, &fit_params, quiet)?
        else {
            let solver = progress::busy(quiet, PREPARING, |busy| {
                Solver::new_with_progress(device, model, params.clone(), &mut |stage| {
                    busy.say(stage)
                })
            })
            .with_context(context)?;
            return Ok((solver, None));
        };
        if !quiet {
            for line in posture.summary("") {
                println!("{line}");
            }
        }
        let solver = progress::busy(quiet, PREPARING, |busy| {
            posture.solver(device, model, params, &mut |stage| busy.say(stage))
        })
        .with_context(context)?;
        Ok((solver, Some(posture)))
    }
}

/// Whether `error` (or one it wraps) is a GPU without room for the work
/// ([`tissue::Error::is_gpu_capacity`]).
pub fn ran_out_on_gpu(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        cause
            .downcast_ref::<tissue::Error>()
            .is_some_and(tissue::Error::is_gpu_capacity)
    })
}

/// The observed-vertex mask of `rest` (the model's rest surface) from
/// `path`: the observed patch of the rest surface as a surface file (its
/// vertices), or its vertices as a point file (`.csv`, `.ply`). Each point
/// must be a vertex of `rest`, to 1e-5 of its size: vertex numbers do not
/// survive reading (an OBJ file's are renumbered by first use), positions
/// do (docs/FORMATS.md).
pub fn read_observed(path: &Path, rest: &SurfaceMesh) -> Result<Vec<bool>> {
    let surface = path.extension().is_some_and(|e| {
        ["obj", "stl", "vtk", "vtp"]
            .iter()
            .any(|known| e.eq_ignore_ascii_case(known))
    });
    let points = if surface {
        tissue::load_surface_as_written(path)?.vertices
    } else {
        tissue::load_points(path)?
    };
    if points.is_empty() {
        bail!("{}: no observed point in the file", path.display());
    }
    let (lo, hi) = rest.vertices.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &v| (lo.min(v), hi.max(v)),
    );
    let tolerance = 1e-5 * (hi - lo).length();
    let cell = |p: Vec3| (p / tolerance).floor().as_ivec3();
    let mut grid: HashMap<IVec3, Vec<usize>> = HashMap::new();
    for (i, &v) in rest.vertices.iter().enumerate() {
        grid.entry(cell(v)).or_default().push(i);
    }
    let mut mask = vec![false; rest.vertices.len()];
    for (k, &p) in points.iter().enumerate() {
        let c = cell(p);
        let near = (-1..=1)
            .flat_map(|x| (-1..=1).flat_map(move |y| (-1..=1).map(move |z| IVec3::new(x, y, z))))
            .filter_map(|d| grid.get(&(c + d)))
            .flatten()
            .copied()
            .find(|&i| rest.vertices[i].distance(p) <= tolerance);
        let Some(i) = near else {
            let (i, d) = rest
                .vertices
                .iter()
                .map(|v| v.distance(p))
                .enumerate()
                .fold(
                    (0, f32::MAX),
                    |best, (i, d)| if d < best.1 { (i, d) } else { best },
                );
            bail!(
                "{}: point {} ({p}) is {d} from the nearest vertex of the model's rest surface \
                 (vertex {i} at {}): observed points must be vertices of the rest surface, in \
                 the rest posture and the model's units",
                path.display(),
                k + 1,
                rest.vertices[i]
            );
        };
        mask[i] = true;
    }
    Ok(mask)
}

/// Reads the deformed surface at `path` and checks it against `rest` (the
/// same mesh with moved vertices, a plausible volume: see
/// `tissue::deformation::check_same_topology`). A surface wound like the
/// file the model was sampled from, where sampling reversed it, is turned
/// the same way.
///
/// The file's vertices are taken as written when they are as many as the
/// rest surface's (two that touch in this frame stay two), else with exact
/// duplicates merged (a file that repeats vertices along seams, or an STL
/// file, which repeats every corner), whichever matches.
pub fn read_frame(path: &Path, rest: &SurfaceMesh) -> Result<SurfaceMesh> {
    let written = tissue::load_surface_as_written(path)?;
    let stl = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("stl"));
    // Welded, its winding turned, its vertices renumbered by the
    // triangles, as another tool's save of the same mesh needs.
    let deformed = written.as_frame_of(rest, stl);
    tissue::deformation::check_same_topology(rest, &deformed).map_err(|err| {
        let hint = if stl && deformed.vertices.len() < rest.vertices.len() {
            " (an STL file stores no shared vertices, so vertices that touch in this frame \
             merge when it is read: save deformed frames as OBJ or PLY)"
        } else {
            ""
        };
        anyhow!("{}: {}{hint}", path.display(), err)
    })?;
    Ok(deformed)
}

/// [`read_frame`], and refused if it passes through itself (two triangles
/// cross), unless the rest surface already does: the whole check of a
/// deformed surface. `track` runs it on every frame before its first
/// solve, then reads each frame again with [`read_frame`] alone.
pub fn read_deformed(path: &Path, rest: &SurfaceMesh) -> Result<SurfaceMesh> {
    let deformed = read_frame(path, rest)?;
    if let Some([a, b]) = tissue::crossing::first_crossing(&deformed) {
        // A rest surface that crosses itself (the model was sampled from
        // it) makes its frames cross too: that is no new defect.
        if tissue::crossing::first_crossing(rest).is_none() {
            bail!(
                "{}: the deformed surface passes through itself (triangles {a} and {b} cross): \
                 a skin pushed through the opposite side or folded over has no tissue shape \
                 behind it",
                path.display()
            );
        }
        log::warn!(
            "{}: triangles {a} and {b} cross, as the rest surface's do",
            path.display()
        );
    }
    Ok(deformed)
}

/// `deformed`, read from `path`, given to `solver` (a frame boundary).
pub fn set_deformed(path: &Path, solver: &mut Solver, deformed: &SurfaceMesh) -> Result<()> {
    solver
        .set_surface(deformed)
        .map_err(|err| anyhow!("{}: {}", path.display(), err))
}

impl DeformArgs {
    /// Every file the command reads, as `(what, path)`.
    fn inputs(&self) -> Vec<(&'static str, &Path)> {
        let mut inputs: Vec<(&'static str, &Path)> = vec![("model", self.model.as_path())];
        inputs.extend(self.surface.as_deref().map(|p| ("deformed surface", p)));
        inputs.extend(self.cloud.as_deref().map(|p| ("cloud", p)));
        for path in self.fiducials.iter().flatten() {
            inputs.push(("fiducials", path.as_path()));
        }
        inputs.extend(self.fixed_region().map(|p| ("fixed region", p)));
        inputs.extend(self.carry.inputs());
        inputs
    }

    /// The match's parameters: `--noise` and `--surface-smoothing` where
    /// given, the library's defaults otherwise.
    fn matching(&self) -> MatchParams {
        observe::matching(self.noise, self.surface_smoothing)
    }
}

/// The default grid spacing of `--displacement-field`, in mean connection
/// lengths (docs/FORMATS.md, "The interior's motion").
pub const FIELD_SPACINGS: f32 = 0.5;

/// `--displacement-field` and `--field-spacing`, checked before any work:
/// a `.nrrd` name, a positive spacing (half the model's mean connection
/// length by default: docs/FORMATS.md), a grid that is not too large around
/// `deformed`.
fn field_request<'a>(
    path: &'a Path,
    spacing: Option<f32>,
    model: &ParticleModel,
    deformed: &SurfaceMesh,
) -> Result<FieldRequest<'a>> {
    let nrrd = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nrrd"));
    if !nrrd {
        bail!(
            "{}: a displacement field is written as NRRD: name it <name>.nrrd",
            path.display()
        );
    }
    let spacing = spacing.unwrap_or_else(|| FIELD_SPACINGS * model.mean_connection_length());
    tissue::resampling::field_grid(deformed, spacing)
        .map_err(|e| anyhow!("--displacement-field {}: {e}", path.display()))?;
    Ok(FieldRequest { path, spacing })
}

/// What `deform` solves for.
enum Target {
    /// The rest surface's frame: the skin follows it vertex by vertex.
    Frame(SurfaceMesh),
    /// An observation without correspondence, with the held region's
    /// vertices of the rest surface.
    Match {
        observation: Box<Observation>,
        held: Vec<bool>,
    },
}

impl DeformArgs {
    /// The observation's file: `--surface` or `--cloud`.
    fn observed_file(&self) -> Result<&Path> {
        match (&self.surface, &self.cloud) {
            (Some(path), None) | (None, Some(path)) => Ok(path),
            _ => bail!("give the deformed surface (--surface) or a scan of the skin (--cloud)"),
        }
    }

    /// The `--fixed-region` file, if one is given (not `auto`).
    fn fixed_region(&self) -> Option<&Path> {
        match self.solve.gravity.fixed_region.as_deref() {
            None | Some("auto") => None,
            Some(file) => Some(Path::new(file)),
        }
    }

    /// What to solve for, read and checked against `model`.
    fn target(&self, model: &ParticleModel, motion: Option<&FiducialFit>) -> Result<Target> {
        let held = |path: &Path| read_observed(path, &model.surface);
        let target = match (&self.surface, &self.cloud) {
            (Some(path), None) => match observe::read_surface(path, &model.surface)? {
                observe::Surface::Frame(_) if motion.is_some() => bail!(
                    "{}: the surface is the model's rest surface with moved vertices, in the \
                     model's frame; --fiducials are for an observation without correspondence",
                    path.display()
                ),
                observe::Surface::Frame(deformed) => {
                    let held_without_posture =
                        self.solve.gravity.fixed_region.is_some() && !self.solve.gravity.given();
                    if held_without_posture
                        || self.noise.is_some()
                        || self.surface_smoothing.is_some()
                    {
                        bail!(
                            "{}: the surface is the model's rest surface with moved vertices, \
                             which the skin follows vertex by vertex; --noise, \
                             --surface-smoothing, and --fixed-region without the posture \
                             options, are for an observation without correspondence (use \
                             --observed for the vertices that were seen)",
                            path.display()
                        );
                    }
                    return Ok(Target::Frame(deformed));
                }
                observe::Surface::Other(mut mesh) => {
                    // In the model's frame first, where fiducials say how.
                    if let Some(motion) = motion {
                        for v in &mut mesh.vertices {
                            *v = motion.apply(*v);
                        }
                    }
                    Target::Match {
                        held: match self.fixed_region() {
                            Some(region) => held(region)?,
                            None => observe::held_on(&mesh, model).map_err(|e| {
                                anyhow!(
                                    "{}: not the same mesh with moved vertices as the model's \
                                     rest surface ({} vertices and {} triangles, against {} and \
                                     {}), so it is matched without correspondence, but {e}",
                                    path.display(),
                                    mesh.vertices.len(),
                                    mesh.triangles.len(),
                                    model.surface.vertices.len(),
                                    model.surface.triangles.len()
                                )
                            })?,
                        },
                        observation: Box::new(Observation::surface(&mesh)?),
                    }
                }
            },
            (None, Some(path)) => {
                if self.surface_smoothing.is_some() {
                    bail!(
                        "{}: --surface-smoothing is for a surface of another triangulation; a \
                         scan's plane is smoothed over its own spacing",
                        path.display()
                    );
                }
                let Some(region) = self.fixed_region() else {
                    bail!(
                        "{}: a scan of part of the skin needs the region held at rest (the \
                         chest wall) as --fixed-region",
                        path.display()
                    );
                };
                Target::Match {
                    observation: Box::new(observe::read_cloud(path, model, self.noise, motion)?),
                    held: held(region)?,
                }
            }
            _ => bail!("give the deformed surface (--surface) or a scan of the skin (--cloud)"),
        };
        if self.solve.observed.is_some() {
            bail!(
                "--observed names the seen vertices of a deformed surface with the rest \
                 surface's vertices; an observation without correspondence is matched where it \
                 is seen (give the held region as --fixed-region)"
            );
        }
        if self.noise.is_some_and(|n| !(n.is_finite() && n >= 0.0)) {
            bail!(
                "--noise is {}: a distance of at least zero is needed",
                self.noise.unwrap_or_default()
            );
        }
        observe::check_smoothing(self.surface_smoothing)?;
        Ok(target)
    }
}

/// `tissue deform`.
pub fn deform(args: &DeformArgs) -> Result<()> {
    let mut params = args.solve.params()?;
    if let Some(path) = &args.picture {
        picture::check_name(path)?;
    }
    let device = backend::pick(args.backend.backend, args.quiet)?;
    let model = read_model(&args.model, &mut params, args.solve.observed.as_deref())?;
    let observed_file = args.observed_file()?;
    crate::carry::check_space_tag(observed_file, args.carry.space)?;
    let aligned = match &args.fiducials {
        Some(files) => Some(observe::read_fiducials(files)?),
        None => None,
    };
    let target = args.target(&model, aligned.as_ref())?;
    let priors = args.uncertainty.priors()?;
    if let Target::Match { held, observation } = &target {
        if !params.force.eq(&ForceModel::Elastic) {
            bail!("an observation without correspondence is matched by the elastic force alone");
        }
        params.observed = Some(held.clone());
        if !args.quiet {
            println!(
                "{}: no correspondence with the model's rest surface; the skin is matched to the \
                 {} ({} points) inside the elastic solve, {} of {} rest vertices held",
                observed_file.display(),
                if observation.is_cloud() {
                    "scan"
                } else {
                    "surface"
                },
                observation.points().len(),
                held.iter().filter(|&&h| h).count(),
                held.len()
            );
        }
    }
    // With the posture options, a match without gravity first says where
    // the skin went: a frame of the rest surface that the stiffness is
    // fitted to, over the skin the observation saw.
    let first = match &target {
        Target::Match { observation, .. } if args.solve.gravity.given() => Some(
            observe::first_match(
                device.clone(),
                &model,
                &params,
                observation,
                &args.matching(),
                args.quiet,
            )
            .with_context(|| format!("{}: the match without gravity", observed_file.display()))?,
        ),
        _ => None,
    };
    // The frame, or for a match the rest surface (the held region stays
    // where it is) or the first match's.
    let placed = match (&target, &first) {
        (Target::Frame(deformed), _) => deformed,
        (Target::Match { .. }, Some((frame, _, _))) => frame,
        (Target::Match { .. }, None) => &model.surface,
    };
    let stage2 = Stage2 {
        path: &args.model,
        model: &model,
        deformed: placed,
        gravity: &args.solve.gravity,
        seen: first.as_ref().map(|(_, seen, _)| seen.as_slice()),
        quiet: args.quiet,
    };
    let (mut solver, mut posture) = stage2.solver(args.backend.backend, device, &mut params)?;
    if let (Some(posture), Some((_, _, short))) = (posture.as_mut(), &first) {
        posture.report.first_match_short = *short;
    }
    set_deformed(observed_file, &mut solver, placed)?;
    if let Some(posture) = &posture {
        posture.warm_start(&mut solver)?;
    }
    let carried = Carried::load(&args.carry, &solver, &model)?;
    let field = match &args.displacement_field {
        Some(path) => Some(field_request(path, args.field_spacing, &model, placed)?),
        None => None,
    };
    let surface_name = observed_file.display().to_string();
    let destination = Destination {
        dir: &args.output_dir,
        report: args.report.as_deref(),
        model: &args.model.display().to_string(),
        surface: &surface_name,
        field,
        picture: args.picture.as_deref(),
    };
    let planned = planned_outputs(&destination, &carried);
    refuse_overwriting(&planned, &args.inputs())?;
    prepare_outputs(&planned)?;
    let _lock = crate::folder::OutputLock::take(&args.output_dir)?;
    remove_earlier_outputs(&destination, &planned, &args.inputs())?;
    let (solve, matched, observation) = match &target {
        Target::Frame(_) => {
            let mut bar = SolveBar::new("solving", args.quiet);
            let solve = solver.solve_with_progress(&mut |step| bar.step(step));
            bar.finish();
            (solve?, None::<MatchReport>, None)
        }
        Target::Match { observation, .. } => {
            let started = std::time::Instant::now();
            let matching = args.matching();
            let report =
                progress::busy(args.quiet, "matching the skin to the observation", |_| {
                    match_observation(&mut solver, &model, observation, &matching)
                })?;
            let mut solve = report.last.clone();
            solve.iterations = report.iterations;
            solve.seconds = started.elapsed().as_secs_f64();
            let mut described =
                observe::ObservationReport::of(observation, &report, args.noise, &model);
            described.alignment = aligned.as_ref().map(observe::Alignment::of);
            (solve, Some(report), Some(described))
        }
    };
    let deformed = matched.as_ref().map_or(placed, |m| &m.surface);
    let answer = uncertain::Answer {
        converged: solve.converged,
        deformed,
        unloaded: posture.as_ref().and_then(|p| p.unloaded.as_ref()),
        held_by: matched.as_ref().map(|m| &m.held),
    };
    let mut explorer = priors.map(Explorer::new);
    let uncertainty = uncertain::regions_after(
        explorer.as_mut(),
        answer,
        (&mut solver, &model),
        &carried,
        args.quiet,
    )?;
    let report = write_solution(
        destination,
        &model,
        &solver,
        deformed,
        &carried,
        Solved {
            params: &params,
            solve,
            posture: posture.as_ref().map(|p| &p.report),
            observation,
            uncertainty: uncertainty.as_ref(),
        },
    )?;
    if !args.quiet {
        println!(
            "deformed {} particles to follow {}",
            report.particles, report.surface
        );
        for line in report.summary("  ") {
            println!("{line}");
        }
        println!("  wrote {}", report.files.join(", "));
    }
    let message = match report.status {
        Status::Converged => return Ok(()),
        Status::Flagged => format!(
            "the solve converged, but its result is flagged ({}): {}",
            args.output_dir.display(),
            report.flags().join("; ")
        ),
        _ if !report.unloaded_converged() => format!(
            "the organ's unloaded shape was NOT found: loaded again with the rest posture's \
             gravity it misses the rest surface by {:.3} (RMS; 0.1 mm asked); the results in {} \
             are not final",
            report
                .posture
                .as_ref()
                .and_then(|p| p.unloaded_residual_mm)
                .unwrap_or(f32::NAN),
            args.output_dir.display()
        ),
        _ => format!(
            "the solve did NOT converge in {} iterations (error estimate {:.1e} of the size); \
             the results in {} are not final: {}",
            report.iterations,
            report.residual,
            args.output_dir.display(),
            remedy(report.stopped_by)
        ),
    };
    Err(Unfinished {
        status: report.status,
        message,
    }
    .into())
}

#[cfg(test)]
mod tests {
    use super::args::{Descent, Force};
    use super::*;
    use tissue::deformation::ElasticSolve;

    /// A GPU without room (out of memory, a limit), under any context, is
    /// what `auto` falls back on; a lost device or another error is not.
    #[test]
    fn only_a_gpu_without_room_is_a_reason_to_fall_back() {
        let gpu = |kind| {
            anyhow::Error::from(tissue::Error::Gpu {
                context: "preparing stage 2 on a GPU".into(),
                kind,
                source: "what the GPU said".into(),
            })
            .context("model.vtp: cannot deform this model")
        };
        assert!(ran_out_on_gpu(&gpu(tissue::GpuFailure::OutOfMemory)));
        assert!(ran_out_on_gpu(&gpu(tissue::GpuFailure::LimitExceeded)));
        assert!(!ran_out_on_gpu(&gpu(tissue::GpuFailure::DeviceLost)));
        assert!(!ran_out_on_gpu(&anyhow!("out of memory, said in words")));
    }

    /// Without `--force` both commands solve with the elastic force, the
    /// library's default, with or without the posture options;
    /// `--force symmetric` and `--force paper` are refused only with them.
    #[test]
    fn the_elastic_force_is_the_default_and_the_others_are_chosen() {
        let args = |force, gravity: bool| SolveArgs {
            force,
            poisson: DeformParams::default().poisson,
            max_iterations: 100,
            tolerance: 1e-4,
            coarse: 2.0,
            elastic_solve: Descent::Chebyshev,
            observed: None,
            gravity: if gravity {
                GravityArgs {
                    gravity_rest: Some(Vec3::NEG_Z),
                    gravity_deformed: Some(Vec3::NEG_Y),
                    ..GravityArgs::default()
                }
            } else {
                GravityArgs::default()
            },
        };
        let force = |f, g| args(f, g).params().map(|p| p.force).ok();
        assert_eq!(force(None, false), Some(ForceModel::Elastic));
        assert_eq!(force(None, true), Some(ForceModel::Elastic));
        assert_eq!(
            force(Some(Force::Symmetric), false),
            Some(ForceModel::Symmetric)
        );
        assert_eq!(force(Some(Force::Paper), false), Some(ForceModel::Paper));
        assert_eq!(force(Some(Force::Symmetric), true), None);
    }

    /// Both commands solve two-level with the library's cell unless told
    /// otherwise, and a cell below one connection length is refused.
    #[test]
    fn coarse_defaults_to_the_library_cell_and_refuses_tiny_cells() {
        let args = |coarse| SolveArgs {
            force: Some(Force::Symmetric),
            poisson: DeformParams::default().poisson,
            max_iterations: 100,
            tolerance: 1e-4,
            coarse,
            elastic_solve: Descent::Chebyshev,
            observed: None,
            gravity: GravityArgs::default(),
        };
        let coarse = |given| args(given).params().map(|p| p.tuning.coarse);
        assert_eq!(coarse(2.0).ok(), Some(2.0));
        assert_eq!(coarse(0.0).ok(), Some(0.0));
        let refused = coarse(0.5).err().map(|e| e.to_string());
        assert!(
            refused
                .as_deref()
                .is_some_and(|e| e.contains("coarse is 0.5")),
            "{refused:?}"
        );
    }

    /// `--elastic-solve` defaults to the library's choice and passes the
    /// one given on to the parameters.
    #[test]
    fn the_elastic_solve_is_the_librarys_unless_chosen() {
        use clap::Parser;
        #[derive(Parser)]
        struct Command {
            #[command(flatten)]
            solve: SolveArgs,
        }
        let solve = |extra: &[&str]| {
            let mut words = vec!["tissue"];
            words.extend_from_slice(extra);
            Command::try_parse_from(words)
                .map_err(|e| e.to_string())
                .and_then(|c| c.solve.params().map_err(|e| e.to_string()))
                .map(|p| p.tuning.elastic_solve)
        };
        assert_eq!(solve(&[]), Ok(DeformParams::default().tuning.elastic_solve));
        assert_eq!(
            solve(&["--elastic-solve", "conjugate-gradient"]),
            Ok(ElasticSolve::ConjugateGradient)
        );
        assert_eq!(
            solve(&["--elastic-solve", "chebyshev"]),
            Ok(ElasticSolve::Chebyshev)
        );
        assert_eq!(
            solve(&["--elastic-solve", "chebyshev-then-conjugate-gradient"]),
            Ok(ElasticSolve::ChebyshevThenConjugateGradient)
        );
        assert!(solve(&["--elastic-solve", "newton"]).is_err());
    }
}
