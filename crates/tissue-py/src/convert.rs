//! Between Python and tissue: numpy arrays and mesh objects as points and
//! surfaces, deformed surfaces matched to the model's, vertex sets, reports
//! as dicts, errors and warnings, progress callbacks.

use std::path::PathBuf;

use numpy::{
    AllowTypeChange, PyArray1, PyArray2, PyArrayLike1, PyArrayLike2, PyArrayMethods,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyRuntimeWarning;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use tissue::{SurfaceMesh, Vec3};

use crate::TissueError;

/// A library error as a Python exception.
pub(crate) fn raise(error: impl std::fmt::Display) -> PyErr {
    TissueError::new_err(error.to_string())
}

/// A serialisable report as a Python dict (through JSON, the CLI's form).
pub(crate) fn as_dict(py: Python<'_>, report: &impl serde::Serialize) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(report).map_err(raise)?;
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

/// An `(n, 3)` array of points: any array-like numpy converts to float64.
pub(crate) fn points_of(
    array: &PyArrayLike2<'_, f64, AllowTypeChange>,
    what: &str,
) -> PyResult<Vec<Vec3>> {
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
pub(crate) fn points_from(object: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Vec3>> {
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
pub(crate) fn deformed_surface(
    rest: &SurfaceMesh,
    surface: &Bound<'_, PyAny>,
) -> PyResult<SurfaceMesh> {
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
pub(crate) type Points<'py> = Bound<'py, PyArray2<f64>>;

pub(crate) fn array_of<'py>(
    py: Python<'py>,
    points: &[Vec3],
) -> PyResult<Bound<'py, PyArray2<f64>>> {
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
pub(crate) fn pair_of_mesh_object<'py>(
    object: &Bound<'py, PyAny>,
) -> PyResult<Option<Bound<'py, PyTuple>>> {
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
pub(crate) fn surface_of(surface: &Bound<'_, PyAny>) -> PyResult<SurfaceMesh> {
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
pub(crate) fn mesh_from_pair(pair: &Bound<'_, PyTuple>) -> PyResult<SurfaceMesh> {
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
pub(crate) struct Callback<'a> {
    call: Option<&'a Py<PyAny>>,
    failed: Option<PyErr>,
}

impl<'a> Callback<'a> {
    pub(crate) fn new(call: Option<&'a Py<PyAny>>) -> Self {
        Self { call, failed: None }
    }

    /// Calls it with the dict `fill` fills, unless it raised before.
    pub(crate) fn tell(&mut self, fill: impl FnOnce(&Bound<'_, PyDict>) -> PyResult<()>) {
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
    pub(crate) fn result(self) -> PyResult<()> {
        self.failed.map_or(Ok(()), Err)
    }
}

pub(crate) fn mesh_tuple<'py>(
    py: Python<'py>,
    mesh: &SurfaceMesh,
) -> PyResult<Bound<'py, PyTuple>> {
    let vertices = array_of(py, &mesh.vertices)?;
    let flat: Vec<i64> = mesh
        .triangles
        .iter()
        .flat_map(|t| t.map(i64::from))
        .collect();
    let triangles = PyArray1::from_vec(py, flat).reshape([mesh.triangles.len(), 3])?;
    PyTuple::new(py, [vertices.into_any(), triangles.into_any()])
}

/// The held region from Python: vertex indices, or one flag per vertex.
pub(crate) fn held_of(held: &Bound<'_, PyAny>, vertices: usize) -> PyResult<Vec<bool>> {
    vertex_mask(held, vertices, "held")
}

/// A set of surface vertices from Python (`what` names the keyword):
/// vertex indices, or one flag per vertex.
pub(crate) fn vertex_mask(
    set: &Bound<'_, PyAny>,
    vertices: usize,
    what: &str,
) -> PyResult<Vec<bool>> {
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
pub(crate) fn warn(py: Python<'_>, message: &str) -> PyResult<()> {
    let warning = py.get_type::<PyRuntimeWarning>();
    PyErr::warn(
        py,
        &warning,
        &std::ffi::CString::new(message).map_err(raise)?,
        1,
    )
}
