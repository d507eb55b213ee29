//! The coarse system of the two-level solve, solved approximately by a
//! two-grid cycle of its own where it is too large to factor cheaply.
//!
//! The two-level solve needs `x = (P^T L P)^-1 b` every iteration for the
//! aggregates' graph Laplacian `A = P^T L P` ([`crate::coarse::laplacian`]). Its
//! factor grows as `n^(5/3)` within its envelope, and as `n^2` even
//! sparsely ([`crate::coarse::cholesky`]: the fill of a 3-D graph's factor), so at
//! a million particles (about 86,000 aggregates of 2 spacings) it is out
//! of reach, and growing the cells instead would cost the fine
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

use glam::{DMat3, DVec3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;

use crate::coarse::cholesky::Cholesky;
use crate::coarse::envelope::{Envelope, reverse_cuthill_mckee};

/// Symmetric two-grid cycles per coarse solve.
pub const CYCLES: usize = 3;

/// Jacobi sweeps before and after each cycle's correction over the groups.
pub const SWEEPS: usize = 3;

/// The weight of each Jacobi sweep: the aggregates' matrix is a weighted
/// graph Laplacian, whose `D^-1 A` has its spectrum in `(0, 2]`, so `2/3`
/// damps its upper half at least threefold a sweep.
pub const JACOBI_WEIGHT: f64 = 2.0 / 3.0;

/// The groups' cells, in the aggregates' cells: about `GROUP^3`
/// aggregates a group. 2, since the groups are capped at 4,096
/// (`SolverTuning::coarse_direct_max_aggregates`, what the GPU substitutes
/// in one workgroup); where the cap bites it grows the groups to about 3
/// anyway (docs/METHOD.md, "Multilevel").
pub const GROUP: f32 = 2.0;

/// [`BlockMultilevel`]'s groups' cells, in the aggregates' cells: its
/// groups' factor is made again at every elastic phase's start, three
/// unknowns a group, so its groups stay larger.
pub const BLOCK_GROUP: f32 = 3.0;

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
    /// The rows of `Q^T A Q` in that order, kept for a device's envelope
    /// factor ([`Multilevel::groups_envelope`]).
    group_rows: Vec<Vec<(u32, f64)>>,
    /// The Cholesky factor of `Q^T A Q`.
    factor: Cholesky,
    /// `values` and `weighted_inverse_diagonal` rounded to `f32`, where
    /// the cycles run in `f32` ([`Multilevel::single`]).
    single: Option<(Vec<f32>, Vec<f32>)>,
}

impl Multilevel {
    /// The same cycles in `f32`, for the solves made every iteration: the
    /// matrix, the sweeps' vectors and the groups' factor
    /// ([`Cholesky::single`]), as the GPU's twin runs them
    /// (`shaders/multilevel.wgsl`); four-lane vectors. The symmetry the
    /// tests hold is that of the `f64` cycles.
    #[must_use]
    pub fn single(self) -> Self {
        let narrow = |values: &[f64]| values.iter().map(|&v| v as f32).collect();
        Self {
            single: Some((
                narrow(&self.values),
                narrow(&self.weighted_inverse_diagonal),
            )),
            factor: self.factor.single(),
            ..self
        }
    }

    /// Whether the cycles run in `f32` ([`Multilevel::single`]).
    pub fn is_single(&self) -> bool {
        self.single.is_some()
    }

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
        let (group, ordered) = grouped(rows, centres, cell * GROUP, max_groups, 0.0, |&w| w != 0.0);
        let factor = Cholesky::new(&ordered)?;
        Some(Self {
            starts,
            columns,
            values,
            weighted_inverse_diagonal,
            group,
            group_rows: ordered,
            factor,
            single: None,
        })
    }

    /// The aggregates' matrix `A` by rows: where each row starts in the
    /// other two (aggregates + 1), its columns and its values.
    pub fn matrix(&self) -> (&[usize], &[u32], &[f64]) {
        (&self.starts, &self.columns, &self.values)
    }

    /// [`JACOBI_WEIGHT`] over each diagonal entry of `A`.
    pub fn weighted_inverse_diagonal(&self) -> &[f64] {
        &self.weighted_inverse_diagonal
    }

    /// Per aggregate its group, numbered as the groups' factor numbers them.
    pub fn group(&self) -> &[u32] {
        &self.group
    }

    /// `Q^T A Q` factored within its envelope, the rows and columns a
    /// device's substitution reads (the host's own factor is sparse).
    /// `None` where a pivot is not positive, which the sparse factor
    /// [`Multilevel::new`] made rules out but for rounding.
    pub fn groups_envelope(&self) -> Option<Envelope> {
        Envelope::cholesky(&self.group_rows)
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
        if let Some((values, inverse_diagonal)) = &self.single {
            self.solve_single(values, inverse_diagonal, b);
            return;
        }
        let rhs = b.to_vec();
        // The first sweep from zero, whose residual is `b` itself.
        let mut x: Vec<DVec3> = rhs
            .par_iter()
            .zip(&self.weighted_inverse_diagonal)
            .map(|(b, &w)| *b * w)
            .collect();
        cycles(
            &mut x,
            |x| self.sweep(&rhs, x),
            |x| {
                let residual = self.residual(&rhs, x);
                let mut coarse = vec![DVec3::ZERO; self.groups()];
                for (&g, r) in self.group.iter().zip(&residual) {
                    coarse[g as usize] += *r;
                }
                self.factor.solve(&mut coarse);
                x.par_iter_mut()
                    .zip(&self.group)
                    .for_each(|(x, &g)| *x += coarse[g as usize]);
            },
        );
        b.copy_from_slice(&x);
    }

    /// [`Multilevel::solve`] in `f32`, the matrix `values` and the
    /// weighted inverse diagonal rounded ([`solve_single`]).
    fn solve_single(&self, values: &[f32], inverse_diagonal: &[f32], b: &mut [DVec3]) {
        let residual_at = |i: usize, rhs: &[Vec3A], x: &[Vec3A]| {
            let mut r = rhs[i];
            for k in self.row(i) {
                r -= x[self.columns[k] as usize] * values[k];
            }
            r
        };
        solve_single(
            b,
            &self.group,
            self.groups(),
            residual_at,
            |i, r| r * inverse_diagonal[i],
            |coarse| self.factor.solve(coarse),
        );
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

    /// One weighted Jacobi sweep: `x += w D^-1 (b - A x)`, each row's
    /// residual formed where it is used.
    fn sweep(&self, b: &[DVec3], x: &mut Vec<DVec3>) {
        let swept = (0..b.len())
            .into_par_iter()
            .map(|i| {
                let mut r = b[i];
                for k in self.row(i) {
                    r -= x[self.columns[k] as usize] * self.values[k];
                }
                x[i] + r * self.weighted_inverse_diagonal[i]
            })
            .collect();
        *x = swept;
    }
}

/// Power-iteration steps for the largest eigenvalue of `D^-1 A` that
/// sets [`BlockMultilevel`]'s Jacobi weight.
pub const WEIGHT_STEPS: usize = 20;

/// The margin on that estimate (power iteration approaches it from below).
pub const WEIGHT_MARGIN: f64 = 1.1;

/// [`Multilevel`]'s twin for the elastic phase's coarse system `P^T K P`
/// ([`crate::coarse::ElasticCoarse`]): a 3x3 block per pair of aggregates (three
/// unknowns, a translation, per aggregate), block Jacobi sweeps, and a
/// translation per group. The volume term couples an aggregate's axes
/// and reaches farther than the Laplacian, so `D^-1 A`'s spectrum is not
/// bounded by 2 as the Laplacian's is: the sweeps' weight is
/// [`JACOBI_WEIGHT`] scaled to its largest eigenvalue, estimated by
/// [`WEIGHT_STEPS`] power steps with [`WEIGHT_MARGIN`] (2/3 where that
/// eigenvalue is 2, as for a Laplacian). The same [`CYCLES`], [`SWEEPS`]
/// as the Laplacian's, groups of [`BLOCK_GROUP`]: a fixed, symmetric approximation of
/// `A^-1` (docs/METHOD.md, "Multilevel").
#[derive(Debug, Clone)]
pub struct BlockMultilevel {
    starts: Vec<usize>,
    columns: Vec<u32>,
    values: Vec<DMat3>,
    /// The weight times the inverse of each diagonal block.
    weighted_inverse_diagonal: Vec<DMat3>,
    /// Per aggregate, its group (in the factor's order).
    group: Vec<u32>,
    /// The scalar rows of `Q^T A Q` in that order, kept for a device's
    /// envelope factor ([`BlockMultilevel::groups_envelope`]).
    group_rows: Vec<Vec<(u32, f64)>>,
    /// The Cholesky factor of `Q^T A Q`, unknown `3 g + axis` for group `g`.
    factor: Cholesky,
    weight: f64,
    /// `values` and `weighted_inverse_diagonal` rounded to `f32`, where
    /// the cycles run in `f32` ([`BlockMultilevel::single`]).
    single: Option<(Vec<Mat3A>, Vec<Mat3A>)>,
}

impl BlockMultilevel {
    /// The same cycles in `f32`, for the solves made every iteration: the
    /// blocks, the sweeps' vectors and the groups' factor
    /// ([`Cholesky::single`]), as the GPU's twin runs them
    /// (`shaders/block_multilevel.wgsl`); four-lane products. The symmetry
    /// the tests hold is that of the `f64` cycles.
    #[must_use]
    pub fn single(self) -> Self {
        let narrow = |blocks: &[DMat3]| {
            blocks
                .par_iter()
                .map(|b| Mat3A::from(b.as_mat3()))
                .collect()
        };
        Self {
            single: Some((
                narrow(&self.values),
                narrow(&self.weighted_inverse_diagonal),
            )),
            factor: self.factor.single(),
            ..self
        }
    }

    /// Whether the cycles run in `f32` ([`BlockMultilevel::single`]).
    pub fn is_single(&self) -> bool {
        self.single.is_some()
    }

    /// The block rows of `A` (each sorted by column, both triangles), the
    /// aggregates' centres and the edge of their cells; the groups' cells
    /// grow (by 1.25) until there are at most `max_groups`. `None` where a
    /// diagonal block or the groups' matrix is not positive definite.
    pub fn new(
        rows: &[Vec<(u32, DMat3)>],
        centres: &[Vec3],
        cell: f32,
        max_groups: usize,
    ) -> Option<Self> {
        let n = rows.len();
        let mut starts = Vec::with_capacity(n + 1);
        starts.push(0);
        let (mut columns, mut values) = (Vec::new(), Vec::new());
        let (mut diagonals, mut inverse_diagonal) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for (i, row) in rows.iter().enumerate() {
            let mut diagonal = None;
            for &(j, block) in row {
                columns.push(j);
                values.push(block);
                if j as usize == i {
                    diagonal = Some(block);
                }
            }
            let diagonal = diagonal?;
            inverse_diagonal.push(positive_inverse(diagonal)?);
            diagonals.push(diagonal);
            starts.push(columns.len());
        }
        let mut space = Self {
            starts,
            columns,
            values,
            weighted_inverse_diagonal: inverse_diagonal,
            group: Vec::new(),
            group_rows: Vec::new(),
            factor: Cholesky::new(&[])?,
            weight: 1.0,
            single: None,
        };
        space.weight =
            JACOBI_WEIGHT * 2.0 / (WEIGHT_MARGIN * space.largest_jacobi_eigenvalue(&diagonals));
        for d in &mut space.weighted_inverse_diagonal {
            *d *= space.weight;
        }
        let (group, ordered) = grouped(
            rows,
            centres,
            cell * BLOCK_GROUP,
            max_groups,
            DMat3::ZERO,
            |_| true,
        );
        space.group_rows = scalar_rows(&ordered);
        space.factor = Cholesky::new(&space.group_rows)?;
        space.group = group;
        Some(space)
    }

    /// The aggregates' matrix `A` by block rows: where each row starts in
    /// the other two (aggregates + 1), its columns and its 3x3 blocks.
    pub fn matrix(&self) -> (&[usize], &[u32], &[DMat3]) {
        (&self.starts, &self.columns, &self.values)
    }

    /// The sweeps' weight times the inverse of each diagonal block of `A`.
    pub fn weighted_inverse_diagonal(&self) -> &[DMat3] {
        &self.weighted_inverse_diagonal
    }

    /// Per aggregate its group, numbered as the groups' factor numbers
    /// them (unknowns `3 g + axis`).
    pub fn group(&self) -> &[u32] {
        &self.group
    }

    /// `Q^T A Q` factored within its envelope, the rows and columns a
    /// device's substitution reads (the host's own factor is sparse).
    /// `None` where a pivot is not positive, which the sparse factor
    /// [`BlockMultilevel::new`] made rules out but for rounding.
    pub fn groups_envelope(&self) -> Option<Envelope> {
        Envelope::cholesky(&self.group_rows)
    }

    /// Number of aggregates.
    pub fn len(&self) -> usize {
        self.group.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.group.is_empty()
    }

    /// Number of groups (a third of the factored matrix's unknowns).
    pub fn groups(&self) -> usize {
        self.factor.len() / 3
    }

    /// The Jacobi sweeps' weight.
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// `b` (a translation per aggregate) replaced by the approximation of
    /// `A^-1 b` that [`CYCLES`] symmetric two-grid cycles from zero give.
    pub fn solve(&self, b: &mut [DVec3]) {
        if let Some((values, inverse_diagonal)) = &self.single {
            self.solve_single(values, inverse_diagonal, b);
            return;
        }
        let rhs = b.to_vec();
        let mut x: Vec<DVec3> = rhs
            .par_iter()
            .zip(&self.weighted_inverse_diagonal)
            .map(|(b, d)| *d * *b)
            .collect();
        cycles(
            &mut x,
            |x| self.sweep(&rhs, x),
            |x| {
                let residual = self.residual(&rhs, x);
                let mut coarse = vec![0.0f64; self.factor.len()];
                for (&g, r) in self.group.iter().zip(&residual) {
                    let g = 3 * g as usize;
                    coarse[g] += r.x;
                    coarse[g + 1] += r.y;
                    coarse[g + 2] += r.z;
                }
                self.factor.solve_scalar(&mut coarse);
                x.par_iter_mut().zip(&self.group).for_each(|(x, &g)| {
                    let g = 3 * g as usize;
                    *x += DVec3::new(coarse[g], coarse[g + 1], coarse[g + 2]);
                });
            },
        );
        b.copy_from_slice(&x);
    }

    /// [`BlockMultilevel::solve`] in `f32`, the blocks `values` and the
    /// weighted inverse diagonal rounded ([`solve_single`]).
    fn solve_single(&self, values: &[Mat3A], inverse_diagonal: &[Mat3A], b: &mut [DVec3]) {
        let residual_at = |i: usize, rhs: &[Vec3A], x: &[Vec3A]| {
            let product = (self.starts[i]..self.starts[i + 1])
                .map(|k| values[k] * x[self.columns[k] as usize])
                .fold(Vec3A::ZERO, |a, b| a + b);
            rhs[i] - product
        };
        solve_single(
            b,
            &self.group,
            self.groups(),
            residual_at,
            |i, r| inverse_diagonal[i] * r,
            |coarse| {
                let mut scalar: Vec<f64> = coarse.iter().flat_map(|v| v.to_array()).collect();
                self.factor.solve_scalar(&mut scalar);
                for (v, s) in coarse.iter_mut().zip(scalar.chunks_exact(3)) {
                    *v = DVec3::new(s[0], s[1], s[2]);
                }
            },
        );
    }

    /// `A x`.
    fn product(&self, x: &[DVec3]) -> Vec<DVec3> {
        (0..x.len())
            .into_par_iter()
            .map(|i| self.row_product(i, x))
            .collect()
    }

    /// Row `i` of `A x`.
    fn row_product(&self, i: usize, x: &[DVec3]) -> DVec3 {
        (self.starts[i]..self.starts[i + 1])
            .map(|k| self.values[k] * x[self.columns[k] as usize])
            .fold(DVec3::ZERO, |a, b| a + b)
    }

    /// `b - A x`.
    fn residual(&self, b: &[DVec3], x: &[DVec3]) -> Vec<DVec3> {
        self.product(x)
            .into_par_iter()
            .zip(b)
            .map(|(ax, b)| *b - ax)
            .collect()
    }

    /// One weighted block Jacobi sweep, each row's residual formed where
    /// it is used.
    fn sweep(&self, b: &[DVec3], x: &mut Vec<DVec3>) {
        let swept = (0..b.len())
            .into_par_iter()
            .map(|i| x[i] + self.weighted_inverse_diagonal[i] * (b[i] - self.row_product(i, x)))
            .collect();
        *x = swept;
    }

    /// The largest eigenvalue of `D^-1 A` (the diagonal blocks' inverses
    /// still unweighted), by power iteration in the `D` inner product from
    /// a fixed irregular start.
    fn largest_jacobi_eigenvalue(&self, diagonals: &[DMat3]) -> f64 {
        let n = diagonals.len();
        let mut x: Vec<DVec3> = (0..n)
            .map(|i| {
                let t = i as f64;
                DVec3::new(
                    (t * 0.618_034).fract() - 0.5,
                    (t * 0.414_214).fract() - 0.5,
                    (t * 0.732_051).fract() - 0.5,
                )
            })
            .collect();
        let mut estimate = 0.0;
        for _ in 0..WEIGHT_STEPS {
            let ax = self.product(&x);
            let y: Vec<DVec3> = ax
                .iter()
                .zip(&self.weighted_inverse_diagonal)
                .map(|(a, d)| *d * *a)
                .collect();
            // The Rayleigh quotient `x^T A x / x^T D x`.
            let (mut num, mut den) = (0.0, 0.0);
            for ((x, a), d) in x.iter().zip(&ax).zip(diagonals) {
                num += x.dot(*a);
                den += x.dot(*d * *x);
            }
            if den > 0.0 {
                estimate = f64::max(estimate, num / den);
            }
            let norm = y.iter().map(|v| v.length_squared()).sum::<f64>().sqrt();
            if norm.is_nan() || norm <= 0.0 {
                break;
            }
            x = y.into_iter().map(|v| v / norm).collect();
        }
        estimate.max(f64::MIN_POSITIVE)
    }
}

/// The inverse of a symmetric 3x3 block where it is positive definite.
fn positive_inverse(block: DMat3) -> Option<DMat3> {
    let (a, b) = (block.x_axis.x, block.y_axis.y);
    let minor = a * b - block.y_axis.x * block.x_axis.y;
    (a > 0.0 && minor > 0.0 && block.determinant() > 0.0).then(|| block.inverse())
}

/// The cycles' schedule, the same for every cycled solve (and the GPU's
/// `cycle_kernels`): from `x`, the first sweep from zero already made,
/// [`CYCLES`] times the sweeps before (one fewer in the first cycle), the
/// correction over the groups, and [`SWEEPS`] sweeps after.
fn cycles<V>(
    x: &mut Vec<V>,
    mut sweep: impl FnMut(&mut Vec<V>),
    mut correct: impl FnMut(&mut Vec<V>),
) {
    for cycle in 0..CYCLES {
        for _ in usize::from(cycle == 0)..SWEEPS {
            sweep(x);
        }
        correct(x);
        for _ in 0..SWEEPS {
            sweep(x);
        }
    }
}

/// The cycles of [`cycles`] in `f32` for the right-hand sides `b` (a
/// translation per aggregate), replaced by the answer: `residual_at(i,
/// rhs, x)` is row `i` of `rhs - A x`, `scale(i, r)` the weighted inverse
/// diagonal's product, and `solve_groups` solves the groups' matrix for
/// the residuals summed per group (in `f64`, aggregate `i` in `group[i]`
/// of `groups`). The twin of the GPU's `cycle_*` and `block_cycle_*`
/// kernels, which run in `f32` too.
fn solve_single(
    b: &mut [DVec3],
    group: &[u32],
    groups: usize,
    residual_at: impl Fn(usize, &[Vec3A], &[Vec3A]) -> Vec3A + Sync,
    scale: impl Fn(usize, Vec3A) -> Vec3A + Sync,
    solve_groups: impl Fn(&mut [DVec3]),
) {
    let rhs: Vec<Vec3A> = b.par_iter().map(|b| b.as_vec3a()).collect();
    // The first sweep from zero, whose residual is `b` itself.
    let mut x: Vec<Vec3A> = (0..rhs.len())
        .into_par_iter()
        .map(|i| scale(i, rhs[i]))
        .collect();
    cycles(
        &mut x,
        |x| {
            let swept = (0..rhs.len())
                .into_par_iter()
                .map(|i| x[i] + scale(i, residual_at(i, &rhs, x)))
                .collect();
            *x = swept;
        },
        |x| {
            let residual: Vec<Vec3A> = (0..rhs.len())
                .into_par_iter()
                .map(|i| residual_at(i, &rhs, x))
                .collect();
            let mut coarse = vec![DVec3::ZERO; groups];
            for (&g, r) in group.iter().zip(&residual) {
                coarse[g as usize] += r.as_dvec3();
            }
            solve_groups(&mut coarse);
            x.par_iter_mut()
                .zip(group)
                .for_each(|(x, &g)| *x += coarse[g as usize].as_vec3a());
        },
    );
    for (b, x) in b.iter_mut().zip(&x) {
        *b = x.as_dvec3();
    }
}

/// Block rows as scalar ones, three per block row: unknown `3 a + axis`.
pub(crate) fn scalar_rows(blocks: &[Vec<(u32, DMat3)>]) -> Vec<Vec<(u32, f64)>> {
    blocks
        .iter()
        .flat_map(|row| {
            (0..3).map(move |r| {
                row.iter()
                    .flat_map(|&(b, block)| {
                        (0..3).map(move |c| (3 * b + c as u32, block.col(c)[r]))
                    })
                    .collect()
            })
        })
        .collect()
}

/// The groups of the aggregates at `centres` (cells of edge `edge`,
/// grown by 1.25 until there are at most `max_groups`) and the
/// groups' Galerkin matrix `Q^T A Q` of `rows` (entries `keep` says are
/// not zero), both numbered in the reverse Cuthill-McKee order of the
/// groups' graph: per aggregate its group, and per group its sorted row.
fn grouped<T: Copy + std::ops::AddAssign>(
    rows: &[Vec<(u32, T)>],
    centres: &[Vec3],
    mut edge: f32,
    max_groups: usize,
    zero: T,
    keep: impl Fn(&T) -> bool,
) -> (Vec<u32>, Vec<Vec<(u32, T)>>) {
    let (mut group, mut count) = groups(centres, edge);
    while count > max_groups.max(1) {
        edge *= 1.25;
        (group, count) = groups(centres, edge);
    }
    let mut sums: Vec<HashMap<u32, T>> = vec![HashMap::new(); count];
    for (i, row) in rows.iter().enumerate() {
        let g = &mut sums[group[i] as usize];
        for &(j, w) in row {
            *g.entry(group[j as usize]).or_insert(zero) += w;
        }
    }
    let sums: Vec<Vec<(u32, T)>> = sums
        .into_iter()
        .map(|row| {
            let mut row: Vec<(u32, T)> = row.into_iter().filter(|(_, w)| keep(w)).collect();
            row.sort_unstable_by_key(|&(h, _)| h);
            row
        })
        .collect();
    let graph: Vec<Vec<(u32, f64)>> = sums
        .iter()
        .map(|row| row.iter().map(|&(h, _)| (h, 1.0)).collect())
        .collect();
    let order = reverse_cuthill_mckee(&graph);
    let mut rank = vec![0u32; count];
    for (k, &g) in order.iter().enumerate() {
        rank[g as usize] = k as u32;
    }
    let ordered = order
        .iter()
        .map(|&g| {
            let mut row: Vec<(u32, T)> = sums[g as usize]
                .iter()
                .map(|&(h, w)| (rank[h as usize], w))
                .collect();
            row.sort_unstable_by_key(|&(h, _)| h);
            row
        })
        .collect();
    (group.iter().map(|&g| rank[g as usize]).collect(), ordered)
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
        // Cells of 2 hold 8 nodes: 8^3 groups over 16^3 nodes.
        assert_eq!(multilevel.len(), 4_096);
        assert_eq!(multilevel.groups(), 512);
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

    /// `grid`'s Laplacian as 3x3 blocks, each connection stiffer along
    /// itself (`I + stretch d d^T`): an elastic-like operator whose blocks
    /// couple the axes.
    fn block_grid(side: usize, stretch: f64) -> (Vec<Vec<(u32, DMat3)>>, Vec<Vec3>) {
        let (rows, centres) = grid(side);
        let blocks = rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let mut diagonal = DMat3::from_diagonal(DVec3::splat(6.0));
                let mut out = Vec::new();
                for &(j, _) in row.iter().filter(|&&(j, _)| j as usize != i) {
                    let d = (centres[j as usize] - centres[i]).as_dvec3().normalize();
                    let edge =
                        DMat3::IDENTITY + stretch * DMat3::from_cols(d * d.x, d * d.y, d * d.z);
                    diagonal += edge - DMat3::IDENTITY;
                    out.push((j, -edge));
                }
                out.push((i as u32, diagonal));
                out.sort_unstable_by_key(|&(j, _)| j);
                out
            })
            .collect();
        (blocks, centres)
    }

    /// The Laplacian's cycles made for the iterations run in `f32` and
    /// solve as the `f64` cycles do, to single precision.
    #[test]
    fn the_single_precision_cycles_solve_as_the_double_ones() {
        let (rows, centres) = grid(12);
        let double = Multilevel::new(&rows, &centres, 1.0, 10_000).expect("definite");
        let single = double.clone().single();
        assert!(single.is_single() && !double.is_single());
        assert_solve_alike(
            |b| double.solve(b),
            |b| single.solve(b),
            field(rows.len(), 5.0),
        );
    }

    /// `double` and `single` solve `b` to single precision of each other,
    /// and not to the bit (the second did run in `f32`).
    fn assert_solve_alike(
        double: impl Fn(&mut [DVec3]),
        single: impl Fn(&mut [DVec3]),
        b: Vec<DVec3>,
    ) {
        let (mut x, mut y) = (b.clone(), b);
        double(&mut x);
        single(&mut y);
        let largest = x.iter().map(|v| v.length()).fold(0.0f64, f64::max);
        let apart = x
            .iter()
            .zip(&y)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0f64, f64::max);
        assert!(apart < 1e-5 * largest, "{apart} apart of {largest}");
        assert!(apart > 0.0, "the cycles did not run in single precision");
    }

    /// The cycles made for the iterations run in `f32` (blocks, vectors
    /// and the groups' factor) and solve as the `f64` cycles do, to single
    /// precision.
    #[test]
    fn the_single_precision_block_cycles_solve_as_the_double_ones() {
        let (rows, centres) = block_grid(12, 4.0);
        let double = BlockMultilevel::new(&rows, &centres, 1.0, 10_000).expect("definite");
        let single = double.clone().single();
        assert!(single.is_single() && !double.is_single());
        assert_solve_alike(
            |b| double.solve(b),
            |b| single.solve(b),
            field(rows.len(), 3.0),
        );
    }

    #[test]
    fn the_block_cycles_are_a_symmetric_approximate_inverse() {
        let (rows, centres) = block_grid(16, 4.0);
        let cycles = BlockMultilevel::new(&rows, &centres, 1.0, 10_000).expect("definite");
        assert_eq!((cycles.len(), cycles.groups()), (4_096, 216));
        // A block Laplacian: `D^-1 A`'s spectrum is within (0, 2], and the
        // weight found near the Laplacian's 2/3 (2/3 times 2 / (1.1 x its
        // estimate, 1.8 here)).
        assert!(
            (0.6..0.75).contains(&cycles.weight()),
            "{}",
            cycles.weight()
        );
        let product = |x: &[DVec3]| -> Vec<DVec3> {
            rows.iter()
                .map(|row| row.iter().map(|&(j, b)| b * x[j as usize]).sum())
                .collect()
        };
        let (x, y) = (field(4_096, 0.0), field(4_096, 17.0));
        let (mut bx, mut by) = (x.clone(), y.clone());
        cycles.solve(&mut bx);
        cycles.solve(&mut by);
        let (yx, xy) = (dot(&y, &bx), dot(&x, &by));
        assert!((yx - xy).abs() < 1e-10 * yx.abs().max(1.0), "{yx} vs {xy}");
        let left: Vec<DVec3> = product(&bx).iter().zip(&x).map(|(a, x)| *x - *a).collect();
        let ratio = (dot(&left, &left) / dot(&x, &x)).sqrt();
        // 0.18 measured: the axes coupled by a stretch of 4 converge more
        // slowly than the scalar Laplacian (under 0.1 above).
        assert!((1e-6..0.25).contains(&ratio), "|b - A B b| / |b| = {ratio}");
        // Positive: B approximates an SPD inverse (Chebyshev needs it).
        assert!(dot(&x, &bx) > 0.0 && dot(&y, &by) > 0.0);
    }
}
