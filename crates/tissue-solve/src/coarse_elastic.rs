//! The two-level solve of the elastic phase: the coarse correction of
//! [`crate::coarse`] for the elastic operator linearised where the phase
//! starts, three unknowns (a translation) per aggregate.
//!
//! The elastic force's operator for a small displacement `u` (rotations
//! held, the force `-2 K u`) is the connection Laplacian plus the volume
//! term's Gauss-Newton part: `K = L + 1/2 sum_i W_i g_i g_i^T`, with `g_i`
//! the gradient of `J_i = det F_i`, whose entries are `cof(F_i) c_ij`
//! at neighbour `j` and minus their sum at `i`
//! ([`crate::elastic::VolumeLinearisation`]). Unlike the Laplacian, `K` depends on the
//! state through `cof(F_i)`, which turns with the particle's rotation; a
//! coarse matrix built at rest (`cof F = I`) diverged on the breast phantoms
//! (docs/METHOD.md, "Elastic model"). So `P^T K P` is assembled at the
//! state the elastic phase starts from (after the shear phase, every
//! neighbourhood near its rest volume and turned by its rotation), factored
//! once, and used for the whole phase, and for warm-started tracking
//! frames after it.

use std::time::Instant;

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use tissue_core::{Connections, DeformError, Error};

use tissue_core::ParticleModel;

use crate::coarse::{Aggregates, Envelope, OUTSIDE, RATE_ITERATIONS, norm, power_start};
use crate::elastic::{Elastic, VolumeLinearisation, cofactor, offsets_product};
use crate::params::{DeformParams, ForceModel};
use crate::plan::Plan;
use crate::tracker::Iteration;

/// The elastic operator's coarse correction, linearised at one state.
#[derive(Debug, Clone)]
pub struct ElasticCoarse {
    /// The operator `K` at the state.
    linearisation: VolumeLinearisation,
    /// The Cholesky factor of `P^T K P`, three rows per aggregate.
    factor: Envelope,
    /// The plain step's `c alpha` this correction was made for.
    contraction: f32,
    rho: f32,
    seconds: f64,
}

impl ElasticCoarse {
    /// `P^T K P` over `aggregates` with `K` linearised at `current`,
    /// factored, and the two-level iteration's contraction for the plain
    /// step's `contraction` (`c alpha`) estimated by power iteration.
    pub fn new(
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
        contraction: f32,
    ) -> Result<Self, Error> {
        let started = Instant::now();
        let linearisation = linearise(rest, current, connections, elastic);
        let rows = assemble(aggregates, rest, connections, &linearisation);
        let factor = Envelope::cholesky(&rows).ok_or_else(|| {
            Error::from(DeformError::CoarseSpace(
                "the elastic coarse matrix is not positive definite (a rounding failure)".into(),
            ))
        })?;
        let mut space = Self {
            linearisation,
            factor,
            contraction,
            rho: 0.0,
            seconds: 0.0,
        };
        space.rho = space.spectral_radius(aggregates, rest, connections);
        space.seconds = started.elapsed().as_secs_f64();
        Ok(space)
    }

    /// [`ElasticCoarse::new`] as a device makes it at a phase's start: told
    /// to the log, and `None` (a warning: the phase then runs uncorrected)
    /// where it cannot be made.
    pub fn at_phase_start(
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
        contraction: f32,
    ) -> Option<Self> {
        match Self::new(aggregates, rest, current, connections, elastic, contraction) {
            Ok(coarse) => {
                log::info!(
                    "elastic two-level solve: {} aggregates, contraction {:.3}, prepared in {:.3} s",
                    aggregates.count(),
                    coarse.rho(),
                    coarse.seconds()
                );
                Some(coarse)
            }
            Err(e) => {
                log::warn!("the elastic phase runs without its two-level solve: {e}");
                None
            }
        }
    }

    /// The contraction of the two-level iteration, for Chebyshev and the
    /// stopping rule: its spectral radius, estimated by power iteration.
    pub fn rho(&self) -> f32 {
        self.rho
    }

    /// The plain step's `c alpha` this correction was made for.
    pub fn contraction(&self) -> f32 {
        self.contraction
    }

    /// Seconds the assembly, the factor and the estimate took.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    /// The operator `K` at the state: per particle `W_i`, `cof(F_i) B_i`,
    /// `a_i cof(F_i)` and `mu_i`.
    pub fn linearisation(&self) -> &VolumeLinearisation {
        &self.linearisation
    }

    /// The Cholesky factor of `P^T K P`, unknown `3 a + axis` for
    /// aggregate `a`.
    pub fn factor(&self) -> &Envelope {
        &self.factor
    }

    /// Whether an elastic phase run with `iteration` needs the correction
    /// made again at its start: it starts a phase of its own
    /// ([`Iteration::relinearise`]), or the correction in hand (if any) was
    /// made for another step. Only for a corrected elastic phase.
    pub fn is_needed_anew(existing: Option<&Self>, iteration: &Iteration) -> bool {
        if iteration.force != ForceModel::Elastic || !iteration.correct {
            return false;
        }
        iteration.relinearise || existing.is_none_or(|c| c.contraction != iteration.contraction)
    }

    /// `K u` at the state, over the particles `aggregates` holds free
    /// (others read as zero; their rows are zero).
    fn operator(
        &self,
        aggregates: &Aggregates,
        rest: &[Vec3],
        connections: &Connections,
        u: &[DVec3],
    ) -> Vec<DVec3> {
        let aggregate = &aggregates.aggregate;
        self.linearisation
            .operator(rest, connections, |i| aggregate[i] != OUTSIDE, u)
    }

    /// Turns the plain step `plain - current` (`-contraction K e` for the
    /// error `e`) into the two-level one: subtracts the `K`-orthogonal
    /// projection onto the coarse space of the error left after it, whose
    /// `K e' = -s / (c alpha) + K s` is known without `e`.
    pub fn correct(
        &self,
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        plain: &mut [Vec3],
        connections: &Connections,
    ) {
        let aggregate = &aggregates.aggregate;
        let inverse = 1.0 / f64::from(self.contraction);
        let step: Vec<DVec3> = current
            .par_iter()
            .zip(plain.par_iter())
            .zip(aggregate)
            .map(|((&q, &p), &a)| {
                if a == OUTSIDE {
                    DVec3::ZERO
                } else {
                    (p - q).as_dvec3()
                }
            })
            .collect();
        let ks = self.operator(aggregates, rest, connections, &step);
        let mut coarse = vec![0.0f64; 3 * aggregates.count()];
        for ((&a, k), s) in aggregate.iter().zip(&ks).zip(&step) {
            if a != OUTSIDE {
                let r = *k - *s * inverse;
                let a = 3 * a as usize;
                coarse[a] += r.x;
                coarse[a + 1] += r.y;
                coarse[a + 2] += r.z;
            }
        }
        self.factor.solve_scalar(&mut coarse);
        plain.par_iter_mut().zip(aggregate).for_each(|(p, &a)| {
            if a != OUTSIDE {
                let a = 3 * a as usize;
                *p -= DVec3::new(coarse[a], coarse[a + 1], coarse[a + 2]).as_vec3();
            }
        });
    }

    /// The spectral radius of `E = (I - Pi)(I - c alpha K)` by power
    /// iteration, as [`crate::coarse::CoarseSpace`] estimates its own.
    fn spectral_radius(
        &self,
        aggregates: &Aggregates,
        rest: &[Vec3],
        connections: &Connections,
    ) -> f32 {
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let mut v = power_start(inside, rest.len());
        let mut radius = 0.0;
        for _ in 0..RATE_ITERATIONS {
            let scale = norm(&v);
            if scale == 0.0 {
                break;
            }
            v.par_iter_mut().for_each(|x| *x /= scale as f32);
            let error: Vec<DVec3> = v.iter().map(|x| x.as_dvec3()).collect();
            let k = self.operator(aggregates, rest, connections, &error);
            let mut plain: Vec<Vec3> = v
                .iter()
                .zip(&k)
                .map(|(&e, k)| e - self.contraction * k.as_vec3())
                .collect();
            self.correct(aggregates, rest, &v, &mut plain, connections);
            radius = norm(&plain) as f32;
            v = plain;
        }
        radius.clamp(0.0, 0.9999)
    }
}

/// `K` linearised at `current`: per particle `cof(F_i)` turns the rest
/// vectors `c_ij` into the volume term's gradient (module docs).
fn linearise(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    elastic: &Elastic,
) -> VolumeLinearisation {
    let c = &elastic.consistency;
    let cofactors: Vec<DMat3> = (0..rest.len())
        .into_par_iter()
        .map(|i| {
            if elastic.weights[i] == 0.0 {
                return DMat3::ZERO;
            }
            let m = offsets_product(rest, current, connections, i);
            let n = c.multipliers_product(current, connections, i);
            cofactor(elastic.gradient(i, m, n)).as_dmat3()
        })
        .collect();
    VolumeLinearisation {
        weights: elastic.weights.iter().map(|&w| f64::from(w)).collect(),
        corrections: cofactors
            .iter()
            .zip(&c.corrections)
            .map(|(cof, b)| *cof * b.as_dmat3())
            .collect(),
        scales: cofactors
            .iter()
            .zip(&c.scales)
            .map(|(cof, &a)| *cof * f64::from(a))
            .collect(),
        multipliers: c.multipliers.iter().map(|m| m.as_dvec3()).collect(),
    }
}

/// The rows of `P^T K P` on three unknowns per aggregate (`3 a + axis`):
/// the coarse Laplacian on each axis, and per particle with a volume
/// weight `1/2 W_i (P^T g_i)(P^T g_i)^T`, each sorted by column.
fn assemble(
    aggregates: &Aggregates,
    rest: &[Vec3],
    connections: &Connections,
    linearisation: &VolumeLinearisation,
) -> Vec<Vec<(u32, f64)>> {
    let weights = &linearisation.weights;
    let aggregate = &aggregates.aggregate;
    let mut rows: Vec<Vec<(u32, f64)>> = aggregates
        .rows
        .iter()
        .flat_map(|row| {
            (0..3u32).map(move |axis| row.iter().map(|&(b, w)| (3 * b + axis, w)).collect())
        })
        .collect();
    // Per particle, `P^T g_i` (its few aggregates and their 3-vectors).
    let parts: Vec<Vec<(u32, DVec3)>> = (0..rest.len())
        .into_par_iter()
        .map(|i| {
            let mut parts: Vec<(u32, DVec3)> = Vec::new();
            if weights[i] == 0.0 {
                return parts;
            }
            let mut add = |a: u32, v: DVec3| {
                if a == OUTSIDE {
                    return;
                }
                match parts.iter_mut().find(|(b, _)| *b == a) {
                    Some((_, w)) => *w += v,
                    None => parts.push((a, v)),
                }
            };
            for &j in connections.of(i) {
                let g = linearisation.entry(rest, i, j as usize);
                add(aggregate[j as usize], g);
                add(aggregate[i], -g);
            }
            parts
        })
        .collect();
    for (i, parts) in parts.iter().enumerate() {
        for &(a, u) in parts {
            for &(b, v) in parts {
                for r in 0..3 {
                    let row = &mut rows[3 * a as usize + r];
                    for c in 0..3 {
                        row.push((3 * b + c as u32, 0.5 * weights[i] * u[r] * v[c]));
                    }
                }
            }
        }
    }
    rows.into_par_iter()
        .map(|mut row| {
            row.sort_unstable_by_key(|&(b, _)| b);
            let mut merged: Vec<(u32, f64)> = Vec::with_capacity(row.len());
            for (b, w) in row {
                match merged.last_mut() {
                    Some((last, sum)) if *last == b => *sum += w,
                    _ => merged.push((b, w)),
                }
            }
            merged
        })
        .collect()
}

/// The aggregates of the elastic phase's two-level solve under `params`:
/// with the elastic force and the two-level solve on, the cells of
/// `coarse` grown until there are at most `elastic_coarse_max_aggregates`;
/// none otherwise, or (with a warning) where they cannot be made.
pub fn elastic_aggregates(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<Aggregates> {
    if plan.elastic.is_none() || params.coarse == 0.0 || params.elastic_coarse_max_aggregates == 0 {
        return None;
    }
    Aggregates::new(
        &model.positions,
        &model.connections,
        &plan.free,
        params.coarse * model.mean_connection_length(),
        params.elastic_coarse_max_aggregates,
    )
    .inspect_err(|e| log::warn!("the elastic phase runs without its two-level solve: {e}"))
    .ok()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use glam::Mat3;

    use super::*;

    /// The elastic force ([`Elastic::force_on`]) with every particle's
    /// rotation held at `rotations` (the devices' kernels compute the same).
    fn elastic_force(
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        rotations: &[Mat3],
        elastic: &Elastic,
    ) -> Vec<Vec3> {
        let terms: Vec<_> = (0..rest.len())
            .map(|i| {
                let m = offsets_product(rest, current, connections, i);
                let n = elastic
                    .consistency
                    .multipliers_product(current, connections, i);
                elastic.terms(i, m, n, rotations[i])
            })
            .collect();
        (0..rest.len())
            .map(|k| elastic.force_on(k, rest, current, connections, &terms))
            .collect()
    }

    /// An 8x8x8 grid of unit spacing jittered by up to 0.2, pairs closer
    /// than 1.5 connected, the outer layer fixed.
    fn jittered_block() -> (Vec<Vec3>, Connections, Vec<bool>) {
        let (positions, pairs, free) = tissue_testkit::jittered_grid(8, 11);
        let connections = Connections::from_pairs(positions.len(), pairs);
        (positions, connections, free)
    }

    /// The block, its aggregates (cells of 2), its elastic model at 0.49
    /// and the coarse correction at `current`.
    fn corrected_at(
        current: impl Fn(Vec3) -> Vec3,
    ) -> (
        Vec<Vec3>,
        Vec<Vec3>,
        Connections,
        Aggregates,
        Elastic,
        ElasticCoarse,
    ) {
        let (rest, connections, free) = jittered_block();
        let current: Vec<Vec3> = rest.iter().map(|&p| current(p)).collect();
        let aggregates = Aggregates::new(&rest, &connections, &free, 2.0, 1_000).unwrap();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let coarse =
            ElasticCoarse::new(&aggregates, &rest, &current, &connections, &elastic, 0.002)
                .unwrap();
        (rest, current, connections, aggregates, elastic, coarse)
    }

    fn turn() -> Mat3 {
        Mat3::from_axis_angle(Vec3::new(0.3, -1.0, 0.5).normalize(), 1.2)
    }

    /// A smooth displacement of the free particles.
    fn displacement(aggregates: &Aggregates, rest: &[Vec3]) -> Vec<DVec3> {
        rest.iter()
            .zip(&aggregates.aggregate)
            .map(|(p, &a)| {
                if a == OUTSIDE {
                    DVec3::ZERO
                } else {
                    let p = p.as_dvec3();
                    DVec3::new((0.7 * p.y).sin(), (0.5 * p.z).cos(), 0.3 * p.x) * 0.01
                }
            })
            .collect()
    }

    /// At a turned state the operator's volume part is the elastic force's
    /// derivative with the rotations held, `-2 (K - L) u = (f(q + u) - f(q - u)) / 2`
    /// less the same for the model without volume resistance (the volume
    /// term turns with the particle, which a matrix built at rest misses);
    /// its shear part is the Laplacian, which the shear terms' derivative is
    /// only near (exactly where every neighbourhood is round and `c = b`).
    #[test]
    fn the_operator_is_the_force_linearised_at_a_turned_state() {
        let r = turn();
        let (rest, current, connections, aggregates, elastic, coarse) =
            corrected_at(|p| r * p + Vec3::new(2.0, -1.0, 0.5));
        let free: Vec<bool> = aggregates.aggregate.iter().map(|&a| a != OUTSIDE).collect();
        let shear_only = Elastic::new(&rest, &connections, 0.0, &free);
        let u = displacement(&aggregates, &rest);
        let k = coarse.operator(&aggregates, &rest, &connections, &u);
        let laplacian: Vec<DVec3> = (0..rest.len())
            .map(|i| {
                let at = |j: usize| if free[j] { u[j] } else { DVec3::ZERO };
                connections
                    .of(i)
                    .iter()
                    .map(|&j| at(i) - at(j as usize))
                    .sum()
            })
            .collect();
        let rotations = vec![r; rest.len()];
        let moved = |sign: f32| -> Vec<Vec3> {
            current
                .iter()
                .zip(&u)
                .map(|(q, u)| *q + sign * u.as_vec3())
                .collect()
        };
        // Central differences: the force's second-order part cancels.
        let change = |elastic: &Elastic| -> Vec<DVec3> {
            let force = |q: &[Vec3]| elastic_force(&rest, q, &connections, &rotations, elastic);
            let (before, after) = (force(&moved(-1.0)), force(&moved(1.0)));
            after
                .iter()
                .zip(&before)
                .map(|(a, b)| 0.5 * (*a - *b).as_dvec3())
                .collect()
        };
        let (full, shear) = (change(&elastic), change(&shear_only));
        let (mut volume_off, mut shear_off, mut scale) = (0.0f64, 0.0f64, 0.0f64);
        for i in (0..rest.len()).filter(|&i| free[i]) {
            let volume = full[i] - shear[i];
            volume_off = volume_off.max((volume + 2.0 * (k[i] - laplacian[i])).length());
            shear_off = shear_off.max((shear[i] + 2.0 * laplacian[i]).length());
            scale = scale.max(full[i].length());
        }
        assert!(scale > 0.0);
        assert!(
            volume_off <= 2e-3 * scale,
            "volume part off by {volume_off} of {scale}"
        );
        assert!(
            shear_off <= 0.05 * scale,
            "shear part off by {shear_off} of {scale}"
        );
        eprintln!(
            "volume part off by {:.2e}, shear part by {:.2e} of the change",
            volume_off / scale,
            shear_off / scale
        );
        // The operator at rest, turned, is not it: the volume part differs.
        let at_rest = elastic.rest_operator(&rest, &connections, &free, &u);
        let off = k
            .iter()
            .zip(&at_rest)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0f64, f64::max);
        assert!(off > 0.1 * scale, "{off} vs {scale}");
    }

    /// After the correction, what is left of the error has no part the
    /// coarse space can remove: `P^T K e'' = 0`.
    #[test]
    fn the_correction_leaves_no_error_in_the_coarse_space() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.1, 0.95, 0.97));
        let r = turn();
        let (rest, _, connections, aggregates, _, coarse) = corrected_at(|p| r * stretch * p);
        let error = displacement(&aggregates, &rest);
        let restricted = |field: &[DVec3]| {
            let k = coarse.operator(&aggregates, &rest, &connections, field);
            let mut sums = vec![DVec3::ZERO; aggregates.count()];
            for (&a, k) in aggregates.aggregate.iter().zip(&k) {
                if a != OUTSIDE {
                    sums[a as usize] += *k;
                }
            }
            sums.iter().map(|s| s.length()).fold(0.0f64, f64::max)
        };
        let k = coarse.operator(&aggregates, &rest, &connections, &error);
        let e: Vec<Vec3> = error.iter().map(|e| e.as_vec3()).collect();
        let mut plain: Vec<Vec3> = e
            .iter()
            .zip(&k)
            .map(|(&e, k)| e - coarse.contraction() * k.as_vec3())
            .collect();
        let before: Vec<DVec3> = plain.iter().map(|p| p.as_dvec3()).collect();
        coarse.correct(&aggregates, &rest, &e, &mut plain, &connections);
        let after: Vec<DVec3> = plain.iter().map(|p| p.as_dvec3()).collect();
        let (was, left) = (restricted(&before), restricted(&after));
        assert!(was > 0.0);
        assert!(left <= 1e-4 * was, "{left} of {was}");
        // And the two-level iteration contracts.
        assert!(
            coarse.rho() > 0.0 && coarse.rho() < 0.99,
            "{}",
            coarse.rho()
        );
    }
}
