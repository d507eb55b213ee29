//! Sparse symmetric positive definite systems factored within their
//! envelope, in reverse Cuthill-McKee order: the form the devices'
//! one-workgroup substitutions read (the coarse Laplacian's factor, the
//! elastic coarse matrix's, the cycles' groups').

use std::collections::VecDeque;

/// An ordering of a graph's nodes that keeps its connections near the
/// diagonal: breadth-first from a node of least degree (for each component),
/// neighbours in order of degree, reversed (reverse Cuthill-McKee).
pub(crate) fn reverse_cuthill_mckee(rows: &[Vec<(u32, f64)>]) -> Vec<u32> {
    let n = rows.len();
    let degree = |a: usize| rows[a].len();
    let mut by_degree: Vec<usize> = (0..n).collect();
    by_degree.sort_by_key(|&a| degree(a));
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    for &start in &by_degree {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut queue = VecDeque::from([start]);
        while let Some(a) = queue.pop_front() {
            order.push(a as u32);
            let mut next: Vec<usize> = rows[a]
                .iter()
                .map(|&(b, _)| b as usize)
                .filter(|&b| !seen[b])
                .collect();
            next.sort_by_key(|&b| degree(b));
            for b in next {
                seen[b] = true;
                queue.push_back(b);
            }
        }
    }
    order.reverse();
    order
}

/// A lower-triangular Cholesky factor stored by rows within its envelope:
/// row `i` holds columns `first[i]..=i`, where `first[i]` is the row's first
/// nonzero in the matrix (Cholesky fills nothing outside the envelope).
/// `a . b` summed in four interleaved lanes, which the compiler turns into
/// vector instructions (one running sum would be a chain of dependent
/// additions); the order is fixed, so the result is the same on every run.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    lanes_dot(a, b)
}

/// `sum_k a_k b_k` for any right-hand side that scales and adds, in the
/// four lanes of [`dot`].
fn lanes_dot<T>(a: &[f64], b: &[T]) -> T
where
    T: Copy + Default + std::ops::Add<Output = T> + std::ops::Mul<f64, Output = T>,
{
    let mut lanes = [T::default(); 4];
    let (a_chunks, b_chunks) = (a.chunks_exact(4), b.chunks_exact(4));
    let (a_tail, b_tail) = (a_chunks.remainder(), b_chunks.remainder());
    for (a, b) in a_chunks.zip(b_chunks) {
        for k in 0..4 {
            lanes[k] = lanes[k] + b[k] * a[k];
        }
    }
    for (k, (&a, &b)) in a_tail.iter().zip(b_tail).enumerate() {
        lanes[k] = lanes[k] + b * a;
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
}

/// Built by [`Envelope::cholesky`]; read by the devices' coarse solves.
#[derive(Debug, Clone)]
pub struct Envelope {
    first: Vec<usize>,
    /// Where each row starts in `values`.
    start: Vec<usize>,
    values: Vec<f64>,
}

impl Envelope {
    /// Factors the symmetric positive definite matrix given by `rows`
    /// (each sorted by column, both triangles present); `None` when a pivot
    /// is not positive.
    pub fn cholesky(rows: &[Vec<(u32, f64)>]) -> Option<Self> {
        let n = rows.len();
        let first: Vec<usize> = rows
            .iter()
            .enumerate()
            .map(|(i, row)| row.first().map_or(i, |&(j, _)| (j as usize).min(i)))
            .collect();
        let mut start = Vec::with_capacity(n + 1);
        start.push(0);
        for i in 0..n {
            start.push(start[i] + i + 1 - first[i]);
        }
        let mut values = vec![0.0; start[n]];
        for (i, row) in rows.iter().enumerate() {
            for &(j, w) in row.iter().filter(|&&(j, _)| j as usize <= i) {
                values[start[i] + j as usize - first[i]] += w;
            }
        }
        for i in 0..n {
            for j in first[i]..=i {
                let from = first[i].max(first[j]);
                let mut s = values[start[i] + j - first[i]];
                let (ri, rj) = (
                    &values[start[i] + from - first[i]..start[i] + j - first[i]],
                    &values[start[j] + from - first[j]..start[j] + j - first[j]],
                );
                s -= dot(ri, rj);
                let entry = if j < i {
                    s / values[start[j] + j - first[j]]
                } else if s > 0.0 {
                    s.sqrt()
                } else {
                    return None;
                };
                values[start[i] + j - first[i]] = entry;
            }
        }
        Some(Self {
            first,
            start,
            values,
        })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.first.len()
    }

    /// Whether the factor has no rows.
    pub fn is_empty(&self) -> bool {
        self.first.is_empty()
    }

    /// Row `i`: its first column and its entries from there to the
    /// diagonal, the diagonal last.
    pub fn row(&self, i: usize) -> (usize, &[f64]) {
        (
            self.first[i],
            &self.values[self.start[i]..self.start[i + 1]],
        )
    }

    /// The strictly lower entries by column, for a substitution that
    /// sweeps columns: per column `j` (`starts[j]..starts[j + 1]`) the
    /// rows `i > j` whose envelope reaches it and `L_ij`.
    pub fn columns(&self) -> (Vec<u32>, Vec<u32>, Vec<f64>) {
        let n = self.len();
        let mut counts = vec![0u32; n + 1];
        for i in 0..n {
            for j in self.first[i]..i {
                counts[j + 1] += 1;
            }
        }
        for j in 0..n {
            counts[j + 1] += counts[j];
        }
        let total = counts[n] as usize;
        let (mut rows, mut values) = (vec![0u32; total], vec![0.0f64; total]);
        let mut next = counts.clone();
        for i in 0..n {
            let (first, row) = self.row(i);
            for (j, &l) in (first..i).zip(row) {
                let at = next[j] as usize;
                (rows[at], values[at]) = (i as u32, l);
                next[j] += 1;
            }
        }
        (counts, rows, values)
    }

    /// Solves `L L^T x = b` in place for three right-hand sides at once.
    #[cfg(test)]
    pub(crate) fn solve(&self, b: &mut [glam::DVec3]) {
        self.solve_in_place(b);
    }

    /// Solves `L L^T x = b` in place for one right-hand side.
    pub fn solve_scalar(&self, b: &mut [f64]) {
        self.solve_in_place(b);
    }

    /// The forward and backward substitutions, for any right-hand side
    /// that scales and subtracts.
    fn solve_in_place<T>(&self, b: &mut [T])
    where
        T: Copy
            + Default
            + std::ops::Add<Output = T>
            + std::ops::Sub<Output = T>
            + std::ops::SubAssign
            + std::ops::Mul<f64, Output = T>
            + std::ops::Div<f64, Output = T>,
    {
        let n = self.len();
        for i in 0..n {
            let row = &self.values[self.start[i]..self.start[i + 1]];
            let (off, diagonal) = row.split_at(row.len() - 1);
            b[i] = (b[i] - lanes_dot(off, &b[self.first[i]..i])) / diagonal[0];
        }
        for i in (0..n).rev() {
            let row = &self.values[self.start[i]..self.start[i + 1]];
            let (off, diagonal) = row.split_at(row.len() - 1);
            let x = b[i] / diagonal[0];
            b[i] = x;
            for (&l, y) in off.iter().zip(&mut b[self.first[i]..i]) {
                *y -= x * l;
            }
        }
    }
}
