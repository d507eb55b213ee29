//! The elastic model of stage 2: the rotation-aware pair energy (shear) plus
//! a volume term weighted by a Poisson ratio (docs/METHOD.md, "Elastic
//! model").
//!
//! Per particle `i`, with rest offsets `d_ij = p_j - p_i` and current
//! offsets `e_ij = q_j - q_i` over its connections:
//! - the moment matrix `A_i = sum_j d_ij d_ij^T` and the corrected gradient
//!   `F_i = M_i A_i^-1`, `M_i = sum_j e_ij d_ij^T`: any affine map `q = B p + t`
//!   gives `F_i = B` exactly, whatever the neighbourhood's shape;
//! - `J_i = det F_i`, the particle's change of volume.
//!
//! The energy is `E = sum_i sum_j |e_ij - R_i d_ij|^2 + sum_i W_i (J_i - 1)^2`.
//! For small strains particle `i`'s pair term is `tr((F_i - R_i) A_i (F_i - R_i)^T)`,
//! `a_i |eps|^2` for a round neighbourhood (`a_i = tr(A_i) / 3`): linear
//! elasticity's `mu |eps|^2` times the particle's volume, with `mu V_i = a_i`.
//! Its `(lambda / 2) tr(eps)^2 V_i` is then `W_i (J_i - 1)^2` to first
//! order, with `W_i = nu / (1 - 2 nu) a_i` (`lambda / mu = 2 nu / (1 - 2 nu)`).
//!
//! The force is `-1/2` the energy's gradient, as for the symmetric model:
//! `f_j = sum_i [(T_i + T_j) d_ij - 2 e_ij]` with the per-particle target
//! `T_i = R_i - H_i`, `H_i = W_i (J_i - 1) cof(F_i) A_i^-1`. The force keeps
//! the symmetric force's shape: a device computes `T_i` where it computes
//! `R_i` and gathers the same sum, with no atomics.

use glam::{DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::Connections;

use crate::spectrum::lanczos_extremes;

/// A neighbourhood whose moment matrix has `det A / (tr A / 3)^3` below this
/// is too flat (its particles nearly on a plane or a line) for a volume:
/// such a particle keeps the shear term only.
pub const FLAT_NEIGHBOURHOOD: f32 = 1e-3;

/// How much stiffer than at rest the elastic operator may become where the
/// solve goes: the volume term's stiffness grows with `cof(F)`, whose
/// entries are products of two stretches. After the shear phase that starts
/// every elastic solve ([`crate::tracker::Tracker::solve`]), both breast
/// phantoms at `nu` 0.49 diverge with 1.0 and converge with 1.5
/// (docs/METHOD.md, "Elastic model"); 2.0 leaves a third more margin.
pub const STIFFENING: f32 = 2.0;

/// The largest Poisson ratio [`crate::params::DeformParams::poisson`] accepts:
/// at 0.5 the volume term's weight is infinite.
pub const MAX_POISSON: f32 = 0.499;

/// What the elastic model knows of each particle at rest.
#[derive(Debug, Clone, PartialEq)]
pub struct Elastic {
    /// Per particle, `A_i^-1` (zero for a flat neighbourhood).
    pub inverse_moments: Vec<Mat3>,
    /// Per particle, the volume term's weight `W_i = nu / (1 - 2 nu) tr(A_i) / 3`
    /// (zero for a flat neighbourhood).
    pub weights: Vec<f32>,
    /// The Poisson ratio the weights were made for.
    pub poisson: f32,
}

impl Elastic {
    /// The moment matrices of every particle's neighbourhood in `rest` and
    /// the volume weights for Poisson ratio `poisson` (in `[0, MAX_POISSON]`).
    pub fn new(rest: &[Vec3], connections: &Connections, poisson: f32) -> Self {
        let ratio = poisson / (1.0 - 2.0 * poisson);
        let (inverse_moments, weights) = (0..rest.len())
            .into_par_iter()
            .map(|i| {
                let a = moment(rest, connections, i);
                if !is_round(a) {
                    return (Mat3::ZERO, 0.0);
                }
                // lambda / 2 = nu / (1 - 2 nu) mu with mu = a_i = tr(A_i) / 3.
                (a.inverse(), ratio * a.diagonal().element_sum() / 3.0)
            })
            .unzip();
        Self {
            inverse_moments,
            weights,
            poisson,
        }
    }

    /// Particle `i`'s corrected gradient `F_i = M_i A_i^-1` from its
    /// offsets product `M_i = sum_j e_ij d_ij^T`.
    pub fn gradient(&self, i: usize, offsets_product: Mat3) -> Mat3 {
        offsets_product * self.inverse_moments[i]
    }

    /// Particle `i`'s target `T_i = R_i - W_i (J_i - 1) cof(F_i) A_i^-1`
    /// from its offsets product and its rotation.
    pub fn target(&self, i: usize, offsets_product: Mat3, rotation: Mat3) -> Mat3 {
        let w = self.weights[i];
        if w == 0.0 {
            return rotation;
        }
        let f = self.gradient(i, offsets_product);
        rotation - (w * (f.determinant() - 1.0)) * cofactor(f) * self.inverse_moments[i]
    }

    /// The volume term `sum_i W_i (J_i - 1)^2` of the energy at `current`.
    pub fn volume_energy(&self, rest: &[Vec3], current: &[Vec3], connections: &Connections) -> f64 {
        (0..rest.len())
            .map(|i| {
                let m = offsets_product(rest, current, connections, i);
                let j = self.gradient(i, m).determinant();
                f64::from(self.weights[i]) * f64::from(j - 1.0).powi(2)
            })
            .sum()
    }

    /// The largest eigenvalue the solve's step is set for, in the units of
    /// the connection Laplacian `L`: [`STIFFENING`] times the rest
    /// operator's ([`Elastic::rest_lambda_max`]).
    pub fn lambda_max(&self, rest: &[Vec3], connections: &Connections, free: &[bool]) -> f32 {
        STIFFENING * self.rest_lambda_max(rest, connections, free)
    }

    /// The largest eigenvalue of the model's operator at rest over free
    /// particles, in the units of the connection Laplacian `L` (the
    /// force of a small displacement `u` from rest is `-2 K u`; for the
    /// pair term alone `K = L`), by 40 Lanczos steps with a 2 % margin.
    pub fn rest_lambda_max(&self, rest: &[Vec3], connections: &Connections, free: &[bool]) -> f32 {
        let apply = |u: &[f64]| -> Vec<f64> {
            let u: Vec<DVec3> = u
                .chunks_exact(3)
                .map(|c| DVec3::new(c[0], c[1], c[2]))
                .collect();
            self.rest_operator(rest, connections, free, &u)
                .iter()
                .flat_map(|r| r.to_array())
                .collect()
        };
        let start: Vec<bool> = free.iter().flat_map(|&f| [f; 3]).collect();
        let (_, hi) = lanczos_extremes(&start, apply, 40);
        hi
    }

    /// `K u`: the model's operator at rest applied to a displacement `u` of
    /// the free particles (entries of fixed ones are read as zero), in the
    /// units of the connection Laplacian: the force of a small displacement
    /// `u` from rest is `-2 K u`, and for the pair term alone `K = L`.
    pub fn rest_operator(
        &self,
        rest: &[Vec3],
        connections: &Connections,
        free: &[bool],
        u: &[DVec3],
    ) -> Vec<DVec3> {
        let at = |i: usize| if free[i] { u[i] } else { DVec3::ZERO };
        // Per particle, the linearised `H_i = W_i tr(G_i) A_i^-1`, with
        // `G_i = sum_j (u_j - u_i) b_ij^T`, `b_ij = A_i^-1 d_ij`.
        let h: Vec<DMat3> = (0..rest.len())
            .into_par_iter()
            .map(|i| {
                if self.weights[i] == 0.0 {
                    return DMat3::ZERO;
                }
                let inverse = self.inverse_moments[i].as_dmat3();
                let mut trace = 0.0;
                for &j in connections.of(i) {
                    let b = inverse * (rest[j as usize] - rest[i]).as_dvec3();
                    trace += (at(j as usize) - at(i)).dot(b);
                }
                inverse * (f64::from(self.weights[i]) * trace)
            })
            .collect();
        (0..rest.len())
            .into_par_iter()
            .map(|j| {
                if !free[j] {
                    return DVec3::ZERO;
                }
                // -f / 2 with f_j = sum_i [-2 (u_j - u_i) - (H_i + H_j) d_ij].
                let mut k = DVec3::ZERO;
                for &i in connections.of(j) {
                    let i = i as usize;
                    let d = (rest[j] - rest[i]).as_dvec3();
                    k += (at(j) - at(i)) + 0.5 * ((h[i] + h[j]) * d);
                }
                k
            })
            .collect()
    }
}

/// Whether a neighbourhood with moment matrix `a` spans three dimensions:
/// `det A / (tr A / 3)^3` at least [`FLAT_NEIGHBOURHOOD`] (false for fewer
/// than three connections, or all of them in a plane or on a line).
pub fn is_round(a: Mat3) -> bool {
    let scale = a.diagonal().element_sum() / 3.0;
    scale > 0.0 && a.determinant() > FLAT_NEIGHBOURHOOD * scale * scale * scale
}

/// `A_i = sum_j d_ij d_ij^T` over particle `i`'s connections at rest.
pub fn moment(rest: &[Vec3], connections: &Connections, i: usize) -> Mat3 {
    let mut a = Mat3::ZERO;
    for &j in connections.of(i) {
        let d = rest[j as usize] - rest[i];
        a += Mat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    a
}

/// `M_i = sum_j (q_j - q_i)(p_j - p_i)^T` over particle `i`'s connections:
/// the matrix whose polar rotation maps its rest offsets onto its current
/// ones, and which `A_i^-1` turns into its gradient.
pub fn offsets_product(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    i: usize,
) -> Mat3 {
    let mut m = Mat3::ZERO;
    for &j in connections.of(i) {
        let d = rest[j as usize] - rest[i];
        let c = current[j as usize] - current[i];
        m += Mat3::from_cols(c * d.x, c * d.y, c * d.z);
    }
    m
}

/// `cof(F) = det(F) F^-T`, the derivative of `det F`, defined for every `F`:
/// its columns are the cross products of `F`'s.
pub fn cofactor(f: Mat3) -> Mat3 {
    Mat3::from_cols(
        f.y_axis.cross(f.z_axis),
        f.z_axis.cross(f.x_axis),
        f.x_axis.cross(f.y_axis),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectrum::laplacian_extremes;

    /// A 6x6x6 grid of unit spacing jittered by up to 0.2, its pairs closer
    /// than 1.5 connected, the outer layer fixed.
    fn jittered_block() -> (Vec<Vec3>, Connections, Vec<bool>) {
        let (positions, pairs, free) = tissue_testkit::jittered_grid(6, 7);
        let connections = Connections::from_pairs(positions.len(), pairs);
        (positions, connections, free)
    }

    #[test]
    fn any_affine_map_gives_its_matrix_as_every_gradient() {
        let (rest, connections, _) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49);
        let b = Mat3::from_cols(
            Vec3::new(1.2, 0.1, -0.3),
            Vec3::new(0.05, 0.9, 0.2),
            Vec3::new(0.4, 0.0, 1.1),
        );
        let current: Vec<Vec3> = rest
            .iter()
            .map(|&p| b * p + Vec3::new(3.0, -1.0, 2.0))
            .collect();
        for i in 0..rest.len() {
            let f = elastic.gradient(i, offsets_product(&rest, &current, &connections, i));
            let off = (f - b)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |m, x| m.max(x.abs()));
            assert!(off < 1e-4, "particle {i}: F off by {off}");
        }
    }

    #[test]
    fn a_rigid_motion_has_no_volume_energy_and_its_rotation_as_target() {
        let (rest, connections, _) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49);
        let r = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 0.8);
        let current: Vec<Vec3> = rest.iter().map(|&p| r * p + Vec3::ONE).collect();
        assert!(elastic.volume_energy(&rest, &current, &connections) < 1e-8);
        for i in 0..rest.len() {
            let t = elastic.target(i, offsets_product(&rest, &current, &connections, i), r);
            let off = (t - r)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |m, x| m.max(x.abs()));
            assert!(off < 1e-4, "particle {i}: target off by {off}");
        }
    }

    #[test]
    fn the_volume_weight_is_lambda_over_two_mu_per_particle() {
        let (rest, connections, _) = jittered_block();
        for poisson in [0.0, 0.3, 0.49] {
            let elastic = Elastic::new(&rest, &connections, poisson);
            for i in [0, 100, 215] {
                let a = moment(&rest, &connections, i);
                let mu = (a.x_axis.x + a.y_axis.y + a.z_axis.z) / 3.0;
                let want = poisson / (1.0 - 2.0 * poisson) * mu;
                assert!((elastic.weights[i] - want).abs() <= 1e-5 * want.max(1.0));
            }
        }
        // 0.49 gives lambda / mu = 49: a weight of 24.5 mu.
        let elastic = Elastic::new(&rest, &connections, 0.49);
        let a = moment(&rest, &connections, 100);
        let mu = (a.x_axis.x + a.y_axis.y + a.z_axis.z) / 3.0;
        assert!((elastic.weights[100] / mu - 24.5).abs() < 1e-3);
    }

    #[test]
    fn a_flat_neighbourhood_keeps_the_shear_term_only() {
        // Three particles on a line and one off it in the plane z = 0.
        let rest = vec![
            Vec3::ZERO,
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            Vec3::new(0.5, 0.5, 0.0),
        ];
        let connections = Connections::from_pairs(5, [(0, 1), (0, 2), (0, 3), (0, 4)]);
        let elastic = Elastic::new(&rest, &connections, 0.49);
        assert_eq!(elastic.weights[0], 0.0);
        assert_eq!(elastic.inverse_moments[0], Mat3::ZERO);
        let squashed: Vec<Vec3> = rest.iter().map(|&p| 0.5 * p).collect();
        let t = elastic.target(
            0,
            offsets_product(&rest, &squashed, &connections, 0),
            Mat3::IDENTITY,
        );
        assert_eq!(t, Mat3::IDENTITY);
    }

    #[test]
    fn without_volume_resistance_the_operator_is_the_laplacian() {
        let (rest, connections, free) = jittered_block();
        let (_, laplacian) = laplacian_extremes(&connections, &free);
        let elastic = Elastic::new(&rest, &connections, 0.0);
        let at_rest = elastic.rest_lambda_max(&rest, &connections, &free);
        assert!(
            (at_rest - laplacian).abs() <= 0.01 * laplacian,
            "{at_rest} vs {laplacian}"
        );
        assert_eq!(
            elastic.lambda_max(&rest, &connections, &free),
            STIFFENING * at_rest
        );
        // Resisting volume change stiffens it: several times the shear alone at 0.49.
        let stiff =
            Elastic::new(&rest, &connections, 0.49).rest_lambda_max(&rest, &connections, &free);
        assert!(stiff > 4.0 * laplacian, "{stiff} vs {laplacian}");
    }

    #[test]
    fn the_cofactor_is_the_derivative_of_the_determinant() {
        for f in tissue_testkit::matrices(20) {
            let cof = cofactor(f);
            assert!(
                (f.transpose() * cof - f.determinant() * Mat3::IDENTITY)
                    .to_cols_array()
                    .iter()
                    .all(|x| x.abs() < 1e-5)
            );
        }
    }
}
