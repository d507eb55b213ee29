//! Twin of `shaders/integrate.wgsl`: the plain step (`integrate`) and the
//! Chebyshev combine (`chebyshev_combine`).

use glam::Vec3;
use rayon::prelude::*;

/// The shader this module is the twin of.
pub const SHADER: &str = "integrate";

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

/// The Chebyshev step: `omega (q_hat - q_old) + q_old`.
pub fn chebyshev_combine(plain: &[Vec3], previous: &[Vec3], omega: f32) -> Vec<Vec3> {
    plain
        .par_iter()
        .zip(previous)
        .map(|(&q_hat, &q_old)| omega * (q_hat - q_old) + q_old)
        .collect()
}
