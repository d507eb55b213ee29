//! Variationally consistent gradient vectors for the elastic model, so that
//! it passes the patch test (docs/METHOD.md, "Elastic model").
//!
//! The elastic energy's stress terms, written per particle through its
//! gradient `F_i = sum_j e_ij c_ij^T` as `sum_i a_i psi(F_i)`, put the force
//! `-(sum_i a_i P c_ik - a_k P sum_j c_kj)` on particle `k` when every
//! particle has the same `P = psi'(F)`, as under an affine map. That force
//! is zero for every `P` only if the gradient vectors satisfy the discrete
//! integration constraint
//!
//! `g_k = sum_i a_i c_ik - a_k sum_j c_kj = 0` at every free particle `k`,
//!
//! which the least-squares vectors `b_ij = A_i^-1 d_ij` do not on irregular
//! neighbourhoods. Of the vectors `c_ij = b_ij + delta_ij` that keep every
//! neighbourhood exact for affine maps (`sum_j delta_ij d_ij^T = 0`) and
//! satisfy the constraint, the one with the least `sum |delta_ij|^2` is
//!
//! `delta_ij = a_i [(mu_j - mu_i) - G_i d_ij]`, `G_i = sum_l (mu_l - mu_i) d_il^T A_i^-1`,
//!
//! with one multiplier `mu_k` per free particle (zero elsewhere): `delta` is
//! `a_i` times the part of `mu`'s offsets over the neighbourhood that its
//! least-squares gradient `G_i` does not take. Then
//! `c_ij = B_i d_ij + a_i (mu_j - mu_i)` with `B_i = A_i^-1 - a_i G_i`. The
//! multipliers solve `S mu = -g0` (`g0` the constraint's residual with `b`),
//! `S = C Pi C^T` symmetric positive semi-definite (`C` the constraint, `Pi`
//! each neighbourhood's projection off the linear maps), by conjugate
//! gradients in `f64` with the diagonal `sum_i (a_i^2 + a_k^2)` as a
//! preconditioner (Jacobi: 115 against 160 iterations at 5,000 particles).
//! `S` is a fourth-order operator (each neighbourhood's projection leaves
//! second differences of `mu`, the constraint takes differences of those),
//! so with Jacobi alone its iterations grow about as `n^(2/3)`: 166 at
//! 10,000 particles, 665 at 100,000 (breast_c). A coarse space of
//! constants and linear functions over aggregates (`CoarseMultipliers`)
//! takes them to 29 and 38.

use glam::{DMat3, DVec3, Mat3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;
use tissue_core::Connections;

use crate::coarse::aggregates::{Aggregates, OUTSIDE, centres};
use crate::coarse::cholesky::Cholesky;

/// The multipliers are solved until the constraint's largest residual is
/// this fraction of the uncorrected one: on the phantom at 5,000 particles
/// the affine patch test's largest error is then 2e-5 of the model's size,
/// as with 1e-4 or 1e-6 (the solve's own tolerance is the floor), against
/// 5e-5 at 1e-2 and 4e-4 at 1e-1 (docs/METHOD.md, "Elastic model").
pub const REDUCTION: f64 = 1e-3;

/// Conjugate-gradient iterations at most for the multipliers (a warning
/// where they stop short).
pub const MAX_ITERATIONS: usize = 5_000;

/// The consistent gradient vectors `c_ij = B_i d_ij + a_i (mu_j - mu_i)`,
/// per particle.
#[derive(Debug, Clone, PartialEq)]
pub struct Consistency {
    /// `a_i = tr(A_i) / 3`, the particle's stress weight (zero for a flat
    /// neighbourhood, which has no gradient).
    pub scales: Vec<f32>,
    /// `mu_i`, zero where the particle is not free.
    pub multipliers: Vec<Vec3>,
    /// `B_i = A_i^-1 - a_i G_i` (zero for a flat neighbourhood).
    pub corrections: Vec<Mat3>,
    /// The constraint's largest residual `|g_k|` with the least-squares
    /// vectors.
    pub residual_before: f64,
    /// The same with the consistent vectors.
    pub residual_after: f64,
    /// Conjugate-gradient iterations the multipliers took.
    pub iterations: usize,
}

impl Consistency {
    /// The consistent vectors for the neighbourhoods `connections` of
    /// `rest`, whose inverse moment matrices are `inverse_moments` (zero
    /// for a flat one), the constraint held at the `free` particles.
    pub fn new(
        rest: &[Vec3],
        connections: &Connections,
        inverse_moments: &[Mat3],
        free: &[bool],
    ) -> Self {
        Self::solved(rest, connections, inverse_moments, free, true)
    }

    /// [`Consistency::new`], the multipliers' conjugate gradients
    /// preconditioned by Jacobi and, with `coarse`, the coarse space of
    /// `CoarseMultipliers`.
    fn solved(
        rest: &[Vec3],
        connections: &Connections,
        inverse_moments: &[Mat3],
        free: &[bool],
        coarse: bool,
    ) -> Self {
        let started = std::time::Instant::now();
        let n = rest.len();
        let inverse: Vec<DMat3> = inverse_moments.iter().map(|m| m.as_dmat3()).collect();
        let offset = |i: usize, j: usize| (rest[j] - rest[i]).as_dvec3();
        let scales: Vec<f64> = (0..n)
            .map(|i| {
                if inverse[i] == DMat3::ZERO {
                    return 0.0;
                }
                let trace: f64 = connections
                    .of(i)
                    .iter()
                    .map(|&j| offset(i, j as usize).length_squared())
                    .sum();
                trace / 3.0
            })
            .collect();
        // g0_k = sum_i a_i A_i^-1 d_ik - a_k A_k^-1 sum_j d_kj.
        let g0: Vec<DVec3> = (0..n)
            .into_par_iter()
            .map(|k| {
                let mut g = DVec3::ZERO;
                if free[k] {
                    for &i in connections.of(k) {
                        let i = i as usize;
                        g += scales[i] * (inverse[i] * offset(i, k))
                            - scales[k] * (inverse[k] * offset(k, i));
                    }
                }
                g
            })
            .collect();
        let gradients_of = |mu: &[DVec3]| -> Vec<DMat3> {
            (0..n)
                .into_par_iter()
                .map(|i| {
                    let mut m = DMat3::ZERO;
                    if scales[i] > 0.0 {
                        for &l in connections.of(i) {
                            let (u, d) = (mu[l as usize] - mu[i], offset(i, l as usize));
                            m += DMat3::from_cols(u * d.x, u * d.y, u * d.z);
                        }
                    }
                    m * inverse[i]
                })
                .collect()
        };
        // S mu = C delta(mu) with delta_ij = a_i [(mu_j - mu_i) - G_i d_ij].
        let apply = |mu: &[DVec3]| -> Vec<DVec3> {
            let g = gradients_of(mu);
            (0..n)
                .into_par_iter()
                .map(|k| {
                    let mut s = DVec3::ZERO;
                    if free[k] {
                        for &i in connections.of(k) {
                            let i = i as usize;
                            let into_k = (mu[k] - mu[i]) - g[i] * offset(i, k);
                            let out_of_k = (mu[i] - mu[k]) - g[k] * offset(k, i);
                            s += scales[i] * scales[i] * into_k - scales[k] * scales[k] * out_of_k;
                        }
                    }
                    s
                })
                .collect()
        };
        let residual_before = largest(&g0);
        let diagonal: Vec<f64> = (0..n)
            .map(|k| {
                if !free[k] {
                    return 0.0;
                }
                connections
                    .of(k)
                    .iter()
                    .map(|&i| scales[i as usize].powi(2) + scales[k].powi(2))
                    .sum()
            })
            .collect();
        let coarse = coarse
            .then(|| CoarseMultipliers::new(rest, connections, &inverse, &scales, free))
            .flatten();
        let (mu, residual_after, iterations) = conjugate_gradients(
            apply,
            &diagonal,
            coarse.as_ref(),
            g0.iter().map(|&g| -g).collect(),
            REDUCTION * residual_before,
        );
        let gradients = gradients_of(&mu);
        if residual_after > REDUCTION * residual_before {
            log::warn!(
                "the elastic model's consistent gradients are partial: the integration \
                 constraint's residual fell from {residual_before:.3e} to {residual_after:.3e} \
                 in {iterations} iterations (the patch test is then passed only approximately)"
            );
        } else {
            log::info!(
                "elastic model: consistent gradients in {iterations} conjugate-gradient \
                 iterations, {:.3} s",
                started.elapsed().as_secs_f64()
            );
        }
        Self {
            scales: scales.iter().map(|&a| a as f32).collect(),
            multipliers: mu.iter().map(|m| m.as_vec3()).collect(),
            corrections: (0..n)
                .map(|i| (inverse[i] - scales[i] * gradients[i]).as_mat3())
                .collect(),
            residual_before,
            residual_after,
            iterations,
        }
    }

    /// `sum_j e_ij (mu_j - mu_i)^T` over particle `i`'s connections, the
    /// multipliers' part of its gradient.
    pub fn multipliers_product(
        &self,
        current: &[Vec3],
        connections: &Connections,
        i: usize,
    ) -> Mat3 {
        offsets_outer(current, &self.multipliers, connections, i)
    }

    /// `c_ij`, particle `i`'s gradient vector for its neighbour `j`.
    pub fn vector(&self, rest: &[Vec3], i: usize, j: usize) -> Vec3 {
        self.corrections[i] * (rest[j] - rest[i])
            + self.scales[i] * (self.multipliers[j] - self.multipliers[i])
    }
}

/// The multipliers' coarse space: per aggregate of free particles (cells
/// of [`COARSE_CELL`] mean spacings), the constant and the three linear
/// functions over it. `S` is a fourth-order operator whose local null
/// space is the linear functions (each neighbourhood's projection takes
/// them off), so a coarse space of constants alone would carry nothing a
/// neighbourhood inside one aggregate sees; with the linear functions the
/// smooth part of the error goes to a small factored matrix
/// `P^T S P = sum_i a_i^2 (E_i P)^T Pi_i (E_i P)`, assembled one
/// neighbourhood at a time, and the preconditioner is additive:
/// `D^-1 r + P (P^T S P)^-1 P^T r`.
#[derive(Debug)]
struct CoarseMultipliers {
    /// Per particle its aggregate, or [`OUTSIDE`].
    aggregate: Vec<u32>,
    /// Per particle its basis values `(1, (x - c_a) / h)`.
    basis: Vec<[f64; 4]>,
    factor: Cholesky,
}

/// The multipliers' coarse cells, in mean connection lengths.
pub const COARSE_CELL: f32 = 4.0;

/// An aggregate carries linear functions where the determinant of its
/// particles' second moments is above this fraction of the cube of their
/// mean eigenvalue (not flat or collinear).
pub const FLATNESS: f64 = 1e-2;

/// At most this many aggregates (four unknowns each) in the multipliers'
/// coarse space; the cells grow past [`COARSE_CELL`] to keep to it. At
/// 1,000,000 particles (the phantom, with the sparse factor of
/// [`Cholesky`]): 2,000 take 136 conjugate-gradient iterations and 50 s,
/// 6,000 89 and 36 s, 10,000 64 and 37 s, 20,000 42 and 43 s (the factor
/// grows as the square of its unknowns); at 100,000 and below the cells
/// of [`COARSE_CELL`] give fewer than 2,000 (docs/METHOD.md, "Preparation
/// and 1M").
pub const COARSE_MAX_AGGREGATES: usize = 6_000;

impl CoarseMultipliers {
    fn new(
        rest: &[Vec3],
        connections: &Connections,
        inverse: &[DMat3],
        scales: &[f64],
        free: &[bool],
    ) -> Option<Self> {
        let n = rest.len();
        let pairs = connections.indices.len().max(1);
        let spacing = (0..n)
            .flat_map(|i| connections.of(i).iter().map(move |&j| (i, j as usize)))
            .map(|(i, j)| f64::from((rest[j] - rest[i]).length()))
            .sum::<f64>()
            / pairs as f64;
        let aggregates = Aggregates::new(
            rest,
            connections,
            free,
            COARSE_CELL * spacing as f32,
            COARSE_MAX_AGGREGATES,
        )
        .ok()?;
        let count = aggregates.count();
        let aggregate = aggregates.aggregate;
        let centres = centres(rest, &aggregate, count);
        let h = f64::from(aggregates.cell);
        // An aggregate too small or too flat to carry linear functions
        // (a weakly connected particle alone, a sliver at the surface)
        // carries its constant only.
        let mut moments = vec![(DMat3::ZERO, 0usize); count];
        for (j, &a) in aggregate.iter().enumerate() {
            if a != OUTSIDE {
                let x = (rest[j] - centres[a as usize]).as_dvec3() / h;
                moments[a as usize].0 += DMat3::from_cols(x * x.x, x * x.y, x * x.z);
                moments[a as usize].1 += 1;
            }
        }
        let linear: Vec<bool> = moments
            .iter()
            .map(|&(m, members)| {
                let mean = (m.x_axis.x + m.y_axis.y + m.z_axis.z) / 3.0;
                members >= 4 && mean > 0.0 && m.determinant() > FLATNESS * mean.powi(3)
            })
            .collect();
        let basis: Vec<[f64; 4]> = (0..n)
            .map(|j| match aggregate[j] {
                OUTSIDE => [0.0; 4],
                a if !linear[a as usize] => [1.0, 0.0, 0.0, 0.0],
                a => {
                    let x = (rest[j] - centres[a as usize]).as_dvec3() / h;
                    [1.0, x.x, x.y, x.z]
                }
            })
            .collect();
        let offset = |i: usize, j: usize| (rest[j] - rest[i]).as_dvec3();
        // Per neighbourhood spanning more than one aggregate, the
        // aggregates it touches and its share of `P^T S P` over them.
        let shares: Vec<Option<(Vec<u32>, Vec<f64>)>> = (0..n)
            .into_par_iter()
            .map(|i| {
                if scales[i] == 0.0 {
                    return None;
                }
                let neighbours = connections.of(i);
                let inside = aggregate[i] != OUTSIDE
                    && neighbours
                        .iter()
                        .all(|&j| aggregate[j as usize] == aggregate[i]);
                let mut touched: Vec<u32> = neighbours
                    .iter()
                    .map(|&j| aggregate[j as usize])
                    .chain(std::iter::once(aggregate[i]))
                    .filter(|&a| a != OUTSIDE)
                    .collect();
                touched.sort_unstable();
                touched.dedup();
                if touched.is_empty() || inside {
                    return None;
                }
                let columns = 4 * touched.len();
                let slot = |a: u32| 4 * touched.binary_search(&a).unwrap_or(0);
                // Y = E_i P: row j is P_j - P_i.
                let mut y = vec![0.0f64; neighbours.len() * columns];
                for (r, &j) in neighbours.iter().enumerate() {
                    let j = j as usize;
                    for (particle, sign) in [(j, 1.0), (i, -1.0)] {
                        if aggregate[particle] != OUTSIDE {
                            let c = slot(aggregate[particle]);
                            for (k, v) in basis[particle].iter().enumerate() {
                                y[r * columns + c + k] += sign * v;
                            }
                        }
                    }
                }
                // Pi Y = Y - D A^-1 D^T Y.
                for c in 0..columns {
                    let mut t = DVec3::ZERO;
                    for (r, &j) in neighbours.iter().enumerate() {
                        t += offset(i, j as usize) * y[r * columns + c];
                    }
                    let t = inverse[i] * t;
                    for (r, &j) in neighbours.iter().enumerate() {
                        y[r * columns + c] -= offset(i, j as usize).dot(t);
                    }
                }
                let weight = scales[i] * scales[i];
                let mut local = vec![0.0; columns * columns];
                for a in 0..columns {
                    for b in a..columns {
                        let v: f64 = (0..neighbours.len())
                            .map(|r| y[r * columns + a] * y[r * columns + b])
                            .sum();
                        local[a * columns + b] = weight * v;
                        local[b * columns + a] = weight * v;
                    }
                }
                Some((touched, local))
            })
            .collect();
        // Per aggregate the neighbourhoods whose share reaches it, in order;
        // then its four rows, summed in that order.
        let mut touching: Vec<Vec<u32>> = vec![Vec::new(); count];
        for (i, share) in shares.iter().enumerate() {
            if let Some((touched, _)) = share {
                for &a in touched {
                    touching[a as usize].push(i as u32);
                }
            }
        }
        // Summed in a dense row per thread (the coarse space's width), each
        // entry's terms in the order of the neighbourhoods, as an ordered
        // map would sum them, then read out in column order.
        let width = 4 * count;
        let mut rows: Vec<Vec<(u32, f64)>> = touching
            .par_iter()
            .enumerate()
            .map_init(
                || (vec![0.0f64; 4 * width], vec![false; width], Vec::new()),
                |(dense, seen, columns), (a, neighbourhoods)| {
                    columns.clear();
                    for &i in neighbourhoods {
                        let Some((touched, local)) = &shares[i as usize] else {
                            continue;
                        };
                        let stride = 4 * touched.len();
                        let at = 4 * touched.binary_search(&(a as u32)).unwrap_or(0);
                        for k in 0..4 {
                            for (c, &b) in touched.iter().enumerate() {
                                for l in 0..4 {
                                    let column = 4 * b as usize + l;
                                    if !seen[column] {
                                        seen[column] = true;
                                        columns.push(column as u32);
                                    }
                                    dense[k * width + column] +=
                                        local[(at + k) * stride + 4 * c + l];
                                }
                            }
                        }
                    }
                    columns.sort_unstable();
                    let block: Vec<Vec<(u32, f64)>> = (0..4)
                        .map(|k| {
                            columns
                                .iter()
                                .map(|&column| (column, dense[k * width + column as usize]))
                                .collect()
                        })
                        .collect();
                    for &column in columns.iter() {
                        seen[column as usize] = false;
                        for k in 0..4 {
                            dense[k * width + column as usize] = 0.0;
                        }
                    }
                    block
                },
            )
            .flat_map_iter(Vec::into_iter)
            .collect();
        // The unused linear unknowns of constant-only aggregates: identity
        // rows (their basis is zero, so they correct nothing; their entries
        // in other rows are zeros).
        for (a, _) in linear.iter().enumerate().filter(|(_, l)| !**l) {
            for k in 1..4 {
                let row = 4 * a + k;
                rows[row] = vec![(row as u32, 1.0)];
            }
        }
        let factor = Cholesky::new(&rows);
        if factor.is_none() {
            log::warn!("the multipliers' coarse matrix is not positive definite: Jacobi alone");
        }
        Some(Self {
            aggregate,
            basis,
            factor: factor?,
        })
    }

    /// `z += P (P^T S P)^-1 P^T r`.
    fn add_correction(&self, r: &[DVec3], z: &mut [DVec3]) {
        let mut coarse = vec![DVec3::ZERO; self.factor.len()];
        for ((&a, p), r) in self.aggregate.iter().zip(&self.basis).zip(r) {
            if a != OUTSIDE {
                for (k, v) in p.iter().enumerate() {
                    coarse[4 * a as usize + k] += *r * *v;
                }
            }
        }
        self.factor.solve(&mut coarse);
        z.par_iter_mut()
            .zip(&self.aggregate)
            .zip(&self.basis)
            .for_each(|((z, &a), p)| {
                if a != OUTSIDE {
                    for (k, v) in p.iter().enumerate() {
                        *z += coarse[4 * a as usize + k] * *v;
                    }
                }
            });
    }
}

/// The largest length among `v`.
fn largest(v: &[DVec3]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.length()))
}

/// Conjugate gradients on `apply(x) = b` from zero until the largest
/// residual is at most `target` (or [`MAX_ITERATIONS`], or the curvature
/// vanishes): the solution, its largest residual and the iterations.
fn conjugate_gradients(
    apply: impl Fn(&[DVec3]) -> Vec<DVec3>,
    diagonal: &[f64],
    coarse: Option<&CoarseMultipliers>,
    b: Vec<DVec3>,
    target: f64,
) -> (Vec<DVec3>, f64, usize) {
    let dot = |a: &[DVec3], b: &[DVec3]| -> f64 { a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum() };
    // (The dot products in order: rayon's sums split by work stealing, and
    // the CPU path's results are the same for any thread count.)
    let precondition = |r: &[DVec3]| -> Vec<DVec3> {
        let mut z: Vec<DVec3> = r
            .par_iter()
            .zip(diagonal)
            .map(|(r, &d)| if d > 0.0 { *r / d } else { DVec3::ZERO })
            .collect();
        if let Some(coarse) = coarse {
            coarse.add_correction(r, &mut z);
        }
        z
    };
    let mut x = vec![DVec3::ZERO; b.len()];
    let mut r = b;
    let mut z = precondition(&r);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS && largest(&r) > target {
        let ap = apply(&p);
        let curvature = dot(&p, &ap);
        if curvature <= 0.0 || !curvature.is_finite() {
            break;
        }
        let step = rz / curvature;
        x.par_iter_mut().zip(&p).for_each(|(x, &p)| *x += step * p);
        r.par_iter_mut().zip(&ap).for_each(|(r, &a)| *r -= step * a);
        z = precondition(&r);
        let next = dot(&r, &z);
        let beta = next / rz;
        rz = next;
        p.par_iter_mut()
            .zip(&z)
            .for_each(|(p, &z)| *p = z + beta * *p);
        iterations += 1;
    }
    let residual = largest(&r);
    (x, residual, iterations)
}

/// `sum_j (a_j - a_i)(b_j - b_i)^T` over particle `i`'s connections: with
/// the current and rest positions `M_i`, with the current positions and
/// the multipliers `N_i` ([`Consistency::multipliers_product`]).
pub fn offsets_outer(a: &[Vec3], b: &[Vec3], connections: &Connections, i: usize) -> Mat3 {
    // In 4-lane vectors, as `Elastic::products`.
    let (ai, bi) = (Vec3A::from(a[i]), Vec3A::from(b[i]));
    let mut m = Mat3A::ZERO;
    for &j in connections.of(i) {
        let j = j as usize;
        let (u, v) = (Vec3A::from(a[j]) - ai, Vec3A::from(b[j]) - bi);
        m += Mat3A::from_cols(u * v.x, u * v.y, u * v.z);
    }
    Mat3::from(m)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;
    use crate::model::elastic::moment;

    fn block() -> (Vec<Vec3>, Connections, Vec<bool>, Vec<Mat3>) {
        let (rest, pairs, free) = tissue_testkit::jittered_grid(6, 7);
        let connections = Connections::from_pairs(rest.len(), pairs);
        let inverse = (0..rest.len())
            .map(|i| moment(&rest, &connections, i).inverse())
            .collect();
        (rest, connections, free, inverse)
    }

    /// `g_k = sum_i a_i c_ik - a_k sum_j c_kj` with the given vectors.
    fn constraint(
        connections: &Connections,
        scales: &[f32],
        vector: impl Fn(usize, usize) -> Vec3,
        k: usize,
    ) -> Vec3 {
        connections
            .of(k)
            .iter()
            .map(|&i| {
                let i = i as usize;
                scales[i] * vector(i, k) - scales[k] * vector(k, i)
            })
            .sum()
    }

    #[test]
    fn the_consistent_vectors_satisfy_the_integration_constraint_at_free_particles() {
        let (rest, connections, free, inverse) = block();
        let c = Consistency::new(&rest, &connections, &inverse, &free);
        assert!(c.residual_after <= REDUCTION * c.residual_before);
        let mut worst = (0.0f32, 0.0f32);
        for k in (0..rest.len()).filter(|&k| free[k]) {
            let least_squares = |i: usize, j: usize| inverse[i] * (rest[j] - rest[i]);
            let before = constraint(&connections, &c.scales, least_squares, k);
            let after = constraint(&connections, &c.scales, |i, j| c.vector(&rest, i, j), k);
            worst = (worst.0.max(before.length()), worst.1.max(after.length()));
        }
        // Jittered neighbourhoods miss it badly; the consistent vectors
        // (stored in f32) to the solve's reduction.
        assert!(worst.0 > 0.1, "uncorrected residual {}", worst.0);
        assert!(
            f64::from(worst.1) <= 2.0 * REDUCTION * f64::from(worst.0),
            "{worst:?}"
        );
        // Fixed particles carry no multiplier.
        for k in (0..rest.len()).filter(|&k| !free[k]) {
            assert_eq!(c.multipliers[k], Vec3::ZERO);
        }
    }

    #[test]
    fn the_consistent_vectors_keep_every_neighbourhood_exact_for_affine_maps() {
        let (rest, connections, free, inverse) = block();
        let c = Consistency::new(&rest, &connections, &inverse, &free);
        for i in 0..rest.len() {
            let mut m = Mat3::ZERO;
            for &j in connections.of(i) {
                let (v, d) = (c.vector(&rest, i, j as usize), rest[j as usize] - rest[i]);
                m += Mat3::from_cols(d * v.x, d * v.y, d * v.z);
            }
            let off = (m - Mat3::IDENTITY)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            assert!(
                off < 1e-4,
                "particle {i}: sum d c^T off the identity by {off}"
            );
        }
    }

    /// The coarse space of constants and linear functions over aggregates
    /// cuts the multipliers' iterations, which otherwise grow as
    /// `n^(2/3)`, to the same constraint residual.
    #[test]
    fn the_coarse_space_cuts_the_multipliers_iterations() {
        let (rest, pairs, free) = tissue_testkit::jittered_grid(18, 3);
        let connections = Connections::from_pairs(rest.len(), pairs);
        let inverse: Vec<Mat3> = (0..rest.len())
            .map(|i| moment(&rest, &connections, i).inverse())
            .collect();
        let jacobi = Consistency::solved(&rest, &connections, &inverse, &free, false);
        let coarse = Consistency::solved(&rest, &connections, &inverse, &free, true);
        for c in [&jacobi, &coarse] {
            assert!(c.residual_after <= REDUCTION * c.residual_before, "{c:?}");
        }
        eprintln!(
            "iterations: Jacobi {}, coarse {}",
            jacobi.iterations, coarse.iterations
        );
        assert!(
            2 * coarse.iterations <= jacobi.iterations,
            "{} against {}",
            coarse.iterations,
            jacobi.iterations
        );
        // The same vectors, to the solve's tolerance: the multipliers agree
        // where the constraint pins them.
        let worst = jacobi
            .corrections
            .iter()
            .zip(&coarse.corrections)
            .map(|(a, b)| {
                (*a - *b)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f32, |m, x| m.max(x.abs()))
            })
            .fold(0.0f32, f32::max);
        let size = jacobi
            .corrections
            .iter()
            .map(|m| m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs())))
            .fold(0.0f32, f32::max);
        assert!(worst <= 0.05 * size, "{worst} of {size}");
    }
}
