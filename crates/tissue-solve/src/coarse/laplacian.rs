//! The two-level solve of stage 2: every iteration, after the plain step,
//! the error left in a coarse space of aggregates is removed exactly.
//!
//! For fixed rotations the plain step is `s = -c alpha L e` for the error
//! `e` (`L` the Dirichlet Laplacian over free particles, `c alpha` the
//! [`Plan::contraction`](crate::stage2::plan::Plan::contraction)), so the
//! error after it, `e' = e + s`, has `L e' = -s / (c alpha) + L s`: known
//! without knowing `e`. The coarse space is piecewise constant over
//! aggregates (the free particles in one cell of a grid of edge `cell`),
//! `P` its prolongation; the correction `-P (P^T L P)^-1 P^T L e'` is the
//! `L`-orthogonal projection of `e'` onto it, so what is left of the error
//! is `L`-orthogonal to every aggregate's translation. That removes the
//! smooth error the plain step hardly touches, and the iteration
//! `E = (I - Pi)(I - c alpha L)` contracts much faster than the plain one
//! (docs/METHOD.md, "Two-level solve").
//!
//! `P^T L P` is the aggregates' own graph Laplacian; it is factored once
//! (Cholesky, in reverse Cuthill-McKee order so the factor stays within a
//! narrow envelope) and solved every iteration for the three coordinates.

use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use tissue_core::{Connections, DeformError, Error, ParticleModel};

pub(crate) use crate::coarse::aggregates::centres;
pub use crate::coarse::aggregates::{Aggregates, OUTSIDE, members_of};
use crate::coarse::cholesky::Cholesky;
pub use crate::coarse::envelope::Envelope;
use crate::coarse::multilevel::Multilevel;
use crate::stage2::params::DeformParams;
use crate::stage2::plan::Plan;

mod shared;
pub use shared::{SharedLaplacian, coarse_space_shared, laplacian_key};

/// Power iterations that estimate the two-level iteration's contraction.
pub const RATE_ITERATIONS: usize = 40;

/// Aggregates of free particles and the factored coarse Laplacian.
#[derive(Debug, Clone)]
pub struct CoarseSpace {
    /// Per particle: its aggregate (numbered in the factor's order), or
    /// [`OUTSIDE`].
    aggregate: Vec<u32>,
    /// Per aggregate, where its particles start in `members` (one more
    /// than there are aggregates).
    member_starts: Vec<u32>,
    /// The particles of each aggregate in turn, in increasing order.
    members: Vec<u32>,
    /// How `P^T L P` is solved.
    solve: CoarseSolve,
    cell: f32,
    rho: f32,
    seconds: f64,
}

impl CoarseSpace {
    /// The aggregates of the free particles of a model with rest positions
    /// `rest` in grid cells of edge `cell`, grown (by factors of 1.25) until
    /// there are at most `max_aggregates`; the coarse Laplacian factored
    /// (at most `direct_max` aggregates) or else prepared for two-grid
    /// cycles ([`Multilevel`]), and the two-level iteration's contraction
    /// estimated for the plain step's `contraction` (`c alpha`).
    pub fn new(
        rest: &[Vec3],
        connections: &Connections,
        free: &[bool],
        cell: f32,
        (max_aggregates, direct_max): (usize, usize),
        contraction: f32,
    ) -> Result<Self, Error> {
        let started = Instant::now();
        let Aggregates {
            aggregate,
            rows,
            cell,
        } = Aggregates::new(rest, connections, free, cell, max_aggregates)?;
        let not_definite = || {
            Error::from(DeformError::CoarseSpace(
                "the coarse Laplacian is not positive definite (a rounding failure)".into(),
            ))
        };
        let count = rows.len();
        let solve = if count <= direct_max {
            CoarseSolve::Direct(Cholesky::new(&rows).ok_or_else(not_definite)?, rows)
        } else {
            let centres = centres(rest, &aggregate, rows.len());
            CoarseSolve::Multilevel(
                Multilevel::new(&rows, &centres, cell, direct_max).ok_or_else(not_definite)?,
            )
        };
        let (member_starts, members) = members_of(&aggregate, count);
        let mut space = Self {
            aggregate,
            member_starts,
            members,
            solve,
            cell,
            rho: 0.0,
            seconds: 0.0,
        };
        space.rho = space.spectral_radius(connections, contraction);
        // Estimated with the factor in `f64`; the iterations solve in `f32`
        // (`Cholesky::single`).
        space.solve = match space.solve {
            CoarseSolve::Direct(factor, rows) => CoarseSolve::Direct(factor.single(), rows),
            CoarseSolve::Multilevel(multilevel) => CoarseSolve::Multilevel(multilevel.single()),
        };
        space.seconds = started.elapsed().as_secs_f64();
        Ok(space)
    }

    /// Number of aggregates.
    pub fn count(&self) -> usize {
        match &self.solve {
            CoarseSolve::Direct(factor, _) => factor.len(),
            CoarseSolve::Multilevel(multilevel) => multilevel.len(),
        }
    }

    /// The edge of the grid cells the aggregates were made of.
    pub fn cell(&self) -> f32 {
        self.cell
    }

    /// Per particle its aggregate (in the factor's order), or [`OUTSIDE`].
    pub fn aggregate(&self) -> &[u32] {
        &self.aggregate
    }

    /// The Cholesky factor of `P^T L P`, where it is factored (at most
    /// `direct_max` aggregates).
    pub fn factor(&self) -> Option<&Cholesky> {
        match &self.solve {
            CoarseSolve::Direct(factor, _) => Some(factor),
            CoarseSolve::Multilevel(_) => None,
        }
    }

    /// `P^T L P` factored within its envelope, the rows and columns a
    /// device's substitution reads, where it is factored on the host.
    pub fn envelope(&self) -> Option<Envelope> {
        match &self.solve {
            CoarseSolve::Direct(_, rows) => Envelope::cholesky(rows),
            CoarseSolve::Multilevel(_) => None,
        }
    }

    /// The two-grid solve of `P^T L P`, where it is too large to factor.
    pub fn multilevel(&self) -> Option<&Multilevel> {
        match &self.solve {
            CoarseSolve::Direct(..) => None,
            CoarseSolve::Multilevel(multilevel) => Some(multilevel),
        }
    }

    /// Seconds the preparation took.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    /// The contraction of the two-level iteration, for Chebyshev and the
    /// stopping rule: its spectral radius, estimated by power iteration.
    pub fn rho(&self) -> f32 {
        self.rho
    }

    /// Turns the plain step `plain - current` (`-contraction L e` for the
    /// error `e`) into the two-level one: subtracts the `L`-orthogonal
    /// projection onto the coarse space of the error left after it.
    pub fn correct(
        &self,
        current: &[Vec3],
        plain: &mut [Vec3],
        connections: &Connections,
        contraction: f32,
    ) {
        let inverse = 1.0 / f64::from(contraction);
        let aggregate = &self.aggregate;
        let step = |i: usize| -> DVec3 {
            if aggregate[i] == OUTSIDE {
                DVec3::ZERO
            } else {
                (plain[i] - current[i]).as_dvec3()
            }
        };
        // Per particle, `(L e')_i = -s_i / (c alpha) + (L s)_i`.
        let residual: Vec<DVec3> = (0..current.len())
            .into_par_iter()
            .map(|i| {
                if aggregate[i] == OUTSIDE {
                    return DVec3::ZERO;
                }
                let row = connections.of(i);
                let mut r = step(i) * (row.len() as f64 - inverse);
                for &j in row {
                    r -= step(j as usize);
                }
                r
            })
            .collect();
        // Summed per aggregate, in the order of its particles.
        let mut coarse: Vec<DVec3> = (0..self.count())
            .into_par_iter()
            .map(|a| {
                self.members[self.member_starts[a] as usize..self.member_starts[a + 1] as usize]
                    .iter()
                    .fold(DVec3::ZERO, |sum, &i| sum + residual[i as usize])
            })
            .collect();
        match &self.solve {
            CoarseSolve::Direct(factor, _) => factor.solve(&mut coarse),
            CoarseSolve::Multilevel(multilevel) => multilevel.solve(&mut coarse),
        }
        let coarse: Vec<Vec3> = coarse.iter().map(|v| v.as_vec3()).collect();
        plain.par_iter_mut().zip(aggregate).for_each(|(p, &a)| {
            if a != OUTSIDE {
                *p -= coarse[a as usize];
            }
        });
    }

    /// The spectral radius of the two-level iteration
    /// `E = (I - Pi)(I - c alpha L)` by power iteration from a fixed start
    /// with every mode in it. `E` is `L`-self-adjoint on the range of
    /// `I - Pi`, where the start lands after one step, so its eigenvalues
    /// are real; the estimate approaches the radius from below, and
    /// Chebyshev still converges on the few modes it leaves out, more slowly.
    fn spectral_radius(&self, connections: &Connections, contraction: f32) -> f32 {
        let n = self.aggregate.len();
        let inside = |i: usize| self.aggregate[i] != OUTSIDE;
        let mut v = power_start(inside, n);
        let mut radius = 0.0;
        for _ in 0..RATE_ITERATIONS {
            let scale = norm(&v);
            if scale == 0.0 {
                break;
            }
            v.par_iter_mut().for_each(|x| *x /= scale as f32);
            let mut plain: Vec<Vec3> = (0..n)
                .into_par_iter()
                .map(|i| {
                    if !inside(i) {
                        return Vec3::ZERO;
                    }
                    let row = connections.of(i);
                    let mut lv = v[i] * row.len() as f32;
                    for &j in row {
                        if inside(j as usize) {
                            lv -= v[j as usize];
                        }
                    }
                    v[i] - contraction * lv
                })
                .collect();
            self.correct(&v, &mut plain, connections, contraction);
            radius = norm(&plain) as f32;
            v = plain;
        }
        radius.clamp(0.0, 0.9999)
    }
}

/// The coarse space a solve of `model` uses under `params` (on either
/// device): none with `coarse` 0, or (with a warning) where it cannot be
/// built.
pub fn coarse_space(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<CoarseSpace> {
    if params.tuning.coarse == 0.0 {
        return None;
    }
    let space = CoarseSpace::new(
        &model.positions,
        &model.connections,
        &plan.free,
        params.tuning.coarse * model.mean_connection_length(),
        (
            params.tuning.coarse_max_aggregates,
            params.tuning.coarse_direct_max_aggregates,
        ),
        plan.contraction(&params.shear()),
    );
    match space {
        Ok(space) => {
            log::info!(
                "two-level solve: {} aggregates in cells of {:.3}, contraction {:.3}, prepared in {:.3} s",
                space.count(),
                space.cell(),
                space.rho(),
                space.seconds()
            );
            Some(space)
        }
        Err(e) => {
            log::warn!("no two-level solve: {e}");
            None
        }
    }
}

/// A start for power iteration with every mode in it: a fixed,
/// irregular vector over the particles `inside` says are free.
pub fn power_start(inside: impl Fn(usize) -> bool, n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            if !inside(i) {
                return Vec3::ZERO;
            }
            let t = (i as f32 * 0.618_034).fract();
            Vec3::new(t, (t * 7.31).fract(), (t * 13.17).fract()) - 0.5
        })
        .collect()
}

/// The Euclidean norm of a field of vectors.
pub fn norm(v: &[Vec3]) -> f64 {
    v.par_iter()
        .map(|x| f64::from(x.length_squared()))
        .sum::<f64>()
        .sqrt()
}

/// How a coarse space's matrix is solved.
#[derive(Debug, Clone)]
enum CoarseSolve {
    /// Factored: solved exactly; the rows kept for a device's envelope
    /// factor ([`CoarseSpace::envelope`]).
    Direct(Cholesky, Vec<Vec<(u32, f64)>>),
    /// Too large to factor: two-grid cycles over groups of aggregates.
    Multilevel(Multilevel),
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;

    #[test]
    fn the_laplacian_key_tells_connections_and_free_particles_apart() {
        let (_, connections, free) = grid(5);
        let key = laplacian_key(&connections, &free);
        assert_eq!(key, laplacian_key(&connections.clone(), &free.clone()));
        let mut one_held = free.clone();
        let inner = one_held.iter().position(|&f| f).expect("a free particle");
        one_held[inner] = false;
        assert_ne!(key, laplacian_key(&connections, &one_held));
        // One connection fewer (the first particle's first, both ways).
        let j = connections.of(0)[0];
        let pairs = (0..connections.particles()).flat_map(|i| {
            connections
                .of(i)
                .iter()
                .map(move |&k| (i as u32, k))
                .filter(move |&(a, b)| a < b && !(a == 0 && b == j))
        });
        let fewer = Connections::from_pairs(connections.particles(), pairs);
        assert_ne!(key, laplacian_key(&fewer, &free));
    }

    /// A `side^3` grid of unit spacing, 6-connected, its outer layer fixed.
    fn grid(side: usize) -> (Vec<Vec3>, Connections, Vec<bool>) {
        let index = |x: usize, y: usize, z: usize| ((z * side + y) * side + x) as u32;
        let mut positions = Vec::new();
        let mut free = Vec::new();
        let mut pairs = Vec::new();
        for z in 0..side {
            for y in 0..side {
                for x in 0..side {
                    positions.push(Vec3::new(x as f32, y as f32, z as f32) + 0.5);
                    free.push([x, y, z].iter().all(|&c| c > 0 && c + 1 < side));
                    if x + 1 < side {
                        pairs.push((index(x, y, z), index(x + 1, y, z)));
                    }
                    if y + 1 < side {
                        pairs.push((index(x, y, z), index(x, y + 1, z)));
                    }
                    if z + 1 < side {
                        pairs.push((index(x, y, z), index(x, y, z + 1)));
                    }
                }
            }
        }
        let connections = Connections::from_pairs(positions.len(), pairs);
        (positions, connections, free)
    }

    /// `L v` over free particles (the Dirichlet Laplacian).
    fn laplacian(v: &[Vec3], connections: &Connections, free: &[bool]) -> Vec<Vec3> {
        (0..v.len())
            .map(|i| {
                if !free[i] {
                    return Vec3::ZERO;
                }
                let row = connections.of(i);
                let mut lv = v[i] * row.len() as f32;
                for &j in row.iter().filter(|&&j| free[j as usize]) {
                    lv -= v[j as usize];
                }
                lv
            })
            .collect()
    }

    /// For fixed rotations and a solution at 0, the positions are the error.
    fn error(free: &[bool]) -> Vec<Vec3> {
        free.iter()
            .enumerate()
            .map(|(i, &f)| {
                let t = i as f32;
                if f {
                    Vec3::new((t * 0.37).sin(), (t * 0.11).cos(), 1.0 + (t * 0.05).sin())
                } else {
                    Vec3::ZERO
                }
            })
            .collect()
    }

    /// `steps` two-level steps shrink an error at least as fast as the
    /// space's estimated contraction, give or take 5 %.
    fn assert_rate_holds(
        space: &CoarseSpace,
        connections: &Connections,
        free: &[bool],
        contraction: f32,
        steps: usize,
    ) {
        let mut e = error(free);
        let start = e.iter().map(|v| v.length_squared()).sum::<f32>().sqrt();
        for _ in 0..steps {
            let l = laplacian(&e, connections, free);
            let mut next: Vec<Vec3> = e
                .iter()
                .zip(&l)
                .map(|(e, le)| *e - contraction * *le)
                .collect();
            space.correct(&e, &mut next, connections, contraction);
            e = next;
        }
        let end = e.iter().map(|v| v.length_squared()).sum::<f32>().sqrt();
        let observed = (end / start).powf(1.0 / steps as f32);
        assert!(
            observed <= space.rho() * 1.05,
            "observed {observed}, rho {}",
            space.rho()
        );
    }

    #[test]
    fn a_two_level_step_leaves_no_error_in_the_coarse_space() {
        let (rest, connections, free) = grid(12);
        let contraction = 0.9 / 6.0;
        let space = CoarseSpace::new(
            &rest,
            &connections,
            &free,
            2.0,
            (10_000, 10_000),
            contraction,
        )
        .expect("a coarse space");
        // 10^3 free particles in cells of 2: 6^3 aggregates (the grid starts at 0.5).
        assert_eq!(space.count(), 216);
        let current = error(&free);
        let l = laplacian(&current, &connections, &free);
        let mut next: Vec<Vec3> = current
            .iter()
            .zip(&l)
            .map(|(e, le)| *e - contraction * *le)
            .collect();
        let plain = next.clone();
        space.correct(&current, &mut next, &connections, contraction);
        // What is left is L-orthogonal to every aggregate's indicator:
        // the residual `L e` sums to zero over each aggregate; the plain
        // step's did not.
        let sums = |e: &[Vec3]| {
            let mut sums = vec![Vec3::ZERO; space.count()];
            for (r, &a) in laplacian(e, &connections, &free)
                .iter()
                .zip(&space.aggregate)
            {
                if a != OUTSIDE {
                    sums[a as usize] += *r;
                }
            }
            sums.iter().map(|s| s.length()).fold(0.0f32, f32::max)
        };
        assert!(sums(&plain) > 1.0, "{}", sums(&plain));
        assert!(sums(&next) < 1e-4, "{}", sums(&next));
    }

    #[test]
    fn the_two_level_iteration_contracts_far_faster_than_the_plain_one() {
        let (rest, connections, free) = grid(18);
        let (lambda_min, lambda_max) =
            crate::stage2::spectrum::laplacian_extremes(&connections, &free);
        // The symmetric force at step fraction 0.9: `c alpha = 1.8 / lambda_max`.
        let contraction = 1.8 / lambda_max;
        let plain = 1.0 - contraction * lambda_min;
        let space = CoarseSpace::new(
            &rest,
            &connections,
            &free,
            2.0,
            (10_000, 10_000),
            contraction,
        )
        .expect("a coarse space");
        // The plain iteration is slower than 0.95 here; the two-level one is
        // held by the step's negative end, `1 - 1.8 lambda_top / lambda_max`.
        assert!(plain > 0.95, "plain {plain}");
        assert!(space.rho() < 0.85, "two-level {}", space.rho());
        // And the estimate holds: 30 two-level steps shrink an error by at
        // least `rho^30` times a small factor, not much less.
        assert_rate_holds(&space, &connections, &free, contraction, 30);
    }

    /// Above `direct_max` aggregates the coarse matrix is solved by
    /// two-grid cycles, not exactly: the iteration then contracts nearly as
    /// fast as with the factor, and its estimate still holds.
    #[test]
    fn the_cycles_over_groups_of_aggregates_nearly_keep_the_two_level_rate() {
        let (rest, connections, free) = grid(26);
        let (_, lambda_max) = crate::stage2::spectrum::laplacian_extremes(&connections, &free);
        let contraction = 1.8 / lambda_max;
        let exact = CoarseSpace::new(
            &rest,
            &connections,
            &free,
            2.0,
            (10_000, 10_000),
            contraction,
        )
        .expect("a coarse space");
        let cycled = CoarseSpace::new(
            &rest,
            &connections,
            &free,
            2.0,
            (10_000, 1_000),
            contraction,
        )
        .expect("a coarse space");
        // 24^3 free particles at 1.5..24.5 in cells of 2: 13^3 aggregates,
        // grouped in cells of 4 (7^3 groups, up to 8 aggregates each).
        assert_eq!(exact.count(), 2_197);
        assert!(exact.factor().is_some() && exact.multilevel().is_none());
        let multilevel = cycled.multilevel().expect("cycles above direct_max");
        assert!(cycled.factor().is_none());
        assert_eq!(multilevel.groups(), 343);
        assert!(
            cycled.rho() < exact.rho() + 0.05,
            "cycled {} against exact {}",
            cycled.rho(),
            exact.rho()
        );
        assert_rate_holds(&cycled, &connections, &free, contraction, 20);
    }

    #[test]
    fn cells_grow_until_the_aggregates_fit_the_budget() {
        let (rest, connections, free) = grid(12);
        let space = CoarseSpace::new(&rest, &connections, &free, 2.0, (50, 50), 0.15)
            .expect("a coarse space");
        assert!(space.count() <= 50, "{}", space.count());
        assert!(space.cell() > 2.0);
        let refused = CoarseSpace::new(&rest, &connections, &free, f32::NAN, (50, 50), 0.15)
            .expect_err("a NaN cell");
        assert!(refused.to_string().contains("cell is NaN"), "{refused}");
        let none = CoarseSpace::new(
            &rest,
            &connections,
            &vec![false; rest.len()],
            2.0,
            (50, 50),
            0.15,
        )
        .expect_err("nothing free");
        assert!(none.to_string().contains("no particle is free"), "{none}");
    }

    #[test]
    fn the_envelope_cholesky_solves_a_banded_system() {
        // The Dirichlet Laplacian of a path (tridiagonal 2, -1), with a
        // long-range entry to exercise the envelope.
        let n = 12;
        let mut rows: Vec<Vec<(u32, f64)>> = (0..n)
            .map(|i| {
                let mut row = vec![(i as u32, 2.5)];
                if i > 0 {
                    row.insert(0, (i as u32 - 1, -1.0));
                }
                if i + 1 < n {
                    row.push((i as u32 + 1, -1.0));
                }
                row
            })
            .collect();
        rows[9].insert(0, (2, -0.3));
        rows[2].push((9, -0.3));
        let factor = Envelope::cholesky(&rows).expect("positive definite");
        let x: Vec<DVec3> = (0..n)
            .map(|i| DVec3::new(i as f64, 1.0, -(i as f64).sin()))
            .collect();
        let mut b: Vec<DVec3> = rows
            .iter()
            .map(|row| row.iter().map(|&(j, w)| x[j as usize] * w).sum())
            .collect();
        factor.solve(&mut b);
        for (got, want) in b.iter().zip(&x) {
            assert!((*got - *want).length() < 1e-12, "{got} vs {want}");
        }
    }
}
