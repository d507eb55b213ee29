//! The Python extension module `tissue._tissue`: stage 1 and stage 2 of
//! [`tissue`] on numpy arrays. The package `tissue` (`python/tissue`)
//! re-exports it; its docstrings are the Python API's documentation.
//!
//! Every call that computes releases the GIL; every error of the library
//! is raised as `tissue.TissueError` with the library's own message.

use std::path::PathBuf;

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use tissue::backend::{Backend, Device, Solver, with_cpu_fallback};
use tissue::deformation::{DeformParams, ForceModel};
use tissue::gravity::{
    FIT_PARTICLES, Gravity, HELD_SPACINGS, held_vertices, observed_frame, unload,
};
use tissue::observation::{HELD_TOLERANCE, MatchParams, Observation};
use tissue::{Error, ParticleModel, SamplingParams, SamplingReport, Vec3};

mod convert;
mod deformer;
mod observation;

use convert::{
    Callback, array_of, as_dict, deformed_surface, held_of, mesh_tuple, raise, surface_of,
    vertex_mask, warn,
};
use deformer::{Deformer, save_motion};

/// What `Model.deformer_in_posture` is given as the deformed posture's
/// skin.
enum Target {
    /// The rest surface with moved vertices.
    Frame(tissue::SurfaceMesh),
    /// Another closed surface of the organ, and it as an observation.
    Other(tissue::SurfaceMesh, Observation),
    /// A scan of part of the skin.
    Scan(Observation),
}

impl Target {
    /// `deformed` for `model`: with `scan`, a scan's points (a path or an
    /// `(n, 3)` array); else a frame of the rest surface where it is one,
    /// or else another closed surface of the organ.
    fn of(
        model: &ParticleModel,
        deformed: &Bound<'_, PyAny>,
        scan: bool,
        noise: Option<f32>,
    ) -> PyResult<Self> {
        if scan {
            return Ok(Self::Scan(observation::scan_of(model, deformed, noise)?));
        }
        match deformed_surface(&model.surface, deformed) {
            Ok(frame) if noise.is_none() => Ok(Self::Frame(frame)),
            Ok(_) => Err(raise(
                "noise= is for an observation without correspondence; the deformed surface is \
                 the model's rest surface with moved vertices, which the skin follows vertex by \
                 vertex",
            )),
            Err(not_a_frame) => match observation::other_surface_of(deformed) {
                Ok((mesh, observation)) => Ok(Self::Other(mesh, observation)),
                Err(_) => Err(not_a_frame),
            },
        }
    }

    /// The observation without correspondence, where it is one.
    fn observation(&self) -> Option<&Observation> {
        match self {
            Self::Frame(_) => None,
            Self::Other(_, observation) | Self::Scan(observation) => Some(observation),
        }
    }
}

create_exception!(
    _tissue,
    TissueError,
    PyException,
    "A tissue error: bad input (a mesh, a file, a parameter) or a failed computation; the message names the problem."
);

fn device_of(backend: &str) -> PyResult<Device> {
    Ok(picked(backend)?.1)
}

/// The backend `backend` names and the device it picks.
fn picked(backend: &str) -> PyResult<(Backend, Device)> {
    let backend: Backend = backend.parse().map_err(raise)?;
    Ok((backend, Device::pick(backend).map_err(raise)?.device))
}

/// Stage 1: fills a closed surface (a file path, or a `(vertices,
/// triangles)` pair of arrays) with `particles` particles. `progress`, if
/// given, is called after every iteration (on the GPU, every batch of
/// them) with a dict: `iteration`, `max_iterations`, `step_rms`,
/// `radius_rms`.
#[pyfunction]
#[pyo3(signature = (surface, particles, seed = 0, backend = "auto", progress = None))]
fn sample(
    py: Python<'_>,
    surface: &Bound<'_, PyAny>,
    particles: i64,
    seed: u64,
    backend: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<Model> {
    let particles = usize::try_from(particles)
        .ok()
        .filter(|&n| n >= 4)
        .ok_or_else(|| raise(format!("particles is {particles}, expected at least 4")))?;
    let surface = surface_of(surface)?;
    let params = SamplingParams::with_particles(particles).with(|p| {
        p.seed = seed;
    });
    let device = device_of(backend)?;
    let mut callback = Callback::new(progress.as_ref());
    let sampled = py
        .detach(|| {
            tissue::backend::sample_on(&device, &surface, &params, &mut |p| {
                callback.tell(|info| {
                    info.set_item("iteration", p.iteration)?;
                    info.set_item("max_iterations", p.max_iterations)?;
                    info.set_item("step_rms", p.step_rms)?;
                    info.set_item("radius_rms", p.radius_rms)
                });
            })
        })
        .map_err(raise)?;
    callback.result()?;
    Ok(Model {
        model: sampled.model,
        report: Some(sampled.report),
    })
}

/// Reads a model written by `Model.save` or `tissue sample -o`.
#[pyfunction]
fn load_model(path: PathBuf) -> PyResult<Model> {
    let model = tissue::load_model(&path).map_err(raise)?;
    Ok(Model {
        model,
        report: None,
    })
}

/// The bundled breast phantom's skin (millimetres), as `(vertices, triangles)`.
#[pyfunction]
fn phantom_breast<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
    mesh_tuple(py, &tissue::phantom::default_breast())
}

/// The phantom's skin sagged by 12 mm (`tissue demo`'s sag), the same
/// triangles as `phantom_breast`.
#[pyfunction]
fn phantom_breast_sagged<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
    mesh_tuple(py, &tissue::deform::sagged_breast())
}

/// A particle model: the particles at rest, their connections and the
/// surface they were sampled in.
#[pyclass(module = "tissue._tissue", frozen)]
struct Model {
    model: ParticleModel,
    report: Option<SamplingReport>,
}

#[pymethods]
impl Model {
    fn __len__(&self) -> usize {
        self.model.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "<tissue.Model: {} particles, {} surface vertices>",
            self.model.len(),
            self.model.surface.vertices.len()
        )
    }

    /// The particles at rest, `(n, 3)`.
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        array_of(py, &self.model.positions)
    }

    /// Each particle's radius, `(n,)`.
    #[getter]
    fn radii<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let radii: Vec<f64> = self.model.radii.iter().map(|&r| f64::from(r)).collect();
        PyArray1::from_vec(py, radii)
    }

    /// Whether each particle lies on the surface (attached to a triangle), `(n,)`.
    #[getter]
    fn on_surface<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        let on: Vec<bool> = self.model.attachments.iter().map(Option::is_some).collect();
        PyArray1::from_vec(py, on)
    }

    /// The surface the model was sampled in, `(vertices, triangles)`.
    #[getter]
    fn surface<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        mesh_tuple(py, &self.model.surface)
    }

    /// Stage 1's quality report (a dict), or None for a model read from a file.
    #[getter]
    fn report(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        self.report.as_ref().map(|r| as_dict(py, r)).transpose()
    }

    /// Writes the model by the name's extension: `.vtp` the whole model
    /// (what `load_model` reads), `.csv` or `.ply` the particles'
    /// positions alone; an existing file is replaced only once the new one
    /// is complete.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| tissue::export_model(&self.model, &path))
            .map_err(raise)
    }

    /// The connections between particles, `(m, 2)` particle indices, each
    /// pair once.
    #[getter]
    fn connections<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let pairs = self.model.connections.pair_list();
        let flat: Vec<i64> = pairs
            .iter()
            .flat_map(|&(i, j)| [i64::from(i), i64::from(j)])
            .collect();
        PyArray1::from_vec(py, flat).reshape([pairs.len(), 2])
    }

    /// Prepares stage 2 on `backend` (`"auto"`, `"gpu"` or `"cpu"`) with the
    /// force `"elastic"` (the default, with `poisson`: the accurate one),
    /// `"symmetric"` (the fastest frame, without a volume term) or
    /// `"paper"`; `max_iterations` caps every solve.
    /// `progress`, if given, is called as each stage of the preparation
    /// starts with a dict: `stage` (`plan`, `elastic_model`, `upload`,
    /// `coarse_space`, `elastic_coarse`) and
    /// `description`. `observed`: the surface vertices the deformed
    /// surfaces observe (`tissue deform --observed`), as indices or one
    /// flag per vertex; the rest of the skin is free, the mechanics
    /// deciding where it goes. None: all.
    #[pyo3(signature = (backend = "auto", force = "elastic", poisson = None, max_iterations = None, progress = None, observed = None))]
    #[allow(clippy::too_many_arguments, reason = "Python keyword arguments")]
    fn deformer(
        &self,
        py: Python<'_>,
        backend: &str,
        force: &str,
        poisson: Option<f32>,
        max_iterations: Option<usize>,
        progress: Option<Py<PyAny>>,
        observed: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Deformer> {
        let mut params = params_of(force, poisson, max_iterations)?;
        if let Some(observed) = observed {
            let vertices = self.model.surface.vertices.len();
            params.observed = Some(vertex_mask(observed, vertices, "observed")?);
        }
        let (backend, device) = picked(backend)?;
        let mut callback = Callback::new(progress.as_ref());
        let (solver, fell_back) = py
            .detach(|| {
                // `auto` runs on the CPU where the GPU it picked has no room.
                with_cpu_fallback(backend, device, Error::is_gpu_capacity, |device| {
                    Solver::new_with_progress(device, &self.model, params.clone(), &mut |stage| {
                        callback.tell(|info| {
                            info.set_item("stage", stage.name())?;
                            info.set_item("description", stage.to_string())
                        });
                    })
                })
            })
            .map_err(raise)?;
        callback.result()?;
        if let Some(why) = fell_back {
            warn(py, &why)?;
        }
        Ok(Deformer {
            solver,
            model: self.model.clone(),
            spacing: self.model.mean_connection_length(),
            deformed: None,
            posture: None,
            guess: None,
            rest_load: None,
            held_by: None,
            explorer: None,
        })
    }

    /// Prepares stage 2 for a scan in another posture, with gravity
    /// (`tissue deform --gravity-rest --gravity-deformed`): the organ's
    /// unloaded shape from this model (the rest scan) under
    /// `gravity_rest`, Young's modulus `stiffness_kpa` or, without it,
    /// fitted so that `gravity_deformed` best gives the skin `deformed`
    /// (the deformed scan's skin, as `Deformer.solve` takes it: a file
    /// path, a `(vertices, triangles)` pair, or the `(v, 3)` vertices in
    /// the model's order), and a
    /// deformer stress-free in the unloaded shape with the deformed
    /// posture's gravity inside; solve it with `deformed`. Gravity vectors
    /// are in units of g in the model's axes (`(0, 0, -1)`: along -z);
    /// `density` in kg/m^3; `unit` the model's length unit (`"mm"`,
    /// `"cm"` or `"m"`). `held`: the surface vertices that do not move
    /// between the scans (the chest wall), as indices or one flag per
    /// vertex; `None` finds them, those that move less than a thousandth
    /// of a connection length. The elastic force always. `progress`, if
    /// given, is called after each of the search's solves with a dict:
    /// `solve`, `iterations`, `converged`, `elastic_retries`, `backtracks`.
    /// The deformer's `posture` says what was found (its `elastic_retries`
    /// and `backtracks` over all the solves). Where gravity does not change and no stiffness is
    /// given there is no load to fit: a RuntimeWarning, and the deformer
    /// is the plain elastic one. An unloaded shape not found within 0.1 mm
    /// also warns, and so does a match without gravity (another surface,
    /// or a scan) that stopped short of its answer, which the stiffness
    /// is then fitted from (`posture["first_match_converged"]` False;
    /// None for a frame of the rest surface). `fit_particles`: the stiffness is fitted on a model of
    /// that many particles sampled on the same surface where this one has
    /// at least twice as many, this model's unloaded shape then found at
    /// the fitted stiffness (several times faster; docs/METHOD.md);
    /// `None` fits on this model.
    ///
    /// `deformed` may also be an observation without correspondence
    /// (`tissue deform --surface` of another triangulation, or `--cloud`
    /// with `scan=True`): another closed surface of the organ, or with
    /// `scan=True` a scan of part of the skin (a file path or an `(n, 3)`
    /// array of points; it needs `held`), with its noise scale `noise`.
    /// The skin is then matched to it without gravity first, the stiffness
    /// fitted to where that put the skin it saw; match the deformer to the
    /// same observation (`Deformer.match_observation`), which starts from
    /// the fit's guess with the deformed posture's gravity inside. `held`
    /// found for another surface: the rest vertices on it.
    #[pyo3(signature = (
        deformed,
        gravity_rest,
        gravity_deformed,
        density = 1000.0,
        stiffness_kpa = None,
        held = None,
        unit = "mm",
        backend = "auto",
        poisson = None,
        max_iterations = None,
        progress = None,
        fit_particles = Some(FIT_PARTICLES),
        scan = false,
        noise = None
    ))]
    #[allow(clippy::too_many_arguments, reason = "Python keyword arguments")]
    fn deformer_in_posture(
        &self,
        py: Python<'_>,
        deformed: &Bound<'_, PyAny>,
        gravity_rest: [f32; 3],
        gravity_deformed: [f32; 3],
        density: f32,
        stiffness_kpa: Option<f32>,
        held: Option<&Bound<'_, PyAny>>,
        unit: &str,
        backend: &str,
        poisson: Option<f32>,
        max_iterations: Option<usize>,
        progress: Option<Py<PyAny>>,
        fit_particles: Option<usize>,
        scan: bool,
        noise: Option<f32>,
    ) -> PyResult<Deformer> {
        let params = params_of("elastic", poisson, max_iterations)?;
        let metres_per_unit = match unit {
            "mm" => 1e-3,
            "cm" => 1e-2,
            "m" => 1.0,
            other => {
                return Err(raise(format!(
                    "unknown unit `{other}`, expected mm, cm or m"
                )));
            }
        };
        let gravity = Gravity {
            rest: Vec3::from(gravity_rest),
            deformed: Vec3::from(gravity_deformed),
            density_kg_m3: density,
            stiffness_kpa,
            metres_per_unit,
            fit_particles,
        };
        gravity.validate().map_err(raise)?;
        let surface = &self.model.surface;
        let spacing = self.model.mean_connection_length();
        let target = Target::of(&self.model, deformed, scan, noise)?;
        let held = match (held, &target) {
            (Some(held), _) => held_of(held, surface.vertices.len())?,
            (None, Target::Frame(deformed)) => {
                held_vertices(surface, deformed, HELD_SPACINGS * spacing).ok_or_else(|| {
                    raise("the deformed surface has other vertices than the model's")
                })?
            }
            (None, Target::Other(mesh, _)) => {
                tissue::observation::held_on(mesh, surface, HELD_TOLERANCE * spacing)
                    .map_err(|e| raise(format!("{e} with held=")))?
            }
            (None, Target::Scan(_)) => {
                return Err(raise(
                    "a scan of part of the skin needs the region held at rest (the chest wall) \
                     as held=",
                ));
            }
        };
        // An observation is matched to the model held where `held` says.
        let params = match target.observation() {
            Some(_) => params.with(|p| p.observed = Some(held.clone())),
            None => params,
        };
        if !held.contains(&true) {
            return Err(raise(
                "no surface vertex is held between the two scans (none moved less than a \
                 thousandth of a connection length): the unloaded shape needs the surface that \
                 does not move, e.g. the chest wall; give it with held=",
            ));
        }
        let (backend, device) = picked(backend)?;
        let model = &self.model;
        if !gravity.changes() && gravity.stiffness_kpa.is_none() {
            warn(
                py,
                "gravity does not change between the postures: the skin says nothing about the \
                 stiffness, and no load is fitted; the deformer is the plain elastic one (give \
                 stiffness_kpa to solve from the unloaded shape anyway)",
            )?;
            let (solver, fell_back) = py
                .detach(|| {
                    with_cpu_fallback(backend, device, Error::is_gpu_capacity, |device| {
                        Solver::new(device, model, params.clone())
                    })
                })
                .map_err(raise)?;
            if let Some(why) = fell_back {
                warn(py, &why)?;
            }
            let posture = PyDict::new(py);
            posture.set_item("stiffness_kpa", py.None())?;
            posture.set_item("stiffness_fitted", false)?;
            posture.set_item("held_vertices", held.iter().filter(|&&h| h).count())?;
            return Ok(Deformer {
                solver,
                model: self.model.clone(),
                spacing: self.model.mean_connection_length(),
                deformed: None,
                posture: Some(posture.unbind().into_any()),
                guess: None,
                rest_load: None,
                held_by: None,
                explorer: None,
            });
        }
        let mut callback = Callback::new(progress.as_ref());
        // `auto` runs the posture on the CPU where the GPU it picked has no room.
        let ((unloaded, solver, deformed, first), fell_back) = py
            .detach(|| {
                with_cpu_fallback(backend, device, Error::is_gpu_capacity, |device| {
                    // An observation's frame: where it puts the skin
                    // without gravity, the fit's targets the skin it saw.
                    let (deformed, fit_params, first) = match &target {
                        Target::Frame(deformed) => (deformed.clone(), params.clone(), None),
                        Target::Other(_, observation) | Target::Scan(observation) => {
                            let matching = MatchParams {
                                noise,
                                ..MatchParams::default()
                            };
                            let observed =
                                observed_frame(&device, model, observation, &params, &matching)?;
                            let seen = observed.seen;
                            let first = (observed.report.converged, observed.report.last.residual);
                            (
                                observed.frame,
                                params.clone().with(|p| p.observed = Some(seen)),
                                Some(first),
                            )
                        }
                    };
                    let unloaded = unload(
                        &device,
                        model,
                        &deformed,
                        &held,
                        &gravity,
                        &fit_params,
                        &mut |p| {
                            callback.tell(|info| {
                                info.set_item("solve", p.solve)?;
                                info.set_item("iterations", p.iterations)?;
                                info.set_item("converged", p.converged)?;
                                info.set_item("elastic_retries", p.elastic_retries)?;
                                info.set_item("backtracks", p.backtracks)
                            });
                        },
                    )?;
                    let params = params.clone().with(|p| p.load = unloaded.deformed_load);
                    let solver =
                        Solver::unloaded(device, model, &unloaded.shape.positions, params)?;
                    Ok::<_, tissue::Error>((unloaded, solver, deformed, first))
                })
            })
            .map_err(raise)?;
        callback.result()?;
        if let Some(why) = fell_back {
            warn(py, &why)?;
        }
        if let Some((false, residual)) = first {
            warn(
                py,
                &format!(
                    "the match without gravity that the stiffness was fitted from stopped short \
                     of its answer (error estimate {residual:.1e} of the size): the fit, and the \
                     answer from it, are not final"
                ),
            )?;
        }
        if !unloaded.shape.converged {
            warn(
                py,
                &format!(
                    "the unloaded shape was not found within 0.1 mm: loaded again it is {:.3e} \
                     model units (RMS) from the rest surface",
                    unloaded.shape.residual
                ),
            )?;
        }
        let posture = PyDict::new(py);
        posture.set_item("stiffness_kpa", unloaded.stiffness_kpa)?;
        posture.set_item("stiffness_fitted", unloaded.fit.is_some())?;
        posture.set_item("fit_residual", unloaded.fit.as_ref().map(|f| f.residual))?;
        posture.set_item("fit_particles", unloaded.fit.as_ref().map(|f| f.particles))?;
        let trials: Vec<(f32, Option<f32>)> = unloaded
            .fit
            .iter()
            .flat_map(|f| &f.trials)
            .map(|t| {
                (
                    t.stiffness_kpa,
                    t.residual.is_finite().then_some(t.residual),
                )
            })
            .collect();
        posture.set_item("fit_trials", trials)?;
        posture.set_item("unloaded_residual", unloaded.shape.residual)?;
        posture.set_item("unloaded_converged", unloaded.shape.converged)?;
        posture.set_item("held_vertices", held.iter().filter(|&&h| h).count())?;
        posture.set_item("solves", unloaded.solves)?;
        posture.set_item("elastic_retries", unloaded.elastic_retries)?;
        posture.set_item("backtracks", unloaded.backtracks)?;
        let load = unloaded.deformed_load;
        posture.set_item("load", (load.x, load.y, load.z))?;
        posture.set_item(
            "first_match_converged",
            first.map(|(converged, _)| converged),
        )?;
        Ok(Deformer {
            solver,
            model: self.model.clone(),
            spacing: self.model.mean_connection_length(),
            deformed: None,
            posture: Some(posture.unbind().into_any()),
            guess: unloaded
                .deformed_guess
                .map(|guess| (deformed.vertices.clone(), guess)),
            rest_load: Some(unloaded.rest_load),
            held_by: None,
            explorer: None,
        })
    }
}

/// Stage 2's parameters from the Python keywords.
fn params_of(
    force: &str,
    poisson: Option<f32>,
    max_iterations: Option<usize>,
) -> PyResult<DeformParams> {
    let force = match force {
        "symmetric" => ForceModel::Symmetric,
        "elastic" => ForceModel::Elastic,
        "paper" => ForceModel::Paper,
        other => {
            return Err(raise(format!(
                "unknown force `{other}`, expected symmetric, elastic or paper"
            )));
        }
    };
    Ok(DeformParams::default().with(|p| {
        p.force = force;
        p.poisson = poisson.unwrap_or(p.poisson);
        p.max_iterations = max_iterations.unwrap_or(p.max_iterations);
    }))
}

#[pymodule]
fn _tissue(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TissueError", m.py().get_type::<TissueError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(sample, m)?)?;
    m.add_function(wrap_pyfunction!(load_model, m)?)?;
    m.add_function(wrap_pyfunction!(phantom_breast, m)?)?;
    m.add_function(wrap_pyfunction!(phantom_breast_sagged, m)?)?;
    m.add_function(wrap_pyfunction!(save_motion, m)?)?;
    m.add_function(wrap_pyfunction!(observation::load_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(observation::rigid_fit, m)?)?;
    m.add_function(wrap_pyfunction!(observation::fiducial_fit, m)?)?;
    m.add_class::<Model>()?;
    m.add_class::<Deformer>()?;
    Ok(())
}
