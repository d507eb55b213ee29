//! The lowest modes of the connection Laplacian over free particles, for
//! deflation: computed once per model, on the host, for every device.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use tissue_core::{Connections, ParticleModel};

use crate::params::DeformParams;
use crate::plan::Plan;

/// The lowest eigenpairs of the connection-graph Laplacian over free
/// particles (control points fixed: Dirichlet rows), for deflation. For fixed
/// rotations the plain step is `-c alpha L e` for the error `e` (`c = 2` for
/// the symmetric force, 1 for the paper's), so the error along an
/// eigenvector `v` with eigenvalue `lambda` is `-(v . step) / (c alpha lambda)`:
/// deflation (each device's kernel) removes it exactly, and what is left of the error
/// lies in modes with eigenvalues from `next` up.
#[derive(Debug, Clone, PartialEq)]
pub struct LowModes {
    /// Particle-major: `vectors[i * count + k]` is eigenvector `k` at particle `i`
    /// (0 at particles that are not free).
    vectors: Vec<f32>,
    /// The eigenvalues, ascending.
    values: Vec<f64>,
    /// A lower estimate of the next eigenvalue, the smallest left to Chebyshev.
    next: f32,
    /// The largest relative residual `|L v - lambda v| / lambda` of the vectors.
    residual: f64,
    /// Seconds spent computing them.
    seconds: f64,
}

impl LowModes {
    /// Number of modes.
    pub fn count(&self) -> usize {
        self.values.len()
    }

    /// The eigenvalues, ascending.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The eigenvectors, particle-major (`vectors()[i * count() + k]` is
    /// mode `k` at particle `i`, 0 where the particle is not free), so the
    /// GPU deflates with the very modes the CPU path does.
    pub fn vectors(&self) -> &[f32] {
        &self.vectors
    }

    /// The smallest eigenvalue left after deflation (estimated from below).
    pub fn next(&self) -> f32 {
        self.next
    }

    /// The largest relative residual of the eigenvectors.
    pub fn residual(&self) -> f64 {
        self.residual
    }

    /// Seconds it took to compute them.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    /// The plain iteration's contraction on what deflation leaves:
    /// `1 - 2 step_fraction next / lambda_max`.
    pub fn rho(&self, plan: &Plan, params: &DeformParams) -> f32 {
        (1.0 - 2.0 * params.step_fraction * self.next / plan.lambda_max).clamp(0.0, 0.9999)
    }

    /// Per mode, `1 / (contraction lambda_k) - 1` in `f64`: what turns the
    /// plain step's component along mode `k` into the correction that
    /// removes its error (the devices' deflation kernels).
    pub fn gain_scales(&self, contraction: f32) -> impl Iterator<Item = f64> + '_ {
        let c = f64::from(contraction);
        self.values
            .iter()
            .map(move |&lambda| 1.0 / (c * lambda) - 1.0)
    }
}

/// The modes a solve of `model` deflates under `params`, as both backends
/// compute them: none without deflation, where none came out (`low_modes`
/// warned), or (with a warning) for a model with more free particles than
/// `deflation_max_particles`.
pub fn deflation_modes(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<LowModes> {
    if params.deflation == 0 {
        return None;
    }
    let free = plan.free.iter().filter(|&&f| f).count();
    if free > params.deflation_max_particles {
        log::warn!(
            "no deflation: {free} free particles, more than deflation_max_particles \
             ({}); preparing {} modes would take minutes",
            params.deflation_max_particles,
            params.deflation
        );
        return None;
    }
    Some(low_modes(
        &model.connections,
        &plan.free,
        params.deflation,
        plan.lambda_min,
        plan.lambda_max,
    ))
    .filter(|m| m.count() > 0)
}

/// Guard vectors carried beyond the modes wanted, so that the last wanted
/// one and the next eigenvalue converge.
const MODE_GUARDS: usize = 8;

/// Degree of the Chebyshev filter of each subspace iteration, per
/// `sqrt(lambda_max / cut)` (what separates the wanted modes by a fixed factor).
const MODE_FILTER_DEGREE: f64 = 4.0;

/// Subspace iterations at most.
const MODE_ITERATIONS: usize = 60;

/// Seed of the random start block (any fixed value: the modes do not depend on it).
const MODE_SEED: u64 = 0x9e37_79b9_7f4a_7c15;

/// Relative eigenvector residual at which the modes are taken as converged.
const MODE_RESIDUAL: f64 = 1e-5;

/// The `count` lowest eigenpairs of the Laplacian over free particles by
/// Chebyshev-filtered subspace iteration (Zhou and Saad 2007) in `f64`:
/// each round applies a Chebyshev polynomial of the Laplacian that
/// damps `[cut, lambda_max]` to a block of `count + 8` vectors,
/// orthonormalises it and takes the Ritz vectors; `cut`, the block's largest
/// Ritz value, falls as they converge. `lambda_max` must bound the spectrum
/// from above.
pub fn low_modes(
    connections: &Connections,
    free: &[bool],
    count: usize,
    lambda_min: f32,
    lambda_max: f32,
) -> LowModes {
    let started = Instant::now();
    let index: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
    let n = index.len();
    let count = count.min(n.saturating_sub(1));
    let empty = || LowModes {
        vectors: vec![0.0; free.len() * count.max(1)],
        values: vec![],
        next: lambda_min,
        residual: 0.0,
        seconds: started.elapsed().as_secs_f64(),
    };
    if count == 0 {
        return empty();
    }
    let block = (count + MODE_GUARDS).min(n);
    // Free-only rows: diagonal (all connections) and free neighbours.
    let mut local = vec![usize::MAX; free.len()];
    for (k, &i) in index.iter().enumerate() {
        local[i] = k;
    }
    // Free-only rows in compressed form: diagonal, and free neighbours.
    let diagonal: Vec<f64> = index
        .iter()
        .map(|&i| connections.of(i).len() as f64)
        .collect();
    let mut offsets = Vec::with_capacity(n + 1);
    let mut columns = Vec::new();
    offsets.push(0);
    for &i in &index {
        columns.extend(
            connections
                .of(i)
                .iter()
                .filter(|&&j| free[j as usize])
                .map(|&j| local[j as usize] as u32),
        );
        offsets.push(columns.len());
    }
    // `L X` for the block `X` held particle-major (`x[i * block + a]`), so
    // one pass over the rows serves every vector and the inner loops run
    // over contiguous vector entries.
    let apply = |x: &[f64]| -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        y.par_chunks_mut(block).enumerate().for_each(|(i, y)| {
            let own = &x[i * block..(i + 1) * block];
            y.iter_mut()
                .zip(own)
                .for_each(|(y, v)| *y = diagonal[i] * v);
            for &j in &columns[offsets[i]..offsets[i + 1]] {
                let j = j as usize;
                y.iter_mut()
                    .zip(&x[j * block..(j + 1) * block])
                    .for_each(|(y, v)| *y -= v);
            }
        });
        y
    };
    // A deterministic random start.
    let mut rng = Pcg64::seed_from_u64(MODE_SEED);
    let mut x: Vec<f64> = (0..n * block).map(|_| rng.random::<f64>() - 0.5).collect();
    let upper = f64::from(lambda_max);
    // The first cut: a guess of where the block's spectrum ends, lowered to
    // the block's largest Ritz value after every round.
    let mut cut = (f64::from(lambda_min) * (block as f64).powf(2.0 / 3.0) * 2.0).min(upper * 0.5);
    let mut values = vec![0.0; block];
    let mut residual = f64::INFINITY;
    for _ in 0..MODE_ITERATIONS {
        // Filter: T_d((L - c) / e) with [cut, upper] mapped onto [-1, 1].
        let (c, e) = (0.5 * (upper + cut), 0.5 * (upper - cut));
        let degree = (MODE_FILTER_DEGREE * (upper / cut).sqrt()).clamp(8.0, 400.0) as usize;
        let mut previous = x;
        let mut current: Vec<f64> = apply(&previous)
            .par_iter()
            .zip(&previous)
            .map(|(l, v)| (l - c * v) / e)
            .collect();
        for _ in 1..degree {
            let next: Vec<f64> = apply(&current)
                .par_iter()
                .zip(&current)
                .zip(&previous)
                .map(|((l, v), p)| 2.0 * (l - c * v) / e - p)
                .collect();
            previous = std::mem::replace(&mut current, next);
            // Keep the scale in range.
            let largest = current.par_iter().map(|x| x.abs()).reduce(|| 0.0, f64::max);
            if largest > 1e100 {
                current.par_iter_mut().for_each(|x| *x /= largest);
                previous.par_iter_mut().for_each(|x| *x /= largest);
            }
        }
        // Orthonormalise (Cholesky QR, twice: Fukaya et al. 2014).
        x = current;
        for _ in 0..2 {
            if !orthonormalise_rows(&mut x, block) {
                log::warn!("the Laplacian's low modes did not come out; no deflation");
                return LowModes {
                    vectors: vec![],
                    ..empty()
                };
            }
        }
        // Rayleigh-Ritz.
        let lx = apply(&x);
        let (theta, z) = symmetric_eigen(&mut row_gram(&x, &lx, block), block);
        x = times_rows(&x, &z, block);
        let lx = times_rows(&lx, &z, block);
        values = theta;
        // Per vector, |L v - theta v|, relative to theta.
        let checked = (count + 1).min(block);
        let squares = lx
            .par_chunks(block)
            .zip(x.par_chunks(block))
            .fold(
                || vec![0.0; checked],
                |mut sums, (l, v)| {
                    for k in 0..checked {
                        sums[k] += (l[k] - values[k] * v[k]).powi(2);
                    }
                    sums
                },
            )
            .reduce(|| vec![0.0; checked], add_entries);
        residual = squares
            .iter()
            .zip(&values)
            .map(|(r, v)| r.sqrt() / v.abs().max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max);
        cut = values[block - 1];
        if residual < MODE_RESIDUAL {
            break;
        }
    }
    if !values.iter().all(|v| v.is_finite() && *v > 0.0) {
        log::warn!("the Laplacian's low modes did not come out; no deflation");
        return LowModes {
            vectors: vec![],
            ..empty()
        };
    }
    let mut vectors = vec![0.0f32; free.len() * count];
    for (k, &i) in index.iter().enumerate() {
        for m in 0..count {
            vectors[i * count + m] = x[k * block + m] as f32;
        }
    }
    LowModes {
        vectors,
        values: values[..count].to_vec(),
        // Ritz values bound eigenvalues from above; a little margin for a
        // next eigenvalue not fully converged.
        next: (values[count] * 0.97) as f32,
        residual,
        seconds: started.elapsed().as_secs_f64(),
    }
}

/// `a + b`, entry by entry: how partial sums from parallel chunks combine.
pub fn add_entries<T: std::ops::AddAssign>(mut a: Vec<T>, b: Vec<T>) -> Vec<T> {
    a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
    a
}

/// `A^T B` for two blocks held particle-major (`a[i * block + k]`): a
/// `block x block` matrix, row-major.
fn row_gram(a: &[f64], b: &[f64], block: usize) -> Vec<f64> {
    a.par_chunks(block)
        .zip(b.par_chunks(block))
        .fold(
            || vec![0.0; block * block],
            |mut sum, (a, b)| {
                for (k, &a) in a.iter().enumerate() {
                    sum[k * block..(k + 1) * block]
                        .iter_mut()
                        .zip(b)
                        .for_each(|(s, b)| *s += a * b);
                }
                sum
            },
        )
        .reduce(|| vec![0.0; block * block], add_entries)
}

/// `X Z` for a block held particle-major and a `block x block` row-major `Z`.
fn times_rows(x: &[f64], z: &[f64], block: usize) -> Vec<f64> {
    let mut out = vec![0.0; x.len()];
    out.par_chunks_mut(block)
        .zip(x.par_chunks(block))
        .for_each(|(out, row)| {
            for (a, &r) in row.iter().enumerate() {
                out.iter_mut()
                    .zip(&z[a * block..(a + 1) * block])
                    .for_each(|(o, z)| *o += r * z);
            }
        });
    out
}

/// Makes the columns of the particle-major block `x` orthonormal by one
/// Cholesky QR step: `X^T X = R^T R`, `X <- X R^-1`. False when the Gram
/// matrix is not numerically positive definite (dependent columns).
fn orthonormalise_rows(x: &mut [f64], block: usize) -> bool {
    let mut r = row_gram(x, x, block);
    // Cholesky, upper: r = R^T R, R stored in r's upper triangle.
    for k in 0..block {
        let pivot = r[k * block + k] - (0..k).map(|a| r[a * block + k].powi(2)).sum::<f64>();
        if !(pivot > 0.0 && pivot.is_finite()) {
            return false;
        }
        let pivot = pivot.sqrt();
        r[k * block + k] = pivot;
        for j in k + 1..block {
            let dot: f64 = (0..k).map(|a| r[a * block + k] * r[a * block + j]).sum();
            r[k * block + j] = (r[k * block + j] - dot) / pivot;
        }
    }
    // Each row y of the result solves y R = x (forward substitution).
    x.par_chunks_mut(block).for_each(|row| {
        for k in 0..block {
            let dot: f64 = (0..k).map(|a| row[a] * r[a * block + k]).sum();
            row[k] = (row[k] - dot) / r[k * block + k];
        }
    });
    true
}

/// Eigenvalues (ascending) and eigenvectors (columns of the row-major
/// `size x size` result) of the symmetric matrix `a`, by cyclic Jacobi.
fn symmetric_eigen(a: &mut [f64], size: usize) -> (Vec<f64>, Vec<f64>) {
    let mut v = vec![0.0; size * size];
    for i in 0..size {
        v[i * size + i] = 1.0;
    }
    for _ in 0..100 {
        let off: f64 = (0..size)
            .flat_map(|i| (0..size).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i * size + j].powi(2))
            .sum();
        let diagonal: f64 = (0..size).map(|i| a[i * size + i].powi(2)).sum();
        if off <= 1e-30 * diagonal {
            break;
        }
        for p in 0..size {
            for q in p + 1..size {
                let apq = a[p * size + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q * size + q] - a[p * size + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..size {
                    let akp = a[k * size + p];
                    let akq = a[k * size + q];
                    a[k * size + p] = c * akp - s * akq;
                    a[k * size + q] = s * akp + c * akq;
                }
                for k in 0..size {
                    let apk = a[p * size + k];
                    let aqk = a[q * size + k];
                    a[p * size + k] = c * apk - s * aqk;
                    a[q * size + k] = s * apk + c * aqk;
                }
                for k in 0..size {
                    let vkp = v[k * size + p];
                    let vkq = v[k * size + q];
                    v[k * size + p] = c * vkp - s * vkq;
                    v[k * size + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..size).collect();
    order.sort_by(|&i, &j| a[i * size + i].total_cmp(&a[j * size + j]));
    let values = order.iter().map(|&i| a[i * size + i]).collect();
    let mut vectors = vec![0.0; size * size];
    for (new, &old) in order.iter().enumerate() {
        for k in 0..size {
            vectors[k * size + new] = v[k * size + old];
        }
    }
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectrum::laplacian_extremes;

    /// [`tissue_testkit::dirichlet_path`] as connections.
    fn dirichlet_path(n: usize) -> (Connections, Vec<bool>) {
        let (total, pairs, free) = tissue_testkit::dirichlet_path(n);
        (Connections::from_pairs(total, pairs), free)
    }

    #[test]
    fn low_modes_of_a_dirichlet_path_are_its_exact_eigenpairs() {
        let n = 60;
        let (connections, free) = dirichlet_path(n);
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let modes = low_modes(&connections, &free, 6, lo, hi);
        let exact =
            |k: usize| 2.0 - 2.0 * (k as f64 * std::f64::consts::PI / (n as f64 + 1.0)).cos();
        assert_eq!(modes.count(), 6);
        for (k, &value) in modes.values().iter().enumerate() {
            let want = exact(k + 1);
            assert!(
                (value - want).abs() <= 1e-6 * want,
                "mode {k}: {value} vs {want}"
            );
        }
        let next = f64::from(modes.next());
        assert!(
            next <= exact(7) && next >= 0.9 * exact(7),
            "next {next} vs {}",
            exact(7)
        );
        assert!(modes.residual() < 1e-4, "{}", modes.residual());
        // Orthonormal over the free particles, zero at the fixed ends.
        let m = modes.count();
        let vectors = &modes.vectors;
        let column = |k: usize| (0..n + 2).map(move |i| vectors[i * m + k]);
        for a in 0..m {
            assert_eq!(column(a).next(), Some(0.0));
            assert_eq!(column(a).next_back(), Some(0.0));
            for b in 0..m {
                let dot: f32 = column(a).zip(column(b)).map(|(x, y)| x * y).sum();
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-5, "v{a} . v{b} = {dot}");
            }
        }
    }

    #[test]
    fn lanczos_finds_the_extreme_eigenvalues_of_a_dirichlet_path() {
        let n = 30;
        let (connections, free) = dirichlet_path(n);
        let (lo, hi) = laplacian_extremes(&connections, &free);
        let exact = |k: f64| 2.0 - 2.0 * (k * std::f64::consts::PI / (n as f64 + 1.0)).cos();
        assert!(
            (f64::from(lo) - exact(1.0)).abs() < 1e-4,
            "{lo} vs {}",
            exact(1.0)
        );
        assert!(
            (f64::from(hi) / 1.02 - exact(n as f64)).abs() < 1e-3,
            "{hi} vs {}",
            exact(n as f64)
        );
    }
}
