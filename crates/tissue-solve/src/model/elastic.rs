//! The elastic model of stage 2: a co-rotated shear term plus a volume term
//! weighted by a Poisson ratio, with gradients that pass the patch test
//! (docs/METHOD.md, "Elastic model").
//!
//! Per particle `i`, with rest offsets `d_ij = p_j - p_i` and current
//! offsets `e_ij = q_j - q_i` over its connections, `A_i = sum_j d_ij d_ij^T`
//! and `M_i = sum_j e_ij d_ij^T`:
//! - the least-squares gradient `Fh_i = M_i A_i^-1`;
//! - the consistent gradient `F_i = sum_j e_ij c_ij^T` with the vectors of
//!   [`crate::model::consistent`], `c_ij = B_i d_ij + a_i (mu_j - mu_i)`:
//!   `F_i = M_i B_i^T + a_i sum_j e_ij (mu_j - mu_i)^T`. Both give any affine
//!   map's matrix exactly, whatever the neighbourhood's shape;
//! - `J_i = det F_i`, `R_i` the polar rotation of `F_i`, `a_i = tr(A_i) / 3`.
//!
//! The energy is
//! `E = sum_i [ sum_j |e_ij - Fh_i d_ij|^2 + a_i |F_i - R_i|^2 + W_i (J_i - 1)^2 ]`.
//! The first two terms are the rotation-aware pair energy
//! `sum_j |e_ij - R_i d_ij|^2` split at `Fh_i` (its non-affine part, zero for
//! any affine map, and `tr((Fh_i - R_i) A_i (Fh_i - R_i)^T)`, made isotropic
//! and moved onto `F_i`); for small strains `a_i |eps|^2` is linear
//! elasticity's `mu |eps|^2` times the particle's volume, so the volume term
//! `(lambda / 2) tr(eps)^2 V_i` is `W_i (J_i - 1)^2` with
//! `W_i = nu / (1 - 2 nu) a_i`. Every stress term is a function of `F_i`
//! weighted by `a_i`, and the vectors satisfy the integration constraint,
//! so an affine map of the boundary is an equilibrium: the patch test.
//!
//! The force is `-1/2` the gradient (rotations held, as for the symmetric
//! model): with `Q_i = a_i (F_i - R_i) + W_i (J_i - 1) cof(F_i)`,
//! `f_k = sum_i [(T_i + T_k) d_ik - (U_i + U_k)(mu_k - mu_i) - 2 e_ik]`,
//! targets `T_i = Fh_i - Q_i B_i` and stresses `U_i = a_i Q_i`: the symmetric
//! force's gather over the offsets `(d_ik, -(mu_k - mu_i))`, no atomics. A
//! flat neighbourhood (no gradient) keeps the pair term `sum_j |e_ij - R_i d_ij|^2`
//! with `R_i` the polar rotation of `M_i`: `T_i = R_i`, `U_i = 0`.

use glam::{DMat3, DVec3, Mat3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;
use tissue_core::Connections;

use crate::model::consistent::Consistency;
pub use crate::model::consistent::offsets_outer;
use crate::model::entries::Entries;
pub use crate::model::entries::{NO_MIRROR, VolumeLinearisation};
use crate::model::svd3::rotation_of;
use crate::stage2::spectrum::lanczos_extremes;

/// A neighbourhood whose moment matrix has `det A / (tr A / 3)^3` below this
/// is too flat (its particles nearly on a plane or a line) for a volume:
/// such a particle keeps the shear term only.
pub const FLAT_NEIGHBOURHOOD: f32 = 1e-3;

/// How much stiffer than at rest the elastic operator may become where the
/// solve goes: the volume term's stiffness grows with `cof(F)`, whose
/// entries are products of two stretches. After the shear phase that starts
/// every elastic solve ([`crate::stage2::tracker::Tracker::solve`]), both breast
/// phantoms at `nu` 0.49 diverge with 1.0 and converge with 1.5
/// (docs/METHOD.md, "Elastic model"); 2.0 leaves a third more margin.
pub const STIFFENING: f32 = 2.0;

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
    /// The consistent gradient vectors: per particle `a_i`, `mu_i`, `B_i`.
    pub consistency: Consistency,
    /// Per connection slot (`connections.indices`' order), the slot of the
    /// same connection in the neighbour's row: `i`'s slot of `j` gives
    /// `j`'s slot of `i` ([`NO_MIRROR`] where `j` does not list `i`).
    pub mirrors: Vec<u32>,
}

/// What particle `i` puts into its neighbours' elastic force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElasticTerms {
    /// `T_i = Fh_i - Q_i B_i`, gathered against the rest offsets.
    pub target: Mat3A,
    /// `U_i = a_i Q_i`, gathered against the multipliers' offsets.
    pub stress: Mat3A,
}

impl Elastic {
    /// The moment matrices of every particle's neighbourhood in `rest`, the
    /// volume weights for Poisson ratio `poisson` (in `[0, MAX_POISSON]`)
    /// and the consistent gradient vectors with the constraint held at the
    /// `free` particles (the interior ones that move: a surface particle's
    /// vectors integrate to its share of the boundary).
    pub fn new(rest: &[Vec3], connections: &Connections, poisson: f32, free: &[bool]) -> Self {
        let (inverse_moments, weights) = moments_and_weights(rest, connections, poisson);
        let consistency = Consistency::new(rest, connections, &inverse_moments, free);
        Self {
            inverse_moments,
            weights,
            poisson,
            consistency,
            mirrors: mirrors(connections),
        }
    }

    /// This model with the volume weights of Poisson ratio `poisson`
    /// (`rest` and `connections` the ones it was made in): what
    /// [`Elastic::new`] makes for that ratio, to the bit, without solving
    /// for the consistent gradients again (they do not depend on the
    /// ratio, and are most of the making).
    pub fn with_poisson(&self, rest: &[Vec3], connections: &Connections, poisson: f32) -> Self {
        let (inverse_moments, weights) = moments_and_weights(rest, connections, poisson);
        Self {
            inverse_moments,
            weights,
            poisson,
            consistency: self.consistency.clone(),
            mirrors: self.mirrors.clone(),
        }
    }

    /// Whether particle `i`'s neighbourhood is flat: no gradient, the pair
    /// term only.
    pub fn is_flat(&self, i: usize) -> bool {
        self.consistency.scales[i] == 0.0
    }

    /// How far the neighbourhoods' volumes at `current` are from one
    /// uniform change: the RMS over the particles with a volume weight of
    /// `J_i - mean(J)`, `J_i = det F_i`. The volume term drives it towards
    /// zero (a nearly incompressible body spreads a volume change the
    /// surface forces over the whole), the pair term does not, so what is
    /// left of it where the shear phase has converged is what the elastic
    /// phase has to move; a rigid turn or a uniform scaling leaves none.
    /// Zero where no particle has a weight. In `f64` sums, in index order.
    pub fn volume_misfit(&self, rest: &[Vec3], current: &[Vec3], connections: &Connections) -> f32 {
        let volumes: Vec<f64> = (0..rest.len())
            .into_par_iter()
            .filter(|&i| self.weights[i] != 0.0 && !self.is_flat(i))
            .map(|i| {
                let (m, n) = self.products(rest, current, connections, i);
                f64::from(self.gradient(i, m, n).determinant())
            })
            .collect();
        if volumes.is_empty() {
            return 0.0;
        }
        let count = volumes.len() as f64;
        let mean = volumes.iter().sum::<f64>() / count;
        let spread = volumes.iter().map(|j| (j - mean).powi(2)).sum::<f64>() / count;
        spread.sqrt() as f32
    }

    /// Particle `i`'s least-squares gradient `Fh_i = M_i A_i^-1` from its
    /// offsets product `M_i = sum_j e_ij d_ij^T`.
    pub fn least_squares_gradient(&self, i: usize, offsets_product: Mat3) -> Mat3 {
        offsets_product * self.inverse_moments[i]
    }

    /// Particle `i`'s consistent gradient `F_i = M_i B_i^T + a_i N_i` from
    /// its offsets product `M_i` and its multipliers' product
    /// `N_i = sum_j e_ij (mu_j - mu_i)^T` ([`Consistency::multipliers_product`]).
    pub fn gradient(&self, i: usize, offsets_product: Mat3, multipliers_product: Mat3) -> Mat3 {
        let c = &self.consistency;
        offsets_product * c.corrections[i].transpose() + c.scales[i] * multipliers_product
    }

    /// Particle `i`'s terms of the force from its two products and its
    /// rotation: the polar rotation of its gradient
    /// ([`Elastic::gradient`]), or of `M_i` for a flat neighbourhood.
    pub fn terms(
        &self,
        i: usize,
        offsets_product: Mat3,
        multipliers_product: Mat3,
        rotation: Mat3,
    ) -> ElasticTerms {
        let turned = self.turned_of(i, offsets_product, multipliers_product);
        self.terms_of_gradient(i, offsets_product, turned, rotation)
    }

    /// The matrix particle `i`'s rotation is the polar rotation of: its
    /// gradient ([`Elastic::gradient`]), or its offsets product `M_i` for a
    /// flat neighbourhood.
    pub fn turned_of(&self, i: usize, offsets_product: Mat3, multipliers_product: Mat3) -> Mat3 {
        if self.is_flat(i) {
            offsets_product
        } else {
            self.gradient(i, offsets_product, multipliers_product)
        }
    }

    /// [`Elastic::terms`] from the offsets product and the matrix `turned`
    /// ([`Elastic::turned_of`]) as already made for the rotation, not made
    /// again.
    pub fn terms_of_gradient(
        &self,
        i: usize,
        offsets_product: Mat3,
        turned: Mat3,
        rotation: Mat3,
    ) -> ElasticTerms {
        if self.is_flat(i) {
            return ElasticTerms {
                target: Mat3A::from(rotation),
                stress: Mat3A::ZERO,
            };
        }
        let (a, f) = (self.consistency.scales[i], turned);
        let q = a * (f - rotation) + (self.weights[i] * (f.determinant() - 1.0)) * cofactor(f);
        ElasticTerms {
            target: Mat3A::from(
                self.least_squares_gradient(i, offsets_product)
                    - q * self.consistency.corrections[i],
            ),
            stress: Mat3A::from(a * q),
        }
    }

    /// Particle `i`'s offsets product `M_i = sum_j e_ij d_ij^T` and its
    /// multipliers' product `N_i = sum_j e_ij (mu_j - mu_i)^T` in one pass
    /// over its connections (each current offset formed once; the WGSL
    /// twin's `products`).
    pub fn products(
        &self,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        i: usize,
    ) -> (Mat3, Mat3) {
        // In 4-lane vectors (`Vec3A`): each entry's products and sums are
        // the ones `Vec3` makes, three at a time.
        let mu = &self.consistency.multipliers;
        let at = |v: &[Vec3], j: usize| Vec3A::from(v[j]);
        let (ri, ci, ui) = (at(rest, i), at(current, i), at(mu, i));
        let (mut m, mut n) = (Mat3A::ZERO, Mat3A::ZERO);
        for &j in connections.of(i) {
            let j = j as usize;
            let (d, e, u) = (at(rest, j) - ri, at(current, j) - ci, at(mu, j) - ui);
            m += Mat3A::from_cols(e * d.x, e * d.y, e * d.z);
            n += Mat3A::from_cols(e * u.x, e * u.y, e * u.z);
        }
        (Mat3::from(m), Mat3::from(n))
    }

    /// The force on particle `k`: the gather over its connections of the
    /// terms every particle gave ([`Elastic::terms`]),
    /// `sum_i [T_i d_ki - U_i (mu_k - mu_i) - 2 e_ki] + T_k sum_i d_ki - U_k sum_i (mu_k - mu_i)`:
    /// `k`'s own terms applied once to the sums of its offsets, not once
    /// per connection.
    pub fn force_on(
        &self,
        k: usize,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        terms: &[ElasticTerms],
    ) -> Vec3 {
        // In 4-lane vectors, as [`Elastic::products`].
        let mu = &self.consistency.multipliers;
        let at = |v: &[Vec3], j: usize| Vec3A::from(v[j]);
        let (rk, ck, uk) = (at(rest, k), at(current, k), at(mu, k));
        let (mut f, mut d_sum, mut u_sum) = (Vec3A::ZERO, Vec3A::ZERO, Vec3A::ZERO);
        for &i in connections.of(k) {
            let i = i as usize;
            let (d, e, u) = (rk - at(rest, i), ck - at(current, i), uk - at(mu, i));
            let ElasticTerms { target, stress } = terms[i];
            f += target * d - stress * u - 2.0 * e;
            d_sum += d;
            u_sum += u;
        }
        let ElasticTerms { target, stress } = terms[k];
        Vec3::from(f + target * d_sum - stress * u_sum)
    }

    /// The energy at `current`, its rotations by the SVD (for checks).
    pub fn energy(&self, rest: &[Vec3], current: &[Vec3], connections: &Connections) -> f64 {
        (0..rest.len())
            .into_par_iter()
            .map(|i| self.particle_energy(i, rest, current, connections))
            .sum()
    }

    /// Particle `i`'s part of the energy at `current`, in `f64` but for its
    /// rotation (the SVD's, in `f32`: the energy is stationary in it).
    pub fn particle_energy(
        &self,
        i: usize,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
    ) -> f64 {
        self.particle_energy_turned(i, rest, current, connections, rotation_of)
    }

    /// [`Elastic::particle_energy`] with the rotation of its gradient (of
    /// `M_i` where flat) found by `rotate` from that matrix in `f32`: the
    /// energy is stationary in the rotation, so a polar update warm-started
    /// from the last iteration's gives it within rounding of the SVD's.
    pub fn particle_energy_turned(
        &self,
        i: usize,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        rotate: impl FnOnce(Mat3) -> Mat3,
    ) -> f64 {
        let sums = self.energy_sums(i, rest, current, connections);
        let rotation =
            rotate(self.turned_of(i, sums.offsets.as_mat3(), sums.multipliers.as_mat3()));
        self.energy_of(i, &sums, rotation)
    }

    /// The sums over particle `i`'s connections its part of the energy is
    /// made of, in `f64`, in one pass over them.
    pub fn energy_sums(
        &self,
        i: usize,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
    ) -> EnergySums {
        // The offsets in `f32`, as the force takes them, then summed in
        // `f64`.
        let mu = &self.consistency.multipliers;
        let mut sums = EnergySums::ZERO;
        for &j in connections.of(i) {
            let j = j as usize;
            let (d, e, u) = (
                (rest[j] - rest[i]).as_dvec3(),
                (current[j] - current[i]).as_dvec3(),
                (mu[j] - mu[i]).as_dvec3(),
            );
            sums.offsets += DMat3::from_cols(e * d.x, e * d.y, e * d.z);
            sums.multipliers += DMat3::from_cols(e * u.x, e * u.y, e * u.z);
            sums.moments += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            sums.lengths += e.length_squared();
        }
        sums
    }

    /// Particle `i`'s part of the energy from its [`EnergySums`] and its
    /// rotation (that of [`Elastic::turned_of`] the sums' products): the
    /// pair term `sum_j |e_ij - T d_ij|^2` of its map `T` (the rotation
    /// where flat, else `M_i A_i^-1`) as `sum_j |e_ij|^2 - 2 T : M_i +
    /// T : (T A_i)` with `A_i = sum_j d_ij d_ij^T` (exact for any `T`; in
    /// `f64` it rounds within about `1e-16 sum_j |e_ij|^2`, far below what
    /// states in `f32` tell apart), plus the shear and volume terms of its
    /// gradient.
    pub fn energy_of(&self, i: usize, sums: &EnergySums, rotation: Mat3) -> f64 {
        let m = sums.offsets;
        let pair = |t: DMat3| pair_term(sums, t);
        let rotation = rotation.as_dmat3();
        if self.is_flat(i) {
            return pair(rotation);
        }
        let c = &self.consistency;
        let a = f64::from(c.scales[i]);
        let f = m * c.corrections[i].as_dmat3().transpose() + a * sums.multipliers;
        let shear = frobenius(f - rotation, f - rotation);
        pair(m * self.inverse_moments[i].as_dmat3())
            + a * shear
            + f64::from(self.weights[i]) * (f.determinant() - 1.0).powi(2)
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
        // The volume term's entries once for the 40 products (each would
        // form three per connection).
        let linearisation = self.rest_linearisation();
        let entries = Entries::new(rest, connections, &self.mirrors, &linearisation);
        largest_eigenvalue(free, |u| {
            entries.operator(&linearisation.weights, connections, |i| free[i], u)
        })
    }

    /// `K u`: the model's operator at rest applied to a displacement `u` of
    /// the free particles (entries of fixed ones are read as zero), in the
    /// units of the connection Laplacian: the Laplacian plus the volume
    /// term's `1/2 sum_i W_i g_i g_i^T`, `g_i`'s entry at neighbour `j`
    /// being `c_ij` at rest ([`volume_operator`] with `cof F = I`).
    pub fn rest_operator(
        &self,
        rest: &[Vec3],
        connections: &Connections,
        free: &[bool],
        u: &[DVec3],
    ) -> Vec<DVec3> {
        self.rest_linearisation()
            .operator(rest, connections, |i| free[i], u)
    }

    /// The volume term linearised at rest (`cof F = I`), in `f64`: what
    /// [`Elastic::rest_operator`] applies (made once for many products).
    pub fn rest_linearisation(&self) -> VolumeLinearisation {
        let c = &self.consistency;
        VolumeLinearisation {
            weights: self.weights.iter().map(|&w| f64::from(w)).collect(),
            corrections: c.corrections.iter().map(|b| b.as_dmat3()).collect(),
            scales: c
                .scales
                .iter()
                .map(|&a| DMat3::from_diagonal(DVec3::splat(f64::from(a))))
                .collect(),
            multipliers: c.multipliers.iter().map(|m| m.as_dvec3()).collect(),
        }
    }
}

/// The sums over a particle's connections `j` its part of the energy is
/// made of ([`Elastic::energy_sums`]): `M_i = sum_j e_ij d_ij^T`, `N_i =
/// sum_j e_ij (mu_j - mu_i)^T`, `A_i = sum_j d_ij d_ij^T` and `sum_j
/// |e_ij|^2` (`d` the rest offsets, `e` the current ones).
#[derive(Debug, Clone, Copy)]
pub struct EnergySums {
    /// `M_i`.
    pub offsets: DMat3,
    /// `N_i`.
    pub multipliers: DMat3,
    /// `A_i`.
    pub moments: DMat3,
    /// `sum_j |e_ij|^2`.
    pub lengths: f64,
}

impl EnergySums {
    /// No connections' sums.
    pub const ZERO: Self = Self {
        offsets: DMat3::ZERO,
        multipliers: DMat3::ZERO,
        moments: DMat3::ZERO,
        lengths: 0.0,
    };
}

/// `sum_j |e_ij - t d_ij|^2` from a particle's sums: `sum_j |e_ij|^2 - 2 t :
/// M_i + t : (t A_i)` (never below zero, where it rounds there).
fn pair_term(sums: &EnergySums, t: DMat3) -> f64 {
    (sums.lengths - 2.0 * frobenius(t, sums.offsets) + frobenius(t, t * sums.moments)).max(0.0)
}

/// The Frobenius inner product `a : b = tr(a^T b)`.
fn frobenius(a: DMat3, b: DMat3) -> f64 {
    a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
}

/// The largest eigenvalue of the symmetric operator `apply` on
/// displacements of the `free` particles (zero elsewhere), by 40 Lanczos
/// steps with a 2 % margin ([`lanczos_extremes`] over their coordinates).
fn largest_eigenvalue(free: &[bool], apply: impl Fn(&[DVec3]) -> Vec<DVec3>) -> f32 {
    let flat = |u: &[f64]| -> Vec<f64> {
        let u: Vec<DVec3> = u
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        apply(&u).iter().flat_map(|r| r.to_array()).collect()
    };
    let start: Vec<bool> = free.iter().flat_map(|&f| [f; 3]).collect();
    let (_, hi) = lanczos_extremes(&start, flat, 40);
    hi
}

/// Whether a neighbourhood with moment matrix `a` spans three dimensions:
/// `det A / (tr A / 3)^3` at least [`FLAT_NEIGHBOURHOOD`] (false for fewer
/// than three connections, or all of them in a plane or on a line). Formed
/// in units of [`moment_unit`], so that it holds for any model size.
pub fn is_round(a: Mat3) -> bool {
    let Some(unit) = moment_unit(a) else {
        return false;
    };
    let (a, scale) = (a / unit, a.diagonal().element_sum() / 3.0 / unit);
    a.determinant() > FLAT_NEIGHBOURHOOD * scale * scale * scale
}

/// The power of two nearest `tr A / 3` for a moment matrix `a` (a squared
/// length: the connections' lengths squared, summed), `None` where that is
/// not positive and finite. `A`'s determinant is a sixth power of lengths:
/// it leaves single precision for connections about 1e6 long and falls to
/// subnormals for ones about 1e-6 long, so determinants and inverses are
/// formed from `A` divided by this. A power of two divides exactly, so
/// wherever `A` itself would do they give the same bits.
pub fn moment_unit(a: Mat3) -> Option<f32> {
    let scale = a.diagonal().element_sum() / 3.0;
    (scale > 0.0 && scale.is_finite()).then(|| 2f32.powi(scale.log2().round() as i32))
}

/// `a`'s inverse for a moment matrix `a` (zero where it has no
/// [`moment_unit`]), formed in units of [`moment_unit`] for any model size.
pub fn moment_inverse(a: Mat3) -> Mat3 {
    match moment_unit(a) {
        Some(unit) => (a / unit).inverse() / unit,
        None => Mat3::ZERO,
    }
}

/// Per particle `A_i^-1` and the volume weight `W_i = nu / (1 - 2 nu)
/// tr(A_i) / 3` for Poisson ratio `poisson` (both zero for a flat
/// neighbourhood).
fn moments_and_weights(
    rest: &[Vec3],
    connections: &Connections,
    poisson: f32,
) -> (Vec<Mat3>, Vec<f32>) {
    let ratio = poisson / (1.0 - 2.0 * poisson);
    (0..rest.len())
        .into_par_iter()
        .map(|i| {
            let a = moment(rest, connections, i);
            if !is_round(a) {
                return (Mat3::ZERO, 0.0);
            }
            // lambda / 2 = nu / (1 - 2 nu) mu with mu = a_i = tr(A_i) / 3.
            (moment_inverse(a), ratio * a.diagonal().element_sum() / 3.0)
        })
        .unzip()
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
    offsets_outer(current, rest, connections, i)
}

/// Per connection slot, the slot of the same connection in the
/// neighbour's row ([`Elastic::mirrors`]).
fn mirrors(connections: &Connections) -> Vec<u32> {
    (0..connections.particles())
        .into_par_iter()
        .flat_map_iter(|i| {
            connections.of(i).iter().map(move |&j| {
                let row = connections.of(j as usize);
                row.binary_search(&(i as u32))
                    .ok()
                    .or_else(|| row.iter().position(|&k| k as usize == i))
                    .map_or(NO_MIRROR, |at| connections.offsets[j as usize] + at as u32)
            })
        })
        .collect()
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
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;
    use crate::stage2::spectrum::laplacian_extremes;

    /// A 6x6x6 grid of unit spacing jittered by up to 0.2, its pairs closer
    /// than 1.5 connected, the outer layer fixed.
    fn jittered_block() -> (Vec<Vec3>, Connections, Vec<bool>) {
        let (positions, pairs, free) = tissue_testkit::jittered_grid(6, 7);
        let connections = Connections::from_pairs(positions.len(), pairs);
        (positions, connections, free)
    }

    /// The force on every particle at `current`, rotations by the SVD.
    fn forces(
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
    ) -> Vec<Vec3> {
        let terms: Vec<ElasticTerms> = (0..rest.len())
            .map(|i| {
                let m = offsets_product(rest, current, connections, i);
                let n = elastic
                    .consistency
                    .multipliers_product(current, connections, i);
                elastic.terms(i, m, n, rotation_of(elastic.turned_of(i, m, n)))
            })
            .collect();
        (0..rest.len())
            .map(|k| elastic.force_on(k, rest, current, connections, &terms))
            .collect()
    }

    fn affine(rest: &[Vec3]) -> (Mat3, Vec<Vec3>) {
        let b = Mat3::from_cols(
            Vec3::new(1.2, 0.1, -0.3),
            Vec3::new(0.05, 0.9, 0.2),
            Vec3::new(0.4, 0.0, 1.1),
        );
        let current = rest
            .iter()
            .map(|&p| b * p + Vec3::new(3.0, -1.0, 2.0))
            .collect();
        (b, current)
    }

    #[test]
    fn any_affine_map_gives_its_matrix_as_every_gradient() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let (b, current) = affine(&rest);
        for i in 0..rest.len() {
            let m = offsets_product(&rest, &current, &connections, i);
            let n = elastic
                .consistency
                .multipliers_product(&current, &connections, i);
            for f in [
                elastic.least_squares_gradient(i, m),
                elastic.gradient(i, m, n),
            ] {
                let off = (f - b)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f32, |m, x| m.max(x.abs()));
                assert!(off < 1e-4, "particle {i}: F off by {off}");
            }
        }
    }

    /// The volumes' misfit is what a uniform change leaves: none for a
    /// turn, a uniform scaling or any affine map (every `J_i` the same), and
    /// the spread of `J` where one half of the block is squeezed.
    #[test]
    fn the_volume_misfit_is_the_spread_of_j_about_its_mean() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let turn = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 2.0).normalize(), 0.7);
        let (_, affine) = affine(&rest);
        for (what, current) in [
            ("turned", rest.iter().map(|&p| turn * p).collect::<Vec<_>>()),
            ("scaled", rest.iter().map(|&p| 0.8 * p).collect()),
            ("affine", affine),
        ] {
            let misfit = elastic.volume_misfit(&rest, &current, &connections);
            assert!(misfit < 1e-4, "{what}: {misfit}");
        }
        // The lower half squeezed to 0.7 of its height: J 0.7 there, 1
        // above, 0.85 about the middle; the spread about half the step.
        let middle = rest.iter().map(|p| p.z).sum::<f32>() / rest.len() as f32;
        let squeezed: Vec<Vec3> = rest
            .iter()
            .map(|&p| {
                let z = if p.z < middle {
                    middle - 0.7 * (middle - p.z)
                } else {
                    p.z
                };
                Vec3::new(p.x, p.y, z)
            })
            .collect();
        let misfit = elastic.volume_misfit(&rest, &squeezed, &connections);
        assert!((0.08..0.16).contains(&misfit), "squeezed: {misfit}");
    }

    /// The patch test, on the force itself: an affine map is an equilibrium
    /// of every free particle (the jittered neighbourhoods left a force of
    /// the size of the stress times the spacing before the consistent vectors).
    #[test]
    fn an_affine_map_puts_no_force_on_free_particles() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let (_, current) = affine(&rest);
        let f = forces(&rest, &current, &connections, &elastic);
        // The same map's stress on one particle, for scale.
        let i = 100;
        let m = offsets_product(&rest, &current, &connections, i);
        let n = elastic
            .consistency
            .multipliers_product(&current, &connections, i);
        let stress = elastic
            .terms(i, m, n, rotation_of(elastic.gradient(i, m, n)))
            .stress;
        let scale = stress
            .to_cols_array()
            .iter()
            .fold(0.0f32, |a, x| a.max(x.abs()));
        let worst = (0..rest.len())
            .filter(|&k| free[k])
            .map(|k| f[k].length())
            .fold(0.0f32, f32::max);
        assert!(scale > 1.0, "stress {scale}");
        assert!(
            worst < 1e-4 * scale,
            "force {worst} against a stress of {scale}"
        );
    }

    /// `rest` turned by `turn`, stretched by 5 % and moved by up to 0.08
    /// per particle in a pattern that is no affine map.
    fn wobbled(rest: &[Vec3], turn: Mat3) -> Vec<Vec3> {
        rest.iter()
            .enumerate()
            .map(|(i, &p)| {
                let t = i as f32;
                turn * p * 1.05
                    + 0.08 * Vec3::new((t * 1.3).sin(), (t * 2.1).cos(), (t * 0.7).sin())
            })
            .collect()
    }

    #[test]
    fn the_elastic_force_is_the_energy_gradient() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.3, &free);
        let x = wobbled(&rest, Mat3::IDENTITY);
        let f = forces(&rest, &x, &connections, &elastic);
        let h = 1e-3f32;
        for k in [43usize, 86, 129] {
            assert!(free[k]);
            for axis in 0..3 {
                let (mut plus, mut minus) = (x.clone(), x.clone());
                plus[k][axis] += h;
                minus[k][axis] -= h;
                let g = (elastic.energy(&rest, &plus, &connections)
                    - elastic.energy(&rest, &minus, &connections))
                    / f64::from(2.0 * h);
                let want = -g / 2.0;
                assert!(
                    (f64::from(f[k][axis]) - want).abs() <= 5e-3 * want.abs().max(1.0),
                    "particle {k} axis {axis}: force {} against -1/2 the gradient {want}",
                    f[k][axis]
                );
            }
        }
    }

    #[test]
    fn the_pair_term_from_the_sums_is_the_sum_over_the_connections() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.3, &free);
        let x = wobbled(&rest, Mat3::from_rotation_z(0.4));
        let map = (Mat3::from_rotation_x(0.3) * 1.1).as_dmat3();
        for i in 0..rest.len() {
            let sums = elastic.energy_sums(i, &rest, &x, &connections);
            let direct: f64 = connections
                .of(i)
                .iter()
                .map(|&j| {
                    let j = j as usize;
                    let (d, e) = ((rest[j] - rest[i]).as_dvec3(), (x[j] - x[i]).as_dvec3());
                    (e - map * d).length_squared()
                })
                .sum();
            let expanded = pair_term(&sums, map);
            assert!(
                (expanded - direct).abs() <= 1e-12 * sums.lengths,
                "particle {i}: {expanded} from the sums, {direct} summed"
            );
            assert!(direct > 1e-3 * sums.lengths, "particle {i}: the map fits");
        }
    }

    #[test]
    fn a_rigid_motion_has_no_energy_and_no_force() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let r = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 0.8);
        let current: Vec<Vec3> = rest.iter().map(|&p| r * p + Vec3::ONE).collect();
        assert!(elastic.energy(&rest, &current, &connections) < 1e-6);
        let worst = forces(&rest, &current, &connections, &elastic)
            .iter()
            .map(|f| f.length())
            .fold(0.0f32, f32::max);
        // f32 rounding: W_i (J_i - 1) with W_i near 25 a_i.
        assert!(worst < 1e-3, "force {worst}");
    }

    #[test]
    fn both_products_in_one_pass_are_the_two_products() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let current: Vec<Vec3> = rest
            .iter()
            .map(|&p| {
                Mat3::from_rotation_y(0.4) * (p * Vec3::new(1.1, 0.9, 1.0))
                    + 0.05 * Vec3::new(p.y, p.z, p.x)
            })
            .collect();
        for i in 0..rest.len() {
            let (m, n) = elastic.products(&rest, &current, &connections, i);
            let m_alone = offsets_product(&rest, &current, &connections, i);
            let n_alone = elastic
                .consistency
                .multipliers_product(&current, &connections, i);
            assert!(
                m.abs_diff_eq(m_alone, 1e-5) && n.abs_diff_eq(n_alone, 1e-5),
                "{i}"
            );
        }
    }

    #[test]
    fn every_connection_slot_knows_its_mirror() {
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        assert_eq!(elastic.mirrors.len(), connections.indices.len());
        for i in 0..rest.len() {
            let slots = connections.offsets[i] as usize..connections.offsets[i + 1] as usize;
            for s in slots {
                let m = elastic.mirrors[s] as usize;
                let j = connections.indices[s] as usize;
                // `j`'s slot `m` names `i`, and its mirror is `s` again.
                assert_eq!(connections.indices[m] as usize, i);
                assert!(
                    (connections.offsets[j] as usize..connections.offsets[j + 1] as usize)
                        .contains(&m)
                );
                assert_eq!(elastic.mirrors[m] as usize, s);
            }
        }
        // A connection its neighbour does not list has no mirror.
        let one_sided = Connections {
            offsets: vec![0, 1, 1],
            indices: vec![1],
        };
        assert_eq!(mirrors(&one_sided), vec![NO_MIRROR]);
    }

    #[test]
    fn the_volume_weight_is_lambda_over_two_mu_per_particle() {
        let (rest, connections, free) = jittered_block();
        for poisson in [0.0, 0.3, 0.49] {
            let elastic = Elastic::new(&rest, &connections, poisson, &free);
            for i in [0, 100, 215] {
                let a = moment(&rest, &connections, i);
                let mu = (a.x_axis.x + a.y_axis.y + a.z_axis.z) / 3.0;
                let want = poisson / (1.0 - 2.0 * poisson) * mu;
                assert!((elastic.weights[i] - want).abs() <= 1e-5 * want.max(1.0));
                assert!((elastic.consistency.scales[i] - mu).abs() <= 1e-5 * mu);
            }
        }
        // 0.49 gives lambda / mu = 49: a weight of 24.5 mu.
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let a = moment(&rest, &connections, 100);
        let mu = (a.x_axis.x + a.y_axis.y + a.z_axis.z) / 3.0;
        assert!((elastic.weights[100] / mu - 24.5).abs() < 1e-3);
    }

    /// Another Poisson ratio from a made model is the model made for that
    /// ratio, to the bit: only the weights depend on it.
    #[test]
    fn another_poisson_ratio_is_the_model_made_for_it() {
        let (rest, connections, free) = jittered_block();
        let made = Elastic::new(&rest, &connections, 0.49, &free);
        for poisson in [0.45, 0.495, 0.49, 0.0] {
            let fresh = Elastic::new(&rest, &connections, poisson, &free);
            assert_eq!(made.with_poisson(&rest, &connections, poisson), fresh);
        }
        assert_ne!(
            made.with_poisson(&rest, &connections, 0.45).weights,
            made.weights
        );
    }

    #[test]
    fn a_flat_neighbourhood_keeps_the_pair_term_only() {
        // Three particles on a line and one off it in the plane z = 0.
        let rest = vec![
            Vec3::ZERO,
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            Vec3::new(0.5, 0.5, 0.0),
        ];
        let connections = Connections::from_pairs(5, [(0, 1), (0, 2), (0, 3), (0, 4)]);
        let free = [true, false, false, false, false];
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        assert!(elastic.is_flat(0));
        assert_eq!(elastic.weights[0], 0.0);
        assert_eq!(elastic.inverse_moments[0], Mat3::ZERO);
        let squashed: Vec<Vec3> = rest.iter().map(|&p| 0.5 * p).collect();
        let m = offsets_product(&rest, &squashed, &connections, 0);
        let n = elastic
            .consistency
            .multipliers_product(&squashed, &connections, 0);
        let terms = elastic.terms(0, m, n, Mat3::IDENTITY);
        assert_eq!(terms.target, Mat3A::IDENTITY);
        assert_eq!(terms.stress, Mat3A::ZERO);
    }

    #[test]
    fn without_volume_resistance_the_operator_is_near_the_laplacian() {
        let (rest, connections, free) = jittered_block();
        let (_, laplacian) = laplacian_extremes(&connections, &free);
        let elastic = Elastic::new(&rest, &connections, 0.0, &free);
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
        let stiff = Elastic::new(&rest, &connections, 0.49, &free).rest_lambda_max(
            &rest,
            &connections,
            &free,
        );
        assert!(stiff > 4.0 * laplacian, "{stiff} vs {laplacian}");
    }

    #[test]
    fn the_largest_eigenvalue_is_that_of_the_rest_operator() {
        // `rest_lambda_max` runs its Lanczos products through the slots'
        // entries, made once; the same steps on `rest_operator`, which forms
        // the entries per product, must give the same estimate.
        let (rest, connections, free) = jittered_block();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let direct = largest_eigenvalue(&free, |u| {
            elastic.rest_operator(&rest, &connections, &free, u)
        });
        let through_entries = elastic.rest_lambda_max(&rest, &connections, &free);
        assert!(
            (through_entries - direct).abs() <= 1e-5 * direct,
            "{through_entries} vs {direct}"
        );
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
