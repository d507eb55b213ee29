//! The surface's samples solved in chains: sample `k` in chain `k %
//! SURFACE_CHAINS`, each chain a run of re-solves on a tracker of its own
//! that starts from the state the samples start from. A device whose state
//! copies ([`crate::stage2::SolveDevice::fork`], the CPU's) runs the chains
//! side by side; another runs them one after the other on its one
//! tracker, put back to that state before each. A sample's re-solve then
//! depends only on its chain, not on how many threads ran the chains
//! (`the_chains_give_the_same_columns_on_any_number_of_threads`).
//!
//! Side by side the chains fill each other's serial stretches (the coarse
//! factor's substitutions, the sums taken in order): on the development
//! machine's two cores a 10,000-particle estimate takes 11-21 % less time
//! with its 16 samples in two chains than in one (the medians of
//! alternating runs on the shared cases).

use glam::Vec3;
use rayon::prelude::*;
use tissue_core::Error;

use super::{Spread, Tracker};
use crate::stage2::tracker::SolveDevice;

/// Chains the surface's samples are solved in.
pub const SURFACE_CHAINS: usize = 2;

/// A re-solve of one sample on a chain's tracker: `(tracker, sample,
/// counted)`, the positions it ends at.
pub(super) type SampleSolve<'a, D, E> =
    dyn Fn(&mut Tracker<D>, usize, &mut Spread) -> Result<Vec<Vec3>, E> + Sync + 'a;

/// A chain's positions, sample after sample, and its re-solves counted.
type Chain = (Vec<Vec<Vec3>>, Spread);

impl Spread {
    /// Adds the re-solves `counted` counted apart ([`counting`]).
    pub(super) fn add_counted(&mut self, counted: &Spread) {
        self.solves += counted.solves;
        self.carried += counted.carried;
        self.iterations += counted.iterations;
        self.converged &= counted.converged;
    }
}

/// A spread with nothing in it yet: re-solves counted apart (a chain's,
/// or beside the chains) and then added to the spread's
/// ([`Spread::add_counted`]), or the spread's own start.
pub(super) fn counting() -> Spread {
    Spread {
        answer: Vec::new(),
        columns: Vec::new(),
        solves: 0,
        carried: 0,
        iterations: 0,
        converged: true,
        seconds: 0.0,
    }
}

/// Each of `count` samples' positions, in sample order: `solve(t, k,
/// counted)` re-solves sample `k` on tracker `t` (the tracker's chain's),
/// counting it in `counted`. The tracker is left where its own chain (the
/// first) ended.
pub(super) fn in_chains<D, E>(
    tracker: &mut Tracker<D>,
    count: usize,
    solve: &SampleSolve<'_, D, E>,
    spread: &mut Spread,
) -> Result<Vec<Vec<Vec3>>, E>
where
    D: SolveDevice + Send,
    E: From<Error> + From<D::Error> + Send,
{
    let chains = SURFACE_CHAINS.clamp(1, count.max(1));
    let run = |t: &mut Tracker<D>, chain: usize| -> Result<Chain, E> {
        let mut counted = counting();
        let mut solved = Vec::new();
        for k in (chain..count).step_by(chains) {
            solved.push(solve(t, k, &mut counted)?);
        }
        Ok((solved, counted))
    };
    let mut twins: Vec<Tracker<D>> = (1..chains).map_while(|_| tracker.fork()).collect();
    let ran: Vec<Result<Chain, E>> = if twins.len() + 1 == chains {
        let mut trackers: Vec<&mut Tracker<D>> = std::iter::once(&mut *tracker)
            .chain(twins.iter_mut())
            .collect();
        trackers
            .par_iter_mut()
            .enumerate()
            .map(|(chain, t)| run(t, chain))
            .collect()
    } else {
        // The last chain first, its own (the first) last: the tracker ends
        // where it would beside the others.
        let start = tracker.checkpoint()?;
        let mut ran: Vec<_> = (0..chains).map(|_| None).collect();
        for chain in (0..chains).rev() {
            tracker.back_to::<E>(start.clone())?;
            ran[chain] = Some(run(tracker, chain));
        }
        ran.into_iter().flatten().collect()
    };
    let mut by_chain = Vec::with_capacity(chains);
    for result in ran {
        let (solved, counted) = result?;
        spread.add_counted(&counted);
        by_chain.push(solved.into_iter());
    }
    let mut positions = Vec::with_capacity(count);
    for k in 0..count {
        positions.extend(by_chain[k % chains].next());
    }
    Ok(positions)
}
