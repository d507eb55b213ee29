//! Welding: vertices at the same position, or within a tolerance, merged
//! into one, found by exact bit pattern or through a hash grid.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::Vec3;

use crate::mesh::SurfaceMesh;

/// Merges vertices closer than `tolerance` (in the mesh's units), remaps
/// the triangles and drops vertices no triangle uses.
///
/// With `tolerance` 0 (or negative, or NaN) only exactly equal positions
/// merge (`-0.0` equals `0.0`). Otherwise vertices are visited in order and
/// each joins the first kept vertex within `tolerance`, found through a hash
/// grid of cell size `tolerance`, so the cost is linear. Non-finite
/// positions never merge. Kept vertices stay in their original order.
/// Triangles are kept even when welding makes two of their corners equal
/// ([`validate::validate`](crate::validate::validate) reports those); an
/// index out of range becomes `u32::MAX`.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::weld;
///
/// // Two triangles that share an edge but each carry their own copy of it.
/// let soup = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X, Vec3::Y, Vec3::ONE, Vec3::NEG_ONE],
///     vec![[0, 1, 2], [3, 5, 4]],
/// );
/// let welded = weld(&soup, 0.0);
/// assert_eq!(welded.vertices, [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE]);
/// assert_eq!(welded.triangles, [[0, 1, 2], [1, 3, 2]]);
/// ```
pub fn weld(mesh: &SurfaceMesh, tolerance: f32) -> SurfaceMesh {
    let count = mesh.vertices.len();
    let mut used = vec![false; count];
    for &index in mesh.triangles.iter().flatten() {
        if let Some(u) = used.get_mut(index as usize) {
            *u = true;
        }
    }

    let mut welder = Welder::new(tolerance);
    let remap: Vec<u32> = mesh
        .vertices
        .iter()
        .zip(&used)
        .map(|(&p, &used)| if used { welder.insert(p) } else { u32::MAX })
        .collect();
    let triangles = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| remap.get(i as usize).copied().unwrap_or(u32::MAX)))
        .collect();
    SurfaceMesh::new(welder.vertices, triangles)
}

/// Kept vertices and a lookup from position to kept vertex.
struct Welder {
    vertices: Vec<Vec3>,
    lookup: Lookup,
}

enum Lookup {
    /// Exact positions, by bit pattern (after turning `-0.0` into `0.0`).
    Exact(FastMap<[u32; 3], u32>),
    /// A hash grid: the first kept vertex of each cell, and for each kept
    /// vertex the next one in the same cell (`u32::MAX` ends the chain).
    Grid {
        cell_size: f64,
        first: FastMap<[i64; 3], u32>,
        next: Vec<u32>,
    },
}

impl Welder {
    fn new(tolerance: f32) -> Self {
        let lookup = if tolerance > 0.0 && tolerance.is_finite() {
            Lookup::Grid {
                cell_size: f64::from(tolerance),
                first: FastMap::default(),
                next: Vec::new(),
            }
        } else {
            Lookup::Exact(FastMap::default())
        };
        Self {
            vertices: Vec::new(),
            lookup,
        }
    }

    /// The index of the kept vertex `p` merges into, adding `p` if none.
    fn insert(&mut self, p: Vec3) -> u32 {
        let new = self.vertices.len() as u32;
        if !p.is_finite() {
            self.vertices.push(p);
            if let Lookup::Grid { next, .. } = &mut self.lookup {
                next.push(u32::MAX);
            }
            return new;
        }
        let found = match &mut self.lookup {
            Lookup::Exact(seen) => {
                let key = (p + Vec3::ZERO).to_array().map(f32::to_bits);
                *seen.entry(key).or_insert(new)
            }
            Lookup::Grid {
                cell_size,
                first,
                next,
            } => {
                let cell = (p.as_dvec3() / *cell_size).floor().as_i64vec3().to_array();
                let limit = *cell_size * *cell_size;
                // The lowest-numbered kept vertex within reach, so the
                // result does not depend on the order cells are visited in.
                let mut found = new;
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let key = [
                                cell[0].saturating_add(dx),
                                cell[1].saturating_add(dy),
                                cell[2].saturating_add(dz),
                            ];
                            let mut at = first.get(&key).copied().unwrap_or(u32::MAX);
                            while at != u32::MAX {
                                let q = self.vertices[at as usize].as_dvec3();
                                if q.distance_squared(p.as_dvec3()) <= limit {
                                    found = found.min(at);
                                }
                                at = next[at as usize];
                            }
                        }
                    }
                }
                if found == new {
                    let head = first.entry(cell).or_insert(u32::MAX);
                    next.push(*head);
                    *head = new;
                }
                found
            }
        };
        if found == new {
            self.vertices.push(p);
        }
        found
    }
}

/// A hash map keyed by a few integers, with a multiply-rotate hash: the
/// keys are not attacker-chosen, and SipHash would triple the cost of welding.
type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<WordHasher>>;

#[derive(Default)]
struct WordHasher(u64);

impl WordHasher {
    fn add(&mut self, word: u64) {
        self.0 = (self.0 ^ word)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(26);
    }
}

impl Hasher for WordHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.add(u64::from_le_bytes(word));
        }
    }

    fn write_u32(&mut self, i: u32) {
        self.add(u64::from(i));
    }

    fn write_u64(&mut self, i: u64) {
        self.add(i);
    }

    fn write_i64(&mut self, i: i64) {
        self.add(i as u64);
    }

    fn write_usize(&mut self, i: usize) {
        self.add(i as u64);
    }

    fn finish(&self) -> u64 {
        // Final avalanche (murmur3's fmix64) so low and high bits both vary.
        let mut h = self.0;
        h ^= h >> 33;
        h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
        h ^= h >> 33;
        h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
        h ^ (h >> 33)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]

    use super::*;

    #[test]
    fn weld_with_tolerance_merges_near_duplicates_only() {
        let eps = 1e-6;
        let mesh = SurfaceMesh::new(
            vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec3::new(1.0 + eps, 0.0, 0.0),
                Vec3::new(0.0, 1.0, eps),
                Vec3::ONE,
            ],
            vec![[0, 1, 2], [3, 5, 4]],
        );
        assert_eq!(weld(&mesh, 0.0).vertices.len(), 6);
        let welded = weld(&mesh, 1e-5);
        assert_eq!(welded.vertices, [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE]);
        assert_eq!(welded.triangles, [[0, 1, 2], [1, 3, 2]]);
    }

    #[test]
    fn weld_merges_signed_zeros_but_never_nan() {
        let mesh = SurfaceMesh::new(
            vec![Vec3::ZERO, Vec3::new(-0.0, 0.0, -0.0), Vec3::NAN, Vec3::NAN],
            vec![[0, 1, 2], [0, 2, 3]],
        );
        for tolerance in [0.0, 0.5] {
            let welded = weld(&mesh, tolerance);
            assert_eq!(welded.vertices.len(), 3, "tolerance {tolerance}");
            assert_eq!(welded.triangles, [[0, 0, 1], [0, 1, 2]]);
        }
    }

    #[test]
    fn weld_survives_cells_beyond_i64() {
        let far = Vec3::new(3e38, -3e38, 0.0);
        let mesh = SurfaceMesh::new(vec![far, far, Vec3::ZERO], vec![[0, 1, 2]]);
        let welded = weld(&mesh, 1e-30);
        assert_eq!(welded.vertices, [far, Vec3::ZERO]);
        assert_eq!(welded.triangles, [[0, 0, 1]]);
    }

    #[test]
    fn weld_marks_out_of_range_indices() {
        let mesh = SurfaceMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 7]]);
        let welded = weld(&mesh, 0.0);
        assert_eq!(welded.vertices.len(), 2);
        assert_eq!(welded.triangles, [[0, 1, u32::MAX]]);
    }
}
