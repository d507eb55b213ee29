//! Twin of `shaders/deflate.wgsl`: the plain step's error along the
//! lowest Laplacian modes removed.

use glam::{DVec3, Vec3, Vec3A};
use rayon::prelude::*;
use tissue_solve::modes::{LowModes, add_entries};

/// The shader this module is the twin of.
pub const SHADER: &str = "deflate";

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
    use tissue_core::Connections;
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
