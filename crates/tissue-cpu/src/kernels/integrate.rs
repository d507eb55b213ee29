//! Twin of `shaders/integrate.wgsl`: the plain step (`integrate`) and the
//! Chebyshev combine (`chebyshev_combine`).

use glam::Vec3;
use rayon::prelude::*;
use tissue_solve::stage2::Spring;
use tissue_solve::stage2::spring_force;

/// The shader this module is the twin of.
pub const SHADER: &str = "integrate";

/// `q += alpha (F + b + p)` for free particles (the stiffness `sigma` and
/// mass `m` fold into `alpha = sigma / m`), `b` the particle's body force
/// from `loads` (none where `loads` is empty) and `p` its spring's pull
/// towards the observation from `springs`
/// ([`tissue_solve::stage2::spring_force`]; none where `springs` is
/// empty: the elastic force's iterations pass the plan's, the others
/// none); control points stay where the surface put them.
pub fn integrate(
    current: &[Vec3],
    force: &[Vec3],
    loads: &[Vec3],
    springs: &[Spring],
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
            q + alpha * (f + applied(i, q, loads, springs))
        })
        .collect()
}

/// What acts on particle `i` at `q` besides the force between particles:
/// its body force and its spring's pull, where there are any.
pub fn applied(i: usize, q: Vec3, loads: &[Vec3], springs: &[Spring]) -> Vec3 {
    let b = loads.get(i).copied().unwrap_or(Vec3::ZERO);
    match springs.get(i) {
        Some(&spring) => b + spring_force(spring, q),
        None => b,
    }
}

/// The Chebyshev step: `omega (q_hat - q_old) + q_old`.
pub fn chebyshev_combine(plain: &[Vec3], previous: &[Vec3], omega: f32) -> Vec<Vec3> {
    plain
        .par_iter()
        .zip(previous)
        .map(|(&q_hat, &q_old)| omega * (q_hat - q_old) + q_old)
        .collect()
}
