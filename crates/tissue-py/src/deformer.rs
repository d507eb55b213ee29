//! `tissue.Deformer`: stage 2 of one model from Python, and the files its
//! results go to.

use std::path::PathBuf;

use numpy::{
    AllowTypeChange, PyArray1, PyArray2, PyArrayLike2, PyArrayMethods, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use tissue::backend::Solver;
use tissue::io::space::Space;
use tissue::observation::{MatchParams, match_observation};
use tissue::{ParticleModel, SurfaceMesh, Vec3};

use crate::convert::{
    Callback, Points, array_of, as_dict, deformed_surface, points_from, raise, warn,
};

/// Stage 2 of one model: the surface particles follow a deformed surface
/// and the interior follows them.
#[pyclass(module = "tissue._tissue")]
pub(crate) struct Deformer {
    pub(crate) solver: Solver,
    /// The model: deformed surfaces are matched to its rest surface,
    /// carried points checked against it, results written with it.
    pub(crate) model: ParticleModel,
    /// The model's mean connection length.
    pub(crate) spacing: f32,
    /// The deformed surface of the last solve.
    pub(crate) deformed: Option<SurfaceMesh>,
    /// What `Model.deformer_in_posture` found.
    pub(crate) posture: Option<Py<PyAny>>,
    /// The fit's deformed surface and where it put the particles
    /// (`Unloaded::deformed_guess`): the first solve of that surface
    /// starts there.
    pub(crate) guess: Option<(Vec<Vec3>, Vec<Vec3>)>,
    /// The rest posture's load, where the deformer solves a posture with
    /// gravity (`Unloaded::rest_load`).
    pub(crate) rest_load: Option<Vec3>,
    /// Where the last answer was a match without correspondence, the
    /// observation as its skin was paired with it: the uncertainty's
    /// re-solves pair it again.
    pub(crate) held_by: Option<tissue::observation::HeldObservation>,
    /// The last `uncertainty` call's explorer: a call with the same priors
    /// starts from it (a sequence's next frame).
    pub(crate) explorer: Option<tissue::uncertainty::Explorer>,
}

impl Deformer {
    /// Raises for a point no particle can carry (more than
    /// [`FARTHEST_DIAGONALS`] of the organ's sizes away: another unit, or
    /// mistyped); warns (RuntimeWarning) of points outside the model's rest
    /// surface by more than a particle spacing, as `tissue deform` flags
    /// them: they are carried by extrapolation.
    fn check_inside(&self, py: Python<'_>, points: &[Vec3], what: &str) -> PyResult<()> {
        let Some((lo, hi)) = self.model.surface.bounds() else {
            return Ok(());
        };
        let (centre, diagonal) = (0.5 * (lo + hi), (hi - lo).length());
        if let Some((k, p)) = points.iter().enumerate().find(|(_, p)| {
            let d = p.distance(centre);
            d.is_nan() || d > FARTHEST_DIAGONALS * diagonal
        }) {
            return Err(raise(format!(
                "{what}: point {k} is at {p}, more than {FARTHEST_DIAGONALS} times the organ's \
                 size ({diagonal:.3}) from it: no particle can carry it; is it in another unit, \
                 or mistyped?"
            )));
        }
        let distances = py
            .detach(|| tissue::field::distances_outside(&self.model.surface, points))
            .map_err(raise)?;
        let tolerance = self.spacing.max(1e-6 * diagonal);
        let outside: Vec<f32> = distances.into_iter().filter(|&d| d > tolerance).collect();
        if !outside.is_empty() {
            warn(
                py,
                &format!(
                    "{} of {} {what} lie outside the model's rest surface, up to {:.2} (more \
                     than one particle spacing, {tolerance:.2}): they are carried by \
                     extrapolation; check their frame and units",
                    outside.len(),
                    points.len(),
                    outside.iter().copied().fold(0.0, f32::max)
                ),
            )?;
        }
        Ok(())
    }
}

/// Points farther than this many of the rest surface's diagonals from its
/// centre cannot be carried (as `tissue deform` refuses them).
pub(crate) const FARTHEST_DIAGONALS: f32 = 1000.0;

#[pymethods]
impl Deformer {
    fn __repr__(&self) -> String {
        format!(
            "<tissue.Deformer: {} particles on {}>",
            self.solver.positions().len(),
            self.solver.backend()
        )
    }

    /// What `Model.deformer_in_posture` found (a dict: `stiffness_kpa`,
    /// `stiffness_fitted`, `fit_residual` and `fit_trials` (model units,
    /// the free skin's RMS distance from the observed), `unloaded_residual`
    /// and `unloaded_converged`, `held_vertices`, `solves`, `load`), or
    /// None for a deformer without gravity.
    #[getter]
    fn posture(&self, py: Python<'_>) -> Option<Py<PyAny>> {
        self.posture.as_ref().map(|p| p.clone_ref(py))
    }

    /// Which device solves (`cpu`, or `gpu (adapter, API)`).
    #[getter]
    fn backend(&self) -> String {
        self.solver.backend()
    }

    /// Moves the surface to `surface` and solves; returns the report as a
    /// dict. `surface` is the deformed skin as a file path (any surface
    /// format), a `(vertices, triangles)` pair in the file's vertex order
    /// (as numpy, meshio or trimesh read it), or its `(v, 3)` vertices in
    /// the model's surface order: a mesh written by another tool is matched
    /// to the model's by its triangles, as `tissue deform` does. A solve that did not converge warns (RuntimeWarning) and
    /// says so in the report. `progress`, if given, is called after every
    /// iteration with a dict: `iteration`, `max_iterations`, `residual`
    /// (the error estimate, a fraction of the model's size).
    #[pyo3(signature = (surface, progress = None))]
    fn solve(
        &mut self,
        py: Python<'_>,
        surface: &Bound<'_, PyAny>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Py<PyAny>> {
        let deformed = deformed_surface(&self.model.surface, surface)?;
        let guess = self
            .guess
            .take()
            .filter(|(fitted, _)| *fitted == deformed.vertices)
            .map(|(_, guess)| guess);
        let solver = &mut self.solver;
        let mut callback = Callback::new(progress.as_ref());
        let report = py
            .detach(|| {
                solver.set_surface(&deformed)?;
                if let Some(guess) = &guess {
                    solver.warm_start(guess)?;
                }
                solver.solve_with_progress(&mut |step| {
                    callback.tell(|info| {
                        info.set_item("iteration", step.iteration)?;
                        info.set_item("max_iterations", step.max_iterations)?;
                        info.set_item("residual", step.residual)
                    });
                })
            })
            .map_err(raise)?;
        callback.result()?;
        self.deformed = Some(deformed);
        self.held_by = None;
        if !report.converged {
            let message = format!(
                "the solve did not converge: {} iterations, stopped by {:?}, estimated error {:e} of the size",
                report.iterations, report.stopped_by, report.residual
            );
            warn(py, &message)?;
        }
        as_dict(py, &report)
    }

    /// Matches the skin to an observation without correspondence and
    /// returns the report as a dict (`tissue deform --surface` of another
    /// triangulation, or `--cloud`): `surface`, a closed surface of the
    /// organ of any triangulation (a file path, a `(vertices, triangles)`
    /// pair, or a trimesh, meshio or pyvista mesh), or `cloud`, a scan of
    /// part of the skin (a file path or an `(n, 3)` array of points), one
    /// of the two. The deformer's `observed` vertices are the region held
    /// at rest (the chest wall: `model.deformer(observed=...)`); the rest
    /// of the skin is pulled onto the observation inside the elastic
    /// solve and slides along it where the mechanics sends it. `noise`:
    /// the observation's noise scale in the model's units (default: a
    /// tenth of a connection length for a surface, for a cloud the larger
    /// of a fifth of its spacing and its points' scatter about their
    /// neighbours' planes; at most a quarter of the organ's size). The report: `iterations`, `converged`, `skin`, `pulled`,
    /// `set_aside` (past a cloud's edge), `beyond_robust` (pulled with a
    /// bounded force, farther off than the robust scale), `outliers` (a
    /// cloud's points set aside), `kept_as_scanned` (a cloud sparse for
    /// the skin's curvature, its points not moved onto their neighbours'
    /// planes), `on_lines` (a cloud's points on lines of points, a
    /// stylus's strips, their normals the model's skin's),
    /// `residual_rms`, `residual_p95`, `residual_max` (the observed
    /// points' distances to the deformed skin), `volume_change`, `stages`.
    /// A match that did not converge, or whose residual is above three
    /// times the noise, warns (RuntimeWarning). `from_last=True` starts
    /// from where the deformer is (the last match's answer: a sequence's
    /// next frame, as `tissue track` matches it) in one solve at full
    /// weight, rather than from the start in four growing ones; with
    /// `predict` (the default) it starts where the last matches' changes
    /// put the skin on the observation, where that lowers the potential;
    /// it starts with the elastic correction the last match kept, if any,
    /// and keeps the one it ends with for the next frame.
    /// `surface_smoothing`: how a surface is paired, in its mean edges
    /// (default 1: the plane smoothed over its vertices; 0: the nearest
    /// point and the distance's curvature there).
    #[pyo3(signature = (surface = None, cloud = None, noise = None, from_last = false, surface_smoothing = None, predict = true))]
    #[allow(clippy::too_many_arguments, reason = "Python keyword arguments")]
    fn match_observation(
        &mut self,
        py: Python<'_>,
        surface: Option<&Bound<'_, PyAny>>,
        cloud: Option<&Bound<'_, PyAny>>,
        noise: Option<f32>,
        from_last: bool,
        surface_smoothing: Option<f32>,
        predict: bool,
    ) -> PyResult<Py<PyAny>> {
        let observation = match (surface, cloud) {
            (Some(surface), None) => crate::observation::other_surface_of(surface)?.1,
            (None, Some(cloud)) => crate::observation::scan_of(&self.model, cloud, noise)?,
            _ => {
                return Err(raise(
                    "give the observation as surface= or as cloud=, one of the two",
                ));
            }
        };
        // The first match after `Model.deformer_in_posture` starts where
        // its fit put the deformed posture.
        let guess = if from_last {
            None
        } else {
            self.guess.take().map(|(_, guess)| guess)
        };
        let (solver, model) = (&mut self.solver, &self.model);
        let params = if from_last {
            // A tracking frame keeps its elastic correction for the next.
            MatchParams {
                keep_correction: true,
                ..MatchParams::next_frame(noise)
            }
        } else {
            MatchParams {
                noise,
                ..MatchParams::default()
            }
        };
        let params = MatchParams {
            surface_smoothing: surface_smoothing.unwrap_or(params.surface_smoothing),
            predict,
            ..params
        };
        let report = py
            .detach(|| {
                solver.set_surface(&model.surface)?;
                if let Some(guess) = &guess {
                    solver.warm_start(guess)?;
                }
                match_observation(solver, model, &observation, &params)
            })
            .map_err(raise)?;
        let scale = noise.unwrap_or_else(|| {
            observation
                .cloud_noise()
                .unwrap_or(tissue::observation::SURFACE_NOISE * self.spacing)
        });
        if !report.converged {
            warn(
                py,
                &format!(
                    "the match did not converge: {} iterations, stopped by {:?}",
                    report.iterations, report.last.stopped_by
                ),
            )?;
        }
        if report.residual.rms > 3.0 * scale {
            warn(
                py,
                &format!(
                    "the model does not reach the observation: its points lie {:.3} from the \
                     deformed skin (RMS), more than three times the noise ({scale:.3})",
                    report.residual.rms
                ),
            )?;
        }
        let summary = serde_json::json!({
            "iterations": report.iterations,
            "converged": report.converged,
            "skin": report.skin,
            "pulled": report.pulled,
            "set_aside": report.set_aside,
            "beyond_robust": report.beyond_robust,
            "outliers": observation.outliers(),
            "kept_as_scanned": observation.kept_as_scanned(),
            "on_lines": observation.on_lines(),
            "residual_rms": report.residual.rms,
            "residual_p95": report.residual.p95,
            "residual_max": report.residual.max,
            "volume_change": report.volume_change,
            "stages": report.stages,
        });
        self.deformed = Some(report.surface);
        self.held_by = Some(report.held);
        as_dict(py, &summary)
    }

    /// How sure the last solve's answer is (`tissue deform
    /// --uncertainty`; docs/METHOD.md, "Uncertainty"): the answer solved
    /// again from itself over the Poisson ratio's range
    /// (`poisson_range`), the observed surface's error along its normals
    /// (`surface_noise` standard deviation and `surface_correlation`
    /// length in the model's units, `samples` samples from `seed`), and
    /// in a posture the load's relative spread (`load_spread`) and each
    /// posture's gravity direction (`gravity_spread`, degrees), without
    /// one an unmodelled change of posture (`posture_spread`, RMS in g:
    /// by default `sqrt(2)`, either posture's gravity in any direction). Returns
    /// a dict: `radius` (`(n,)`: each particle's 95 % radius),
    /// `covariance` (`(n, 6)`: xx, yy, zz, xy, xz, yz), `dominant` (each
    /// particle's unknown: `"poisson"`, `"surface"`, `"load"`,
    /// `"gravity"`, `"posture"`, or `None`), with `points` (`(k, 3)` at
    /// rest) `points_radius` and `points_covariance` likewise, and
    /// `solves`, `carried`, `iterations`, `seconds`, `converged`. Warns
    /// (RuntimeWarning) where a re-solve did not converge. After
    /// `match_observation`, re-solved with the skin paired with the
    /// observation as the match paired it (docs/METHOD.md, "Uncertainty"). A call with the
    /// priors of the last
    /// starts each re-solve from where the last call's ended (a tracked
    /// sequence's next frame: fewer iterations, the same regions within
    /// the solves' tolerance); with `refresh=N` such a call makes only
    /// `N` of its re-solves anew, in turn, and carries the others from the
    /// call that made them last (`tissue track --uncertainty-refresh`:
    /// docs/METHOD.md, "Uncertainty", *Tracking*).
    #[pyo3(signature = (points = None, samples = 16, surface_noise = 0.5,
                        surface_correlation = 10.0, poisson_range = (0.45, 0.495),
                        load_spread = 0.14, gravity_spread = 3.0,
                        posture_spread = tissue::uncertainty::POSTURE_G,
                        seed = tissue::uncertainty::SEED, refresh = None))]
    #[allow(clippy::too_many_arguments, reason = "Python keyword arguments")]
    fn uncertainty(
        &mut self,
        py: Python<'_>,
        points: Option<&Bound<'_, PyAny>>,
        samples: usize,
        surface_noise: f32,
        surface_correlation: f32,
        poisson_range: (f32, f32),
        load_spread: f32,
        gravity_spread: f32,
        posture_spread: f32,
        seed: u64,
        refresh: Option<usize>,
    ) -> PyResult<Py<PyAny>> {
        use pyo3::types::PyDict;
        use tissue::uncertainty::{
            Answered, Explorer, HeldBy, Priors, Refresh, Region, exact_vertices,
        };
        let refresh = match refresh {
            None => Refresh::all(),
            Some(0) => {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "refresh: a count of re-solves of at least 1, or None for all of them",
                ));
            }
            Some(count) => Refresh::every(count),
        };
        let deformed = self.solved()?.clone();
        let priors = Priors::default().with(|p| {
            p.samples = samples;
            p.surface_noise = surface_noise;
            p.surface_correlation = surface_correlation;
            p.poisson = poisson_range;
            p.load_spread = load_spread;
            p.gravity_degrees = gravity_spread;
            p.posture_g = posture_spread;
            p.seed = seed;
        });
        priors.validate().map_err(raise)?;
        let points = points.map(|p| points_from(p, "points")).transpose()?;
        if let Some(points) = &points {
            self.check_inside(py, points, "points")?;
        }
        // The last call's explorer where the priors are the same: its
        // re-solves start from the last answer's.
        let mut explorer = match self.explorer.take() {
            Some(explorer)
                if *explorer.priors() == priors
                    && explorer.refresh().per_answer() == refresh.per_answer() =>
            {
                explorer
            }
            _ => Explorer::new(priors).refreshing(refresh),
        };
        let (solver, model, rest_load) = (&mut self.solver, &self.model, self.rest_load);
        let held_by = self.held_by.as_ref();
        let (spread, carriers, explorer) = py
            .detach(move || {
                let carriers = match &points {
                    Some(points) => Some(solver.bind(points)?.carriers().to_vec()),
                    None => None,
                };
                let exact = exact_vertices(&model.surface, &deformed);
                let answered = Answered {
                    surface: &deformed,
                    exact: &exact,
                    rest_load,
                    metres_per_unit: 1e-3,
                    held_by: held_by.map(|h| h as &dyn HeldBy),
                };
                let spread = explorer.explore(solver, model, answered)?;
                Ok::<_, tissue::Error>((spread, carriers, explorer))
            })
            .map_err(raise)?;
        self.explorer = Some(explorer);
        if !spread.converged {
            warn(
                py,
                "not every solve of the uncertainty converged: its regions are not to be trusted",
            )?;
        }
        let out = PyDict::new(py);
        let fill = |regions: &[Region], prefix: &str| -> PyResult<()> {
            let radius: Vec<f64> = regions.iter().map(|r| f64::from(r.radius)).collect();
            let covariance: Vec<f64> = regions.iter().flat_map(|r| r.covariance).collect();
            out.set_item(format!("{prefix}radius"), PyArray1::from_vec(py, radius))?;
            out.set_item(
                format!("{prefix}covariance"),
                PyArray1::from_vec(py, covariance).reshape([regions.len(), 6])?,
            )?;
            let dominant: Vec<Option<&str>> = regions
                .iter()
                .map(|r| r.dominant.map(|u| u.name()))
                .collect();
            out.set_item(format!("{prefix}dominant"), dominant)
        };
        fill(&spread.particle_regions(), "")?;
        if let Some(carriers) = &carriers {
            let regions = spread.regions(&|positions: &[Vec3]| {
                carriers
                    .iter()
                    .map(|c| c.iter().map(|&(j, w)| w * positions[j as usize]).sum())
                    .collect()
            });
            fill(&regions, "points_")?;
        }
        out.set_item("solves", spread.solves)?;
        out.set_item("carried", spread.carried)?;
        out.set_item("iterations", spread.iterations)?;
        out.set_item("seconds", spread.seconds)?;
        out.set_item("converged", spread.converged)?;
        Ok(out.unbind().into_any())
    }

    /// The particles after the last solve, `(n, 3)`.
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        array_of(py, self.solver.positions())
    }

    /// Where points given at rest (`(k, 3)`, inside the model: a tumour's
    /// vertices, landmarks) are after the last solve, `(k, 3)`.
    fn carry<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'_, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let points = points_from(points, "points")?;
        self.check_inside(py, &points, "points")?;
        let solver = &self.solver;
        let moved = py
            .detach(|| {
                let bound = solver.bind(&points)?;
                solver.carry(&bound)
            })
            .map_err(raise)?;
        array_of(py, &moved)
    }

    /// How a rigid structure with rest vertices `vertices` (`(k, 3)`,
    /// inside the model: a tumour taken as rigid) moved in the last solve:
    /// its vertices moved, `(k, 3)`, and the motion as a 4x4 homogeneous
    /// matrix (rest coordinates to moved ones), a rotation about its rest
    /// centroid fitted to the particles around it and the centroid
    /// carried like a landmark (as `tissue deform --rigid-structure`).
    fn carry_rigid<'py>(
        &self,
        py: Python<'py>,
        vertices: &Bound<'_, PyAny>,
    ) -> PyResult<(Points<'py>, Points<'py>)> {
        let vertices = points_from(vertices, "vertices")?;
        if vertices.is_empty() {
            return Err(raise("a rigid structure needs at least one vertex"));
        }
        self.check_inside(py, &vertices, "the rigid structure's vertices")?;
        let solver = &self.solver;
        let motion = py
            .detach(|| {
                let bound = solver.bind_rigid(&vertices)?;
                solver.carry_rigid(&bound)
            })
            .map_err(raise)?;
        let moved: Vec<Vec3> = vertices.iter().map(|&x| motion.apply(x)).collect();
        let matrix: Vec<f64> = motion
            .homogeneous()
            .iter()
            .flatten()
            .map(|&v| f64::from(v))
            .collect();
        Ok((
            array_of(py, &moved)?,
            PyArray1::from_vec(py, matrix).reshape([4, 4])?,
        ))
    }

    /// Writes the last solve's result as `tissue deform` writes
    /// `particles.vtp`: the moved particles and the deformed surface with
    /// their `displacement` from rest (ParaView colours by it), tagged with
    /// `space` (`"lps"` or `"ras"`) for 3D Slicer.
    #[pyo3(signature = (path, space = "lps"))]
    fn save_particles(&self, py: Python<'_>, path: PathBuf, space: &str) -> PyResult<()> {
        let space: Space = space.parse().map_err(raise)?;
        let deformed = self.solved()?;
        let current = self.solver.positions();
        py.detach(|| {
            tissue::io::model::save_moved_particles_in(&self.model, current, deformed, space, &path)
        })
        .map_err(raise)
    }

    /// Writes the interior's displacement after the last solve on a grid of
    /// `spacing` (default: half the mean connection length) as a NRRD
    /// file 3D Slicer opens as a grid transform (`tissue deform
    /// --displacement-field`; docs/FORMATS.md), in `space`.
    #[pyo3(signature = (path, spacing = None, space = "lps"))]
    fn save_displacement_field(
        &self,
        py: Python<'_>,
        path: PathBuf,
        spacing: Option<f32>,
        space: &str,
    ) -> PyResult<()> {
        let space: Space = space.parse().map_err(raise)?;
        let deformed = self.solved()?;
        let spacing = spacing.unwrap_or(0.5 * self.spacing);
        let rotations = self.solver.rotations().map_err(raise)?;
        py.detach(|| {
            let field = tissue::resampling::resampling_field(
                self.solver.reference(),
                self.solver.positions(),
                &rotations,
                &self.model.connections,
                deformed,
                spacing,
            )
            .map_err(|e| format!("{}: {e}", path.display()))?;
            tissue::io::nrrd::save_displacement_field(&field, space, &path)
                .map_err(|e| e.to_string())
        })
        .map_err(raise)
    }

    /// Carries the landmarks of `points` (a 3D Slicer markups `.mrk.json`,
    /// in `space` unless the file says, or a `.csv` / `.ply` of points) to
    /// where the last solve moved them and writes them to `output` in the
    /// same form (a markups file keeps its labels and settings, as `tissue
    /// deform --points` writes it); returns them, `(k, 3)`. The output may
    /// not be the input.
    #[pyo3(signature = (points, output, space = "lps"))]
    fn carry_file<'py>(
        &self,
        py: Python<'py>,
        points: PathBuf,
        output: PathBuf,
        space: &str,
    ) -> PyResult<Points<'py>> {
        let space: Space = space.parse().map_err(raise)?;
        self.solved()?;
        let same = match (points.canonicalize(), output.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        };
        if same {
            return Err(raise(format!(
                "{}: the output would overwrite the points file; choose another path",
                output.display()
            )));
        }
        let markups = points
            .to_string_lossy()
            .to_ascii_lowercase()
            .ends_with(".json")
            .then(|| tissue::io::markups::load_markups(&points, space))
            .transpose()
            .map_err(raise)?;
        let rest = match &markups {
            Some(markups) => markups.points().to_vec(),
            None => tissue::load_points(&points).map_err(raise)?,
        };
        self.check_inside(py, &rest, "points")?;
        let solver = &self.solver;
        let moved = py
            .detach(|| {
                let bound = solver.bind(&rest)?;
                let moved = solver.carry(&bound)?;
                match &markups {
                    Some(markups) => tissue::io::markups::save_markups(markups, &moved, &output)?,
                    None => tissue::save_points(&moved, &output)?,
                }
                Ok::<_, tissue::Error>(moved)
            })
            .map_err(raise)?;
        array_of(py, &moved)
    }

    /// Back to rest: the next solve starts from the rest shape.
    fn reset(&mut self, py: Python<'_>) -> PyResult<()> {
        let solver = &mut self.solver;
        self.deformed = None;
        py.detach(|| solver.reset()).map_err(raise)
    }
}

impl Deformer {
    /// The last solve's deformed surface, or an error saying to solve first.
    fn solved(&self) -> PyResult<&SurfaceMesh> {
        self.deformed
            .as_ref()
            .ok_or_else(|| raise("nothing solved yet: call solve() first"))
    }
}

/// Writes a rigid structure's motion (the 4x4 matrix `Deformer.carry_rigid`
/// returns, rest to moved) as the ITK `.tfm` 3D Slicer and ITK read
/// (`tissue deform --rigid-structure` writes the same), in `space`.
#[pyfunction]
#[pyo3(signature = (matrix, path, space = "lps"))]
pub(crate) fn save_motion(
    py: Python<'_>,
    matrix: PyArrayLike2<'_, f64, AllowTypeChange>,
    path: PathBuf,
    space: &str,
) -> PyResult<()> {
    let space: Space = space.parse().map_err(raise)?;
    if matrix.shape() != [4, 4] {
        return Err(raise(format!(
            "a motion is a 4x4 matrix, got shape {:?}",
            matrix.shape()
        )));
    }
    let view = matrix.as_array();
    let mut rows = [[0f32; 4]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        for (c, value) in row.iter_mut().enumerate() {
            *value = view[[r, c]] as f32;
        }
    }
    let motion = tissue::io::itk::Affine::from_rows(&rows);
    py.detach(|| tissue::io::itk::save_motion_tfm(&motion, space, &path))
        .map_err(raise)
}
