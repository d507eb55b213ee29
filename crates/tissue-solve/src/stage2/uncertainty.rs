//! How sure an answer is: the solve repeated over what the program does
//! not know, each repeat started from the answer (docs/METHOD.md,
//! "Uncertainty").
//!
//! The unknowns ([`Unknown`]) and their priors ([`Priors`]):
//! - **the Poisson ratio**, uniform over a range: solved again at the
//!   range's ends on trackers of their own (the ratio is prepared into a
//!   solve), the answer's positions taken as quadratic in `(1 - 2 nu) /
//!   (2 nu)` (the shear over the volume stiffness) through the three, and
//!   their spread integrated over the range by three-point Gauss-Legendre.
//!   With a load, each ratio's response is to the change of load between
//!   the postures, what the unloaded shape's search turns into the
//!   deformed posture's move (for an answer matched to an observation,
//!   taken linear in the ratio between the range's ends: its own ratio's
//!   response is not solved);
//! - **the observed surface**, in error along its normals by a smooth
//!   random field ([`SurfaceNoise`]): a Monte Carlo ensemble, each sample a
//!   re-solve on the answer's tracker or a copy of it ([`chains`]);
//! - with a load (a posture's gravity): **the load's scale** (density and
//!   stiffness, relative), the change of load between the postures scaled
//!   (the unloaded shape is found from the rest scan, so to first order the
//!   deformed posture moves by the response to that change), and **the
//!   gravity's directions**, each posture's tilted about two axes: one
//!   linearised re-solve per column;
//! - without one, **the unmodelled posture**: a change of gravity between
//!   the scans that the answer left out, of an RMS size in g on tissue of
//!   a given stiffness, one linearised re-solve along each axis at the
//!   answer's Poisson ratio and at the range's lower end, taken piecewise
//!   linear in the stiffness ratio and integrated over the range by the
//!   ratio's quadrature (with the skin held, the response to a body force
//!   grows fast as the ratio falls).
//!
//! The Poisson ratio and the loads are the elastic force's: with another
//! force only the surface's error is sampled.
//!
//! An answer matched to an observation without correspondence ([`HeldBy`])
//! is re-solved with its skin paired with the observation at every
//! iteration, as the match's last stage paired it: the answer is then
//! the re-solves' own equilibrium, and the skin slides along the
//! observation only as far as the observation's shape lets it. The
//! surface's error moves the observation's points along their normals by
//! the field's offset there, and each sample pairs with its field made
//! again.
//!
//! Every column is a re-solve's positions less the answer's with a weight;
//! a target's covariance is the weighted sum of its offsets' outer
//! products ([`Region::of`]). Written once for every device: the columns
//! are solves of a [`Tracker`].

pub mod chains;
pub mod noise;
pub mod priors;
mod quadrature;
pub mod refresh;
pub mod region;

use std::time::Instant;

use glam::{Quat, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use tissue_core::field::SurfaceField;
use tissue_core::{Error, ParamError, SurfaceMesh};

use crate::model::gravity::gravity_load;
use crate::stage2::pairing::Pairing;
use crate::stage2::params::{DeformParams, ForceModel};
use crate::stage2::tracker::{SolveDevice, Tracker};

use quadrature::{between_the_ratios, gauss_legendre, over_the_range, ratio};

pub use noise::{NoiseSample, SurfaceNoise};
pub use priors::{
    COLUMN_TOLERANCE, GRAVITY_DEGREES, LOAD_SPREAD, POISSON_RANGE, POSTURE_G, POSTURE_KPA, Priors,
    SEED, SURFACE_CORRELATION_MM, SURFACE_NOISE_MM, SURFACE_SAMPLES, TISSUE_DENSITY_KG_M3,
};
pub use refresh::Refresh;
pub use region::{CHI2_3_95, FLAT_FLOOR, Region, radius_95, symmetric_eigen};

/// What the spread is owed to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Unknown {
    /// The Poisson ratio.
    Poisson,
    /// The observed surface's error.
    Surface,
    /// The load's scale: density and stiffness.
    Load,
    /// The postures' gravity directions.
    Gravity,
    /// Without a posture's gravity: the change of gravity between the
    /// scans that the answer did not model.
    Posture,
}

impl Unknown {
    /// Every unknown, in the order of [`Region::shares`].
    pub const ALL: [Unknown; 5] = [
        Unknown::Poisson,
        Unknown::Surface,
        Unknown::Load,
        Unknown::Gravity,
        Unknown::Posture,
    ];

    /// Its place in [`Unknown::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Unknown::Poisson => "poisson",
            Unknown::Surface => "surface",
            Unknown::Load => "load",
            Unknown::Gravity => "gravity",
            Unknown::Posture => "posture",
        }
    }
}

/// One column of the spread: the positions of a re-solve, with its
/// unknown and its weight in the covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    /// What was changed.
    pub unknown: Unknown,
    /// Its weight: `sum w (x - x0)(x - x0)^T` is the covariance.
    pub weight: f64,
    /// Every particle's position in the re-solve.
    pub positions: Vec<Vec3>,
}

/// The answer and its re-solves.
#[derive(Debug, Clone, PartialEq)]
pub struct Spread {
    /// The answer's positions, one per particle.
    pub answer: Vec<Vec3>,
    /// The re-solves.
    pub columns: Vec<Column>,
    /// Stage-2 solves made (one per column, and one per other Poisson
    /// ratio).
    pub solves: usize,
    /// Re-solves carried from an earlier answer of a sequence instead
    /// ([`Refresh::every`]): that answer's offset put on this one.
    pub carried: usize,
    /// Their iterations.
    pub iterations: usize,
    /// Whether every re-solve converged.
    pub converged: bool,
    /// Wall-clock seconds, the trackers' preparation included.
    pub seconds: f64,
}

impl Spread {
    /// The region of each target, where `targets` maps particle positions
    /// to the targets' (carried points, say: called once on the answer and
    /// once per column).
    pub fn regions(&self, targets: &dyn Fn(&[Vec3]) -> Vec<Vec3>) -> Vec<Region> {
        let answer = targets(&self.answer);
        let moved: Vec<Vec<Vec3>> = self.columns.iter().map(|c| targets(&c.positions)).collect();
        (0..answer.len())
            .into_par_iter()
            .map(|k| {
                Region::of(
                    self.columns
                        .iter()
                        .zip(&moved)
                        .map(|(c, m)| (c.unknown, c.weight, m[k] - answer[k])),
                )
            })
            .collect()
    }

    /// Each particle's region.
    pub fn particle_regions(&self) -> Vec<Region> {
        self.regions(&|positions| positions.to_vec())
    }
}

/// What the answer was solved for.
#[derive(Debug, Clone, Copy)]
pub struct Answered<'a> {
    /// The deformed surface the skin followed.
    pub surface: &'a SurfaceMesh,
    /// Per surface vertex, whether it is exact (the held region: no
    /// surface error there).
    pub exact: &'a [bool],
    /// The rest posture's load, where the answer has a load (the deformed
    /// posture's is the tracker's).
    pub rest_load: Option<Vec3>,
    /// The model's length unit in metres (0.001 for millimetres), for the
    /// unmodelled posture's load.
    pub metres_per_unit: f32,
    /// Where the answer matched an observation without correspondence:
    /// the observation and how the skin was paired with it. `None` where
    /// the skin followed `surface` point for point.
    pub held_by: Option<&'a dyn HeldBy>,
}

/// What held a matched answer's skin ([`Answered::held_by`]): the
/// observation it was paired with at every iteration, and how.
pub trait HeldBy: Sync + std::fmt::Debug {
    /// The observation's field the skin was paired on.
    fn field(&self) -> &SurfaceField;
    /// The match's last pairing: the particles paired and the rule.
    fn pairing(&self) -> &Pairing;
    /// The field of the observation with each of its points moved along
    /// its normal by `offset` there (a sample of the observation's
    /// error; `offset` may be called on several threads at once).
    ///
    /// # Errors
    ///
    /// Where the field cannot be made.
    fn moved(&self, offset: &(dyn Fn(Vec3) -> f32 + Sync)) -> Result<SurfaceField, Error>;
}

/// The spread of the answer `tracker` holds (its last solve's, converged,
/// on `answered.surface`) under `priors`: every column solved from the
/// answer, the Poisson ratio's on trackers `other` prepares for the
/// tracker's parameters with another ratio. The tracker is left at the
/// answer, its history as it was. [`Explorer`] does the same for a
/// sequence of answers, each from the last one's columns.
///
/// # Errors
///
/// [`ParamError`] for priors out of range or an `exact` mask of the wrong
/// length; what the solves and `other` return.
pub fn explore<D, E>(
    tracker: &mut Tracker<D>,
    answered: Answered<'_>,
    priors: &Priors,
    other: &mut (dyn FnMut(DeformParams) -> Result<Tracker<D>, E> + Send),
) -> Result<Spread, E>
where
    D: SolveDevice + Send,
    E: From<Error> + From<D::Error> + Send,
{
    Explorer::new(priors.clone()).explore(tracker, answered, other)
}

/// [`explore`] over a sequence of answers (a tracking run's frames): the
/// other Poisson ratios' trackers are prepared once and kept, and each
/// re-solve starts from the answer moved by what the same re-solve moved
/// the last answer by (the columns change little from frame to frame);
/// with [`Refresh::every`], only a few re-solves are made at each answer
/// after the first, the others carried.
pub struct Explorer<D> {
    priors: Priors,
    /// Which re-solves each answer makes anew, and where it got to.
    refresh: Refresh,
    /// The other Poisson ratios' trackers, by ratio.
    others: Vec<(f32, Tracker<D>)>,
    /// The last spread's re-solves, each its positions less its answer's,
    /// in the order they are made.
    last: Vec<Vec<Vec3>>,
}

impl<D: SolveDevice + Send> Explorer<D> {
    /// An explorer with nothing prepared.
    pub fn new(priors: Priors) -> Self {
        Self {
            priors,
            refresh: Refresh::all(),
            others: Vec::new(),
            last: Vec::new(),
        }
    }

    /// The explorer refreshing its re-solves as `refresh` says.
    pub fn refreshing(mut self, refresh: Refresh) -> Self {
        self.refresh = refresh;
        self
    }

    /// How it refreshes its re-solves.
    pub fn refresh(&self) -> Refresh {
        self.refresh
    }

    /// The priors it samples.
    pub fn priors(&self) -> &Priors {
        &self.priors
    }

    /// [`explore`] of the answer `tracker` holds, from what this explorer
    /// kept of the last one; `other` is asked only for a ratio it has no
    /// tracker of yet.
    ///
    /// # Errors
    ///
    /// As [`explore`].
    pub fn explore<E>(
        &mut self,
        tracker: &mut Tracker<D>,
        answered: Answered<'_>,
        other: &mut (dyn FnMut(DeformParams) -> Result<Tracker<D>, E> + Send),
    ) -> Result<Spread, E>
    where
        E: From<Error> + From<D::Error> + Send,
    {
        let priors = self.priors.clone();
        let last = std::mem::take(&mut self.last);
        let mut made: Vec<Vec<Vec3>> = Vec::new();
        let spread = self.columns(tracker, answered, &priors, other, &last, &mut made);
        self.last = made;
        spread
    }

    /// The columns of the answer `tracker` holds; each re-solve `i` starts
    /// from the answer plus `last[i]` where the last answer had one, its
    /// offset pushed onto `made`.
    fn columns<E>(
        &mut self,
        tracker: &mut Tracker<D>,
        answered: Answered<'_>,
        priors: &Priors,
        other: &mut (dyn FnMut(DeformParams) -> Result<Tracker<D>, E> + Send),
        last: &[Vec<Vec3>],
        made: &mut Vec<Vec<Vec3>>,
    ) -> Result<Spread, E>
    where
        E: From<Error> + From<D::Error> + Send,
    {
        let started = Instant::now();
        priors.validate().map_err(Error::from)?;
        ParamError::check(
            answered.exact.len() == answered.surface.vertices.len(),
            "uncertainty exact",
            answered.exact.len(),
            format!(
                "one flag per surface vertex ({})",
                answered.surface.vertices.len()
            ),
        )
        .map_err(Error::from)?;
        let kept = tracker.checkpoint()?;
        let answer = tracker.positions().to_vec();
        let asked = tracker.params().clone();
        let loose = priors.column_tolerance;
        tracker.set_params(asked.clone().with(|p| p.tolerance *= loose))?;
        let mut spread = Spread {
            answer: answer.clone(),
            ..chains::counting()
        };
        // A matched answer's skin paired with its observation in every
        // re-solve, as its match's last stage paired it.
        let held = answered.held_by.map(|h| (h.field(), h.pairing()));
        // Each re-solve on `surface`, its skin paired where the answer was
        // matched.
        // Re-solve `i` starts from the answer moved by the last answer's
        // re-solve `i`, where there is one.
        let start_of = |i: usize| -> Vec<Vec3> {
            match last.get(i) {
                Some(offsets) if offsets.len() == answer.len() => {
                    answer.iter().zip(offsets).map(|(a, o)| *a + *o).collect()
                }
                _ => answer.clone(),
            }
        };
        let offsets_from = |positions: &[Vec3]| -> Vec<Vec3> {
            positions
                .iter()
                .zip(&answer)
                .map(|(p, a)| *p - *a)
                .collect()
        };
        // The Poisson ratio: quadratic in the stiffness ratio through the
        // answer and the range's ends, integrated over the range. With a
        // load, each ratio's response to the change of load between the
        // postures (what the unloaded shape's search turns into the deformed
        // posture's move), from the answer's tracker under that change.
        let params = tracker.params().clone();
        let load = params.load;
        let change = answered
            .rest_load
            .filter(|_| load != Vec3::ZERO)
            .map(|r| load - r);
        // A matched answer's own ratio is not solved under the change: with
        // its skin paired with the observation, the change presses the skin
        // on it with a whole change of posture, a solve whose energy watch
        // stepped back until it gave up (breast_e's remeshed surface, 2 g).
        // Its positions are taken linear in the stiffness ratio between the
        // range's ends instead (on the correspondence's runs with gravity,
        // median radii within 2 % of the quadratic's).
        let nu0 = params.poisson;
        let (lo, hi) = priors.poisson;
        let between_ends = change.is_some() && answered.held_by.is_some() && lo < hi;
        // The Poisson ratio and the loads are the elastic force's.
        let elastic = params.force == ForceModel::Elastic;
        let poisson = elastic && !(lo == hi && lo == nu0);
        let mut others = Vec::new();
        if poisson {
            others = vec![lo, hi];
            if (lo - nu0).abs() <= 1e-6 || (hi - nu0).abs() <= 1e-6 {
                // The solve's own ratio at an end: the middle is the third.
                others = vec![lo, 0.5 * (lo + hi), hi];
            }
            others.retain(|nu| (nu - nu0).abs() > 1e-6);
            others.dedup();
        }
        // The load's scale and the gravity's directions, linearised; without
        // a load, the change of gravity the answer did not model, along each
        // axis.
        let mut changes = Vec::new();
        if let (Some(rest_load), Some(change)) = (answered.rest_load, change) {
            if priors.load_spread > 0.0 {
                changes.push((Unknown::Load, priors.load_spread * change));
            }
            if priors.gravity_degrees > 0.0 {
                let angle = priors.gravity_degrees.to_radians();
                for (posture, sign) in [(load, 1.0), (rest_load, -1.0)] {
                    let (a, b) = posture.normalize_or_zero().any_orthonormal_pair();
                    for axis in [a, b] {
                        let tilted = Quat::from_axis_angle(axis, angle) * posture;
                        changes.push((Unknown::Gravity, sign * (tilted - posture)));
                    }
                }
            }
        }
        // The unmodelled posture's change of gravity along each axis, as a
        // load at Poisson ratio `nu` (the load is scaled by the shear
        // modulus, which the ratio sets).
        let unmodelled = elastic && load == Vec3::ZERO && priors.posture_g > 0.0;
        let posture_loads = |nu: f32| -> Result<[Vec3; 3], Error> {
            let unit = gravity_load(
                Vec3::Z,
                TISSUE_DENSITY_KG_M3,
                priors.posture_kpa,
                nu,
                answered.metres_per_unit,
            )?
            .length();
            let each = priors.posture_g * unit / 3f32.sqrt();
            Ok([Vec3::X, Vec3::Y, Vec3::Z].map(|axis| each * axis))
        };
        if unmodelled && change.is_none() {
            for each in posture_loads(nu0)? {
                changes.push((Unknown::Posture, each));
            }
        }
        // The response to a change of gravity with the skin held grows fast
        // as the ratio falls (nearly incompressible tissue answers a
        // uniform body force with pressure), so the unmodelled posture is
        // solved at other ratios too and its covariance integrated over the
        // range.
        let posture_by_ratio = unmodelled && change.is_none() && poisson;
        // Its columns are taken piecewise linear in the stiffness ratio
        // between the solved ratios ([`between_the_ratios`]), so it is
        // solved only at the other ratios on whose side of the answer's a
        // quadrature node lies (with the default range, the lower end):
        // other ratio `j`'s three re-solves are the `k`-th such ratio's.
        let nodes: Vec<f64> = gauss_legendre(lo, hi)
            .iter()
            .map(|&(node, _)| ratio(node) - ratio(nu0))
            .collect();
        let mut needed = 0;
        let posture_at: Vec<Option<usize>> = others
            .iter()
            .map(|&nu| {
                let side = ratio(nu) - ratio(nu0);
                let wanted =
                    posture_by_ratio && nodes.iter().any(|&n| n * side > 0.0 && n.abs() > 1e-9);
                wanted.then(|| {
                    needed += 1;
                    needed - 1
                })
            })
            .collect();
        let samples_count = if priors.surface_noise > 0.0 {
            priors.samples
        } else {
            0
        };
        // The re-solves in the order they are made: the Poisson ratio's
        // base under a load, the other ratios, the surface's samples, the
        // loads' changes. Those of the last answer are carried where this
        // explorer refreshes only some.
        let base_solved = poisson && change.is_some() && !between_ends;
        let count =
            usize::from(base_solved) + others.len() + 3 * needed + samples_count + changes.len();
        let can_carry = last.len() == count && last.iter().all(|o| o.len() == answer.len());
        let plan = self.refresh.plan(count, can_carry);
        // Re-solve `i` made anew, or carried from the last answer: its
        // start, as it ended there.
        let fresh = |i: usize| plan.get(i).is_none_or(|&f| f);
        let carry = |i: usize, counted: &mut Spread| {
            counted.carried += 1;
            start_of(i)
        };
        let solve = |t: &mut Tracker<D>,
                     (surface, held): (&SurfaceMesh, Option<Held<'_>>),
                     spread: &mut Spread,
                     made: &mut Vec<Vec<Vec3>>|
         -> Result<Vec<Vec3>, E> {
            let i = made.len();
            let positions = if fresh(i) {
                resolve::<D, E>(t, (surface, held), &start_of(i), spread)?
            } else {
                carry(i, spread)
            };
            made.push(offsets_from(&positions));
            Ok(positions)
        };

        let base = match change {
            _ if !poisson => Vec::new(),
            Some(_) if between_ends => Vec::new(),
            Some(change) => {
                tracker.set_load::<E>(change)?;
                let base = solve(tracker, (answered.surface, held), &mut spread, made)?;
                tracker.set_load::<E>(load)?;
                base
            }
            None => answer.clone(),
        };

        // The surface's error: a Monte Carlo ensemble.
        // Each sample's error belongs to the skin's points: read where they
        // are at rest, it moves with them from one answer to the next.
        let mut noise = SurfaceNoise::new(
            answered.surface,
            answered.exact,
            priors.surface_noise,
            priors.surface_correlation,
            priors.seed,
        )
        .attached_to(tracker.rest_surface());
        let samples: Vec<NoiseSample> = (0..samples_count).map(|_| noise.next_sample()).collect();
        let noise = &noise;

        // The other ratios' re-solves (on trackers of their own, prepared
        // by `other` where this explorer has none yet) beside the surface's
        // samples (on the answer's tracker and its copies): neither touches
        // the other's state. Re-solve `first + j` of the last answer's is
        // the other ratio `j`'s, then come the samples', the loads'
        // changes', and last, where the unmodelled posture is solved at
        // other ratios, the `k`-th such ratio's response to axis `a` at
        // `late + 3 k + a`.
        let first = made.len();
        let late = first + others.len() + samples_count + changes.len();
        let trackers = &mut self.others;
        let mut ratios = |counted: &mut Spread| -> Result<Vec<AtRatio>, E> {
            let mut solved = Vec::new();
            for (j, &nu) in others.iter().enumerate() {
                let wanted = params.clone().with(|p| {
                    p.tolerance *= loose;
                    p.poisson = nu;
                    p.load = change.unwrap_or(load);
                });
                let held_here = (answered.surface, held);
                let positions = if fresh(first + j) {
                    let k = tracker_at(trackers, nu, &wanted, &mut *other)?;
                    let start = start_of(first + j);
                    resolve::<D, E>(&mut trackers[k].1, held_here, &start, counted)?
                } else {
                    carry(first + j, counted)
                };
                let mut postures = Vec::new();
                if let Some(k) = posture_at[j] {
                    for (a, each) in posture_loads(nu)?.into_iter().enumerate() {
                        let i = late + 3 * k + a;
                        if !fresh(i) {
                            postures.push(carry(i, counted));
                            continue;
                        }
                        let k = tracker_at(trackers, nu, &wanted, &mut *other)?;
                        let t = &mut trackers[k].1;
                        // From the ratio's answer where no earlier answer
                        // moved it.
                        let start = match last.get(i) {
                            Some(o) if o.len() == answer.len() => start_of(i),
                            _ => positions.clone(),
                        };
                        t.set_load::<E>(each)?;
                        let moved = resolve::<D, E>(t, held_here, &start, counted);
                        t.set_load::<E>(wanted.load)?;
                        postures.push(moved?);
                    }
                }
                solved.push(AtRatio {
                    nu,
                    positions,
                    postures,
                });
            }
            Ok(solved)
        };
        let after = first + others.len();
        let one = |t: &mut Tracker<D>, k: usize, counted: &mut Spread| {
            if !fresh(after + k) {
                return Ok(carry(after + k, counted));
            }
            let start = start_of(after + k);
            match (answered.held_by, held) {
                // The observation's error moves its points; the held
                // region stays where it is.
                (Some(held_by), Some((_, pairing))) => {
                    let moved = held_by.moved(&|x| noise.offset(&samples[k], x))?;
                    let observed = Some((&moved, pairing));
                    resolve::<D, E>(t, (answered.surface, observed), &start, counted)
                }
                _ => resolve::<D, E>(t, (&noise.moved(&samples[k]), None), &start, counted),
            }
        };
        let (mut at_ratios, mut at_samples) = (chains::counting(), chains::counting());
        let (solved, sampled) = rayon::join(
            || ratios(&mut at_ratios),
            || chains::in_chains(tracker, samples.len(), &one, &mut at_samples),
        );
        let (solved, sampled) = (solved?, sampled?);
        spread.add_counted(&at_ratios);
        spread.add_counted(&at_samples);

        // The Poisson ratio's columns: quadratic in the stiffness ratio
        // through the answer and the other ratios, integrated over the range.
        made.extend(solved.iter().map(|r| offsets_from(&r.positions)));
        if poisson {
            let base = match solved.as_slice() {
                [a, b] if between_ends => {
                    let t = ((ratio(nu0) - ratio(a.nu)) / (ratio(b.nu) - ratio(a.nu))) as f32;
                    a.positions
                        .iter()
                        .zip(&b.positions)
                        .map(|(x, y)| *x + t * (*y - *x))
                        .collect()
                }
                _ => base,
            };
            let mut points: Vec<(f32, Vec<Vec3>)> = vec![(nu0, vec![Vec3::ZERO; answer.len()])];
            for r in &solved {
                let offsets = r
                    .positions
                    .iter()
                    .zip(&base)
                    .map(|(x, b)| *x - *b)
                    .collect();
                points.push((r.nu, offsets));
            }
            for (weight, positions) in over_the_range(&answer, &points, (lo, hi)) {
                spread.columns.push(Column {
                    unknown: Unknown::Poisson,
                    weight,
                    positions,
                });
            }
        }
        for positions in sampled {
            made.push(offsets_from(&positions));
            spread.columns.push(Column {
                unknown: Unknown::Surface,
                weight: 1.0 / priors.samples as f64,
                positions,
            });
        }

        // The unmodelled posture at the answer's ratio, per axis, where it
        // is integrated over the ratios.
        let mut postures = Vec::new();
        for (unknown, change) in changes {
            tracker.set_load::<E>(load + change)?;
            let positions = solve(tracker, (answered.surface, held), &mut spread, made)?;
            if posture_by_ratio && unknown == Unknown::Posture {
                postures.push(positions);
                continue;
            }
            spread.columns.push(Column {
                unknown,
                weight: 1.0,
                positions,
            });
        }
        for r in &solved {
            made.extend(r.postures.iter().map(|p| offsets_from(p)));
        }
        for (a, at_answer) in postures.iter().enumerate() {
            let mut points = vec![(nu0, offsets_from(at_answer))];
            // Each other ratio's response from its own re-solve.
            for r in &solved {
                if let Some(moved) = r.postures.get(a) {
                    let offsets = moved.iter().zip(&r.positions).map(|(x, b)| *x - *b);
                    points.push((r.nu, offsets.collect()));
                }
            }
            for (weight, positions) in between_the_ratios(&answer, &points, (lo, hi)) {
                spread.columns.push(Column {
                    unknown: Unknown::Posture,
                    weight,
                    positions,
                });
            }
        }
        if tracker.params().load != load {
            tracker.set_load::<E>(load)?;
        }
        tracker.set_params(asked)?;
        if held.is_some() {
            // The tracker as it was: no pairing, observation or springs.
            tracker.set_pairing::<E>(None)?;
            tracker.set_observation(None)?;
            tracker.set_springs::<E>(Vec::new())?;
        }
        tracker.back_to::<E>(kept)?;
        spread.seconds = started.elapsed().as_secs_f64();
        Ok(spread)
    }
}

/// An observation's field and the pairing of the skin with it.
type Held<'a> = (&'a SurfaceField, &'a Pairing);

/// One other Poisson ratio's re-solves.
struct AtRatio {
    nu: f32,
    /// Its re-solve of the answer.
    positions: Vec<Vec3>,
    /// Its re-solves under the unmodelled posture's change along each axis
    /// (empty where the posture is not solved at this ratio).
    postures: Vec<Vec<Vec3>>,
}

/// The index in `trackers` of the one prepared for `wanted` at ratio `nu`,
/// prepared by `other` (replacing any other at that ratio) where there is
/// none.
fn tracker_at<D, E>(
    trackers: &mut Vec<(f32, Tracker<D>)>,
    nu: f32,
    wanted: &DeformParams,
    other: &mut (dyn FnMut(DeformParams) -> Result<Tracker<D>, E> + Send),
) -> Result<usize, E>
where
    D: SolveDevice,
{
    let kept = trackers
        .iter()
        .position(|(ratio, t)| *ratio == nu && t.params() == wanted);
    Ok(match kept {
        Some(k) => k,
        None => {
            trackers.retain(|(ratio, _)| *ratio != nu);
            trackers.push((nu, other(wanted.clone())?));
            trackers.len() - 1
        }
    })
}

/// Solves `t` from `start` with its control points on `surface` and, with
/// `held`, its skin paired with that observation from its springs at
/// `start` on, as the match's stages were ([`Pairing::for_solve_from`]: a
/// cloud's rim held at its springs there); counts the solve in `spread`.
fn resolve<D, E>(
    t: &mut Tracker<D>,
    (surface, held): (&SurfaceMesh, Option<Held<'_>>),
    start: &[Vec3],
    spread: &mut Spread,
) -> Result<Vec<Vec3>, E>
where
    D: SolveDevice,
    E: From<Error> + From<D::Error>,
{
    if let Some((field, pairing)) = held {
        t.set_observation(Some(field))?;
        let (springs, iterated) = pairing.for_solve_from(field, start);
        t.set_springs::<E>(springs)?;
        t.set_pairing::<E>(Some(iterated))?;
    }
    t.set_surface::<E>(surface)?;
    t.warm_start::<E>(start)?;
    let report = t.solve()?;
    log::debug!(
        "uncertainty re-solve {}: {} iterations, stopped by {:?}",
        spread.solves,
        report.iterations,
        report.stopped_by
    );
    spread.solves += 1;
    spread.iterations += report.iterations;
    spread.converged &= report.converged;
    Ok(t.positions().to_vec())
}

#[cfg(test)]
mod tests {
    use super::quadrature::lagrange;
    use super::*;

    /// The quadrature integrates a quartic in the ratio's neighbourhood
    /// exactly over the uniform range, and its weights sum to one.
    #[test]
    fn gauss_legendre_integrates_the_uniform_range() {
        let nodes = gauss_legendre(0.45, 0.495);
        let sum: f64 = nodes.iter().map(|n| n.1).sum();
        assert!((sum - 1.0).abs() < 1e-12);
        let mean: f64 = nodes.iter().map(|&(x, w)| w * f64::from(x)).sum();
        assert!((mean - 0.4725).abs() < 1e-6, "{mean}");
        let second: f64 = nodes
            .iter()
            .map(|&(x, w)| w * (f64::from(x) - 0.4725).powi(2))
            .sum();
        assert!((second - 0.045f64.powi(2) / 12.0).abs() < 1e-8, "{second}");
    }

    /// Between the solved ratios each node's offset is the linear
    /// interpolation in the stiffness ratio of its two neighbours' (a convex
    /// combination), held at the nearest one beyond them; the weights are
    /// the quadrature's.
    #[test]
    fn between_the_ratios_interpolates_linearly_in_the_stiffness_ratio() {
        use super::quadrature::between_the_ratios;
        let answer = vec![Vec3::ZERO; 2];
        let at = |x: f32| vec![Vec3::new(x, 0.0, 0.0), Vec3::new(0.0, 2.0 * x, 0.0)];
        // The answer's 0.49 and the range's lower end.
        let points = vec![(0.49, at(1.0)), (0.45, at(3.0))];
        let columns = between_the_ratios(&answer, &points, (0.45, 0.495));
        let nodes = gauss_legendre(0.45, 0.495);
        assert_eq!(columns.len(), 3);
        for ((weight, positions), (node, w)) in columns.iter().zip(&nodes) {
            assert_eq!(weight, w);
            let t = ((ratio(*node) - ratio(0.49)) / (ratio(0.45) - ratio(0.49))) as f32;
            let expected = 1.0 + 2.0 * t.clamp(0.0, 1.0);
            assert!(
                (positions[0].x - expected).abs() < 1e-5,
                "{node}: {positions:?}"
            );
            assert!((positions[1].y - 2.0 * expected).abs() < 1e-5);
            assert!((1.0..=3.0).contains(&positions[0].x));
        }
    }

    /// The Lagrange basis is one at its own point, zero at the others.
    #[test]
    fn lagrange_basis_interpolates() {
        let xs = [0.1, 0.02, 0.01];
        for (j, &x) in xs.iter().enumerate() {
            let basis = lagrange(&xs, x);
            for (m, b) in basis.iter().enumerate() {
                assert!((b - f64::from(u8::from(m == j))).abs() < 1e-12);
            }
        }
    }

    /// The defaults are those docs/METHOD.md ("Uncertainty") gives and
    /// argues for.
    #[test]
    fn the_defaults_are_the_documented_ones() {
        let p = Priors::default();
        assert_eq!(p.poisson, (0.45, 0.495));
        assert_eq!((p.surface_noise, p.surface_correlation), (0.5, 10.0));
        assert_eq!(p.samples, 16);
        assert_eq!((p.load_spread, p.gravity_degrees), (0.14, 3.0));
        assert_eq!((p.posture_g, p.posture_kpa), (2f32.sqrt(), 2.0));
        assert_eq!(p.column_tolerance, 8.0);
    }

    /// The defaults are in range, and a priors' field out of range is
    /// refused by name.
    #[test]
    fn priors_are_checked() {
        assert!(Priors::default().validate().is_ok());
        let bad = Priors::default().with(|p| p.poisson = (0.49, 0.45));
        let err = bad.validate().err().map(|e| e.to_string());
        assert!(err.is_some_and(|e| e.contains("poisson")));
        let bad = Priors::default().with(|p| p.samples = 1);
        assert!(bad.validate().is_err());
        assert_eq!(
            Priors::in_units(10.0).surface_noise,
            SURFACE_NOISE_MM / 10.0
        );
    }
}
