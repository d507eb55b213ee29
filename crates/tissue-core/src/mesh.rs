//! Closed triangle surfaces: the organ's skin (or any closed structure).

use glam::Vec3;

/// A triangle surface mesh: shared vertices and counter-clockwise triangles
/// (seen from outside, so normals point outward once validated).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SurfaceMesh {
    /// Vertex positions, in the file's units (millimetres for the bundled phantom).
    pub vertices: Vec<Vec3>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    /// A mesh from vertices and triangles, unchecked.
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        Self {
            vertices,
            triangles,
        }
    }

    /// The three corners of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }

    /// Axis-aligned bounds `(min, max)`; `None` for a mesh without vertices.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.vertices.first()?;
        Some(
            self.vertices
                .iter()
                .fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v))),
        )
    }

    /// Signed volume (divergence theorem); positive when triangles face outward.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|v| v.as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|v| v.as_dvec3());
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// The point with barycentric coordinates `bary` on triangle `t`.
    pub fn point_on(&self, t: usize, bary: [f32; 3]) -> Vec3 {
        let [a, b, c] = self.corners(t);
        a * bary[0] + b * bary[1] + c * bary[2]
    }
}
