//! The Python extension module `tissue._tissue`: stage 1 and stage 2 of
//! [`tissue`] on numpy arrays. The package `tissue` (`python/tissue`)
//! re-exports it; its docstrings are the Python API's documentation.
//!
//! Every call that computes releases the GIL; every error of the library
//! is raised as `tissue.TissueError` with the library's own message.

use std::path::PathBuf;

use numpy::{
    AllowTypeChange, PyArray1, PyArray2, PyArrayLike1, PyArrayLike2, PyArrayMethods,
    PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyRuntimeWarning};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use tissue::backend::{Backend, Device, Solver};
use tissue::deformation::{DeformParams, ForceModel};
use tissue::gravity::{FIT_PARTICLES, Gravity, HELD_SPACINGS, held_vertices, unload};
use tissue::io::space::Space;
use tissue::{ParticleModel, SamplingParams, SamplingReport, SurfaceMesh, Vec3};

create_exception!(
    _tissue,
    TissueError,
    PyException,
    "A tissue error: bad input (a mesh, a file, a parameter) or a failed computation; the message names the problem."
);

/// A library error as a Python exception.
fn raise(error: impl std::fmt::Display) -> PyErr {
    TissueError::new_err(error.to_string())
}

/// A serialisable report as a Python dict (through JSON, the CLI's form).
fn as_dict(py: Python<'_>, report: &impl serde::Serialize) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(report).map_err(raise)?;
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

/// An `(n, 3)` array of points: any array-like numpy converts to float64.
fn points_of(array: &PyArrayLike2<'_, f64, AllowTypeChange>, what: &str) -> PyResult<Vec<Vec3>> {
    let shape = array.shape();
    if shape[1] != 3 {
        return Err(raise(format!(
            "{what} must be an (n, 3) array, got shape ({}, {})",
            shape[0], shape[1]
        )));
    }
    let view = array.as_array();
    let points: Vec<Vec3> = view
        .rows()
        .into_iter()
        .map(|r| Vec3::new(r[0] as f32, r[1] as f32, r[2] as f32))
        .collect();
    if let Some(i) = points.iter().position(|p| !p.is_finite()) {
        return Err(raise(format!(
            "{what}: row {i} is not finite ({})",
            points[i]
        )));
    }
    Ok(points)
}

/// Points from any array-like: `(n, 3)`, or one point of 3 numbers.
fn points_from(object: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Vec3>> {
    if let Ok(array) = object.extract::<PyArrayLike2<'_, f64, AllowTypeChange>>() {
        return points_of(&array, what);
    }
    if let Ok(one) = object.extract::<PyArrayLike1<'_, f64, AllowTypeChange>>() {
        let values = one.as_array();
        if values.len() != 3 {
            return Err(raise(format!(
                "{what}: one point is 3 numbers, got {}",
                values.len()
            )));
        }
        let point = Vec3::new(values[0] as f32, values[1] as f32, values[2] as f32);
        if !point.is_finite() {
            return Err(raise(format!("{what}: the point is not finite ({point})")));
        }
        return Ok(vec![point]);
    }
    Err(raise(format!(
        "{what} must be an (n, 3) array of points, or one point of 3 numbers"
    )))
}

/// The surface `rest` deformed, from a file path (any surface format, as
/// `tissue deform --surface` reads it), a `(vertices, triangles)` pair or
/// a trimesh, meshio or pyvista mesh (in the file's vertex order), or
/// the `(v, 3)` vertices alone in the model's order: welded, turned and
/// renumbered by the triangles where another tool wrote the same mesh in
/// its own order (`SurfaceMesh::as_frame_of`), then checked to be `rest`
/// with moved vertices.
fn deformed_surface(rest: &SurfaceMesh, surface: &Bound<'_, PyAny>) -> PyResult<SurfaceMesh> {
    if let Some(pair) = pair_of_mesh_object(surface)? {
        let deformed = mesh_from_pair(&pair)?.as_frame_of(rest, false);
        tissue::deformation::check_same_topology(rest, &deformed)
            .map_err(|e| raise(format!("the deformed mesh: {e}")))?;
        return Ok(deformed);
    }
    let (deformed, what) = if let Ok(pair) = surface.cast::<PyTuple>() {
        (
            mesh_from_pair(pair)?.as_frame_of(rest, false),
            "the deformed surface".to_owned(),
        )
    } else if let Ok(path) = surface.extract::<PathBuf>() {
        let written = tissue::load_surface_as_written(&path).map_err(raise)?;
        let stl = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("stl"));
        (written.as_frame_of(rest, stl), path.display().to_string())
    } else {
        let vertices = points_from(surface, "deformed vertices")?;
        if vertices.len() != rest.vertices.len() {
            return Err(raise(format!(
                "the deformed surface has {} vertices, the model's surface {}: give the \
                 model's surface vertices in the same order, or the deformed mesh as \
                 (vertices, triangles) or a file path, matched by its triangles",
                vertices.len(),
                rest.vertices.len()
            )));
        }
        return Ok(SurfaceMesh::new(vertices, rest.triangles.clone()));
    };
    tissue::deformation::check_same_topology(rest, &deformed)
        .map_err(|e| raise(format!("{what}: {e}")))?;
    Ok(deformed)
}

/// `points` as an `(n, 3)` float64 array.
/// An `(n, k)` array of coordinates handed to Python.
type Points<'py> = Bound<'py, PyArray2<f64>>;

fn array_of<'py>(py: Python<'py>, points: &[Vec3]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = points
        .iter()
        .flat_map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)])
        .collect();
    PyArray1::from_vec(py, flat).reshape([points.len(), 3])
}

/// A mesh object of another Python library as a `(vertices, triangles)`
/// pair: trimesh's `Trimesh` (`vertices`, `faces`), meshio's `Mesh`
/// (`points`, `cells_dict["triangle"]`) or pyvista's `PolyData` (`points`,
/// `regular_faces`); `None` for anything else.
fn pair_of_mesh_object<'py>(object: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyTuple>>> {
    let py = object.py();
    let pair = |vertices: Bound<'py, PyAny>, triangles: Bound<'py, PyAny>| {
        PyTuple::new(py, [vertices, triangles]).map(Some)
    };
    if object.cast::<PyTuple>().is_ok() || object.extract::<PathBuf>().is_ok() {
        return Ok(None);
    }
    if object.hasattr("vertices")? && object.hasattr("faces")? {
        return pair(object.getattr("vertices")?, object.getattr("faces")?);
    }
    if object.hasattr("points")? && object.hasattr("cells_dict")? {
        let cells = object.getattr("cells_dict")?;
        let triangles = cells.get_item("triangle").map_err(|_| {
            raise("the meshio mesh has no triangle cells (cells_dict[\"triangle\"])")
        })?;
        return pair(object.getattr("points")?, triangles);
    }
    if object.hasattr("points")? && object.hasattr("regular_faces")? {
        let faces = object.getattr("regular_faces").map_err(|e| {
            raise(format!(
                "the pyvista mesh's faces are not all triangles (triangulate() it first): {e}"
            ))
        })?;
        return pair(object.getattr("points")?, faces);
    }
    Ok(None)
}

/// A surface from a file path, a `(vertices, triangles)` pair, or a mesh
/// object of trimesh, meshio or pyvista ([`pair_of_mesh_object`]).
fn surface_of(surface: &Bound<'_, PyAny>) -> PyResult<SurfaceMesh> {
    if let Some(pair) = pair_of_mesh_object(surface)? {
        return mesh_from_pair(&pair);
    }
    if let Ok(pair) = surface.cast::<PyTuple>() {
        return mesh_from_pair(pair);
    }
    let path: PathBuf = surface
        .extract()
        .map_err(|_| raise("a surface is a file path or a (vertices, triangles) pair"))?;
    tissue::load_closed_surface(&path).map_err(raise)
}

/// A mesh from a `(vertices, triangles)` pair of array-likes.
fn mesh_from_pair(pair: &Bound<'_, PyTuple>) -> PyResult<SurfaceMesh> {
    {
        if pair.len() != 2 {
            return Err(raise(
                "a surface is a file path or a (vertices, triangles) pair",
            ));
        }
        let vertices: PyArrayLike2<'_, f64, AllowTypeChange> = pair.get_item(0)?.extract()?;
        let vertices = points_of(&vertices, "surface vertices")?;
        let triangles: PyArrayLike2<'_, i64, AllowTypeChange> = pair.get_item(1)?.extract()?;
        if triangles.shape()[1] != 3 {
            return Err(raise(
                "surface triangles must be an (m, 3) array of vertex indices",
            ));
        }
        let mut corners = Vec::with_capacity(triangles.shape()[0]);
        for (t, row) in triangles.as_array().rows().into_iter().enumerate() {
            let mut triangle = [0u32; 3];
            for (k, &v) in row.iter().enumerate() {
                triangle[k] = u32::try_from(v)
                    .ok()
                    .filter(|&v| (v as usize) < vertices.len())
                    .ok_or_else(|| {
                        raise(format!(
                            "surface triangle {t} names vertex {v}, not one of the {} vertices",
                            vertices.len()
                        ))
                    })?;
            }
            corners.push(triangle);
        }
        Ok(SurfaceMesh::new(vertices, corners))
    }
}

/// A Python progress callback, called from computing (GIL-free) code with a
/// dict of where the work is; the first exception it raises is kept, the
/// rest of the work left to finish, and raised after it.
struct Callback<'a> {
    call: Option<&'a Py<PyAny>>,
    failed: Option<PyErr>,
}

impl<'a> Callback<'a> {
    fn new(call: Option<&'a Py<PyAny>>) -> Self {
        Self { call, failed: None }
    }

    /// Calls it with the dict `fill` fills, unless it raised before.
    fn tell(&mut self, fill: impl FnOnce(&Bound<'_, PyDict>) -> PyResult<()>) {
        let Some(call) = self.call else { return };
        if self.failed.is_some() {
            return;
        }
        let outcome = Python::attach(|py| -> PyResult<()> {
            let info = PyDict::new(py);
            fill(&info)?;
            call.call1(py, (info,))?;
            Ok(())
        });
        self.failed = outcome.err();
    }

    /// The exception it raised, if any.
    fn result(self) -> PyResult<()> {
        self.failed.map_or(Ok(()), Err)
    }
}

fn device_of(backend: &str) -> PyResult<Device> {
    let backend: Backend = backend.parse().map_err(raise)?;
    Ok(Device::pick(backend).map_err(raise)?.device)
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

fn mesh_tuple<'py>(py: Python<'py>, mesh: &SurfaceMesh) -> PyResult<Bound<'py, PyTuple>> {
    let vertices = array_of(py, &mesh.vertices)?;
    let flat: Vec<i64> = mesh
        .triangles
        .iter()
        .flat_map(|t| t.map(i64::from))
        .collect();
    let triangles = PyArray1::from_vec(py, flat).reshape([mesh.triangles.len(), 3])?;
    PyTuple::new(py, [vertices.into_any(), triangles.into_any()])
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
    /// force `"symmetric"` (the default), `"elastic"` (with `poisson`, the
    /// accurate one) or `"paper"`; `max_iterations` caps every solve.
    /// `progress`, if given, is called as each stage of the preparation
    /// starts with a dict: `stage` (`plan`, `elastic_model`, `upload`,
    /// `coarse_space`, `deflation_modes`, `elastic_coarse`) and
    /// `description`. `observed`: the surface vertices the deformed
    /// surfaces observe (`tissue deform --observed`), as indices or one
    /// flag per vertex; the rest of the skin is free, the mechanics
    /// deciding where it goes. None: all.
    #[pyo3(signature = (backend = "auto", force = "symmetric", poisson = None, max_iterations = None, progress = None, observed = None))]
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
        let device = device_of(backend)?;
        let mut callback = Callback::new(progress.as_ref());
        let solver = py
            .detach(|| {
                Solver::new_with_progress(device, &self.model, params, &mut |stage| {
                    callback.tell(|info| {
                        info.set_item("stage", stage.name())?;
                        info.set_item("description", stage.to_string())
                    });
                })
            })
            .map_err(raise)?;
        callback.result()?;
        Ok(Deformer {
            solver,
            model: self.model.clone(),
            spacing: self.model.mean_connection_length(),
            deformed: None,
            posture: None,
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
    /// `solve`, `iterations`, `converged`. The deformer's `posture` says
    /// what was found. Where gravity does not change and no stiffness is
    /// given there is no load to fit: a RuntimeWarning, and the deformer
    /// is the plain elastic one. An unloaded shape not found within 0.1 mm
    /// also warns. `fit_particles`: the stiffness is fitted on a model of
    /// that many particles sampled on the same surface where this one has
    /// at least twice as many, this model's unloaded shape then found at
    /// the fitted stiffness (several times faster; docs/METHOD.md);
    /// `None` fits on this model.
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
        fit_particles = Some(FIT_PARTICLES)
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
        let deformed = deformed_surface(surface, deformed)?;
        let held = match held {
            Some(held) => held_of(held, surface.vertices.len())?,
            None => held_vertices(
                surface,
                &deformed,
                HELD_SPACINGS * self.model.mean_connection_length(),
            )
            .ok_or_else(|| raise("the deformed surface has other vertices than the model's"))?,
        };
        if !held.contains(&true) {
            return Err(raise(
                "no surface vertex is held between the two scans (none moved less than a \
                 thousandth of a connection length): the unloaded shape needs the surface that \
                 does not move, e.g. the chest wall; give it with held=",
            ));
        }
        let device = device_of(backend)?;
        let model = &self.model;
        if !gravity.changes() && gravity.stiffness_kpa.is_none() {
            warn(
                py,
                "gravity does not change between the postures: the skin says nothing about the \
                 stiffness, and no load is fitted; the deformer is the plain elastic one (give \
                 stiffness_kpa to solve from the unloaded shape anyway)",
            )?;
            let solver = py
                .detach(|| Solver::new(device, model, params))
                .map_err(raise)?;
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
            });
        }
        let mut callback = Callback::new(progress.as_ref());
        let (unloaded, solver) = py
            .detach(|| {
                let unloaded = unload(
                    &device,
                    model,
                    &deformed,
                    &held,
                    &gravity,
                    &params,
                    &mut |p| {
                        callback.tell(|info| {
                            info.set_item("solve", p.solve)?;
                            info.set_item("iterations", p.iterations)?;
                            info.set_item("converged", p.converged)
                        });
                    },
                )?;
                let params = params.with(|p| p.load = unloaded.deformed_load);
                let solver = Solver::unloaded(device, model, &unloaded.shape.positions, params)?;
                Ok::<_, tissue::Error>((unloaded, solver))
            })
            .map_err(raise)?;
        callback.result()?;
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
        let load = unloaded.deformed_load;
        posture.set_item("load", (load.x, load.y, load.z))?;
        Ok(Deformer {
            solver,
            model: self.model.clone(),
            spacing: self.model.mean_connection_length(),
            deformed: None,
            posture: Some(posture.unbind().into_any()),
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

/// The held region from Python: vertex indices, or one flag per vertex.
fn held_of(held: &Bound<'_, PyAny>, vertices: usize) -> PyResult<Vec<bool>> {
    vertex_mask(held, vertices, "held")
}

/// A set of surface vertices from Python (`what` names the keyword):
/// vertex indices, or one flag per vertex.
fn vertex_mask(set: &Bound<'_, PyAny>, vertices: usize, what: &str) -> PyResult<Vec<bool>> {
    if let Ok(flags) = set.extract::<Vec<bool>>()
        && !flags.is_empty()
    {
        if flags.len() != vertices {
            return Err(raise(format!(
                "{what}: {} flags, expected one per surface vertex ({vertices}), or vertex indices",
                flags.len()
            )));
        }
        return Ok(flags);
    }
    let indices: Vec<i64> = set.extract().map_err(|_| {
        raise(format!(
            "{what} must be surface vertex indices or one flag per surface vertex"
        ))
    })?;
    let mut flags = vec![false; vertices];
    for index in indices {
        let slot = usize::try_from(index)
            .ok()
            .and_then(|i| flags.get_mut(i))
            .ok_or_else(|| {
                raise(format!(
                    "{what}: vertex {index} is not a surface vertex (0 to {})",
                    vertices.saturating_sub(1)
                ))
            })?;
        *slot = true;
    }
    Ok(flags)
}

/// A RuntimeWarning with `message`.
fn warn(py: Python<'_>, message: &str) -> PyResult<()> {
    let warning = py.get_type::<PyRuntimeWarning>();
    PyErr::warn(
        py,
        &warning,
        &std::ffi::CString::new(message).map_err(raise)?,
        1,
    )
}

/// Stage 2 of one model: the surface particles follow a deformed surface
/// and the interior follows them.
#[pyclass(module = "tissue._tissue")]
struct Deformer {
    solver: Solver,
    /// The model: deformed surfaces are matched to its rest surface,
    /// carried points checked against it, results written with it.
    model: ParticleModel,
    /// The model's mean connection length.
    spacing: f32,
    /// The deformed surface of the last solve.
    deformed: Option<SurfaceMesh>,
    /// What `Model.deformer_in_posture` found.
    posture: Option<Py<PyAny>>,
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
const FARTHEST_DIAGONALS: f32 = 1000.0;

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
        let solver = &mut self.solver;
        let mut callback = Callback::new(progress.as_ref());
        let report = py
            .detach(|| {
                solver.set_surface(&deformed)?;
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
        if !report.converged {
            let message = format!(
                "the solve did not converge: {} iterations, stopped by {:?}, estimated error {:e} of the size",
                report.iterations, report.stopped_by, report.residual
            );
            warn(py, &message)?;
        }
        as_dict(py, &report)
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
fn save_motion(
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

#[pymodule]
fn _tissue(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TissueError", m.py().get_type::<TissueError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(sample, m)?)?;
    m.add_function(wrap_pyfunction!(load_model, m)?)?;
    m.add_function(wrap_pyfunction!(phantom_breast, m)?)?;
    m.add_function(wrap_pyfunction!(phantom_breast_sagged, m)?)?;
    m.add_function(wrap_pyfunction!(save_motion, m)?)?;
    m.add_class::<Model>()?;
    m.add_class::<Deformer>()?;
    Ok(())
}
