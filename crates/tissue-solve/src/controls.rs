//! The deformed surface and the control points on it.

use tissue_core::{DeformError, SurfaceMesh};

/// The deformed surface must be the rest surface with moved vertices.
pub fn check_same_topology(rest: &SurfaceMesh, deformed: &SurfaceMesh) -> Result<(), DeformError> {
    if deformed.vertices.len() != rest.vertices.len()
        || deformed.triangles.len() != rest.triangles.len()
    {
        return Err(DeformError::SurfaceSize {
            vertices: deformed.vertices.len(),
            triangles: deformed.triangles.len(),
            rest_vertices: rest.vertices.len(),
            rest_triangles: rest.triangles.len(),
        });
    }
    if let Some(t) = (0..rest.triangles.len()).find(|&t| rest.triangles[t] != deformed.triangles[t])
    {
        return Err(DeformError::TriangleMismatch {
            triangle: t,
            deformed: deformed.triangles[t],
            rest: rest.triangles[t],
        });
    }
    if let Some(v) = deformed.vertices.iter().position(|v| !v.is_finite()) {
        return Err(DeformError::NonFiniteVertex {
            vertex: v,
            value: deformed.vertices[v],
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use glam::Vec3;

    use super::*;

    #[test]
    fn a_surface_that_is_not_the_rest_surface_moved_is_refused_with_what_differs() {
        let (vertices, triangles) = tissue_testkit::octahedron();
        let rest = SurfaceMesh::new(vertices, triangles);
        assert_eq!(check_same_topology(&rest, &rest), Ok(()));

        let mut fewer = rest.clone();
        fewer.triangles.pop();
        assert!(matches!(
            check_same_topology(&rest, &fewer),
            Err(DeformError::SurfaceSize {
                triangles: 7,
                rest_triangles: 8,
                ..
            })
        ));
        let mut turned = rest.clone();
        turned.triangles[3] = [0, 4, 3];
        assert_eq!(
            check_same_topology(&rest, &turned),
            Err(DeformError::TriangleMismatch {
                triangle: 3,
                deformed: [0, 4, 3],
                rest: [3, 0, 4],
            })
        );
        let mut broken = rest.clone();
        broken.vertices[5] = Vec3::new(0.0, f32::NAN, 1.0);
        let err = check_same_topology(&rest, &broken).unwrap_err();
        assert!(matches!(
            err,
            DeformError::NonFiniteVertex { vertex: 5, .. }
        ));
        assert!(
            err.to_string()
                .contains("vertex 5 of the deformed surface is not finite"),
            "{err}"
        );
    }
}
