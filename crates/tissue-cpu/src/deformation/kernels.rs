//! The stage-2 kernels on the CPU, each the twin of a shader of the same
//! name: rotations, force, the plain step, the Chebyshev combine, the step
//! norms and deflation.

use glam::{DVec3, Mat3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;
use tissue_core::Connections;
use tissue_solve::coarse::OUTSIDE;
use tissue_solve::elastic::{Elastic, ElasticTerms, offsets_product};
use tissue_solve::modes::{LowModes, add_entries};
use tissue_solve::params::{ForceModel, RotationMethod};
use tissue_solve::svd3::rotation_of;

use super::polar::{LANES, warm_rotations};

/// The Chebyshev step: `omega (q_hat - q_old) + q_old`.
pub fn chebyshev_combine(plain: &[Vec3], previous: &[Vec3], omega: f32) -> Vec<Vec3> {
    plain
        .par_iter()
        .zip(previous)
        .map(|(&q_hat, &q_old)| omega * (q_hat - q_old) + q_old)
        .collect()
}

/// Largest and RMS plain step over all particles (`old` to `new`), as
/// [`Deformer::solve`] measures each iteration.
pub fn steps(old: &[Vec3], new: &[Vec3]) -> (f32, f32) {
    let squares: Vec<f32> = old
        .par_iter()
        .zip(new)
        .map(|(a, b)| (*b - *a).length_squared())
        .collect();
    let max = squares.iter().copied().fold(0.0, f32::max).sqrt();
    let mean = squares.iter().map(|&x| f64::from(x)).sum::<f64>() / squares.len().max(1) as f64;
    (max, mean.sqrt() as f32)
}

/// Per particle, the rotation that best maps rest offsets onto current
/// offsets: the polar rotation of `M_i = sum_j (q_j - q_i)(p_j - p_i)^T`.
pub fn local_rotations(rest: &[Vec3], current: &[Vec3], connections: &Connections) -> Vec<Mat3> {
    (0..rest.len())
        .into_par_iter()
        .map(|i| rotation_of(offsets_product(rest, current, connections, i)))
        .collect()
}

/// [`local_rotations`] by Müller et al.'s polar iteration, warm-started
/// from `previous`, eight particles side by side ([`warm_rotations`]) (rest offsets onto current offsets, like `local_rotations`).
pub fn local_rotations_warm(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    previous: &[Mat3],
) -> Vec<Mat3> {
    let mut rotations = vec![Mat3::IDENTITY; rest.len()];
    rotations
        .par_chunks_mut(LANES)
        .zip(previous.par_chunks(LANES))
        .enumerate()
        .for_each(|(chunk, (out, previous))| {
            let first = chunk * LANES;
            let m: [Mat3; LANES] = std::array::from_fn(|l| {
                if l < out.len() {
                    offsets_product(rest, current, connections, first + l)
                } else {
                    Mat3::ZERO
                }
            });
            warm_rotations(&m[..out.len()], previous, out);
        });
    rotations
}

/// Per particle, the elastic model's terms ([`Elastic::terms`]) and its
/// rotation: the polar rotation of its gradient `F_i`, or of `M_i` for a
/// flat neighbourhood, by `method` (warm polar from `rotations`, the last
/// iteration's). The elastic phase's rotations pass: the rotations of the
/// `M_i` alone are not needed in it.
pub fn elastic_terms(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    rotations: &[Mat3],
    elastic: &Elastic,
    method: RotationMethod,
) -> (Vec<ElasticTerms>, Vec<Mat3>) {
    let blank = ElasticTerms {
        target: Mat3::ZERO,
        stress: Mat3::ZERO,
    };
    let mut terms = vec![blank; rest.len()];
    let mut turned = vec![Mat3::IDENTITY; rest.len()];
    terms
        .par_chunks_mut(LANES)
        .zip(turned.par_chunks_mut(LANES))
        .zip(rotations.par_chunks(LANES))
        .enumerate()
        .for_each(|(chunk, ((terms, turned), previous))| {
            let (first, count) = (chunk * LANES, terms.len());
            let mut products = [(Mat3::ZERO, Mat3::ZERO); LANES];
            let mut of = [Mat3::ZERO; LANES];
            for l in 0..count {
                let i = first + l;
                let (m, n) = elastic.products(rest, current, connections, i);
                products[l] = (m, n);
                of[l] = if elastic.is_flat(i) {
                    m
                } else {
                    elastic.gradient(i, m, n)
                };
            }
            match method {
                RotationMethod::Svd => {
                    for (turned, &of) in turned.iter_mut().zip(&of) {
                        *turned = rotation_of(of);
                    }
                }
                RotationMethod::WarmPolar => warm_rotations(&of[..count], previous, turned),
            }
            for (l, ((m, n), &rotation)) in products.iter().zip(turned.iter()).enumerate() {
                terms[l] = elastic.terms(first + l, *m, *n, rotation);
            }
        });
    (terms, turned)
}

/// The elastic force on every particle ([`Elastic::force_on`]), gathered
/// over its connections from the terms of [`elastic_terms`].
pub fn elastic_force(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    terms: &[ElasticTerms],
    elastic: &Elastic,
) -> Vec<Vec3> {
    (0..rest.len())
        .into_par_iter()
        .map(|k| elastic.force_on(k, rest, current, connections, terms))
        .collect()
}

/// The force on every particle, gathered over its connections (the paper's
/// and the symmetric force; the elastic force is [`elastic_force`]).
pub fn deformation_force(
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
    connections: &Connections,
    model: ForceModel,
) -> Vec<Vec3> {
    (0..rest.len())
        .into_par_iter()
        .map(|j| {
            // In 4-lane vectors (`Vec3A`, `Mat3A`): the products and sums
            // `Vec3` makes, three at a time.
            let at = |v: &[Vec3], i: usize| Vec3A::from(v[i]);
            let (rj, cj, turn_j) = (at(rest, j), at(current, j), Mat3A::from(rotations[j]));
            let mut f = Vec3A::ZERO;
            for &i in connections.of(j) {
                let i = i as usize;
                let d = rj - at(rest, i);
                let c = cj - at(current, i);
                let turn_i = Mat3A::from(rotations[i]);
                f += match model {
                    ForceModel::Paper => turn_i * d - c,
                    // (The elastic force is gathered by [`elastic_force`].)
                    ForceModel::Symmetric | ForceModel::Elastic => (turn_i + turn_j) * d - 2.0 * c,
                };
            }
            Vec3::from(f)
        })
        .collect()
}

/// `q += alpha (F + b)` for free particles (the stiffness `sigma` and mass
/// `m` fold into `alpha = sigma / m`), `b` the particle's body force from
/// `loads` (none where `loads` is empty); control points stay where the
/// surface put them.
pub fn integrate(
    current: &[Vec3],
    force: &[Vec3],
    loads: &[Vec3],
    free: &[bool],
    alpha: f32,
) -> Vec<Vec3> {
    current
        .par_iter()
        .zip(force)
        .zip(free)
        .enumerate()
        .map(|(i, ((&q, &f), &free))| {
            if !free {
                return q;
            }
            match loads.get(i) {
                Some(&b) => q + alpha * (f + b),
                None => q + alpha * f,
            }
        })
        .collect()
}

/// The elastic phase's residual for the volume smoother: half the force,
/// loads included, at the particles inside an aggregate (`K e = -r` for the
/// error `e` while the rotations are held), in `f64`; zero elsewhere.
pub fn elastic_residual(force: &[Vec3], loads: &[Vec3], aggregate: &[u32]) -> Vec<DVec3> {
    force
        .par_iter()
        .zip(aggregate)
        .enumerate()
        .map(|(i, (&f, &a))| {
            if a == OUTSIDE {
                return DVec3::ZERO;
            }
            let b = loads.get(i).copied().unwrap_or(Vec3::ZERO);
            0.5 * (f + b).as_dvec3()
        })
        .collect()
}

/// Deflation's kernel: turns the plain step `plain - current` into one that also removes the
/// error along every mode: the step's component `s_k` along mode `k` is
/// `c alpha lambda_k` times the error there (`contraction = c alpha`),
/// so the mode moves by `s_k / (c alpha lambda_k)` instead of `s_k`.
pub fn deflate(modes: &LowModes, current: &[Vec3], plain: &mut [Vec3], contraction: f32) {
    let m = modes.count();
    const CHUNK: usize = 1024;
    // Per particle, one 4-lane multiply-add per mode (`Vec3A`), summed in
    // `f32` within a chunk and in `f64` across chunks.
    let projections = current
        .par_chunks(CHUNK)
        .zip(plain.par_chunks(CHUNK))
        .zip(modes.vectors().par_chunks(CHUNK * m))
        .map(|((q, p), v)| {
            let mut c = vec![Vec3A::ZERO; m];
            for ((q, p), v) in q.iter().zip(p).zip(v.chunks_exact(m)) {
                let s = Vec3A::from(*p - *q);
                for (c, &v) in c.iter_mut().zip(v) {
                    *c += s * v;
                }
            }
            c.into_iter().map(|c| c.as_dvec3()).collect::<Vec<_>>()
        })
        .reduce(|| vec![DVec3::ZERO; m], add_entries);
    let gains: Vec<Vec3A> = projections
        .iter()
        .zip(modes.gain_scales(contraction))
        .map(|(c, scale)| Vec3A::from((*c * scale).as_vec3()))
        .collect();
    plain
        .par_chunks_mut(CHUNK)
        .zip(modes.vectors().par_chunks(CHUNK * m))
        .for_each(|(p, v)| {
            for (p, v) in p.iter_mut().zip(v.chunks_exact(m)) {
                let mut d = Vec3A::ZERO;
                for (&g, &v) in gains.iter().zip(v) {
                    d += g * v;
                }
                *p += Vec3::from(d);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use tissue_solve::modes::low_modes;
    use tissue_solve::spectrum::laplacian_extremes;

    /// [`tissue_testkit::dirichlet_path`] as connections.
    fn dirichlet_path(n: usize) -> (Connections, Vec<bool>) {
        let (total, pairs, free) = tissue_testkit::dirichlet_path(n);
        (Connections::from_pairs(total, pairs), free)
    }

    #[test]
    fn deflation_removes_the_error_of_a_deflated_mode_in_one_step() {
        let n = 60;
        let (connections, free) = dirichlet_path(n);
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let modes = low_modes(&connections, &free, 4, lo, hi);
        let m = modes.count();
        let contraction = 0.9 / hi;
        // An error along one mode, and one along a mode left to Chebyshev.
        for (k, deflated) in [(1, true), (9, false)] {
            let angle = |i: usize| (k * i) as f32 * std::f32::consts::PI / (n as f32 + 1.0);
            let lambda = 2.0 - 2.0 * angle(1).cos();
            let direction = Vec3::new(0.3, -1.0, 0.5);
            let error: Vec<Vec3> = (0..n + 2)
                .map(|i| {
                    if free[i] {
                        angle(i).sin() * direction
                    } else {
                        Vec3::ZERO
                    }
                })
                .collect();
            // The plain step for fixed rotations: -contraction L e.
            let mut plain: Vec<Vec3> = error
                .iter()
                .map(|&e| e - contraction * lambda * e)
                .collect();
            deflate(&modes, &error, &mut plain, contraction);
            for i in 0..n + 2 {
                let step = plain[i] - error[i];
                let want = if deflated {
                    -error[i]
                } else {
                    -contraction * lambda * error[i]
                };
                assert!(
                    (step - want).length() < 1e-4 * direction.length(),
                    "mode {k} (m = {m}), particle {i}: step {step} vs {want}"
                );
            }
        }
    }
}
