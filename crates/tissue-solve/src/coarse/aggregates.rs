//! The free particles grouped into aggregates, one per cell of a grid,
//! and the aggregates' weighted Laplacian: what the two-level solves (the
//! Laplacian's and the elastic phase's) are made of.

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use tissue_core::{Connections, DeformError, Error};

use crate::coarse::envelope::reverse_cuthill_mckee;

/// Marks a particle that belongs to no aggregate (a control point, or a
/// particle held because nothing connects it to the surface).
pub const OUTSIDE: u32 = u32::MAX;

/// The free particles grouped into aggregates (numbered in reverse
/// Cuthill-McKee order of the coarse graph) and the coarse Laplacian's rows
/// in that order: what the two-level solves share.
#[derive(Debug, Clone)]
pub struct Aggregates {
    /// Per particle: its aggregate, or [`OUTSIDE`].
    pub aggregate: Vec<u32>,
    /// The rows of `P^T L P`, each sorted by column.
    pub rows: Vec<Vec<(u32, f64)>>,
    /// The edge of the cells the aggregates were made of.
    pub cell: f32,
}

impl Aggregates {
    /// The aggregates of the free particles in grid cells of edge `cell`,
    /// grown (by factors of 1.25) until there are at most `max_aggregates`.
    pub fn new(
        rest: &[Vec3],
        connections: &Connections,
        free: &[bool],
        cell: f32,
        max_aggregates: usize,
    ) -> Result<Self, Error> {
        if !(cell > 0.0 && cell.is_finite()) {
            return Err(DeformError::CoarseSpace(format!(
                "the coarse space's cell is {cell}, expected a positive length"
            ))
            .into());
        }
        let (mut cell, mut aggregate, mut count) = (cell, Vec::new(), 0);
        for _ in 0..MAX_GROWTH {
            (aggregate, count) = aggregates(rest, connections, free, cell);
            if count <= max_aggregates.max(1) {
                break;
            }
            cell *= 1.25;
        }
        if count == 0 {
            return Err(DeformError::CoarseSpace(
                "the coarse space has no aggregates: no particle is free".into(),
            )
            .into());
        }
        let rows = coarse_laplacian(&aggregate, connections, count);
        let order = reverse_cuthill_mckee(&rows);
        let mut rank = vec![0u32; count];
        for (k, &a) in order.iter().enumerate() {
            rank[a as usize] = k as u32;
        }
        for a in aggregate.iter_mut().filter(|a| **a != OUTSIDE) {
            *a = rank[*a as usize];
        }
        let rows = order
            .iter()
            .map(|&a| {
                let mut row: Vec<(u32, f64)> = rows[a as usize]
                    .iter()
                    .map(|&(b, w)| (rank[b as usize], w))
                    .collect();
                row.sort_unstable_by_key(|&(b, _)| b);
                row
            })
            .collect();
        Ok(Self {
            aggregate,
            rows,
            cell,
        })
    }

    /// Number of aggregates.
    pub fn count(&self) -> usize {
        self.rows.len()
    }
}

/// Per aggregate the start of its particles in the member list (`count + 1`
/// entries), and the list, aggregate by aggregate, each in particle order
/// (what the devices restrict by).
pub fn members_of(aggregate: &[u32], count: usize) -> (Vec<u32>, Vec<u32>) {
    let mut starts = vec![0u32; count + 1];
    for &a in aggregate.iter().filter(|&&a| a != OUTSIDE) {
        starts[a as usize + 1] += 1;
    }
    for a in 0..count {
        starts[a + 1] += starts[a];
    }
    let mut next = starts.clone();
    let mut members = vec![0u32; starts[count] as usize];
    for (i, &a) in aggregate.iter().enumerate() {
        if a != OUTSIDE {
            members[next[a as usize] as usize] = i as u32;
            next[a as usize] += 1;
        }
    }
    (starts, members)
}

/// The centre of each aggregate's particles at rest.
pub(crate) fn centres(rest: &[Vec3], aggregate: &[u32], count: usize) -> Vec<Vec3> {
    let mut sums = vec![(DVec3::ZERO, 0u32); count];
    for (p, &a) in rest.iter().zip(aggregate) {
        if a != OUTSIDE {
            sums[a as usize].0 += p.as_dvec3();
            sums[a as usize].1 += 1;
        }
    }
    sums.iter()
        .map(|&(sum, n)| (sum / f64::from(n.max(1))).as_vec3())
        .collect()
}

/// Cells the coarse space grows by at most to stay within its aggregate
/// budget: `1.25^40`, 7,500 times the edge.
const MAX_GROWTH: usize = 40;

/// A free particle with fewer connections than this is an aggregate of its
/// own: its error barely reaches its neighbours (a low eigenvalue of the
/// Laplacian held at one particle), so an aggregate's constant would not
/// represent it, and the solve would wait on it.
const WEAK_DEGREE: usize = 4;

/// Per particle, the aggregate of the free ones in cells of edge `cell`,
/// weakly connected particles alone (numbered in order of first
/// appearance); and how many there are.
fn aggregates(
    rest: &[Vec3],
    connections: &Connections,
    free: &[bool],
    cell: f32,
) -> (Vec<u32>, usize) {
    let mut cells: HashMap<[i32; 3], u32> = HashMap::new();
    let mut count = 0u32;
    let aggregate = (0..rest.len())
        .map(|i| {
            if !free[i] {
                return OUTSIDE;
            }
            count += 1;
            if connections.of(i).len() < WEAK_DEGREE {
                return count - 1;
            }
            let key = (rest[i] / cell).floor().as_ivec3().to_array();
            let next = count - 1;
            let a = *cells.entry(key).or_insert(next);
            if a != next {
                count -= 1;
            }
            a
        })
        .collect();
    (aggregate, count as usize)
}

/// The rows of `P^T L P`: per aggregate, its diagonal (every connection
/// leaving its particles, control points included) and minus the number
/// of connections to each other aggregate, sorted by column.
fn coarse_laplacian(
    aggregate: &[u32],
    connections: &Connections,
    count: usize,
) -> Vec<Vec<(u32, f64)>> {
    let mut rows: Vec<HashMap<u32, f64>> = vec![HashMap::new(); count];
    for (i, &a) in aggregate.iter().enumerate() {
        if a == OUTSIDE {
            continue;
        }
        let row = &mut rows[a as usize];
        for &j in connections.of(i) {
            *row.entry(a).or_default() += 1.0;
            let b = aggregate[j as usize];
            if b != OUTSIDE {
                *row.entry(b).or_default() -= 1.0;
            }
        }
    }
    rows.into_iter()
        .map(|row| {
            let mut row: Vec<(u32, f64)> = row.into_iter().filter(|&(_, w)| w != 0.0).collect();
            row.sort_unstable_by_key(|&(b, _)| b);
            row
        })
        .collect()
}
