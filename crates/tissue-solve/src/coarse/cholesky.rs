//! The host's factor of a coarse matrix: a sparse Cholesky factor in a
//! fill-reducing order (approximate minimum degree, supernodal), from the
//! `faer` crate.
//!
//! The coarse matrices of this crate (the aggregates' Laplacian, the
//! elastic operator's `P^T K P`, the multipliers' coarse space, the groups
//! of the multilevel cycles) were factored within their envelope in reverse
//! Cuthill-McKee order ([`crate::coarse::envelope::Envelope`]), which fills the whole
//! band: at 10,000 particles the elastic matrix's 2,502 unknowns took 220
//! million multiply-adds, 100-160 ms on the development machine, made again
//! at every elastic phase's start. This factor takes 12-20 ms on the same
//! matrix and its substitutions read a tenth of the entries (docs/METHOD.md,
//! "The coarse factor"). The envelope stays for the devices: the GPU's
//! substitution reads its rows and columns (`shaders/coarse.wgsl`).
//!
//! Sequential (`Par::Seq`): the result does not depend on the thread count.
//!
//! A factor solved every iteration (the two-level solves' corrections) is
//! kept in `f32` ([`Cholesky::single`]): its substitutions, which read every
//! entry twice and are bound by memory, take a third of the time (1.2 ->
//! 0.4 ms on the elastic matrix at 10,000 particles, 635,000 entries), and
//! the correction they make is a step of the iteration, not its answer.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};
use glam::{DMat3, DVec3};

/// `L L^T = P A P^T` of a sparse symmetric positive definite matrix.
#[derive(Debug, Clone)]
pub struct Cholesky {
    /// The lower triangle's pattern, by columns (what [`Cholesky::refactor`]
    /// compares).
    pattern: Arc<SymbolicSparseColMat<u32>>,
    symbolic: Arc<SymbolicCholesky<u32>>,
    values: Values,
}

/// The factor's entries, in `f64` as factored or rounded to `f32`.
#[derive(Debug, Clone)]
enum Values {
    Double(Vec<f64>),
    Single(Vec<f32>),
}

impl Cholesky {
    /// Factors the symmetric positive definite matrix given by `rows`
    /// (each sorted by column, both triangles present, as
    /// [`crate::coarse::envelope::Envelope::cholesky`] takes it); `None` when it is
    /// not positive definite (or holds a value that is not finite).
    pub fn new(rows: &[Vec<(u32, f64)>]) -> Option<Self> {
        Self::of_upper(Upper::of_rows(rows)?, None, false)
    }

    /// Factors `rows` as [`Cholesky::new`] does, reusing this factor's
    /// order and symbolic analysis (a third of the work on the elastic
    /// coarse matrix at 10,000 particles) where `rows` has this factor's
    /// pattern, as a new linearisation over the same aggregates does; from
    /// the start otherwise.
    pub fn refactor(&self, rows: &[Vec<(u32, f64)>]) -> Option<Self> {
        Self::of_upper(Upper::of_rows(rows)?, Some(self), false)
    }

    /// [`Cholesky::new`] or [`Cholesky::refactor`] (where `previous` is
    /// given) for a factor only ever solved in `f32` ([`Cholesky::single`]):
    /// the numeric factorization itself runs in `f32`, where it finds the
    /// matrix positive definite, and in `f64` (then rounded) where not.
    pub fn single_of(rows: &[Vec<(u32, f64)>], previous: Option<&Self>) -> Option<Self> {
        Self::of_upper(Upper::of_rows(rows)?, previous, true)
    }

    /// The factor of the matrix given by block rows, three unknowns a block
    /// row (`3 a + axis`), each sorted by block column: the same factor as
    /// of their scalar rows ([`crate::coarse::multilevel::scalar_rows`]), made
    /// without them. Only the blocks on and above the diagonal are read,
    /// so the blocks below may be left out. `previous` and `single` as in
    /// [`Cholesky::refactor`] and [`Cholesky::single_of`].
    pub(crate) fn of_blocks(
        blocks: &[Vec<(u32, DMat3)>],
        previous: Option<&Self>,
        single: bool,
    ) -> Option<Self> {
        Self::of_upper(Upper::of_blocks(blocks)?, previous, single)
    }

    /// `upper` factored in `f64`, or for `single` in `f32` where that finds
    /// it positive definite and in `f64` (then rounded) where not.
    fn of_upper(upper: Upper, previous: Option<&Self>, single: bool) -> Option<Self> {
        if !single {
            return Self::factored(&upper, previous, false);
        }
        Self::factored(&upper, previous, true)
            .or_else(|| Self::factored(&upper, previous, false).map(Self::single))
    }

    fn factored(upper: &Upper, previous: Option<&Self>, single: bool) -> Option<Self> {
        let n = upper.col_ptr.len() - 1;
        let (col_ptr, row_idx, values) = (&upper.col_ptr, &upper.row_idx, &upper.values);
        let same = previous.filter(|p| {
            p.pattern.col_ptr() == col_ptr.as_slice() && p.pattern.row_idx() == row_idx.as_slice()
        });
        let (pattern, symbolic) = match same {
            Some(p) => (Arc::clone(&p.pattern), Arc::clone(&p.symbolic)),
            None => {
                let pattern =
                    SymbolicSparseColMat::new_checked(n, n, col_ptr.clone(), None, row_idx.clone());
                let symbolic = factorize_symbolic_cholesky(
                    pattern.as_ref(),
                    Side::Lower,
                    SymmetricOrdering::Amd,
                    Default::default(),
                )
                .ok()?;
                (Arc::new(pattern), Arc::new(symbolic))
            }
        };
        let values = if single {
            let narrow: Vec<f32> = values.iter().map(|&v| v as f32).collect();
            Values::Single(numeric(&pattern, &symbolic, &narrow)?)
        } else {
            Values::Double(numeric(&pattern, &symbolic, values)?)
        };
        Some(Self {
            pattern,
            symbolic,
            values,
        })
    }

    /// The same factor with its entries rounded to `f32`, for solves made
    /// every iteration: right-hand sides and answers stay `f64`, the
    /// substitutions run in `f32` (relative error about the matrix's
    /// condition number times 6e-8) and read half the memory.
    #[must_use]
    pub fn single(self) -> Self {
        let values = match self.values {
            Values::Double(values) => Values::Single(values.iter().map(|&v| v as f32).collect()),
            single @ Values::Single(_) => single,
        };
        Self { values, ..self }
    }

    /// Whether the entries are kept in `f32` ([`Cholesky::single`]).
    pub fn is_single(&self) -> bool {
        matches!(self.values, Values::Single(_))
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.symbolic.nrows()
    }

    /// Whether the factor has no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entries of the factor (its supernodes' dense blocks included).
    pub fn entries(&self) -> usize {
        match &self.values {
            Values::Double(values) => values.len(),
            Values::Single(values) => values.len(),
        }
    }

    /// Solves `A x = b` in place for one right-hand side.
    pub fn solve_scalar(&self, b: &mut [f64]) {
        self.solve_columns(b, 1);
    }

    /// Solves `A x = b` in place for three right-hand sides at once.
    pub fn solve(&self, b: &mut [DVec3]) {
        let n = b.len();
        let mut columns = vec![0.0; 3 * n];
        for (i, v) in b.iter().enumerate() {
            (columns[i], columns[n + i], columns[2 * n + i]) = (v.x, v.y, v.z);
        }
        self.solve_columns(&mut columns, 3);
        for (i, v) in b.iter_mut().enumerate() {
            *v = DVec3::new(columns[i], columns[n + i], columns[2 * n + i]);
        }
    }

    /// `columns` holds `count` right-hand sides one after the other.
    fn solve_columns(&self, columns: &mut [f64], count: usize) {
        let n = self.len();
        assert_eq!(
            columns.len(),
            n * count,
            "right-hand sides of the factor's size"
        );
        if n == 0 {
            return;
        }
        match &self.values {
            Values::Double(values) => substitute(&self.symbolic, values, columns, n, count),
            Values::Single(values) => {
                let mut narrow: Vec<f32> = columns.iter().map(|&v| v as f32).collect();
                substitute(&self.symbolic, values, &mut narrow, n, count);
                for (wide, &v) in columns.iter_mut().zip(&narrow) {
                    *wide = f64::from(v);
                }
            }
        }
    }
}

/// A symmetric matrix's upper triangle by rows, which is its lower
/// triangle by columns (what the factorization reads): row `i`'s columns
/// and values are `col_ptr[i]..col_ptr[i + 1]` of `row_idx` and `values`,
/// ascending from the diagonal.
#[derive(Debug)]
struct Upper {
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    values: Vec<f64>,
}

impl Upper {
    /// The upper triangle of `rows` (each sorted by column); `None` where a
    /// column is out of range, a value is not finite or a row not sorted.
    fn of_rows(rows: &[Vec<(u32, f64)>]) -> Option<Self> {
        let n = rows.len();
        let valid = rows.iter().all(|row| {
            row.iter().all(|&(j, w)| (j as usize) < n && w.is_finite())
                && row.windows(2).all(|pair| pair[0].0 < pair[1].0)
        });
        if !valid {
            return None;
        }
        let mut upper = Self::with_rows(n);
        for (i, row) in rows.iter().enumerate() {
            for &(j, w) in row.iter().filter(|&&(j, _)| j as usize >= i) {
                upper.row_idx.push(j);
                upper.values.push(w);
            }
            upper.end_row()?;
        }
        Some(upper)
    }

    /// The upper triangle of the scalar rows of `blocks` (block row `a`
    /// holds unknowns `3 a + axis`; each sorted by block column), read
    /// from the blocks on and above the diagonal; `None` as
    /// [`Upper::of_rows`].
    fn of_blocks(blocks: &[Vec<(u32, DMat3)>]) -> Option<Self> {
        let count = blocks.len();
        let valid = blocks.iter().all(|row| {
            row.iter()
                .all(|&(b, block)| (b as usize) < count && block.is_finite())
                && row.windows(2).all(|pair| pair[0].0 < pair[1].0)
        });
        if !valid {
            return None;
        }
        let mut upper = Self::with_rows(3 * count);
        for (a, row) in blocks.iter().enumerate() {
            let above = &row[row.partition_point(|&(b, _)| (b as usize) < a)..];
            for axis in 0..3 {
                let i = 3 * a + axis;
                for &(b, block) in above {
                    for c in 0..3 {
                        let j = 3 * b as usize + c;
                        if j >= i {
                            upper.row_idx.push(j as u32);
                            upper.values.push(block.col(c)[axis]);
                        }
                    }
                }
                upper.end_row()?;
            }
        }
        Some(upper)
    }

    fn with_rows(n: usize) -> Self {
        let mut col_ptr = Vec::with_capacity(n + 1);
        col_ptr.push(0);
        Self {
            col_ptr,
            row_idx: Vec::new(),
            values: Vec::new(),
        }
    }

    /// Closes the row being written; `None` past `u32`'s entries.
    fn end_row(&mut self) -> Option<()> {
        self.col_ptr.push(u32::try_from(self.row_idx.len()).ok()?);
        Some(())
    }
}

/// The numeric factor of the lower triangle `lower` (of `pattern`) in
/// `symbolic`'s order; `None` where it is not positive definite.
fn numeric<T: faer::traits::RealField>(
    pattern: &SymbolicSparseColMat<u32>,
    symbolic: &SymbolicCholesky<u32>,
    lower: &[T],
) -> Option<Vec<T>> {
    let lower = SparseColMatRef::new(pattern.as_ref(), lower);
    let mut factor = vec![T::zero_impl(); symbolic.len_val()];
    let mut scratch = MemBuffer::try_new(
        symbolic.factorize_numeric_llt_scratch::<T>(Par::Seq, Default::default()),
    )
    .ok()?;
    symbolic
        .factorize_numeric_llt(
            &mut factor,
            lower,
            Side::Lower,
            Default::default(),
            Par::Seq,
            MemStack::new(&mut scratch),
            Default::default(),
        )
        .ok()?;
    Some(factor)
}

/// The forward and back substitutions of the factor `values` (of
/// `symbolic`'s pattern) on `count` columns of `n` rows, in place.
fn substitute<T: faer::traits::RealField>(
    symbolic: &SymbolicCholesky<u32>,
    values: &[T],
    columns: &mut [T],
    n: usize,
    count: usize,
) {
    let mut scratch = MemBuffer::new(symbolic.solve_in_place_scratch::<T>(count, Par::Seq));
    LltRef::new(symbolic, values).solve_in_place_with_conj(
        Conj::No,
        MatMut::from_column_major_slice_mut(columns, n, count),
        Par::Seq,
        MemStack::new(&mut scratch),
    );
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;
    use crate::coarse::envelope::Envelope;

    /// The Laplacian of a `side^3` grid, 6-connected, plus `shift` on the
    /// diagonal, as rows sorted by column.
    fn grid_rows(side: usize, shift: f64) -> Vec<Vec<(u32, f64)>> {
        let index = |x: usize, y: usize, z: usize| ((z * side + y) * side + x) as u32;
        let mut rows = Vec::new();
        for z in 0..side {
            for y in 0..side {
                for x in 0..side {
                    let mut row = vec![(index(x, y, z), shift)];
                    let mut add = |j: u32| {
                        row.push((j, -1.0));
                        row[0].1 += 1.0;
                    };
                    if x > 0 {
                        add(index(x - 1, y, z));
                    }
                    if x + 1 < side {
                        add(index(x + 1, y, z));
                    }
                    if y > 0 {
                        add(index(x, y - 1, z));
                    }
                    if y + 1 < side {
                        add(index(x, y + 1, z));
                    }
                    if z > 0 {
                        add(index(x, y, z - 1));
                    }
                    if z + 1 < side {
                        add(index(x, y, z + 1));
                    }
                    row.sort_unstable_by_key(|&(j, _)| j);
                    rows.push(row);
                }
            }
        }
        rows
    }

    fn product(rows: &[Vec<(u32, f64)>], x: &[f64]) -> Vec<f64> {
        rows.iter()
            .map(|row| row.iter().map(|&(j, w)| w * x[j as usize]).sum())
            .collect()
    }

    #[test]
    fn it_solves_what_the_envelope_solves_with_fewer_entries() {
        let rows = grid_rows(12, 0.01);
        let sparse = Cholesky::new(&rows).expect("positive definite");
        let envelope = Envelope::cholesky(&rows).expect("positive definite");
        let n = rows.len();
        let b: Vec<f64> = (0..n).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        let (mut x, mut y) = (b.clone(), b.clone());
        sparse.solve_scalar(&mut x);
        envelope.solve_scalar(&mut y);
        let residual = product(&rows, &x)
            .iter()
            .zip(&b)
            .map(|(ax, b)| (ax - b).abs())
            .fold(0.0, f64::max);
        assert!(residual < 1e-9, "residual {residual}");
        let apart = x
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(apart < 1e-8, "the two factors' solutions {apart} apart");
        let envelope_entries = (0..n).map(|i| envelope.row(i).1.len()).sum::<usize>();
        assert!(
            2 * sparse.entries() < envelope_entries,
            "{} entries against the envelope's {envelope_entries}",
            sparse.entries()
        );
    }

    #[test]
    fn three_right_hand_sides_are_three_scalar_solves() {
        let rows = grid_rows(5, 0.5);
        let factor = Cholesky::new(&rows).expect("positive definite");
        let n = rows.len();
        let mut b: Vec<DVec3> = (0..n)
            .map(|i| DVec3::new(i as f64, (i % 7) as f64, 1.0))
            .collect();
        let mut columns: Vec<Vec<f64>> = (0..3)
            .map(|axis| b.iter().map(|v| v[axis]).collect())
            .collect();
        factor.solve(&mut b);
        for (axis, column) in columns.iter_mut().enumerate() {
            factor.solve_scalar(column);
            for (v, c) in b.iter().zip(column.iter()) {
                assert_eq!(v[axis], *c);
            }
        }
    }

    #[test]
    fn it_refuses_what_is_not_positive_definite() {
        assert!(Cholesky::new(&grid_rows(4, -0.5)).is_none());
        let mut rows = grid_rows(3, 0.1);
        rows[4][0].1 = f64::NAN;
        assert!(Cholesky::new(&rows).is_none());
        rows = grid_rows(3, 0.1);
        rows[2].push((99, 1.0));
        assert!(Cholesky::new(&rows).is_none());
        assert!(Cholesky::new(&[]).is_some_and(|f| f.is_empty()));
    }

    /// For a fixed right-hand side, the largest entry of `a`'s solution
    /// and the largest difference of `b`'s from it.
    fn solved_apart(a: &Cholesky, b: &Cholesky) -> (f64, f64) {
        let rhs: Vec<f64> = (0..a.len()).map(|i| ((i * 29) % 13) as f64 - 6.0).collect();
        let (mut x, mut y) = (rhs.clone(), rhs);
        a.solve_scalar(&mut x);
        b.solve_scalar(&mut y);
        let largest = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let apart = x
            .iter()
            .zip(&y)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
        (largest, apart)
    }

    #[test]
    fn a_single_precision_factor_solves_to_single_precision() {
        let rows = grid_rows(10, 0.05);
        let double = Cholesky::new(&rows).expect("positive definite");
        let single = double.clone().single();
        assert!(single.is_single() && !double.is_single());
        assert_eq!(single.entries(), double.entries());
        let (largest, apart) = solved_apart(&double, &single);
        // The grid's condition number is about 200: single precision
        // leaves some 1e-5 of the answer; a wrong factor would leave O(1).
        assert!(apart < 1e-4 * largest, "{apart} apart of {largest}");
        assert!(apart > 0.0, "the solve did not run in single precision");
    }

    #[test]
    fn a_refactored_matrix_of_the_same_pattern_reuses_the_analysis() {
        let rows = grid_rows(6, 0.1);
        let first = Cholesky::new(&rows).expect("positive definite");
        // The same pattern, other values: the analysis is shared.
        let scaled: Vec<Vec<(u32, f64)>> = rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                row.iter()
                    .map(|&(j, w)| (j, if j as usize == i { 2.0 * w + 1.0 } else { w }))
                    .collect()
            })
            .collect();
        let again = first.refactor(&scaled).expect("positive definite");
        assert!(Arc::ptr_eq(&first.symbolic, &again.symbolic));
        let fresh = Cholesky::new(&scaled).expect("positive definite");
        let b: Vec<f64> = (0..rows.len()).map(|i| (i % 5) as f64).collect();
        let (mut x, mut y) = (b.clone(), b);
        again.solve_scalar(&mut x);
        fresh.solve_scalar(&mut y);
        assert_eq!(x, y);
        // Another pattern: analysed anew.
        let other = first
            .refactor(&grid_rows(5, 0.1))
            .expect("positive definite");
        assert!(!Arc::ptr_eq(&first.symbolic, &other.symbolic));
        assert_eq!(other.len(), 125);
    }

    /// The grid's rows as 3x3 blocks on three unknowns a node, the axes
    /// coupled by `coupling` within each node's diagonal block (positive
    /// definite below a coupling of `0.1 / sqrt(2)`).
    fn grid_blocks(side: usize, coupling: f64) -> Vec<Vec<(u32, DMat3)>> {
        let couple = DMat3::from_cols_array(&[
            0.0, coupling, 0.0, //
            coupling, 0.0, coupling, //
            0.0, coupling, 0.0,
        ]);
        grid_rows(side, 0.1)
            .iter()
            .enumerate()
            .map(|(i, row)| {
                row.iter()
                    .map(|&(j, w)| {
                        let block = DMat3::from_diagonal(glam::DVec3::splat(w));
                        (
                            j,
                            if j as usize == i {
                                block + couple
                            } else {
                                block
                            },
                        )
                    })
                    .collect()
            })
            .collect()
    }

    /// Block rows factor as their scalar rows do, with or without the
    /// blocks below the diagonal, in `f64` and in `f32`; what is not a
    /// matrix is refused.
    #[test]
    fn a_factor_of_block_rows_is_the_factor_of_their_scalar_rows() {
        let blocks = grid_blocks(4, 0.05);
        let upper: Vec<Vec<(u32, DMat3)>> = blocks
            .iter()
            .enumerate()
            .map(|(a, row)| {
                row.iter()
                    .copied()
                    .filter(|&(b, _)| b as usize >= a)
                    .collect()
            })
            .collect();
        let rows = crate::coarse::multilevel::scalar_rows(&blocks);
        let b: Vec<f64> = (0..rows.len()).map(|i| (i % 7) as f64 - 3.0).collect();
        let solved = |factor: &Cholesky| {
            let mut x = b.clone();
            factor.solve_scalar(&mut x);
            x
        };
        let expected = solved(&Cholesky::new(&rows).expect("positive definite"));
        let single = solved(&Cholesky::single_of(&rows, None).expect("positive definite"));
        for given in [&blocks, &upper] {
            let factor = Cholesky::of_blocks(given, None, false).expect("positive definite");
            assert_eq!(factor.len(), rows.len());
            assert_eq!(solved(&factor), expected);
            let again = Cholesky::of_blocks(given, Some(&factor), true).expect("positive definite");
            assert!(again.is_single() && Arc::ptr_eq(&factor.symbolic, &again.symbolic));
            assert_eq!(solved(&again), single);
        }
        let mut broken = blocks.clone();
        broken[1][0].1.x_axis.y = f64::NAN;
        assert!(Cholesky::of_blocks(&broken, None, false).is_none());
        let mut beyond = blocks.clone();
        beyond[0].push((
            u32::try_from(blocks.len()).expect("a small grid"),
            DMat3::IDENTITY,
        ));
        assert!(Cholesky::of_blocks(&beyond, None, false).is_none());
        let mut unsorted = blocks;
        unsorted[2].reverse();
        assert!(Cholesky::of_blocks(&unsorted, None, false).is_none());
    }

    #[test]
    fn a_factor_made_in_single_precision_solves_as_the_rounded_one() {
        let rows = grid_rows(10, 0.05);
        let rounded = Cholesky::new(&rows).expect("positive definite").single();
        let made = Cholesky::single_of(&rows, None).expect("positive definite");
        let again = Cholesky::single_of(&rows, Some(&made)).expect("positive definite");
        assert!(made.is_single() && again.is_single());
        assert!(Arc::ptr_eq(&made.symbolic, &again.symbolic));
        let (largest, apart) = solved_apart(&rounded, &made);
        assert!(apart < 1e-4 * largest, "{apart} apart of {largest}");
        // Positive definite in `f64` only: its off-diagonal rounds to 1 in
        // `f32`, so it is factored in `f64` and rounded.
        let near = 1.0 - 1e-9;
        let singular_in_f32 = vec![vec![(0, 1.0), (1, near)], vec![(0, near), (1, 1.0)]];
        let upper = Upper::of_rows(&singular_in_f32).expect("valid rows");
        assert!(Cholesky::factored(&upper, None, true).is_none());
        let factor = Cholesky::single_of(&singular_in_f32, None).expect("positive definite");
        assert!(factor.is_single());
    }
}
