//! Observations without correspondence: a point cloud read from a file,
//! the rigid motion that puts a cloud on a surface, and the one that puts
//! fiducials on the model's.

use std::path::PathBuf;

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tissue::io::space::Space;

use crate::convert::{array_of, points_from, raise, surface_of};

/// The points of a point-cloud file (`.csv`, `.ply`, `.vtk`, `.vtp`, or a
/// 3D Slicer markups `.mrk.json`, converted to `space`), `(n, 3)`.
#[pyfunction]
#[pyo3(signature = (path, space = "lps"))]
pub(crate) fn load_cloud<'py>(
    py: Python<'py>,
    path: PathBuf,
    space: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let space: Space = space.parse().map_err(raise)?;
    let points = py
        .detach(|| tissue::observation::load_cloud(&path, space))
        .map_err(raise)?;
    array_of(py, &points)
}

/// The rigid motion that best puts `points` (`(n, 3)`) on a closed
/// `surface` (a file path, a `(vertices, triangles)` pair, or a trimesh,
/// meshio or pyvista mesh): iterative closest points, robust to outliers
/// (docs/METHOD.md, "Observations without correspondence"). Points farther
/// than `reach` from the surface (default: a quarter of its bounding
/// box's diagonal) are set aside. A point `p` goes to `rotation @ p +
/// translation`. Returns a dict: `rotation` (3x3), `translation` (3,),
/// `angle_degrees`, `rms`, `set_aside`, `steps`, `converged`.
#[pyfunction]
#[pyo3(signature = (points, surface, reach = None))]
pub(crate) fn rigid_fit<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    surface: &Bound<'py, PyAny>,
    reach: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let points = points_from(points, "points")?;
    let surface = surface_of(surface)?;
    let reach = match reach {
        Some(reach) if reach.is_finite() && reach > 0.0 => reach as f32,
        Some(reach) => {
            return Err(raise(format!("reach {reach} is not a positive length")));
        }
        None => surface
            .bounds()
            .map_or(0.0, |(lo, hi)| 0.25 * (hi - lo).length()),
    };
    let fit = py
        .detach(|| tissue::observation::rigid_fit_to_surface(&points, &surface, reach))
        .map_err(raise)?;
    let dict = motion_dict(
        py,
        std::array::from_fn(|k| fit.rotation.col(k % 3)[k / 3]),
        fit.translation,
        fit.angle_degrees,
    )?;
    dict.set_item("rms", f64::from(fit.rms))?;
    dict.set_item("set_aside", fit.set_aside)?;
    dict.set_item("steps", fit.steps)?;
    dict.set_item("converged", fit.converged)?;
    Ok(dict)
}

/// The rigid motion that best puts fiducials given in an observation's
/// frame (`observed`, `(n, 3)`) onto the same fiducials in the model's
/// (`model`, `(n, 3)`, the same order), in least squares (the `tissue
/// deform --fiducials` fit; docs/METHOD.md, "Observations without
/// correspondence"). A point `p` goes to `rotation @ p + translation`.
/// Fewer than three fiducials, lists of different lengths, collinear
/// fiducials, spreads that differ by more than a quarter (another unit)
/// or a fit that leaves them farther apart than 5 % of their spread (they
/// do not correspond) raise `TissueError` with the reason. Returns a
/// dict: `rotation` (3x3), `translation` (3,), `angle_degrees`,
/// `fiducials`, `residual_rms`, `residual_max` (the fiducial registration
/// error).
#[pyfunction]
pub(crate) fn fiducial_fit<'py>(
    py: Python<'py>,
    observed: &Bound<'py, PyAny>,
    model: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let observed = points_from(observed, "observed")?;
    let model = points_from(model, "model")?;
    let fit = tissue::observation::fiducial_fit(&observed, &model).map_err(raise)?;
    let dict = motion_dict(
        py,
        std::array::from_fn(|k| fit.rotation.col(k % 3)[k / 3]),
        fit.translation,
        fit.angle_degrees,
    )?;
    dict.set_item("fiducials", fit.count)?;
    dict.set_item("residual_rms", f64::from(fit.rms))?;
    dict.set_item("residual_max", f64::from(fit.max))?;
    Ok(dict)
}

/// A rigid motion as a dict: `rotation` (3x3, from its `rows`, row by
/// row), `translation` (3,), `angle_degrees`.
fn motion_dict<'py>(
    py: Python<'py>,
    rows: [f32; 9],
    translation: tissue::Vec3,
    angle_degrees: f32,
) -> PyResult<Bound<'py, PyDict>> {
    let rows = rows.map(f64::from).to_vec();
    let dict = PyDict::new(py);
    dict.set_item("rotation", PyArray1::from_vec(py, rows).reshape([3, 3])?)?;
    dict.set_item(
        "translation",
        PyArray1::from_vec(py, translation.to_array().map(f64::from).to_vec()),
    )?;
    dict.set_item("angle_degrees", f64::from(angle_degrees))?;
    Ok(dict)
}

/// A scan of part of the skin as an observation of `model`: a file path
/// (`load_cloud`'s formats) or an `(n, 3)` array of points, cleaned with
/// the noise scale `noise` (or the default), its normals turned away from
/// the model's inside.
pub(crate) fn scan_of(
    model: &tissue::ParticleModel,
    cloud: &Bound<'_, PyAny>,
    noise: Option<f32>,
) -> PyResult<tissue::observation::Observation> {
    let points = match cloud.extract::<PathBuf>() {
        Ok(path) => tissue::observation::load_cloud(&path, Space::Lps).map_err(raise)?,
        Err(_) => points_from(cloud, "cloud")?,
    };
    let centre = model.positions.iter().copied().sum::<tissue::Vec3>() / model.len() as f32;
    let cloud = tissue::observation::Cloud::new(points).map_err(raise)?;
    tissue::observation::Observation::cloud(&cloud, noise, centre).map_err(raise)
}

/// A closed surface of the organ of any triangulation as an observation
/// (a file path, a `(vertices, triangles)` pair, or a trimesh, meshio or
/// pyvista mesh), checked as `sample` checks a surface; the mesh too.
pub(crate) fn other_surface_of(
    surface: &Bound<'_, PyAny>,
) -> PyResult<(tissue::SurfaceMesh, tissue::observation::Observation)> {
    let mut mesh = surface_of(surface)?;
    let _checked = tissue::validate(&mut mesh).map_err(raise)?;
    let observation = tissue::observation::Observation::surface(&mesh).map_err(raise)?;
    Ok((mesh, observation))
}
