//! Internal structures (a tumour, a vessel) and landmark points, carried by
//! the particles around them.
//!
//! - **Deformable**: every point is carried by its `K` nearest particles at
//!   rest: `x' = sum_k w_k (q_k + R_k (x - p_k)) / sum_k w_k`, with `R_k` the
//!   particle's rotation and weights `w_k = (1 - (d_k / h)^2)^2`, `h` a little
//!   beyond the farthest of the `K`. A rigid motion of all particles
//!   (`q = R p + t`, `R_k = R`) moves every point by exactly that motion.
//! - **Rigid** (the paper's tumour): the structure's centre is carried as a
//!   deformable point; its rotation is the Procrustes fit over the particles
//!   nearest the centre. The centre is passive: it does not push back.

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::model::svd3::rotation_of;
use crate::stage1::grid::{Grid, grid_build};

/// Particles carrying each point.
pub const CARRIERS: usize = 8;
/// Particles whose fit gives a rigid structure's rotation.
pub const RIGID_NEIGHBOURS: usize = 16;

/// Points bound to particles at rest, ready to be moved with them.
#[derive(Debug, Clone)]
pub struct Embedding {
    /// Rest positions of the points.
    pub points: Vec<Vec3>,
    /// Per point, `(particle, weight)`, weights summing to one.
    pub carriers: Vec<Vec<(u32, f32)>>,
}

/// The `k` nearest particles of `p` (fewer when there are fewer), nearest first,
/// ties by index.
pub fn k_nearest(grid: &Grid, positions: &[Vec3], p: Vec3, k: usize) -> Vec<(u32, f32)> {
    let k = k.min(positions.len());
    let centre = grid.cell_of(p);
    let mut best: Vec<(u32, f32)> = Vec::with_capacity(4 * k);
    for shell in 0..=grid.max_shell() {
        grid.for_each_in_shell(centre, shell, |j| {
            best.push((j, (positions[j as usize] - p).length()))
        });
        best.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        best.truncate(k);
        // Everything outside shells 0..=shell is at least shell cells away.
        if best.len() == k && best.last().is_some_and(|b| b.1 <= shell as f32 * grid.cell) {
            break;
        }
    }
    best
}

/// The particles that carry a point at `x`: its `CARRIERS` nearest of
/// `particles` (binned in `grid`), with weights `(1 - (d / h)^2)^2`
/// summing to one, `h` a little beyond the farthest.
pub fn carriers_of(grid: &Grid, particles: &[Vec3], x: Vec3) -> Vec<(u32, f32)> {
    let near = k_nearest(grid, particles, x, CARRIERS);
    let h = near.last().map_or(1.0, |n| n.1) * 1.1 + 1e-12;
    let mut weights: Vec<(u32, f32)> = near
        .iter()
        .map(|&(j, d)| (j, (1.0 - (d / h).powi(2)).powi(2)))
        .collect();
    let total: f32 = weights.iter().map(|w| w.1).sum();
    for w in &mut weights {
        w.1 /= total;
    }
    weights
}

impl Embedding {
    /// Binds `points` to the `CARRIERS` nearest of the rest `particles`.
    pub fn new(particles: &[Vec3], points: &[Vec3]) -> Self {
        let spacing = typical_spacing(particles);
        let grid = grid_build(particles, spacing);
        let carriers = points
            .par_iter()
            .map(|&x| carriers_of(&grid, particles, x))
            .collect();
        Self {
            points: points.to_vec(),
            carriers,
        }
    }

    /// Where the points are when the particles are at `current` with `rotations`.
    pub fn moved(&self, rest: &[Vec3], current: &[Vec3], rotations: &[Mat3]) -> Vec<Vec3> {
        embedding_moved(&self.points, &self.carriers, rest, current, rotations)
    }
}

/// Where embedded `points` go: `x' = sum_k w_k (q_k + R_k (x - p_k))` over
/// each point's `carriers`. The twin of `embedding_moved.wgsl`.
pub fn embedding_moved(
    points: &[Vec3],
    carriers: &[Vec<(u32, f32)>],
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
) -> Vec<Vec3> {
    points
        .par_iter()
        .zip(carriers)
        .map(|(&x, carriers)| {
            carriers
                .iter()
                .map(|&(k, w)| {
                    let k = k as usize;
                    w * (current[k] + rotations[k] * (x - rest[k]))
                })
                .sum()
        })
        .collect()
}

/// A rigid structure's motion: `x -> rotation (x - rest_centre) + moved_centre`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidMotion {
    /// Centroid of the structure at rest.
    pub rest_centre: Vec3,
    /// Where that centroid went.
    pub moved_centre: Vec3,
    /// Rotation (rows of the 3x3 matrix).
    pub rotation: [[f32; 3]; 3],
}

impl RigidMotion {
    /// The rotation matrix.
    pub fn matrix(&self) -> Mat3 {
        Mat3::from_cols_array_2d(&self.rotation).transpose()
    }

    /// Applies the motion to a point.
    pub fn apply(&self, x: Vec3) -> Vec3 {
        self.matrix() * (x - self.rest_centre) + self.moved_centre
    }

    /// The 4x4 homogeneous matrix (row-major), as 3D Slicer and ITK expect.
    pub fn homogeneous(&self) -> [[f32; 4]; 4] {
        let r = self.rotation;
        let t = self.moved_centre - self.matrix() * self.rest_centre;
        [
            [r[0][0], r[0][1], r[0][2], t.x],
            [r[1][0], r[1][1], r[1][2], t.y],
            [r[2][0], r[2][1], r[2][2], t.z],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }
}

/// A rigid structure bound at rest: its centre's carriers and the particles
/// whose fit gives its rotation.
#[derive(Debug, Clone)]
pub struct RigidBinding {
    centre: Embedding,
    neighbours: Vec<u32>,
}

impl RigidBinding {
    /// Binds the structure with rest `vertices` (its centroid is the centre).
    pub fn new(particles: &[Vec3], vertices: &[Vec3]) -> Self {
        let centre = vertices.iter().copied().sum::<Vec3>() / vertices.len().max(1) as f32;
        let grid = grid_build(particles, typical_spacing(particles));
        let neighbours = k_nearest(&grid, particles, centre, RIGID_NEIGHBOURS)
            .into_iter()
            .map(|(j, _)| j)
            .collect();
        Self {
            centre: Embedding::new(particles, &[centre]),
            neighbours,
        }
    }

    /// The structure's motion for the particles at `current`.
    pub fn motion(&self, rest: &[Vec3], current: &[Vec3], rotations: &[Mat3]) -> RigidMotion {
        let moved_centre = self.centre.moved(rest, current, rotations)[0];
        self.motion_from(moved_centre, rest, current)
    }

    /// The centre, embedded like a landmark (one point).
    pub fn centre(&self) -> &Embedding {
        &self.centre
    }

    /// The motion when the centre has gone to `moved_centre` (carried
    /// elsewhere, on the GPU say) and the particles are at `current`.
    pub fn motion_from(&self, moved_centre: Vec3, rest: &[Vec3], current: &[Vec3]) -> RigidMotion {
        let n = self.neighbours.len().max(1) as f32;
        let rest_mean = self
            .neighbours
            .iter()
            .map(|&j| rest[j as usize])
            .sum::<Vec3>()
            / n;
        let current_mean = self
            .neighbours
            .iter()
            .map(|&j| current[j as usize])
            .sum::<Vec3>()
            / n;
        let mut m = Mat3::ZERO;
        for &j in &self.neighbours {
            let d = rest[j as usize] - rest_mean;
            let c = current[j as usize] - current_mean;
            m += Mat3::from_cols(c * d.x, c * d.y, c * d.z);
        }
        let rotation = rotation_of(m);
        RigidMotion {
            rest_centre: self.centre.points[0],
            moved_centre,
            rotation: rotation.transpose().to_cols_array_2d(),
        }
    }
}

/// About the mean spacing of a particle cloud, for grid cells.
pub fn typical_spacing(particles: &[Vec3]) -> f32 {
    let (lo, hi) = particles.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let volume = (hi - lo).max(Vec3::splat(1e-12)).element_product();
    (volume / particles.len().max(1) as f32).cbrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn k_nearest_matches_brute_force_and_orders_ties_by_index() {
        let mut s = 99u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut points: Vec<Vec3> = (0..1_531)
            .map(|_| Vec3::new(next(), next() * 0.2, next()))
            .collect();
        points.push(Vec3::splat(30.0)); // a far outlier widens the search
        points.push(points[5]); // an exact tie
        let grid = grid_build(&points, typical_spacing(&points));
        for q in [
            points[5],
            Vec3::splat(0.5),
            Vec3::new(-3.0, 0.1, 0.4),
            Vec3::splat(29.0),
        ] {
            for k in [1, 8, 16] {
                let got = k_nearest(&grid, &points, q, k);
                let mut brute: Vec<(u32, f32)> = (0..points.len() as u32)
                    .map(|j| (j, (points[j as usize] - q).length()))
                    .collect();
                brute.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                brute.truncate(k);
                assert_eq!(got, brute, "k = {k} at {q}");
            }
        }
    }
}
