//! The extreme eigenvalues of the connection Laplacian over free particles.

use rayon::prelude::*;
use tissue_core::Connections;

/// Lanczos steps for the Laplacian's extreme eigenvalues.
const LANCZOS_STEPS: usize = 40;

/// The smallest and largest eigenvalues of the graph Laplacian restricted to
/// free particles (control points fixed: Dirichlet rows), by 40 Lanczos steps
/// in `f64`. The Ritz values bracket the spectrum from inside: `lambda_min`
/// comes out slightly high (so the Chebyshev `rho` slightly low, which still
/// converges) and `lambda_max` slightly low (so it gets a 2% margin).
pub fn laplacian_extremes(connections: &Connections, free: &[bool]) -> (f32, f32) {
    laplacian_extremes_with(connections, free, LANCZOS_STEPS)
}

/// [`laplacian_extremes`] with `steps` Lanczos steps.
pub fn laplacian_extremes_with(
    connections: &Connections,
    free: &[bool],
    steps: usize,
) -> (f32, f32) {
    let n = free.len();
    let apply = |v: &[f64]| -> Vec<f64> {
        (0..n)
            .into_par_iter()
            .map(|i| {
                if !free[i] {
                    return 0.0;
                }
                let row = connections.of(i);
                let mut s = row.len() as f64 * v[i];
                for &j in row {
                    if free[j as usize] {
                        s -= v[j as usize];
                    }
                }
                s
            })
            .collect()
    };
    lanczos_extremes(free, apply, steps)
}

/// The smallest and largest eigenvalues of the symmetric operator `apply`
/// on vectors whose entries are zero where `mask` is false (the operator
/// keeps them zero), by `steps` Lanczos steps in `f64` from a fixed start
/// with every mode in it. The Ritz values bracket the spectrum from inside,
/// so the largest gets a 2 % margin.
pub fn lanczos_extremes(
    mask: &[bool],
    apply: impl Fn(&[f64]) -> Vec<f64>,
    steps: usize,
) -> (f32, f32) {
    let n = mask.len();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    // A deterministic start with every mode in it.
    let mut v: Vec<f64> = (0..n)
        .map(|i| {
            if mask[i] {
                1.0 + 0.5 * ((i as f64) * 0.618_033_988_7).fract()
            } else {
                0.0
            }
        })
        .collect();
    let norm = dot(&v, &v).sqrt();
    if norm == 0.0 {
        return (1.0, 1.0);
    }
    v.iter_mut().for_each(|x| *x /= norm);
    let mut previous = vec![0.0; n];
    let (mut alphas, mut betas) = (Vec::new(), Vec::new());
    let mut beta = 0.0f64;
    for _ in 0..steps.max(2) {
        let mut w = apply(&v);
        for i in 0..n {
            w[i] -= beta * previous[i];
        }
        let alpha = dot(&w, &v);
        for i in 0..n {
            w[i] -= alpha * v[i];
        }
        alphas.push(alpha);
        beta = dot(&w, &w).sqrt();
        if beta < 1e-10 {
            break;
        }
        betas.push(beta);
        previous = std::mem::replace(&mut v, w.iter().map(|x| x / beta).collect());
    }
    betas.truncate(alphas.len().saturating_sub(1));
    let lo = tridiagonal_eigenvalue(&alphas, &betas, 0);
    let hi = tridiagonal_eigenvalue(&alphas, &betas, alphas.len() - 1);
    (lo as f32, (hi * 1.02) as f32)
}

/// The `k`-th smallest eigenvalue of the symmetric tridiagonal matrix with
/// diagonal `a` and off-diagonal `b`, by bisection on Sturm counts.
pub(crate) fn tridiagonal_eigenvalue(a: &[f64], b: &[f64], k: usize) -> f64 {
    // Gershgorin bounds.
    let mut lo = f64::MAX;
    let mut hi = f64::MIN;
    for i in 0..a.len() {
        let r = b.get(i).map_or(0.0, |x| x.abs()) + if i > 0 { b[i - 1].abs() } else { 0.0 };
        lo = lo.min(a[i] - r);
        hi = hi.max(a[i] + r);
    }
    // Number of eigenvalues below x.
    let below = |x: f64| {
        let mut count = 0;
        let mut d = 1.0f64;
        for i in 0..a.len() {
            let off = if i > 0 { b[i - 1] * b[i - 1] } else { 0.0 };
            d = a[i] - x - if i > 0 { off / d } else { 0.0 };
            if d == 0.0 {
                d = -1e-300;
            }
            if d < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if below(mid) > k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}
