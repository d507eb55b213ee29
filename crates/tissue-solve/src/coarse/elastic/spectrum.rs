//! The two-level iteration's spectrum: its ends by Lanczos steps in the
//! `K` inner product, and the contraction they give.

use glam::DVec3;
use tissue_core::Connections;

use super::ElasticCoarse;
use crate::coarse::laplacian::{Aggregates, OUTSIDE, power_start};

impl ElasticCoarse {
    /// The spectral radius of the two-level iteration by `steps` Lanczos
    /// steps ([`ElasticCoarse::spectrum_ends`]).
    #[cfg(test)]
    pub(super) fn spectral_radius(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        steps: usize,
    ) -> f32 {
        let (lo, hi) = self.spectrum_ends(aggregates, connections, steps);
        radius_of(lo, hi)
    }

    /// The most negative and the largest eigenvalue of the two-level
    /// iteration (0.0 both where it has no spectrum to measure) by `steps`
    /// Lanczos steps in the `K` inner product, in which `E` is self-adjoint on the
    /// range of `I - Pi` (`Pi` is the `K`-orthogonal projection onto the
    /// coarse space): the start is a fixed, irregular field with every mode
    /// in it, after one step of `E`, which puts it in that range. The
    /// extreme Ritz values approach the spectrum's ends from within, as
    /// power iteration's estimate does, but in far fewer steps. Dot
    /// products are taken in order (the same estimate for any thread count).
    pub(super) fn spectrum_ends(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        steps: usize,
    ) -> (f64, f64) {
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let apply = |v: &[DVec3]| self.operator(aggregates, connections, v);
        let dot = |a: &[DVec3], b: &[DVec3]| a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum::<f64>();
        let start: Vec<DVec3> = power_start(inside, aggregates.aggregate.len())
            .iter()
            .map(|v| v.as_dvec3())
            .collect();
        let mut v = self.two_level(aggregates, connections, &start, &apply(&start));
        let mut kv = apply(&v);
        let scale = dot(&v, &kv).sqrt();
        if scale.is_nan() || scale <= 0.0 {
            return (0.0, 0.0);
        }
        v.iter_mut().for_each(|x| *x /= scale);
        kv.iter_mut().for_each(|x| *x /= scale);
        let mut previous = vec![DVec3::ZERO; v.len()];
        let (mut alphas, mut betas) = (Vec::new(), Vec::new());
        let mut beta = 0.0f64;
        for _ in 0..steps.max(2) {
            let mut w = self.two_level(aggregates, connections, &v, &kv);
            let alpha = dot(&w, &kv);
            for ((w, v), p) in w.iter_mut().zip(&v).zip(&previous) {
                *w -= alpha * *v + beta * *p;
            }
            alphas.push(alpha);
            let kw = apply(&w);
            beta = dot(&w, &kw).max(0.0).sqrt();
            if beta < 1e-12 {
                break;
            }
            betas.push(beta);
            previous = std::mem::replace(&mut v, w.iter().map(|x| *x / beta).collect());
            kv = kw.iter().map(|x| *x / beta).collect();
        }
        betas.truncate(alphas.len().saturating_sub(1));
        let lo = crate::stage2::spectrum::tridiagonal_eigenvalue(&alphas, &betas, 0);
        let hi = crate::stage2::spectrum::tridiagonal_eigenvalue(&alphas, &betas, alphas.len() - 1);
        (lo, hi)
    }
}

/// The spectral radius of an iteration whose spectrum spans `lo..hi`,
/// kept below one.
pub(super) fn radius_of(lo: f64, hi: f64) -> f32 {
    (lo.abs().max(hi.abs()) as f32).clamp(0.0, 0.9999)
}
