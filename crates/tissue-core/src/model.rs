//! The particle model: the relaxed state that stage 1 produces and stage 2 deforms.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::mesh::SurfaceMesh;

/// Where a surface particle sits on the rest surface: a triangle and the
/// barycentric coordinates of the particle on it. Surface particles are the
/// control points of stage 2: they follow the deformed surface through this.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Attachment {
    /// Index of the triangle in the rest surface.
    pub triangle: u32,
    /// Barycentric coordinates on that triangle (sum to one).
    pub barycentric: [f32; 3],
}

/// Symmetric particle connections in compressed sparse row form: the
/// neighbours of particle `i` are `indices[offsets[i]..offsets[i + 1]]`,
/// sorted ascending. If `j` is a neighbour of `i`, `i` is a neighbour of `j`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Connections {
    /// Row starts, `particles + 1` entries, first `0`, last `indices.len()`.
    pub offsets: Vec<u32>,
    /// Neighbour indices, row by row.
    pub indices: Vec<u32>,
}

impl Connections {
    /// The neighbours of particle `i`.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Number of particles the rows describe.
    pub fn particles(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Number of undirected connections (each pair counted once).
    pub fn pairs(&self) -> usize {
        self.indices.len() / 2
    }

    /// Builds symmetric rows from undirected pairs; duplicates and self-pairs are dropped.
    pub fn from_pairs(particles: usize, pairs: impl IntoIterator<Item = (u32, u32)>) -> Self {
        let mut rows: Vec<Vec<u32>> = vec![Vec::new(); particles];
        for (a, b) in pairs {
            if a != b {
                rows[a as usize].push(b);
                rows[b as usize].push(a);
            }
        }
        let mut offsets = Vec::with_capacity(particles + 1);
        let mut indices = Vec::new();
        offsets.push(0);
        for row in &mut rows {
            row.sort_unstable();
            row.dedup();
            indices.extend_from_slice(row);
            offsets.push(indices.len() as u32);
        }
        Self { offsets, indices }
    }

    /// Each undirected pair once, `(i, j)` with `i < j`, in row order.
    pub fn pair_list(&self) -> Vec<(u32, u32)> {
        (0..self.particles())
            .flat_map(|i| {
                self.of(i)
                    .iter()
                    .filter(move |&&j| (i as u32) < j)
                    .map(move |&j| (i as u32, j))
            })
            .collect()
    }
}

/// A sampled particle model of a closed surface's interior.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParticleModel {
    /// Rest positions of the particles.
    pub positions: Vec<Vec3>,
    /// Balloon radius of each particle at rest.
    pub radii: Vec<f32>,
    /// `Some` for surface particles (control points), `None` for interior ones.
    pub attachments: Vec<Option<Attachment>>,
    /// Symmetric connections between particles.
    pub connections: Connections,
    /// The rest surface the attachments refer to.
    pub surface: SurfaceMesh,
}

impl ParticleModel {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when the model has no particles.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// True when particle `i` is a surface particle.
    pub fn is_surface(&self, i: usize) -> bool {
        self.attachments[i].is_some()
    }

    /// Mean distance from a particle to its nearest neighbour at rest
    /// (the "mean spacing"), estimated from connection lengths.
    pub fn mean_connection_length(&self) -> f32 {
        let pairs = self.connections.pair_list();
        if pairs.is_empty() {
            return 0.0;
        }
        let sum: f64 = pairs
            .iter()
            .map(|&(i, j)| {
                f64::from((self.positions[i as usize] - self.positions[j as usize]).length())
            })
            .sum();
        (sum / pairs.len() as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connections_from_pairs_are_symmetric_sorted_and_deduplicated() {
        let c = Connections::from_pairs(4, [(2, 0), (0, 2), (1, 3), (3, 3), (0, 1)]);
        assert_eq!(c.of(0), &[1, 2]);
        assert_eq!(c.of(1), &[0, 3]);
        assert_eq!(c.of(2), &[0]);
        assert_eq!(c.of(3), &[1]);
        assert_eq!(c.pairs(), 3);
        assert_eq!(c.pair_list(), vec![(0, 1), (0, 2), (1, 3)]);
    }
}
