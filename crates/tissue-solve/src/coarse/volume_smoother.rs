//! The elastic phase's smoother with the volume term taken implicitly
//! (docs/METHOD.md, "Elastic model", "The volume smoother").
//!
//! The elastic operator for a small displacement is
//! `K = L + 1/2 G W G^T` ([`crate::model::elastic::VolumeLinearisation`]): the
//! connection Laplacian and, per particle, the volume term's Gauss-Newton
//! part, `G`'s column `i` being `g_i`, the gradient of `J_i`. At a Poisson
//! ratio of 0.49 the volume part is 7-12 times stiffer than the Laplacian
//! at its stiffest, and a plain step `alpha f` must be stable for it: every
//! mode that changes no volume then moves at a tenth of the speed it could,
//! and those are the modes the coarse space does not carry (the two-level
//! contraction 0.97 against the Laplacian's 0.75).
//!
//! This smoother is instead `M^-1 r` with `M = delta I + 1/2 G W G^T`:
//! the shear part stepped as the shear phase steps it (`delta` a little
//! above the Laplacian's largest eigenvalue) and the volume part taken
//! implicitly. With `H = G sqrt(W / 2)` (column `i` is `h_i = sqrt(W_i / 2)
//! g_i`), `M = delta I + H H^T`, and by the Woodbury identity
//! `M^-1 r = (r - H z) / delta` with `(delta I + H^T H) z = H^T r`: one
//! unknown (a pressure) per particle. That system is not diagonally
//! dominant, so `z` is a few Jacobi sweeps relaxed by [`RELAXATION`]
//! from zero (as many as the model's volume term needs: [`Smoothing`]), which keep `M^-1` symmetric (a fixed polynomial in `D^-1 S`).
//! Each sweep costs a product with `H` and one with `H^T`, passes over the
//! connections as the operator's are. The GPU's twin,
//! `shaders/volume_smoother.wgsl`, runs the same passes in `f32`.
//!
//! On the breast phantoms at 10,000 particles, at the state where the
//! elastic phase starts, it takes the two-level iteration's contraction
//! from 0.97 (the plain step) to 0.88: the linear problem to a thousandth
//! of the error in 15-16 iterations instead of 33.

use glam::DVec3;

use crate::stage2::springs::Spring;
use rayon::prelude::*;
use tissue_core::Connections;

use crate::model::entries::{Entries, slots};

/// `delta` in units of the connection Laplacian's largest eigenvalue (the
/// plan's, margin included). 2.0 keeps the iteration's most negative
/// eigenvalue near -0.2; smaller values bring it towards -1 (1.5 diverges
/// on breast_c at 100,000 particles), and 2.0 costs 1-3 iterations at
/// 10,000 (docs/METHOD.md, "The volume smoother").
pub const SHEAR_STEP: f64 = 2.0;

/// The Jacobi sweeps' relaxation on the pressures. With `SHEAR_STEP` 1.5
/// and two sweeps, 0.6 diverges (an eigenvalue at -1.59), 0.4 and 0.5 give
/// the same contraction; 0.5 keeps the margin.
pub const RELAXATION: f64 = 0.5;

/// Jacobi sweeps on the pressures a model is first tried with. One
/// diverges at any relaxation that helps (`S` is not diagonally dominant);
/// three give the same contraction as two at a Poisson ratio of 0.49
/// (0.882 against 0.878) at the cost of two more passes.
pub const SMOOTHER_SWEEPS: usize = 2;

/// The most Jacobi sweeps a model's smoother is given. A stiffer volume
/// term needs more: its weight `W_i` grows as `nu / (1 - 2 nu)`, and
/// sweeps that reach too few of the pressures under-correct it until the
/// iteration diverges (the bundled phantom at 10,000 particles takes its
/// smoother with 2 sweeps at 0.495, 8 at 0.498 and 16 at 0.499:
/// contractions 0.913, 0.941 and 0.956). A model's sweeps are doubled
/// from [`SMOOTHER_SWEEPS`] until its contraction at rest is below
/// [`crate::coarse::elastic::SMOOTHER_MAX_RATE`]; past this many the plain step
/// smooths (docs/METHOD.md, "The volume smoother").
pub const MAX_SMOOTHER_SWEEPS: usize = 32;

/// How a model's volume smoother is made: `delta` and its Jacobi sweeps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Smoothing {
    /// `delta`, the shear part's step's inverse ([`SHEAR_STEP`] times the
    /// Laplacian's largest eigenvalue).
    pub delta: f64,
    /// Jacobi sweeps on the pressures, at least 1.
    pub sweeps: usize,
}

/// The smoother at one linearisation.
///
/// With springs towards the observation (`P_k / 2` of `K` at particle
/// `k`, `P = a I + b u u^T`: [`crate::stage2::springs`]), the shear part's
/// `delta I` becomes `M_0`, `delta I + P_k / 2` on particle `k`: the
/// smoother takes each spring exactly, so `M - K` is `delta I - L` with
/// springs as without. Woodbury's
/// `M^-1 r = M_0^-1 (r - H y)` with `(I + H^T M_0^-1 H) y = H^T M_0^-1 r`;
/// in the pressures `z = delta y` and with `Phi = delta M_0^-1`, per
/// particle `(delta / alpha) (I - beta u u^T / (alpha + beta |u|^2))` with
/// `alpha = delta + a / 2` and `beta = b / 2` (the identity without a
/// spring), the system is `(delta I + H^T Phi H) z = H^T Phi r`, `Phi`
/// applied to each field before `H^T` reads it, and the step
/// `Phi (r - H z) / delta`.
#[derive(Debug, Clone)]
pub struct VolumeSmoother {
    /// `delta`, the shear part's step's inverse.
    delta: f64,
    /// Jacobi sweeps on the pressures.
    sweeps: usize,
    /// Per particle `sqrt(W_i / 2)` (0 where the neighbourhood is flat).
    roots: Vec<f64>,
    /// Per particle `D_i = delta + sum_j h_ij^T Phi_j h_ij` over the
    /// entries at free particles, the pressure system's diagonal.
    diagonal: Vec<f64>,
    /// Per particle `Phi`'s axis `u`, scale `delta / alpha` and
    /// `beta / (alpha + beta |u|^2)` (empty without springs: `Phi = I`).
    springs: Vec<(DVec3, f64, f64)>,
}

impl VolumeSmoother {
    /// The smoother for the volume gradients `entries` with weights
    /// `weights` over the particles `inside` says are free, made as
    /// `smoothing` says.
    /// `springs` (one per particle, or none) raise each one's `delta_k`.
    pub(crate) fn new(
        entries: &Entries,
        weights: &[f64],
        connections: &Connections,
        inside: &(impl Fn(usize) -> bool + Sync),
        smoothing: Smoothing,
        springs: &[Spring],
    ) -> Self {
        let Smoothing { delta, sweeps } = smoothing;
        let roots: Vec<f64> = weights.iter().map(|&w| (0.5 * w).sqrt()).collect();
        let springs = phi_springs(springs, delta);
        // `g^T Phi_j g`.
        let seen = |j: usize, g: DVec3| match springs.get(j) {
            Some(&(u, scale, along)) => scale * (g.length_squared() - along * u.dot(g).powi(2)),
            None => g.length_squared(),
        };
        let diagonal = (0..weights.len())
            .into_par_iter()
            .map(|i| {
                let range = slots(connections, i);
                let mut own = DVec3::ZERO;
                let mut sum = 0.0;
                for (&j, g) in connections.indices[range.clone()]
                    .iter()
                    .zip(&entries.own[range])
                {
                    let g = g.as_dvec3();
                    own -= g;
                    if inside(j as usize) {
                        sum += seen(j as usize, g);
                    }
                }
                if inside(i) {
                    sum += seen(i, own);
                }
                delta + 0.5 * weights[i] * sum
            })
            .collect();
        Self {
            delta,
            sweeps: sweeps.max(1),
            roots,
            diagonal,
            springs,
        }
    }

    /// Takes `springs` (one per particle, or none) for `Phi`; the
    /// pressures' diagonal stays as made (`ElasticCoarse::set_pulls`).
    pub(crate) fn set_springs(&mut self, springs: &[Spring]) {
        self.springs = phi_springs(springs, self.delta);
    }

    /// `Phi` at particle `k` applied to `x`: `(delta / alpha) (x - u (u . x)
    /// beta / (alpha + beta |u|^2))` with its spring, `x` without.
    fn phi(&self, k: usize, x: DVec3) -> DVec3 {
        match self.springs.get(k) {
            Some(&(u, scale, along)) => scale * (x - u * (u.dot(x) * along)),
            None => x,
        }
    }

    /// `Phi x` (`x` itself without springs).
    fn scaled<'a>(&self, x: &'a [DVec3]) -> std::borrow::Cow<'a, [DVec3]> {
        if self.springs.is_empty() {
            return std::borrow::Cow::Borrowed(x);
        }
        std::borrow::Cow::Owned(
            x.par_iter()
                .enumerate()
                .map(|(k, &x)| self.phi(k, x))
                .collect(),
        )
    }

    /// `delta`.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// The Jacobi sweeps on the pressures.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// Per particle the pressure system's diagonal `delta + |h_i|^2`.
    pub fn diagonal(&self) -> &[f64] {
        &self.diagonal
    }

    /// `M^-1 r` for a residual `r` (zero outside): the smoothed step.
    ///
    /// Two passes over the connections a sweep, each of which also makes what the next reads, per particle: `H^T r` with the first
    /// sweep's pressures, their force `H z`, `H^T H z` with the next sweep's
    /// pressures, and their force with the step.
    pub(crate) fn smooth(
        &self,
        entries: &Entries,
        connections: &Connections,
        inside: &(impl Fn(usize) -> bool + Sync),
        residual: &[DVec3],
    ) -> Vec<DVec3> {
        let (roots, diagonal) = (&self.roots, &self.diagonal);
        debug_assert!(
            (0..residual.len()).all(|i| inside(i) || residual[i] == DVec3::ZERO),
            "the smoother's residual is zero outside"
        );
        let scaled_residual = self.scaled(residual);
        // Per particle `(t_i, z_i)`, `t = H^T r` and the pressure `z_i`,
        // and apart (the next pass reads it at the neighbours) `y_i =
        // sqrt(W_i / 2) z_i`, so that `H z = G y`. The first sweep from
        // zero.
        let (mut sweep, mut scaled): (Vec<(f64, f64)>, Vec<f64>) = (0..residual.len())
            .into_par_iter()
            .map(|i| {
                let t = change_at(entries, connections, &scaled_residual, i) * roots[i];
                let z = RELAXATION * t / diagonal[i];
                ((t, z), z * roots[i])
            })
            .unzip();
        for _ in 1..self.sweeps {
            // Zero outside, as `change_at` reads it.
            let forces = pressure_forces(entries, connections, inside, &scaled);
            let forces = self.scaled(&forces);
            (sweep, scaled) = (0..residual.len())
                .into_par_iter()
                .map(|i| {
                    let (t, z) = sweep[i];
                    let back = change_at(entries, connections, &forces, i) * roots[i];
                    let s_z = self.delta * z + back;
                    let z = z + RELAXATION * (t - s_z) / diagonal[i];
                    ((t, z), z * roots[i])
                })
                .unzip();
        }
        (0..residual.len())
            .into_par_iter()
            .map(|i| {
                if inside(i) {
                    let f = pressure_force_at(entries, connections, &scaled, i);
                    self.phi(i, residual[i] - f) / self.delta
                } else {
                    DVec3::ZERO
                }
            })
            .collect()
    }
}

/// Per spring `Phi`'s axis `u`, scale `delta / alpha` and
/// `beta / (alpha + beta |u|^2)` (`alpha = delta + a / 2`, `beta = b / 2`),
/// what `Phi` reads.
fn phi_springs(springs: &[Spring], delta: f64) -> Vec<(DVec3, f64, f64)> {
    springs
        .iter()
        .map(|s| {
            let (a, b, u) = s.stiffness();
            let alpha = delta + 0.5 * a;
            let beta = 0.5 * b;
            (u, delta / alpha, beta / (alpha + beta * u.length_squared()))
        })
        .collect()
}

/// `G^T x`: per particle the change of its `J_i` under the displacement
/// `x` (read as zero at particles `inside` says are not free), `g_i . x`.
#[cfg(test)]
pub(crate) fn volume_changes(
    entries: &Entries,
    connections: &Connections,
    inside: &(impl Fn(usize) -> bool + Sync),
    x: &[DVec3],
) -> Vec<f64> {
    let x: Vec<DVec3> = (0..x.len())
        .map(|i| if inside(i) { x[i] } else { DVec3::ZERO })
        .collect();
    (0..x.len())
        .into_par_iter()
        .map(|i| change_at(entries, connections, &x, i))
        .collect()
}

/// `g_i . x` at particle `i` for a field `x` that is zero at the particles
/// that are not free: one particle's row of `G^T x`. The field comes
/// masked (once a pass, not at each of the connections' reads).
fn change_at(entries: &Entries, connections: &Connections, x: &[DVec3], i: usize) -> f64 {
    let (xi, range) = (x[i], slots(connections, i));
    connections.indices[range.clone()]
        .iter()
        .zip(&entries.own[range])
        .map(|(&j, g)| (x[j as usize] - xi).dot(g.as_dvec3()))
        .sum()
}

/// `G y`: per particle the force of the pressures `y`,
/// `sum_i y_i (g_i)_k` (zero at particles `inside` says are not free).
/// `g_i`'s entry at its neighbour `k` is the mirrored slot of `k`'s row,
/// `g_k`'s own entry at `k` minus the sum of its entries.
pub(crate) fn pressure_forces(
    entries: &Entries,
    connections: &Connections,
    inside: &(impl Fn(usize) -> bool + Sync),
    y: &[f64],
) -> Vec<DVec3> {
    (0..y.len())
        .into_par_iter()
        .map(|k| {
            if inside(k) {
                pressure_force_at(entries, connections, y, k)
            } else {
                DVec3::ZERO
            }
        })
        .collect()
}

/// [`pressure_forces`] at a free particle `k`: the mirrored slots alone
/// ([`Entries::sums`] gives `g_k`'s own entry).
fn pressure_force_at(entries: &Entries, connections: &Connections, y: &[f64], k: usize) -> DVec3 {
    let range = slots(connections, k);
    let mut f = DVec3::ZERO;
    for (&i, h) in connections.indices[range.clone()]
        .iter()
        .zip(&entries.mirrored[range])
    {
        f += y[i as usize] * h.as_dvec3();
    }
    f - y[k] * entries.sums[k]
}
