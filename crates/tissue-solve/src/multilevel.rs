//! The coarse system of the two-level solve, solved approximately by a
//! two-grid cycle of its own where it is too large to factor cheaply.
//!
//! The two-level solve needs `x = (P^T L P)^-1 b` every iteration for the
//! aggregates' graph Laplacian `A = P^T L P` ([`crate::coarse`]). Its
//! envelope factor grows as `n^(5/3)` and its substitutions as `n^(4/3)`,
//! so at a million particles (about 86,000 aggregates of 2 spacings) it is
//! out of reach, and the cells had to grow instead, which costs the fine
//! iteration its speed. Here the aggregates themselves are grouped, those
//! whose centres share a cell [`GROUP`] times as large, into a second
//! coarse space `Q` whose matrix `Q^T A Q` is small enough to factor, and
//! `A x = b` is solved by [`CYCLES`] symmetric two-grid cycles from zero:
//! Jacobi sweeps weighted by [`JACOBI_WEIGHT`] before and after the exact
//! correction over the groups. That is a fixed, symmetric approximation
//! `B` of `A^-1`, so the iteration it corrects stays a fixed linear map
//! and Chebyshev and the stopping rule can run on its measured contraction
//! (docs/METHOD.md, "Two-level solve", "Multilevel").

use std::collections::HashMap;
use std::ops::Range;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::coarse::{Envelope, reverse_cuthill_mckee};

/// Symmetric two-grid cycles per coarse solve.
pub const CYCLES: usize = 3;

/// Jacobi sweeps before and after each cycle's correction over the groups.
pub const SWEEPS: usize = 3;

/// The weight of each Jacobi sweep: the aggregates' matrix is a weighted
/// graph Laplacian, whose `D^-1 A` has its spectrum in `(0, 2]`, so `2/3`
/// damps its upper half at least threefold a sweep.
pub const JACOBI_WEIGHT: f64 = 2.0 / 3.0;

/// The groups' cells, in the aggregates' cells: about `GROUP^3`
/// aggregates a group.
pub const GROUP: f32 = 3.0;

/// The aggregates' matrix, its groups and the groups' factored matrix.
#[derive(Debug, Clone)]
pub struct Multilevel {
    /// The rows of `A`: row `i` is `starts[i]..starts[i + 1]` of `columns`
    /// and `values`.
    starts: Vec<usize>,
    columns: Vec<u32>,
    values: Vec<f64>,
    /// `JACOBI_WEIGHT / A_ii` per row.
    weighted_inverse_diagonal: Vec<f64>,
    /// Per aggregate, its group (in the factor's order).
    group: Vec<u32>,
    /// The Cholesky factor of `Q^T A Q`.
    factor: Envelope,
}

impl Multilevel {
    /// The aggregates' matrix `rows` (each sorted by column, both
    /// triangles), their centres and the edge of their cells; the groups'
    /// cells grow (by factors of 1.25) until there are at most
    /// `max_groups`. `None` when the groups' matrix is not positive
    /// definite.
    pub fn new(
        rows: &[Vec<(u32, f64)>],
        centres: &[Vec3],
        cell: f32,
        max_groups: usize,
    ) -> Option<Self> {
        let n = rows.len();
        let mut starts = Vec::with_capacity(n + 1);
        starts.push(0);
        let (mut columns, mut values) = (Vec::new(), Vec::new());
        let mut weighted_inverse_diagonal = Vec::with_capacity(n);
        for (i, row) in rows.iter().enumerate() {
            let mut diagonal = 0.0;
            for &(j, w) in row {
                columns.push(j);
                values.push(w);
                if j as usize == i {
                    diagonal = w;
                }
            }
            if diagonal <= 0.0 {
                return None;
            }
            weighted_inverse_diagonal.push(JACOBI_WEIGHT / diagonal);
            starts.push(columns.len());
        }
        let (mut group, mut count) = groups(centres, cell * GROUP);
        let mut edge = cell * GROUP;
        while count > max_groups.max(1) {
            edge *= 1.25;
            (group, count) = groups(centres, edge);
        }
        let mut grouped: Vec<HashMap<u32, f64>> = vec![HashMap::new(); count];
        for (i, row) in rows.iter().enumerate() {
            let g = &mut grouped[group[i] as usize];
            for &(j, w) in row {
                *g.entry(group[j as usize]).or_default() += w;
            }
        }
        let grouped: Vec<Vec<(u32, f64)>> = grouped
            .into_iter()
            .map(|row| {
                let mut row: Vec<(u32, f64)> = row.into_iter().filter(|&(_, w)| w != 0.0).collect();
                row.sort_unstable_by_key(|&(b, _)| b);
                row
            })
            .collect();
        let order = reverse_cuthill_mckee(&grouped);
        let mut rank = vec![0u32; count];
        for (k, &g) in order.iter().enumerate() {
            rank[g as usize] = k as u32;
        }
        let ordered: Vec<Vec<(u32, f64)>> = order
            .iter()
            .map(|&g| {
                let mut row: Vec<(u32, f64)> = grouped[g as usize]
                    .iter()
                    .map(|&(h, w)| (rank[h as usize], w))
                    .collect();
                row.sort_unstable_by_key(|&(h, _)| h);
                row
            })
            .collect();
        let factor = Envelope::cholesky(&ordered)?;
        let group = group.iter().map(|&g| rank[g as usize]).collect();
        Some(Self {
            starts,
            columns,
            values,
            weighted_inverse_diagonal,
            group,
            factor,
        })
    }

    /// Number of aggregates (unknowns of `A`).
    pub fn len(&self) -> usize {
        self.group.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.group.is_empty()
    }

    /// Number of groups (unknowns of the factored matrix).
    pub fn groups(&self) -> usize {
        self.factor.len()
    }

    /// `b` replaced by `B b`, the approximation of `A^-1 b` that
    /// [`CYCLES`] symmetric two-grid cycles from zero give.
    pub fn solve(&self, b: &mut [DVec3]) {
        let rhs = b.to_vec();
        // The first sweep from zero, whose residual is `b` itself.
        let mut x: Vec<DVec3> = rhs
            .par_iter()
            .zip(&self.weighted_inverse_diagonal)
            .map(|(b, &w)| *b * w)
            .collect();
        for cycle in 0..CYCLES {
            for _ in usize::from(cycle == 0)..SWEEPS {
                self.sweep(&rhs, &mut x);
            }
            let residual = self.residual(&rhs, &x);
            let mut coarse = vec![DVec3::ZERO; self.groups()];
            for (&g, r) in self.group.iter().zip(&residual) {
                coarse[g as usize] += *r;
            }
            self.factor.solve(&mut coarse);
            x.par_iter_mut()
                .zip(&self.group)
                .for_each(|(x, &g)| *x += coarse[g as usize]);
            for _ in 0..SWEEPS {
                self.sweep(&rhs, &mut x);
            }
        }
        b.copy_from_slice(&x);
    }

    fn row(&self, i: usize) -> Range<usize> {
        self.starts[i]..self.starts[i + 1]
    }

    /// `b - A x`.
    fn residual(&self, b: &[DVec3], x: &[DVec3]) -> Vec<DVec3> {
        (0..b.len())
            .into_par_iter()
            .map(|i| {
                let mut r = b[i];
                for k in self.row(i) {
                    r -= x[self.columns[k] as usize] * self.values[k];
                }
                r
            })
            .collect()
    }

    /// One weighted Jacobi sweep: `x += w D^-1 (b - A x)`.
    fn sweep(&self, b: &[DVec3], x: &mut [DVec3]) {
        let residual = self.residual(b, x);
        x.par_iter_mut()
            .zip(&residual)
            .zip(&self.weighted_inverse_diagonal)
            .for_each(|((x, r), &w)| *x += *r * w);
    }
}

/// Per centre, its group (the centres in one cell of edge `cell`, numbered
/// in order of first appearance), and how many groups there are.
fn groups(centres: &[Vec3], cell: f32) -> (Vec<u32>, usize) {
    let mut cells = HashMap::new();
    let group = centres
        .iter()
        .map(|c| {
            let key = (*c / cell).floor().as_ivec3().to_array();
            let next = cells.len() as u32;
            *cells.entry(key).or_insert(next)
        })
        .collect();
    (group, cells.len())
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;

    /// The Dirichlet Laplacian of a `side^3` grid of unit spacing,
    /// 6-connected, held outside it; and its nodes' centres.
    fn grid(side: usize) -> (Vec<Vec<(u32, f64)>>, Vec<Vec3>) {
        let index = |x: usize, y: usize, z: usize| ((z * side + y) * side + x) as u32;
        let mut rows = Vec::new();
        let mut centres = Vec::new();
        for z in 0..side {
            for y in 0..side {
                for x in 0..side {
                    let mut row = vec![(index(x, y, z), 6.0)];
                    for (dx, dy, dz) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        for sign in [-1i64, 1] {
                            let (a, b, c) = (
                                x as i64 + sign * dx,
                                y as i64 + sign * dy,
                                z as i64 + sign * dz,
                            );
                            let inside = |v: i64| (0..side as i64).contains(&v);
                            if inside(a) && inside(b) && inside(c) {
                                row.push((index(a as usize, b as usize, c as usize), -1.0));
                            }
                        }
                    }
                    row.sort_unstable_by_key(|&(j, _)| j);
                    rows.push(row);
                    centres.push(Vec3::new(x as f32, y as f32, z as f32) + 0.5);
                }
            }
        }
        (rows, centres)
    }

    fn product(rows: &[Vec<(u32, f64)>], x: &[DVec3]) -> Vec<DVec3> {
        rows.iter()
            .map(|row| row.iter().map(|&(j, w)| x[j as usize] * w).sum())
            .collect()
    }

    fn field(n: usize, phase: f64) -> Vec<DVec3> {
        (0..n)
            .map(|i| {
                let t = i as f64 + phase;
                DVec3::new((t * 0.37).sin(), (t * 0.11).cos(), (t * 0.05).sin())
            })
            .collect()
    }

    fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
        a.iter().zip(b).map(|(a, b)| a.dot(*b)).sum()
    }

    #[test]
    fn the_cycles_are_a_symmetric_approximate_inverse() {
        let (rows, centres) = grid(16);
        let multilevel = Multilevel::new(&rows, &centres, 1.0, 10_000).expect("definite");
        // Cells of 3 hold 27 nodes: 6^3 groups over 16^3 nodes.
        assert_eq!(multilevel.len(), 4_096);
        assert_eq!(multilevel.groups(), 216);
        let (x, y) = (field(4_096, 0.0), field(4_096, 17.0));
        let (mut bx, mut by) = (x.clone(), y.clone());
        multilevel.solve(&mut bx);
        multilevel.solve(&mut by);
        // Symmetric: y . B x = x . B y (Chebyshev needs a fixed, self-adjoint
        // correction).
        let (yx, xy) = (dot(&y, &bx), dot(&x, &by));
        assert!((yx - xy).abs() < 1e-10 * yx.abs().max(1.0), "{yx} vs {xy}");
        // Close to the inverse: what `A B` leaves of a right-hand side is a
        // small part of it.
        let left: Vec<DVec3> = product(&rows, &bx)
            .iter()
            .zip(&x)
            .map(|(abx, x)| *x - *abx)
            .collect();
        let ratio = (dot(&left, &left) / dot(&x, &x)).sqrt();
        assert!(ratio < 0.1, "|b - A B b| / |b| = {ratio}");
        // One cycle fewer would leave more: the cycles are what converges.
        assert!(ratio > 1e-6, "{ratio}: more exact than cycles can be");
    }

    #[test]
    fn the_groups_grow_until_they_fit_the_factor_budget() {
        let (rows, centres) = grid(12);
        let multilevel = Multilevel::new(&rows, &centres, 1.0, 20).expect("definite");
        assert!(multilevel.groups() <= 20, "{}", multilevel.groups());
        assert!(multilevel.groups() > 1);
        // A matrix with a non-positive diagonal is refused, not solved.
        let mut broken = rows.clone();
        broken[5].iter_mut().for_each(|(j, w)| {
            if *j == 5 {
                *w = 0.0;
            }
        });
        assert!(Multilevel::new(&broken, &centres, 1.0, 20).is_none());
    }
}
