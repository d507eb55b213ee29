//! The particle model: the relaxed state that stage 1 produces and stage 2 deforms.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::Error;
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

    /// Checks what every part of tissue relies on: at least one particle;
    /// as many radii and attachments as positions; finite positions and
    /// positive finite radii; a rest surface with finite vertices and
    /// triangles that use existing ones; attachments to existing triangles
    /// with finite barycentric coordinates; and connections in the form
    /// [`Connections`] promises (one row per particle, rows sorted ascending
    /// without repeats, indices in range, no particle connected to itself,
    /// every connection in both rows).
    ///
    /// A model that passes can be saved and read back, and stage 2 can index
    /// with it without bounds surprises.
    ///
    /// # Errors
    ///
    /// [`Error::InvalidModel`] naming the first problem found.
    ///
    /// # Example
    ///
    /// ```
    /// use tissue_core::{Connections, ParticleModel, SurfaceMesh, Vec3};
    ///
    /// let mut model = ParticleModel {
    ///     positions: vec![Vec3::ZERO, Vec3::X],
    ///     radii: vec![0.5, 0.5],
    ///     attachments: vec![None, None],
    ///     connections: Connections::from_pairs(2, [(0, 1)]),
    ///     surface: SurfaceMesh::default(),
    /// };
    /// assert!(model.validate().is_ok());
    /// model.radii.pop();
    /// let message = model.validate().unwrap_err().to_string();
    /// assert!(message.contains("2 positions but 1 radii"), "{message}");
    /// ```
    pub fn validate(&self) -> Result<(), Error> {
        self.check().map_err(Error::InvalidModel)
    }

    fn check(&self) -> Result<(), String> {
        let n = self.positions.len();
        if n == 0 {
            return Err("the model has no particles".into());
        }
        if self.radii.len() != n {
            return Err(format!("{n} positions but {} radii", self.radii.len()));
        }
        if self.attachments.len() != n {
            return Err(format!(
                "{n} positions but {} attachments",
                self.attachments.len()
            ));
        }
        for (i, &p) in self.positions.iter().enumerate() {
            if !p.is_finite() {
                return Err(format!("particle {i}: position {p} is not finite"));
            }
        }
        for (i, &r) in self.radii.iter().enumerate() {
            if !(r.is_finite() && r > 0.0) {
                return Err(format!(
                    "particle {i}: radius {r} is not a positive finite number"
                ));
            }
        }
        check_surface(&self.surface)?;
        let triangles = self.surface.triangles.len();
        for (i, a) in self.attachments.iter().enumerate() {
            let Some(a) = a else { continue };
            if a.triangle as usize >= triangles {
                return Err(format!(
                    "particle {i}: attached to triangle {} but the surface has {triangles} triangles",
                    a.triangle
                ));
            }
            if !a.barycentric.iter().all(|b| b.is_finite()) {
                return Err(format!(
                    "particle {i}: barycentric coordinates {:?} are not finite",
                    a.barycentric
                ));
            }
        }
        check_connections(&self.connections, n)
    }
}

fn check_surface(surface: &SurfaceMesh) -> Result<(), String> {
    let vertices = surface.vertices.len();
    for (v, &p) in surface.vertices.iter().enumerate() {
        if !p.is_finite() {
            return Err(format!("surface vertex {v}: position {p} is not finite"));
        }
    }
    for (t, tri) in surface.triangles.iter().enumerate() {
        if let Some(&v) = tri.iter().find(|&&v| v as usize >= vertices) {
            return Err(format!(
                "surface triangle {t} uses vertex {v} but the surface has {vertices} vertices"
            ));
        }
    }
    Ok(())
}

/// The CSR invariants of [`Connections`] for `n` particles: `n + 1`
/// monotone offsets, rows sorted strictly ascending, no self-connections,
/// and symmetry. The model file stores each pair once, so an asymmetric row
/// would not survive the trip.
fn check_connections(c: &Connections, n: usize) -> Result<(), String> {
    if c.offsets.len() != n + 1 {
        return Err(format!(
            "connections have {} row offsets, expected {} (particles + 1)",
            c.offsets.len(),
            n + 1
        ));
    }
    if c.offsets[0] != 0 || c.offsets[n] as usize != c.indices.len() {
        return Err(format!(
            "connection offsets run from {} to {}, expected 0 to {} (the number of indices)",
            c.offsets[0],
            c.offsets[n],
            c.indices.len()
        ));
    }
    if let Some(i) = c.offsets.windows(2).position(|w| w[0] > w[1]) {
        return Err(format!("connection offsets decrease at particle {i}"));
    }
    for i in 0..n {
        let row = c.of(i);
        for (k, &j) in row.iter().enumerate() {
            if j as usize >= n {
                return Err(format!("particle {i} is connected to particle {j} of {n}"));
            }
            if j as usize == i {
                return Err(format!("particle {i} is connected to itself"));
            }
            if k > 0 && row[k - 1] >= j {
                return Err(format!(
                    "the connections of particle {i} are not sorted ascending without repeats"
                ));
            }
            if c.of(j as usize).binary_search(&(i as u32)).is_err() {
                return Err(format!(
                    "particle {i} is connected to {j} but {j} is not connected to {i}"
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    /// A tetrahedron with two interior particles and two attached ones.
    pub(crate) fn small_model() -> ParticleModel {
        let surface = SurfaceMesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        );
        ParticleModel {
            positions: vec![
                Vec3::splat(0.2),
                Vec3::new(0.1, 0.15, 0.1),
                Vec3::new(0.25, 0.25, 0.0),
                Vec3::new(0.3, 0.0, 0.3),
            ],
            radii: vec![0.1, 0.1, 0.05, 0.05],
            attachments: vec![
                None,
                None,
                Some(Attachment {
                    triangle: 0,
                    barycentric: [0.5, 0.25, 0.25],
                }),
                Some(Attachment {
                    triangle: 1,
                    barycentric: [0.4, 0.3, 0.3],
                }),
            ],
            connections: Connections::from_pairs(4, [(0, 1), (0, 2), (1, 3), (2, 3)]),
            surface,
        }
    }

    /// The message of [`ParticleModel::validate`]'s error.
    fn problem(model: &ParticleModel) -> String {
        match model.validate() {
            Err(Error::InvalidModel(message)) => message,
            other => panic!("expected Error::InvalidModel, got {other:?}"),
        }
    }

    #[test]
    fn consistent_model_is_valid() {
        small_model().validate().unwrap();
    }

    #[test]
    fn inconsistent_models_are_refused() {
        let mut model = small_model();
        model.radii.pop();
        assert!(problem(&model).contains("4 positions but 3 radii"));

        let mut model = small_model();
        model.connections.indices[0] = 3; // row 0 becomes [3, 2]: unsorted, asymmetric
        assert!(model.validate().is_err());

        let mut model = small_model();
        model.attachments[2] = Some(Attachment {
            triangle: 9,
            barycentric: [1.0, 0.0, 0.0],
        });
        assert!(problem(&model).contains("triangle 9"));

        assert!(problem(&ParticleModel::default()).contains("no particles"));
    }

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
