//! The deformed surface and the control points on it.

use tissue_core::{Error, SurfaceMesh};

/// The deformed surface must be the rest surface with moved vertices.
pub fn check_same_topology(rest: &SurfaceMesh, deformed: &SurfaceMesh) -> Result<(), Error> {
    if deformed.vertices.len() != rest.vertices.len()
        || deformed.triangles.len() != rest.triangles.len()
    {
        return Err(Error::Deformation(format!(
            "the deformed surface has {} vertices and {} triangles; the model's rest surface has {} and {} \
             (it must be the same mesh with moved vertices)",
            deformed.vertices.len(),
            deformed.triangles.len(),
            rest.vertices.len(),
            rest.triangles.len()
        )));
    }
    if let Some(t) = (0..rest.triangles.len()).find(|&t| rest.triangles[t] != deformed.triangles[t])
    {
        return Err(Error::Deformation(format!(
            "triangle {t} of the deformed surface is {:?}, in the rest surface {:?} \
             (it must be the same mesh with moved vertices)",
            deformed.triangles[t], rest.triangles[t]
        )));
    }
    if let Some(v) = deformed.vertices.iter().position(|v| !v.is_finite()) {
        return Err(Error::Deformation(format!(
            "vertex {v} of the deformed surface is not finite: {}",
            deformed.vertices[v]
        )));
    }
    Ok(())
}
