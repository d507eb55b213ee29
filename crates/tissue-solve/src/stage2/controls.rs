//! The deformed surface and the control points on it.

use tissue_core::{DeformError, SurfaceMesh};

/// The range of deformed over rest volume [`check_same_topology`] accepts:
/// soft tissue keeps its volume within a few per cent, so a surface outside
/// it was mirrored, turned inside out, collapsed or given in other units.
pub const VOLUME_RATIO: (f64, f64) = (0.5, 2.0);

/// The deformed surface must be the rest surface with moved vertices,
/// enclosing a plausible volume ([`VOLUME_RATIO`] of the rest volume).
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
    let rest_volume = rest.signed_volume();
    // A rest surface without a positive volume gives nothing to compare with.
    if rest_volume > 0.0 {
        let ratio = deformed.signed_volume() / rest_volume;
        let (min, max) = VOLUME_RATIO;
        if !(min..=max).contains(&ratio) {
            return Err(DeformError::ImplausibleVolume { ratio, min, max });
        }
    }
    Ok(())
}

#[cfg(test)]
mod volume_tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use glam::Vec3;

    use super::*;

    #[test]
    fn a_mirrored_collapsed_or_rescaled_surface_is_refused() {
        let (vertices, triangles) = tissue_testkit::octahedron();
        let rest = SurfaceMesh::new(vertices.clone(), triangles.clone());
        assert!(rest.signed_volume() > 0.0);
        let moved = |f: &dyn Fn(Vec3) -> Vec3| {
            SurfaceMesh::new(vertices.iter().map(|&v| f(v)).collect(), triangles.clone())
        };
        // A sag-like change of shape (volume within a few per cent) passes.
        assert!(check_same_topology(&rest, &moved(&|v| v + Vec3::Z * 0.1 * v.x * v.x)).is_ok());
        assert!(check_same_topology(&rest, &moved(&|v| v * 1.1)).is_ok());
        for (what, f, sign) in [
            (
                "mirrored",
                &(|v: Vec3| v * Vec3::new(-1.0, 1.0, 1.0)) as &dyn Fn(Vec3) -> Vec3,
                -1.0,
            ),
            ("collapsed", &|v: Vec3| v * Vec3::new(1.0, 1.0, 0.01), 1.0),
            ("in metres", &|v: Vec3| v * 1e-3, 1.0),
            ("in millimetres", &|v: Vec3| v * 1e3, 1.0),
        ] {
            let err = check_same_topology(&rest, &moved(f)).unwrap_err();
            let DeformError::ImplausibleVolume { ratio, .. } = err else {
                panic!("{what}: {err:?}");
            };
            assert_eq!(ratio.signum(), sign, "{what}: {ratio}");
            assert!(err.to_string().contains("volume"), "{err}");
        }
    }
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
