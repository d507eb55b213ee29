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

    /// The generalized winding number of the surface around `p` (van
    /// Oosterom and Strackee's solid angle of each triangle, summed in
    /// `f64`): 1 inside a closed outward surface, 0 outside, whatever the
    /// surface near `p` looks like. Where a surface crosses itself, the
    /// nearest triangle's side (its pseudo-normal) can point the wrong way
    /// while this still counts how many times the surface wraps `p`.
    /// Costs a pass over every triangle.
    pub fn winding_number(&self, p: Vec3) -> f64 {
        let p = p.as_dvec3();
        let total: f64 = (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|v| v.as_dvec3() - p);
                let (la, lb, lc) = (a.length(), b.length(), c.length());
                let numerator = a.dot(b.cross(c));
                let denominator = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
                2.0 * numerator.atan2(denominator)
            })
            .sum();
        total / (4.0 * std::f64::consts::PI)
    }

    /// The point with barycentric coordinates `bary` on triangle `t`.
    pub fn point_on(&self, t: usize, bary: [f32; 3]) -> Vec3 {
        let [a, b, c] = self.corners(t);
        a * bary[0] + b * bary[1] + c * bary[2]
    }

    /// `self` with its vertices renumbered as `rest`'s, where the two have
    /// the same triangles in the same order up to a renumbering of the
    /// vertices (what another tool writing the same mesh in its own vertex
    /// order gives): the vertex at corner `k` of triangle `t` here goes
    /// where `rest` has corner `k` of triangle `t`. `None` where no single
    /// renumbering does it (other triangles, or a vertex that would go to
    /// two places), or the counts differ.
    pub fn renumbered_like(&self, rest: &SurfaceMesh) -> Option<SurfaceMesh> {
        if self.vertices.len() != rest.vertices.len()
            || self.triangles.len() != rest.triangles.len()
        {
            return None;
        }
        const UNSET: u32 = u32::MAX;
        let mut to_rest = vec![UNSET; self.vertices.len()];
        let mut taken = vec![false; rest.vertices.len()];
        for (mine, theirs) in self.triangles.iter().zip(&rest.triangles) {
            for (&o, &r) in mine.iter().zip(theirs) {
                let slot = to_rest.get_mut(o as usize)?;
                if *slot == UNSET {
                    if std::mem::replace(taken.get_mut(r as usize)?, true) {
                        return None;
                    }
                    *slot = r;
                } else if *slot != r {
                    return None;
                }
            }
        }
        if to_rest.contains(&UNSET) {
            return None;
        }
        let mut vertices = vec![Vec3::ZERO; self.vertices.len()];
        for (o, &r) in to_rest.iter().enumerate() {
            vertices[r as usize] = self.vertices[o];
        }
        Some(SurfaceMesh::new(vertices, rest.triangles.clone()))
    }

    /// `rest`'s mesh with each vertex where the corners of `self`'s
    /// triangles that stand for it lie, `self` listing `rest`'s triangles
    /// in `rest`'s order (each wound the same way, or each reversed) with
    /// vertices of its own numbering, however many: an STL file's three
    /// corners a triangle. `None` where the triangle counts differ or two
    /// corners standing for one vertex of `rest` lie apart. Vertices that
    /// touch in the frame stay two, which welding would merge.
    fn corners_in_order(&self, rest: &SurfaceMesh) -> Option<SurfaceMesh> {
        if self.triangles.len() != rest.triangles.len() || rest.triangles.is_empty() {
            return None;
        }
        [false, true].into_iter().find_map(|reversed| {
            let mut at: Vec<Option<Vec3>> = vec![None; rest.vertices.len()];
            for (mine, theirs) in self.triangles.iter().zip(&rest.triangles) {
                let mine = if reversed {
                    [mine[0], mine[2], mine[1]]
                } else {
                    *mine
                };
                for (&m, &r) in mine.iter().zip(theirs) {
                    let corner = *self.vertices.get(m as usize)?;
                    match at.get_mut(r as usize)? {
                        slot @ None => *slot = Some(corner),
                        Some(seen) if *seen == corner => {}
                        Some(_) => return None,
                    }
                }
            }
            let vertices = at.into_iter().collect::<Option<Vec<Vec3>>>()?;
            Some(SurfaceMesh::new(vertices, rest.triangles.clone()))
        })
    }

    /// `self`, a deformed frame of `rest` as another tool wrote it, made
    /// `rest`'s mesh with moved vertices where it can be: with more or
    /// fewer vertices than `rest` (an `stl` file stores three corners a
    /// triangle), read by its corners where it lists `rest`'s triangles in
    /// their order ([`SurfaceMesh::corners_in_order`]: vertices that touch
    /// stay two), else with coinciding vertices welded when that gives
    /// `rest`'s count (an `stl` file always is); every triangle's winding
    /// reversed when all of `rest`'s are (sampling turned an inward-facing
    /// surface outward), and the vertices renumbered by the triangles when
    /// only their numbering differs. What cannot be matched is returned as
    /// it is, for the topology check to name.
    pub fn as_frame_of(self, rest: &SurfaceMesh, stl: bool) -> SurfaceMesh {
        let mut deformed = if self.vertices.len() == rest.vertices.len() {
            self
        } else if let Some(frame) = self.corners_in_order(rest) {
            log::info!(
                "the frame lists the rest surface's triangles in their order: read by their corners"
            );
            frame
        } else {
            let welded = crate::io::surface::weld(&self, 0.0);
            if welded.vertices.len() == rest.vertices.len() || stl {
                welded
            } else {
                self
            }
        };
        let reversed = deformed.triangles.len() == rest.triangles.len()
            && deformed
                .triangles
                .iter()
                .zip(&rest.triangles)
                .all(|(d, r)| [d[0], d[2], d[1]] == *r);
        if reversed && !deformed.triangles.is_empty() {
            log::info!(
                "reversed the winding of every triangle, as sampling did to the rest surface"
            );
            for t in &mut deformed.triangles {
                t.swap(1, 2);
            }
        }
        if deformed.triangles != rest.triangles {
            let flipped = || {
                let mut f = deformed.clone();
                f.triangles.iter_mut().for_each(|t| t.swap(1, 2));
                f
            };
            let renumbered = deformed
                .renumbered_like(rest)
                .or_else(|| flipped().renumbered_like(rest));
            if let Some(renumbered) = renumbered {
                log::info!(
                    "the frame's vertices are numbered differently from the rest surface's; \
                     matched them by the triangles"
                );
                deformed = renumbered;
            }
        }
        deformed
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;

    fn octahedron() -> SurfaceMesh {
        let (vertices, triangles) = tissue_testkit::octahedron();
        SurfaceMesh::new(vertices, triangles)
    }

    #[test]
    fn the_winding_number_counts_how_often_the_surface_wraps_a_point() {
        let mesh = octahedron();
        let scale = mesh.bounds().map(|(lo, hi)| lo.distance(hi)).unwrap();
        assert!(mesh.signed_volume() > 0.0, "the octahedron faces outward");
        assert!((mesh.winding_number(Vec3::ZERO) - 1.0).abs() < 1e-12);
        assert!((mesh.winding_number(Vec3::splat(0.05 * scale)) - 1.0).abs() < 1e-12);
        assert!(mesh.winding_number(Vec3::splat(scale)).abs() < 1e-12);
        // The same surface twice wraps its inside twice; turned inside out,
        // once the other way.
        let count = mesh.vertices.len() as u32;
        let mut twice = mesh.clone();
        twice.vertices.extend(mesh.vertices.iter().copied());
        twice
            .triangles
            .extend(mesh.triangles.iter().map(|t| t.map(|v| v + count)));
        assert!((twice.winding_number(Vec3::ZERO) - 2.0).abs() < 1e-12);
        let mut inverted = mesh.clone();
        inverted.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        assert!((inverted.winding_number(Vec3::ZERO) + 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_same_mesh_in_another_vertex_order_is_renumbered_back() {
        let rest = octahedron();
        // Vertex i of the rest mesh is vertex order[i] in the other file.
        let order = [3u32, 5, 0, 4, 1, 2];
        let mut vertices = vec![Vec3::ZERO; 6];
        for (i, &o) in order.iter().enumerate() {
            vertices[o as usize] = rest.vertices[i] + Vec3::X;
        }
        let triangles = rest
            .triangles
            .iter()
            .map(|t| t.map(|v| order[v as usize]))
            .collect();
        let other = SurfaceMesh::new(vertices, triangles);
        let back = other.renumbered_like(&rest).unwrap();
        assert_eq!(back.triangles, rest.triangles);
        for (b, r) in back.vertices.iter().zip(&rest.vertices) {
            assert_eq!(*b, *r + Vec3::X);
        }
    }

    /// `mesh` as an STL file stores it: three corners a triangle, each its
    /// own vertex, the triangles wound as given by `reversed`.
    fn soup(mesh: &SurfaceMesh, reversed: bool) -> SurfaceMesh {
        let vertices = mesh
            .triangles
            .iter()
            .flat_map(|t| t.map(|v| mesh.vertices[v as usize]))
            .collect();
        let triangles = (0..mesh.triangles.len() as u32)
            .map(|t| {
                let [a, b, c] = [3 * t, 3 * t + 1, 3 * t + 2];
                if reversed { [a, c, b] } else { [a, b, c] }
            })
            .collect();
        SurfaceMesh::new(vertices, triangles)
    }

    #[test]
    fn a_frame_whose_vertices_touch_is_read_by_its_corners_not_welded() {
        let rest = octahedron();
        // Two opposite vertices pressed together: welded, they would merge.
        let mut frame = rest.clone();
        frame.vertices[0] = Vec3::ZERO;
        frame.vertices[1] = Vec3::ZERO;
        for reversed in [false, true] {
            let read = soup(&frame, reversed).as_frame_of(&rest, true);
            assert_eq!(read.triangles, rest.triangles, "reversed {reversed}");
            assert_eq!(read.vertices, frame.vertices, "reversed {reversed}");
        }
        // The same touching frame as written with the two merged (an OBJ
        // with one vertex for both) is read by its corners too.
        let mut merged = frame.clone();
        merged.vertices.remove(1);
        merged
            .triangles
            .iter_mut()
            .flatten()
            .for_each(|v| *v = v.saturating_sub(1));
        let read = merged.as_frame_of(&rest, false);
        assert_eq!(read.triangles, rest.triangles);
        assert_eq!(read.vertices, frame.vertices);
        // Triangles in another order: one vertex's corners lie apart, so
        // none are read, and the welded soup is no frame of `rest`.
        let mut shuffled = rest.clone();
        shuffled.triangles.rotate_left(3);
        assert!(soup(&shuffled, false).corners_in_order(&rest).is_none());
        let read = soup(&shuffled, false).as_frame_of(&rest, true);
        assert_ne!(read.triangles, rest.triangles);
    }

    #[test]
    fn other_triangles_are_not_renumbered() {
        let rest = octahedron();
        let mut other = rest.clone();
        // Two triangles swapped: vertex 0 would have to go to two places.
        other.triangles.swap(0, 5);
        assert!(other.renumbered_like(&rest).is_none());
        let mut fewer = rest.clone();
        fewer.vertices.pop();
        assert!(fewer.renumbered_like(&rest).is_none());
    }
}
