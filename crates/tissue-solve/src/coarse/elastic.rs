//! The two-level solve of the elastic phase: the coarse correction of
//! [`crate::coarse::laplacian`] for the elastic operator linearised where the phase
//! starts, three unknowns (a translation) per aggregate.
//!
//! The elastic force's operator for a small displacement `u` (rotations
//! held, the force `-2 K u`) is the connection Laplacian plus the volume
//! term's Gauss-Newton part: `K = L + 1/2 sum_i W_i g_i g_i^T`, with `g_i`
//! the gradient of `J_i = det F_i`, whose entries are `cof(F_i) c_ij`
//! at neighbour `j` and minus their sum at `i`
//! ([`crate::model::elastic::VolumeLinearisation`]). Unlike the Laplacian, `K` depends on the
//! state through `cof(F_i)`, which turns with the particle's rotation; a
//! coarse matrix built at rest (`cof F = I`) diverged on the breast phantoms
//! (docs/METHOD.md, "Elastic model"). So `P^T K P` is assembled at the
//! state the elastic phase starts from (after the shear phase, every
//! neighbourhood near its rest volume and turned by its rotation), factored
//! once, and used for the whole phase, and for warm-started tracking
//! frames after it.
//!
//! *Springs.* A phase whose free skin carries springs towards the
//! observation (`P / 2` in `K`, taken exactly by the volume smoother)
//! iterates with the contraction estimated at rest without them
//! ([`setup::rest_rate`]). The springs only add to `K` and to the
//! smoother's `M` together, leaving `M - K` as it was, so they shrink the
//! smoother's error rather than grow it: on the shared breast cases'
//! remeshed surfaces and scans, 40 Lanczos steps with each stage's springs
//! estimated 0.909-0.918 where the rest estimate is 0.930-0.938. Estimated
//! anew, with 40 steps, it cost as much as 40 iterations at every stage.

use std::time::Instant;

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use tissue_core::{Connections, DeformError, Error};

use crate::coarse::cholesky::Cholesky;
use crate::coarse::laplacian::{Aggregates, Envelope, OUTSIDE, centres};
use crate::coarse::multilevel::{BlockMultilevel, scalar_rows};
use crate::coarse::volume_smoother::{Smoothing, VolumeSmoother};
use crate::model::elastic::{Elastic, VolumeLinearisation, cofactor};
use crate::stage2::device::Iteration;
use crate::stage2::params::ForceModel;
use crate::stage2::springs::{Spring, spring_block, spring_operator};

mod setup;
mod spectrum;

use spectrum::radius_of;

pub(crate) use crate::model::entries::Entries;
use crate::model::entries::{Parts, own_entries};
pub use setup::{
    FREE_SKIN_SWEEPS, SMOOTHER_MAX_CELL, SMOOTHER_MAX_RATE, SMOOTHER_MIN_LOWEST,
    elastic_aggregates, rest_rate, volume_smoother,
};

/// Lanczos steps for the two-level iteration's contraction. On both breast
/// phantoms at 10,000 particles, 10 steps estimate what 40 steps of power
/// iteration did (0.958 and 0.958 against 0.958 and 0.957) at a quarter of
/// the cost; 20 steps estimate 0.970, 40 steps 0.973. The closer estimate
/// shortens Chebyshev's sag and indentation from rest (4-8 iterations) but
/// raises the stopping rule's bound `1 / (1 - rho)`, so tracking frames
/// ran longer (2-11 iterations a frame on the bench against 2-7) for an
/// error the tests already find within the tolerance: 10 it is
/// (docs/METHOD.md, "Elastic model").
pub const RATE_STEPS: usize = 10;

/// Lanczos steps for the contraction of the two-level iteration with the
/// volume smoother, estimated once per model at rest ([`rest_rate`]): 12
/// steps estimate 0.856 / 0.851 on the breast phantoms, 20 steps 0.871 /
/// 0.870, 40 steps 0.878 / 0.878, and the estimate at rest is within 0.004
/// of the one at the state the elastic phase starts from on both
/// (docs/METHOD.md, "The volume smoother").
pub const REST_RATE_STEPS: usize = 40;

/// What an elastic correction is made for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectionFor {
    /// The plain step's `c alpha`.
    pub contraction: f32,
    /// How the volume smoother is made ([`crate::coarse::volume_smoother`]);
    /// `None`: the plain step smooths.
    pub smoothing: Option<Smoothing>,
    /// The two-level iteration's contraction where it is known (with the
    /// volume smoother, estimated once per model at rest: [`rest_rate`]);
    /// `None`: estimated where the correction is made, in [`RATE_STEPS`]
    /// Lanczos steps.
    pub rho: Option<f32>,
    /// Up to how many aggregates `P^T K P` is factored; above, it is
    /// solved by the cycles of [`BlockMultilevel`], their groups' matrix
    /// factored at most this large.
    pub direct_max_aggregates: usize,
    /// Where `P^T K P` is factored: in the envelope form a device's
    /// substitution reads (`true`: the GPU uploads it) rather than the
    /// host's sparse factor ([`Cholesky`]), the same solution.
    pub envelope: bool,
}

/// How `P^T K P` is solved.
#[derive(Debug, Clone)]
enum CoarseSolve {
    /// Its sparse Cholesky factor, three rows per aggregate.
    Direct(Cholesky),
    /// Its Cholesky factor within its envelope, for a device.
    Envelope(Envelope),
    /// Two-grid cycles over groups of aggregates.
    Multilevel(BlockMultilevel),
}

/// The elastic operator's coarse correction, linearised at one state.
#[derive(Debug, Clone)]
pub struct ElasticCoarse {
    /// The operator `K` at the state.
    linearisation: VolumeLinearisation,
    /// `K`'s volume part per connection, for the CPU's products.
    entries: Entries,
    /// Per particle its spring towards the observation, whose
    /// `P / 2` is part of `K` (empty without springs).
    springs: Vec<Spring>,
    /// The solve of `P^T K P`.
    solve: CoarseSolve,
    /// The volume smoother, where the iteration smooths with it.
    smoother: Option<VolumeSmoother>,
    /// The plain step's `c alpha` this correction was made for.
    contraction: f32,
    rho: f32,
    /// The two-level iteration's most negative eigenvalue, where its
    /// contraction was estimated here (NaN where it was given).
    lowest: f32,
    seconds: f64,
}

/// How a correction is made, beyond what it is made for: the Lanczos
/// steps that estimate its contraction where [`CorrectionFor::rho`] does
/// not give it, an earlier correction over the same aggregates whose
/// factor lends its order and symbolic analysis ([`Cholesky::refactor`]),
/// and whether its coarse solves then run in `f32` (a device's iterations)
/// or stay in `f64` (what the tests hold exactly).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Making<'a> {
    pub(crate) rate_steps: usize,
    pub(crate) previous: Option<&'a ElasticCoarse>,
    pub(crate) single: bool,
    /// Per particle its spring towards the observation
    /// ([`crate::stage2::plan::Plan::springs`]; empty without).
    pub(crate) springs: &'a [Spring],
}

impl Default for Making<'_> {
    fn default() -> Self {
        Self {
            rate_steps: RATE_STEPS,
            previous: None,
            single: false,
            springs: &[],
        }
    }
}

impl ElasticCoarse {
    /// `P^T K P` over `aggregates` with `K` linearised at `current`,
    /// factored, the volume smoother where `made_for` asks for it, and the
    /// two-level iteration's contraction (given, or estimated by Lanczos).
    pub fn new(
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
        made_for: CorrectionFor,
    ) -> Result<Self, Error> {
        Self::made(
            aggregates,
            rest,
            current,
            connections,
            elastic,
            made_for,
            Making::default(),
        )
    }

    /// [`ElasticCoarse::new`] made as `making` says.
    pub(crate) fn made(
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
        made_for: CorrectionFor,
        making: Making<'_>,
    ) -> Result<Self, Error> {
        let started = Instant::now();
        let linearisation = linearise(rest, current, connections, elastic);
        // `g_i`'s entries, formed once: rounded into the slots and summed
        // over the aggregates.
        let (own, parts) = own_entries(
            rest,
            connections,
            &linearisation,
            Some(&aggregates.aggregate),
        );
        // The coarse matrix's factor (on one thread at 10,000 particles)
        // while the slots' entries and the smoother are made beside it.
        let (solve, (entries, smoother)) = rayon::join(
            || {
                // A factor on the host reads the blocks on and above the
                // diagonal alone; the cycles and a device's envelope both.
                let factored = aggregates.count() <= made_for.direct_max_aggregates;
                let upper = factored && !made_for.envelope;
                let blocks = assemble(
                    aggregates,
                    &parts,
                    &linearisation.weights,
                    making.springs,
                    upper,
                );
                coarse_solve(aggregates, rest, &blocks, made_for, making)
            },
            || {
                let entries = Entries::of_own(own, connections, &elastic.mirrors);
                let smoother = made_for.smoothing.map(|smoothing| {
                    let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
                    VolumeSmoother::new(
                        &entries,
                        &linearisation.weights,
                        connections,
                        &inside,
                        smoothing,
                        making.springs,
                    )
                });
                (entries, smoother)
            },
        );
        let solve = solve.ok_or_else(|| {
            Error::from(DeformError::CoarseSpace(
                "the elastic coarse matrix is not positive definite (a rounding failure)".into(),
            ))
        })?;
        let mut space = Self {
            linearisation,
            entries,
            springs: making.springs.to_vec(),
            solve,
            smoother,
            contraction: made_for.contraction,
            rho: 0.0,
            lowest: f32::NAN,
            seconds: 0.0,
        };
        match made_for.rho {
            Some(rho) => space.rho = rho,
            None => {
                let (lo, hi) = space.spectrum_ends(aggregates, connections, making.rate_steps);
                space.rho = radius_of(lo, hi);
                space.lowest = lo as f32;
            }
        }
        // Estimated with the factor in `f64`; a device's iterations solve
        // in `f32` (`Cholesky::single`).
        if making.single {
            space.solve = match space.solve {
                CoarseSolve::Direct(factor) => CoarseSolve::Direct(factor.single()),
                CoarseSolve::Multilevel(cycles) => CoarseSolve::Multilevel(cycles.single()),
                envelope @ CoarseSolve::Envelope(_) => envelope,
            };
        }
        space.seconds = started.elapsed().as_secs_f64();
        Ok(space)
    }

    /// [`ElasticCoarse::new`] as a device makes it at a phase's start: told
    /// to the log, and `None` (a warning: the phase then runs uncorrected)
    /// where it cannot be made. `previous`, the correction made over the
    /// same aggregates at an earlier phase's start, lends its factor's
    /// order and symbolic analysis ([`Cholesky::refactor`]). Its coarse
    /// solves run in `f32` ([`Cholesky::single`]), after its contraction,
    /// where not given, is estimated in `f64`. `springs` (one per particle,
    /// or none) are part of its operator; the contraction given for the
    /// model at rest (with the volume smoother) bounds its iteration with
    /// them (module docs, *Springs*), and the plain step's, not given, is
    /// then estimated in [`REST_RATE_STEPS`] Lanczos steps.
    #[allow(clippy::too_many_arguments, reason = "what a phase's start hands over")]
    pub fn at_phase_start(
        aggregates: &Aggregates,
        rest: &[Vec3],
        current: &[Vec3],
        connections: &Connections,
        elastic: &Elastic,
        made_for: CorrectionFor,
        springs: &[Spring],
        previous: Option<&Self>,
    ) -> Option<Self> {
        // The rest contraction given with the volume smoother bounds the
        // iteration with springs (module docs, *Springs*); the plain step's
        // is estimated, more closely with springs.
        let rate_steps = if springs.is_empty() {
            RATE_STEPS
        } else {
            REST_RATE_STEPS
        };
        let made = Self::made(
            aggregates,
            rest,
            current,
            connections,
            elastic,
            made_for,
            Making {
                rate_steps,
                previous,
                single: true,
                springs,
            },
        );
        match made {
            Ok(coarse) => {
                log::info!(
                    "elastic two-level solve: {} aggregates, {}, contraction {:.3}, prepared in {:.3} s",
                    aggregates.count(),
                    if coarse.smoother.is_some() {
                        "the volume smoother"
                    } else {
                        "the plain step"
                    },
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

    /// Takes `springs` (one per particle, or none) as the springs of the
    /// iterations that follow, where a pairing sets them anew each
    /// iteration: the per-particle parts (the operator's `P / 2` in
    /// its products, the smoother's `Phi`) take them, while the coarse
    /// matrix and the smoother's diagonal stay as made, a preconditioner
    /// for springs that change little. A device's kernels read the
    /// iteration's springs the same way.
    pub fn set_pulls(&mut self, springs: &[Spring]) {
        springs.clone_into(&mut self.springs);
        if let Some(smoother) = &mut self.smoother {
            smoother.set_springs(springs);
        }
    }

    /// The volume smoother, where the iteration smooths with it.
    pub fn smoother(&self) -> Option<&VolumeSmoother> {
        self.smoother.as_ref()
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

    /// The sparse Cholesky factor of `P^T K P`, unknown `3 a + axis` for
    /// aggregate `a`; `None` where it is solved by cycles or factored for
    /// a device instead.
    pub fn factor(&self) -> Option<&Cholesky> {
        match &self.solve {
            CoarseSolve::Direct(factor) => Some(factor),
            CoarseSolve::Envelope(_) | CoarseSolve::Multilevel(_) => None,
        }
    }

    /// The factor of `P^T K P` in envelope form, where it was made for a
    /// device ([`CorrectionFor::envelope`]).
    pub fn envelope(&self) -> Option<&Envelope> {
        match &self.solve {
            CoarseSolve::Envelope(factor) => Some(factor),
            CoarseSolve::Direct(_) | CoarseSolve::Multilevel(_) => None,
        }
    }

    /// The cycles that solve `P^T K P`, where it is not factored.
    pub fn multilevel(&self) -> Option<&BlockMultilevel> {
        match &self.solve {
            CoarseSolve::Direct(_) | CoarseSolve::Envelope(_) => None,
            CoarseSolve::Multilevel(cycles) => Some(cycles),
        }
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
        connections: &Connections,
        u: &[DVec3],
    ) -> Vec<DVec3> {
        self.operator_then(aggregates, connections, u, |_, k| k)
    }

    /// [`ElasticCoarse::operator`] with `finish(k, (K u)_k)` made of each
    /// row in the same pass ([`Entries::operator_then`]).
    fn operator_then(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        u: &[DVec3],
        finish: impl Fn(usize, DVec3) -> DVec3 + Sync,
    ) -> Vec<DVec3> {
        let aggregate = &aggregates.aggregate;
        let springs = &self.springs;
        self.entries.operator_then(
            &self.linearisation.weights,
            connections,
            |i| aggregate[i] != OUTSIDE,
            u,
            |k, ku| match springs.get(k) {
                Some(&spring) if aggregate[k] != OUTSIDE => {
                    finish(k, ku + spring_operator(spring, u[k]))
                }
                _ => finish(k, ku),
            },
        )
    }

    /// Turns the plain step `plain - current` (`-contraction K e` for the
    /// error `e`) into the two-level one: subtracts the `K`-orthogonal
    /// projection onto the coarse space of the error left after it, whose
    /// `K e' = -s / (c alpha) + K s` is known without `e`.
    pub fn correct(
        &self,
        aggregates: &Aggregates,
        current: &[Vec3],
        plain: &mut [Vec3],
        connections: &Connections,
    ) {
        let aggregate = &aggregates.aggregate;
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
        let coarse = self.coarse_part(aggregates, connections, &step);
        plain.par_iter_mut().zip(aggregate).for_each(|(p, &a)| {
            if a != OUTSIDE {
                let a = 3 * a as usize;
                *p -= DVec3::new(coarse[a], coarse[a + 1], coarse[a + 2]).as_vec3();
            }
        });
    }

    /// The two-level step with the volume smoother for the residual `r`
    /// (zero outside the aggregates; half the force, loads included, at
    /// the current positions: `K e = -r` for the error `e` while the
    /// rotations are held): the smoothed step `s = M^-1 r`, less the
    /// coarse space's part of the error left after it, whose `K e'` is
    /// `K s - r`. `None` where this correction has no volume smoother.
    pub fn smoothed_step(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        residual: &[DVec3],
    ) -> Option<Vec<DVec3>> {
        let smoother = self.smoother.as_ref()?;
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let mut step = smoother.smooth(&self.entries, connections, &inside, residual);
        let left = self.operator_then(aggregates, connections, &step, |k, ks| ks - residual[k]);
        let coarse = self.coarse_of(aggregates, left);
        step.par_iter_mut()
            .zip(&aggregates.aggregate)
            .for_each(|(s, &a)| {
                if a != OUTSIDE {
                    let a = 3 * a as usize;
                    *s -= DVec3::new(coarse[a], coarse[a + 1], coarse[a + 2]);
                }
            });
        Some(step)
    }

    /// The coarse solution `(P^T K P)^-1 P^T k` for a field `k`.
    fn coarse_of(&self, aggregates: &Aggregates, k: Vec<DVec3>) -> Vec<f64> {
        let mut sums = vec![DVec3::ZERO; aggregates.count()];
        for (&a, k) in aggregates.aggregate.iter().zip(&k) {
            if a != OUTSIDE {
                sums[a as usize] += *k;
            }
        }
        match &self.solve {
            CoarseSolve::Direct(factor) => {
                let mut coarse: Vec<f64> = sums.iter().flat_map(|v| v.to_array()).collect();
                factor.solve_scalar(&mut coarse);
                coarse
            }
            CoarseSolve::Envelope(factor) => {
                let mut coarse: Vec<f64> = sums.iter().flat_map(|v| v.to_array()).collect();
                factor.solve_scalar(&mut coarse);
                coarse
            }
            CoarseSolve::Multilevel(cycles) => {
                cycles.solve(&mut sums);
                sums.iter().flat_map(|v| v.to_array()).collect()
            }
        }
    }

    /// The coarse space's part of the error left after the plain step
    /// `step` (`s`), three numbers per aggregate: the solution of
    /// `P^T K P c = P^T K e'` with `K e' = -s / (c alpha) + K s`.
    fn coarse_part(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        step: &[DVec3],
    ) -> Vec<f64> {
        let inverse = 1.0 / f64::from(self.contraction);
        let left = self.operator_then(aggregates, connections, step, |k, ks| {
            ks - step[k] * inverse
        });
        self.coarse_of(aggregates, left)
    }

    /// `E v` for the two-level iteration, given `k = K v`: with the plain
    /// step `E = (I - Pi)(I - c alpha K)`, the step `s = -c alpha k` with
    /// the coarse space's part of what is left removed; with the volume
    /// smoother `E = (I - Pi)(I - M^-1 K)`, its step for the residual
    /// `-k`. In `f64`.
    fn two_level(
        &self,
        aggregates: &Aggregates,
        connections: &Connections,
        v: &[DVec3],
        k: &[DVec3],
    ) -> Vec<DVec3> {
        if self.smoother.is_some() {
            let residual: Vec<DVec3> = k.iter().map(|k| -*k).collect();
            if let Some(step) = self.smoothed_step(aggregates, connections, &residual) {
                return aggregates
                    .aggregate
                    .iter()
                    .zip(v.iter().zip(&step))
                    .map(|(&a, (v, s))| if a == OUTSIDE { DVec3::ZERO } else { *v + *s })
                    .collect();
            }
        }
        let c = f64::from(self.contraction);
        let step: Vec<DVec3> = k.iter().map(|k| -c * *k).collect();
        let coarse = self.coarse_part(aggregates, connections, &step);
        aggregates
            .aggregate
            .iter()
            .enumerate()
            .map(|(i, &a)| {
                if a == OUTSIDE {
                    return DVec3::ZERO;
                }
                let a = 3 * a as usize;
                v[i] + step[i] - DVec3::new(coarse[a], coarse[a + 1], coarse[a + 2])
            })
            .collect()
    }
}

/// `P^T K P` (its block rows `blocks`) factored, or cycled above
/// `made_for.direct_max_aggregates`; `None` where it is not positive
/// definite.
fn coarse_solve(
    aggregates: &Aggregates,
    rest: &[Vec3],
    blocks: &[Vec<(u32, DMat3)>],
    made_for: CorrectionFor,
    making: Making<'_>,
) -> Option<CoarseSolve> {
    if aggregates.count() <= made_for.direct_max_aggregates {
        if made_for.envelope {
            return Envelope::cholesky(&scalar_rows(blocks)).map(CoarseSolve::Envelope);
        }
        let previous = match making.previous.map(|p| &p.solve) {
            Some(CoarseSolve::Direct(factor)) => Some(factor),
            _ => None,
        };
        // Factored in `f32` at once where it will only be solved so (no
        // contraction to estimate with it first).
        let single = making.single && made_for.rho.is_some();
        Cholesky::of_blocks(blocks, previous, single).map(CoarseSolve::Direct)
    } else {
        let centres = centres(rest, &aggregates.aggregate, aggregates.count());
        BlockMultilevel::new(
            blocks,
            &centres,
            aggregates.cell,
            made_for.direct_max_aggregates,
        )
        .map(CoarseSolve::Multilevel)
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
            let (m, n) = elastic.products(rest, current, connections, i);
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
/// weight `1/2 W_i (P^T g_i)(P^T g_i)^T` (`parts`), each sorted by column;
/// with `upper`, only the blocks on and above the diagonal (half the outer
/// products: what a host factor reads). Each particle's spring (`springs`:
/// one per particle, or none) adds its `P / 2` to its aggregate's
/// diagonal block.
fn assemble(
    aggregates: &Aggregates,
    parts: &Parts,
    weights: &[f64],
    springs: &[Spring],
    upper: bool,
) -> Vec<Vec<(u32, DMat3)>> {
    // Per aggregate, the particles whose `g_i` reaches it, in order.
    let mut touching: Vec<Vec<u32>> = vec![Vec::new(); aggregates.count()];
    for i in 0..weights.len() {
        for &(a, _) in parts.of(i) {
            touching[a as usize].push(i as u32);
        }
    }
    // Per aggregate, its springs' blocks summed in the particles' order.
    let mut pulled = vec![DMat3::ZERO; aggregates.count()];
    for (&a, &spring) in aggregates.aggregate.iter().zip(springs) {
        if a != OUTSIDE && !spring.is_zero() {
            pulled[a as usize] += spring_block(spring);
        }
    }
    // One block row per aggregate: its 3x3 blocks summed in the particles'
    // order, then the coarse Laplacian on the diagonal of each block.
    // Each thread keeps, per aggregate, where its block is in the row being
    // summed (`NOWHERE` where it has none yet), cleared after each row.
    const NOWHERE: u32 = u32::MAX;
    touching
        .par_iter()
        .zip(&aggregates.rows)
        .enumerate()
        .map_init(
            || vec![NOWHERE; aggregates.count()],
            |position, (a, (particles, laplacian))| {
                let mut blocks: Vec<(u32, DMat3)> = Vec::with_capacity(4 * laplacian.len());
                let mut add = |b: u32, block: DMat3| match position[b as usize] {
                    NOWHERE => {
                        position[b as usize] = blocks.len() as u32;
                        blocks.push((b, block));
                    }
                    at => blocks[at as usize].1 += block,
                };
                let kept = |b: u32| !upper || b as usize >= a;
                for &(b, w) in laplacian.iter().filter(|&&(b, _)| kept(b)) {
                    add(b, DMat3::from_diagonal(DVec3::splat(w)));
                }
                if pulled[a] != DMat3::ZERO {
                    add(a as u32, pulled[a]);
                }
                for &i in particles {
                    let parts = parts.of(i as usize);
                    let Some(&(_, u)) = parts.iter().find(|&&(b, _)| b as usize == a) else {
                        continue;
                    };
                    let u = 0.5 * weights[i as usize] * u;
                    for &(b, v) in parts.iter().filter(|&&(b, _)| kept(b)) {
                        // Column `c` of the block `u v^T` is `u v_c`.
                        add(b, DMat3::from_cols(u * v.x, u * v.y, u * v.z));
                    }
                }
                for &(b, _) in &blocks {
                    position[b as usize] = NOWHERE;
                }
                blocks.sort_unstable_by_key(|&(b, _)| b);
                blocks
            },
        )
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use glam::Mat3;

    use super::*;
    use crate::coarse::laplacian::power_start;
    use crate::coarse::volume_smoother::{pressure_forces, volume_changes};

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
                let (m, n) = elastic.products(rest, current, connections, i);
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
        let plain = CorrectionFor {
            contraction: 0.002,
            smoothing: None,
            rho: None,
            direct_max_aggregates: usize::MAX,
            envelope: false,
        };
        let coarse =
            ElasticCoarse::new(&aggregates, &rest, &current, &connections, &elastic, plain)
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
        let k = coarse.operator(&aggregates, &connections, &u);
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
            let k = coarse.operator(&aggregates, &connections, field);
            let mut sums = vec![DVec3::ZERO; aggregates.count()];
            for (&a, k) in aggregates.aggregate.iter().zip(&k) {
                if a != OUTSIDE {
                    sums[a as usize] += *k;
                }
            }
            sums.iter().map(|s| s.length()).fold(0.0f64, f64::max)
        };
        let k = coarse.operator(&aggregates, &connections, &error);
        let e: Vec<Vec3> = error.iter().map(|e| e.as_vec3()).collect();
        let mut plain: Vec<Vec3> = e
            .iter()
            .zip(&k)
            .map(|(&e, k)| e - coarse.contraction() * k.as_vec3())
            .collect();
        let before: Vec<DVec3> = plain.iter().map(|p| p.as_dvec3()).collect();
        coarse.correct(&aggregates, &e, &mut plain, &connections);
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

    /// The products through the slots' entries are the linearisation's own
    /// `K u` ([`VolumeLinearisation::operator`]), to the entries' rounding
    /// to `f32` (2.4e-8 of the product here; 1e-16 when they were `f64`).
    #[test]
    fn the_slot_products_are_the_operator() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.1, 0.95, 0.97));
        let r = turn();
        let (rest, _, connections, aggregates, _, coarse) = corrected_at(|p| r * stretch * p);
        let u = displacement(&aggregates, &rest);
        let fast = coarse.operator(&aggregates, &connections, &u);
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let direct = coarse
            .linearisation()
            .operator(&rest, &connections, inside, &u);
        let (scale, off) = largest_and_apart(&direct, &fast);
        assert!(scale > 0.0);
        assert!(off <= 1e-6 * scale, "{off} of {scale}");
    }

    /// The block's correction at `current` with the volume smoother, its
    /// contraction by 40 Lanczos steps.
    fn smoothed_at(
        current: impl Fn(Vec3) -> Vec3,
    ) -> (Vec<Vec3>, Connections, Aggregates, ElasticCoarse) {
        smoothed_made(current, None, false)
    }

    /// The block's correction at `current` with the volume smoother, its
    /// contraction `rho` (or 40 Lanczos steps), factored for a device
    /// (`envelope`) or the host.
    fn smoothed_made(
        current: impl Fn(Vec3) -> Vec3,
        rho: Option<f32>,
        envelope: bool,
    ) -> (Vec<Vec3>, Connections, Aggregates, ElasticCoarse) {
        let (rest, connections, free) = jittered_block();
        let current: Vec<Vec3> = rest.iter().map(|&p| current(p)).collect();
        let aggregates = Aggregates::new(&rest, &connections, &free, 2.0, 1_000).unwrap();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let (_, lambda_max) = crate::stage2::spectrum::laplacian_extremes(&connections, &free);
        let made_for = CorrectionFor {
            contraction: 0.002,
            smoothing: Some(Smoothing {
                delta: crate::coarse::volume_smoother::SHEAR_STEP * f64::from(lambda_max),
                sweeps: crate::coarse::volume_smoother::SMOOTHER_SWEEPS,
            }),
            rho,
            direct_max_aggregates: usize::MAX,
            envelope,
        };
        let coarse = ElasticCoarse::made(
            &aggregates,
            &rest,
            &current,
            &connections,
            &elastic,
            made_for,
            Making {
                rate_steps: REST_RATE_STEPS,
                ..Making::default()
            },
        )
        .unwrap();
        (rest, connections, aggregates, coarse)
    }

    /// The host's sparse factor and the envelope a device uploads solve
    /// the same coarse system: the smoothed corrected steps agree to
    /// rounding, and each correction holds the factor it was asked for.
    #[test]
    fn the_sparse_and_the_envelope_factor_give_the_same_step() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.1, 0.95, 0.97));
        let warp = |p: Vec3| turn() * stretch * p;
        let (rest, connections, aggregates, sparse) = smoothed_made(warp, Some(0.9), false);
        let (.., envelope) = smoothed_made(warp, Some(0.9), true);
        assert!(sparse.factor().is_some() && sparse.envelope().is_none());
        assert!(envelope.envelope().is_some() && envelope.factor().is_none());
        let residual = displacement(&aggregates, &rest);
        let a = sparse
            .smoothed_step(&aggregates, &connections, &residual)
            .unwrap();
        let b = envelope
            .smoothed_step(&aggregates, &connections, &residual)
            .unwrap();
        let (scale, off) = largest_and_apart(&a, &b);
        assert!(scale > 0.0);
        assert!(off <= 1e-9 * scale, "{off} of {scale}");
    }

    /// A factor on the host reads the blocks on and above the diagonal
    /// alone: assembled so, they are the full rows' blocks to the bit, and
    /// factored from the blocks they solve as the full scalar rows'
    /// factor does, to the bit.
    #[test]
    fn the_host_factor_reads_the_upper_blocks_alone() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.1, 0.95, 0.97));
        let (rest, connections, free) = jittered_block();
        let current: Vec<Vec3> = rest.iter().map(|&p| turn() * stretch * p).collect();
        let aggregates = Aggregates::new(&rest, &connections, &free, 2.0, 1_000).unwrap();
        let elastic = Elastic::new(&rest, &connections, 0.49, &free);
        let linearisation = linearise(&rest, &current, &connections, &elastic);
        let (_, parts) = own_entries(
            &rest,
            &connections,
            &linearisation,
            Some(&aggregates.aggregate),
        );
        let weights = &linearisation.weights;
        let full = assemble(&aggregates, &parts, weights, &[], false);
        let upper = assemble(&aggregates, &parts, weights, &[], true);
        assert!(aggregates.count() > 8);
        for (a, (full, upper)) in full.iter().zip(&upper).enumerate() {
            let above: Vec<(u32, DMat3)> = full
                .iter()
                .copied()
                .filter(|&(b, _)| b as usize >= a)
                .collect();
            assert_eq!(*upper, above, "block row {a}");
        }
        let count = |rows: &[Vec<(u32, DMat3)>]| rows.iter().map(Vec::len).sum::<usize>();
        // The diagonal's and half the others.
        assert_eq!(2 * count(&upper), count(&full) + full.len());
        let rows = scalar_rows(&full);
        let from_rows = Cholesky::new(&rows).unwrap();
        let from_blocks = Cholesky::of_blocks(&upper, None, false).unwrap();
        let b: Vec<f64> = (0..rows.len())
            .map(|i| ((i * 7) % 11) as f64 - 5.0)
            .collect();
        let (mut x, mut y) = (b.clone(), b);
        from_rows.solve_scalar(&mut x);
        from_blocks.solve_scalar(&mut y);
        assert_eq!(x, y);
    }

    /// The largest vector of `a` and how far apart `a` and `b` are at most.
    fn largest_and_apart(a: &[DVec3], b: &[DVec3]) -> (f64, f64) {
        let largest = a.iter().map(|v| v.length()).fold(0.0f64, f64::max);
        let apart = a
            .iter()
            .zip(b)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0f64, f64::max);
        (largest, apart)
    }

    /// The volume changes (`G^T x`) and the pressures' forces (`G y`) are
    /// each other's transpose: `y . G^T x = x . G y` over the free particles.
    #[test]
    fn the_volume_changes_and_the_pressure_forces_are_adjoint() {
        let (rest, connections, aggregates, coarse) = smoothed_at(|p| turn() * p);
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let x = displacement(&aggregates, &rest);
        let y: Vec<f64> = (0..rest.len()).map(|i| ((i as f64) * 0.37).sin()).collect();
        let changes = volume_changes(&coarse.entries, &connections, &inside, &x);
        let forces = pressure_forces(&coarse.entries, &connections, &inside, &y);
        let left: f64 = y.iter().zip(&changes).map(|(y, c)| y * c).sum();
        let right: f64 = x.iter().zip(&forces).map(|(x, f)| x.dot(*f)).sum();
        assert!(left.abs() > 1e-6, "{left}");
        assert!(
            (left - right).abs() <= 1e-10 * left.abs(),
            "{left} vs {right}"
        );
    }

    /// The smoother is symmetric (`u . M^-1 v = v . M^-1 u`), as the
    /// Lanczos estimate of its iteration's contraction needs, and positive.
    #[test]
    fn the_volume_smoother_is_symmetric_and_positive() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.1, 0.95, 0.97));
        let (rest, connections, aggregates, coarse) = smoothed_at(|p| turn() * stretch * p);
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let smoother = coarse.smoother().unwrap();
        let u = displacement(&aggregates, &rest);
        let v: Vec<DVec3> = (0..rest.len())
            .map(|i| {
                let t = i as f64;
                if inside(i) {
                    DVec3::new((0.3 * t).cos(), (0.7 * t).sin(), (1.1 * t).cos())
                } else {
                    DVec3::ZERO
                }
            })
            .collect();
        let smooth = |r: &[DVec3]| smoother.smooth(&coarse.entries, &connections, &inside, r);
        let dot = |a: &[DVec3], b: &[DVec3]| a.iter().zip(b).map(|(a, b)| a.dot(*b)).sum::<f64>();
        let (mu, mv) = (smooth(&u), smooth(&v));
        let (a, b) = (dot(&u, &mv), dot(&v, &mu));
        assert!((a - b).abs() <= 1e-10 * a.abs().max(b.abs()), "{a} vs {b}");
        assert!(dot(&u, &mu) > 0.0 && dot(&v, &mv) > 0.0);
    }

    /// With the volume smoother the two-level iteration contracts, and much
    /// faster than with the plain step (on the block at 0.49: 0.73
    /// against 0.98, measured by 40 Lanczos steps each).
    #[test]
    fn the_volume_smoother_contracts_faster_than_the_plain_step() {
        let stretch = Mat3::from_diagonal(Vec3::new(1.05, 1.0, 0.97));
        let r = turn();
        let (_, connections, aggregates, smoothed) = smoothed_at(|p| r * stretch * p);
        let (_, _, _, _, _, plain) = corrected_at(|p| r * stretch * p);
        let plain_rho = plain.spectral_radius(&aggregates, &connections, 40);
        let rho = smoothed.rho();
        eprintln!("two-level contraction: {rho:.4} smoothed, {plain_rho:.4} plain");
        assert!(rho > 0.1 && rho < 0.9, "{rho}");
        assert!(1.0 - rho >= 2.0 * (1.0 - plain_rho), "{rho} vs {plain_rho}");
    }

    /// After the smoothed step and its correction, what is left of the
    /// error has no part the coarse space can remove: `P^T (r - K s) = 0`.
    #[test]
    fn the_smoothed_step_leaves_no_error_in_the_coarse_space() {
        let r = turn();
        let (rest, connections, aggregates, coarse) = smoothed_at(|p| r * p);
        let error = displacement(&aggregates, &rest);
        let residual: Vec<DVec3> = coarse
            .operator(&aggregates, &connections, &error)
            .iter()
            .map(|k| -*k)
            .collect();
        let step = coarse
            .smoothed_step(&aggregates, &connections, &residual)
            .unwrap();
        let k = coarse.operator(&aggregates, &connections, &step);
        let mut left = vec![DVec3::ZERO; aggregates.count()];
        let mut was = vec![DVec3::ZERO; aggregates.count()];
        for (i, &a) in aggregates.aggregate.iter().enumerate() {
            if a != OUTSIDE {
                left[a as usize] += residual[i] - k[i];
                was[a as usize] += residual[i];
            }
        }
        let largest = |v: &[DVec3]| v.iter().map(|x| x.length()).fold(0.0f64, f64::max);
        assert!(largest(&was) > 0.0);
        assert!(
            largest(&left) <= 1e-8 * largest(&was),
            "{} of {}",
            largest(&left),
            largest(&was)
        );
    }

    /// The volume smoother's settings and its contraction's Lanczos steps,
    /// as docs/METHOD.md measured them, and on by default.
    #[test]
    fn the_volume_smoother_defaults_are_the_measured_ones() {
        use crate::coarse::volume_smoother::{
            MAX_SMOOTHER_SWEEPS, RELAXATION, SHEAR_STEP, SMOOTHER_SWEEPS,
        };
        assert_eq!((SHEAR_STEP, RELAXATION, SMOOTHER_SWEEPS), (2.0, 0.5, 2));
        assert_eq!(MAX_SMOOTHER_SWEEPS, 32);
        assert_eq!(REST_RATE_STEPS, 40);
        assert!(
            crate::stage2::params::DeformParams::default()
                .tuning
                .volume_smoother
        );
    }

    /// Lanczos' estimate of the two-level iteration's radius against the
    /// radius itself, found by power iteration run to a standstill, and
    /// against 40 steps of power iteration (the estimate before Lanczos):
    /// from below, and at least as near as those 40 steps.
    #[test]
    fn the_contraction_estimate_is_near_the_radius_from_below() {
        let r = turn();
        let (_, _, connections, aggregates, _, coarse) =
            corrected_at(|p| r * Mat3::from_diagonal(Vec3::new(1.05, 1.0, 0.97)) * p);
        let n = aggregates.aggregate.len();
        let inside = |i: usize| aggregates.aggregate[i] != OUTSIDE;
        let mut v: Vec<DVec3> = power_start(inside, n)
            .iter()
            .map(|v| v.as_dvec3())
            .collect();
        let length = |v: &[DVec3]| v.iter().map(|x| x.length_squared()).sum::<f64>().sqrt();
        let (mut radius, mut after_40) = (0.0, 0.0);
        for step in 1..=3_000 {
            let k = coarse.operator(&aggregates, &connections, &v);
            let next = coarse.two_level(&aggregates, &connections, &v, &k);
            radius = length(&next) / length(&v);
            if step == 40 {
                after_40 = radius;
            }
            let scale = length(&next);
            v = next.iter().map(|x| *x / scale).collect();
        }
        let estimate = f64::from(coarse.rho());
        let more = f64::from(coarse.spectral_radius(&aggregates, &connections, 40));
        eprintln!(
            "radius {radius:.5}; Lanczos {estimate:.5} in {RATE_STEPS} steps, {more:.5} in 40; \
             power iteration {after_40:.5} in 40"
        );
        assert!(radius > 0.5 && radius < 1.0, "radius {radius}");
        assert!(
            estimate <= radius && estimate >= after_40,
            "estimate {estimate} for a radius of {radius} (power iteration: {after_40})"
        );
        // With more steps, the radius (power iteration is still a little
        // below it after 3,000 steps).
        assert!(
            more >= estimate && (more - radius).abs() <= 1e-3 * radius,
            "{more} in 40 steps against {radius}"
        );
    }
}
