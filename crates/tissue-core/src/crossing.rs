//! Whether a surface passes through itself: two of its triangles that
//! cross, an edge of one piercing the other's inside.
//! A deformed skin that does this (pushed through the opposite side, a
//! fold) has no tissue shape behind it.
//!
//! Touching is not crossing: triangles that meet at a point or along an
//! edge without piercing (two vertices that touch in a frame) pass, and so
//! do coplanar overlaps, whose sign tests are all zero. Neighbours pass by
//! the same rule: an edge that ends on a shared vertex has an end on the
//! other triangle's plane, and the difference of two equal points is an
//! exact zero. The sign tests run on `f64` copies of the `f32` coordinates.

use glam::{DVec3, Vec3};
use parry3d::bounding_volume::Aabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};
use rayon::prelude::*;

use crate::SurfaceMesh;

/// The first pair of triangles `[a, b]` (`a < b`, lowest `a`) of `mesh`
/// that cross, if any (see the module's doc): neighbours included, so a
/// fold between two triangles that share a vertex is found too. Triangles
/// naming a vertex out of range are skipped.
pub fn first_crossing(mesh: &SurfaceMesh) -> Option<[usize; 2]> {
    let corners = |t: usize| -> Option<[DVec3; 3]> {
        let [a, b, c] = mesh.triangles[t];
        let v = |i: u32| mesh.vertices.get(i as usize).map(|p| p.as_dvec3());
        Some([v(a)?, v(b)?, v(c)?])
    };
    let boxes: Vec<Aabb> = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.triangles[t];
            let v = |i: u32| mesh.vertices.get(i as usize).copied().unwrap_or(Vec3::NAN);
            let (a, b, c) = (v(a), v(b), v(c));
            Aabb::new(a.min(b).min(c), a.max(b).max(c))
        })
        .collect();
    let bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &boxes);
    (0..mesh.triangles.len())
        .into_par_iter()
        .filter_map(|a| {
            let first = corners(a)?;
            bvh.intersect_aabb(&boxes[a])
                .map(|b| b as usize)
                .filter(|&b| b > a)
                .filter(|&b| corners(b).is_some_and(|second| cross(&first, &second)))
                .min()
                .map(|b| [a, b])
        })
        .min()
}

/// Whether triangles `s` and `t` cross: an edge of one pierces the other.
fn cross(s: &[DVec3; 3], t: &[DVec3; 3]) -> bool {
    let edges = |u: &[DVec3; 3]| [(u[0], u[1]), (u[1], u[2]), (u[2], u[0])];
    edges(s).iter().any(|&(p, q)| pierces(p, q, t))
        || edges(t).iter().any(|&(p, q)| pierces(p, q, s))
}

/// Six times the signed volume of the tetrahedron `a b c d`.
fn orient(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a)
}

/// Whether segment `p q` passes strictly through the inside of triangle
/// `t`: its ends strictly on opposite sides of `t`'s plane, and the line
/// strictly on the same side of all three edges.
fn pierces(p: DVec3, q: DVec3, t: &[DVec3; 3]) -> bool {
    let [a, b, c] = *t;
    let (sp, sq) = (orient(a, b, c, p), orient(a, b, c, q));
    if !(sp > 0.0 && sq < 0.0 || sp < 0.0 && sq > 0.0) {
        return false;
    }
    let e1 = orient(p, q, a, b);
    let e2 = orient(p, q, b, c);
    let e3 = orient(p, q, c, a);
    e1 > 0.0 && e2 > 0.0 && e3 > 0.0 || e1 < 0.0 && e2 < 0.0 && e3 < 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shared octahedron (radius 1, counter-clockwise from outside),
    /// scaled to radius `r` and centred at `centre`.
    fn octahedron(centre: Vec3, r: f32) -> SurfaceMesh {
        let (vertices, triangles) = tissue_testkit::octahedron();
        SurfaceMesh::new(
            vertices.iter().map(|&v| centre + v * r).collect(),
            triangles,
        )
    }

    /// Two meshes as one.
    fn both(a: &SurfaceMesh, b: &SurfaceMesh) -> SurfaceMesh {
        let offset = a.vertices.len() as u32;
        let mut vertices = a.vertices.clone();
        vertices.extend(&b.vertices);
        let mut triangles = a.triangles.clone();
        triangles.extend(b.triangles.iter().map(|t| t.map(|i| i + offset)));
        SurfaceMesh::new(vertices, triangles)
    }

    #[test]
    fn a_closed_surface_does_not_cross_itself() {
        assert_eq!(first_crossing(&octahedron(Vec3::ZERO, 1.0)), None);
        // Two apart, and two that touch at one vertex.
        let apart = both(
            &octahedron(Vec3::ZERO, 1.0),
            &octahedron(Vec3::X * 3.0, 1.0),
        );
        assert_eq!(first_crossing(&apart), None);
        let touching = both(
            &octahedron(Vec3::ZERO, 1.0),
            &octahedron(Vec3::X * 2.0, 1.0),
        );
        assert_eq!(first_crossing(&touching), None);
    }

    #[test]
    fn overlapping_shells_cross() {
        // Off-centre, so that no edge meets a vertex or an edge exactly.
        let overlapping = both(
            &octahedron(Vec3::ZERO, 1.0),
            &octahedron(Vec3::new(0.9, 0.13, 0.07), 1.0),
        );
        let [a, b] = first_crossing(&overlapping).unwrap_or([0, 0]);
        assert!(a < 8 && b >= 8, "{a} {b}");
    }

    #[test]
    fn a_skin_pushed_through_the_chest_wall_crosses_and_a_deep_poke_does_not() {
        // The phantom's tip poked down, 15 mm wide: 40 mm deep stays inside
        // (its base is at z = 0, its tip at 55 mm); 80 mm goes through the
        // base.
        let breast = crate::phantom::default_breast();
        let tip = breast
            .vertices
            .iter()
            .copied()
            .fold(Vec3::splat(f32::MIN), |a, b| if b.z > a.z { b } else { a });
        let poked = |depth: f32| {
            let mut mesh = breast.clone();
            for v in &mut mesh.vertices {
                let d = v.distance(tip);
                if d < 15.0 {
                    v.z -= depth * (1.0 - d / 15.0);
                }
            }
            mesh
        };
        assert_eq!(first_crossing(&breast), None);
        assert_eq!(first_crossing(&poked(40.0)), None);
        assert!(first_crossing(&poked(80.0)).is_some());
    }

    #[test]
    fn pierces_needs_a_strict_crossing() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let down = |x: f64, y: f64| (DVec3::new(x, y, 1.0), DVec3::new(x, y, -1.0));
        let (p, q) = down(0.25, 0.25);
        assert!(pierces(p, q, &t));
        // Through an edge or a corner, or stopping on the plane: not strict.
        for (p, q) in [
            down(0.5, 0.0),
            down(0.0, 0.0),
            (DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, 0.0)),
        ] {
            assert!(!pierces(p, q, &t), "{p} {q}");
        }
        let (p, q) = down(1.0, 1.0);
        assert!(!pierces(p, q, &t));
    }
}
