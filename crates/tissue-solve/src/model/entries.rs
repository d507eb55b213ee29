//! The elastic operator's volume part per connection slot, for the CPU's
//! products with `K` ([`crate::coarse::elastic::ElasticCoarse`], the volume smoother).

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use tissue_core::Connections;

use crate::coarse::aggregates::OUTSIDE;

/// `Elastic::mirrors`' entry for a connection its neighbour does not list.
pub const NO_MIRROR: u32 = u32::MAX;

/// The elastic operator for a small displacement, rotations held, at one
/// state: `K = L + 1/2 sum_i W_i g_i g_i^T` with `g_i` the gradient of `J_i`,
/// whose entry at neighbour `j` is `cof(F_i) c_ij
/// = [cof(F_i) B_i] d_ij + [a_i cof(F_i)] (mu_j - mu_i)` and minus their sum
/// at `i` (the Gauss-Newton part; the `(J_i - 1)` second derivative is left
/// out, small where every neighbourhood is near its rest volume).
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeLinearisation {
    /// `W_i`.
    pub weights: Vec<f64>,
    /// `cof(F_i) B_i` (zero where flat).
    pub corrections: Vec<DMat3>,
    /// `a_i cof(F_i)`.
    pub scales: Vec<DMat3>,
    /// `mu_i`.
    pub multipliers: Vec<DVec3>,
}

impl VolumeLinearisation {
    /// `g_i`'s entry at neighbour `j`.
    #[inline]
    pub fn entry(&self, rest: &[Vec3], i: usize, j: usize) -> DVec3 {
        self.corrections[i] * (rest[j] - rest[i]).as_dvec3()
            + self.scales[i] * (self.multipliers[j] - self.multipliers[i])
    }

    /// `K u` over the particles `inside` says (others read as zero; their
    /// rows are zero).
    pub fn operator(
        &self,
        rest: &[Vec3],
        connections: &Connections,
        inside: impl Fn(usize) -> bool + Sync,
        u: &[DVec3],
    ) -> Vec<DVec3> {
        let at = |i: usize| if inside(i) { u[i] } else { DVec3::ZERO };
        // Per particle `z_i = W_i (g_i . u)`.
        let z: Vec<f64> = (0..rest.len())
            .into_par_iter()
            .map(|i| {
                if self.weights[i] == 0.0 {
                    return 0.0;
                }
                let change: f64 = connections
                    .of(i)
                    .iter()
                    .map(|&j| (at(j as usize) - at(i)).dot(self.entry(rest, i, j as usize)))
                    .sum();
                self.weights[i] * change
            })
            .collect();
        (0..rest.len())
            .into_par_iter()
            .map(|k| {
                if !inside(k) {
                    return DVec3::ZERO;
                }
                // The Laplacian's part and `1/2 sum_i z_i g_i` at `k`,
                // gathered: `g_i`'s entry at `k`, and `g_k`'s at `k` minus
                // the sum of its own.
                let mut r = DVec3::ZERO;
                for &i in connections.of(k) {
                    let i = i as usize;
                    let (into_k, out_of_k) = (self.entry(rest, i, k), self.entry(rest, k, i));
                    r += (at(k) - at(i)) + 0.5 * (z[i] * into_k - z[k] * out_of_k);
                }
                r
            })
            .collect()
    }
}

/// `K`'s volume part per connection slot (`connections.indices`' order):
/// `g_i`'s entry at `j` in the slot of `j` in `i`'s row, and in the same
/// slot the mirrored one, `g_j`'s entry at `i`. Made once per
/// linearisation, so that a product with `K` reads vectors where it would
/// multiply two matrices per connection. Kept in `f32` (the passes that
/// read them compute in `f64`): they are read every pass over the
/// connections, and `K`, a linearisation, stays exactly symmetric, since
/// a slot and its mirror hold the same rounded number.
#[derive(Debug, Clone)]
pub(crate) struct Entries {
    /// `g_i`'s entry at `j`, in the slot of `j` in `i`'s row.
    pub(crate) own: Vec<Vec3>,
    /// `g_j`'s entry at `i`, in the same slot.
    pub(crate) mirrored: Vec<Vec3>,
    /// Per particle `i` the sum of its own entries (`g_i`'s entry at `i` is
    /// minus it), so that a gather of `sum_j y_j g_j` at `i` reads the
    /// mirrored slots alone.
    pub(crate) sums: Vec<DVec3>,
}

impl Entries {
    /// The entries of `linearisation` over `connections`, whose mirrored
    /// slots are `mirrors`.
    pub(crate) fn new(
        rest: &[Vec3],
        connections: &Connections,
        mirrors: &[u32],
        linearisation: &VolumeLinearisation,
    ) -> Self {
        let (own, _) = own_entries(rest, connections, linearisation, None);
        Self::of_own(own, connections, mirrors)
    }

    /// The entries from `g_i`'s own ones ([`own_entries`]): the mirrored
    /// slots and each particle's sum.
    pub(crate) fn of_own(own: Vec<Vec3>, connections: &Connections, mirrors: &[u32]) -> Self {
        // Connections are symmetric (checked where a model is validated); a
        // missing mirror reads as no coupling.
        let mirrored: Vec<Vec3> = mirrors
            .par_iter()
            .map(|&m| {
                if m == NO_MIRROR {
                    Vec3::ZERO
                } else {
                    own[m as usize]
                }
            })
            .collect();
        let sums = (0..connections.offsets.len().saturating_sub(1))
            .into_par_iter()
            .map(|i| {
                own[slots(connections, i)]
                    .iter()
                    .map(|g| g.as_dvec3())
                    .sum()
            })
            .collect();
        Self {
            own,
            mirrored,
            sums,
        }
    }

    /// `K u` for the linearisation these are the entries of, whose volume
    /// weights are `weights`, over the particles `inside` says (others
    /// read as zero; their rows are zero).
    pub(crate) fn operator(
        &self,
        weights: &[f64],
        connections: &Connections,
        inside: impl Fn(usize) -> bool + Sync,
        u: &[DVec3],
    ) -> Vec<DVec3> {
        self.operator_then(weights, connections, inside, u, |_, k| k)
    }

    /// [`Entries::operator`] with `finish(k, (K u)_k)` made of each
    /// particle's row in the same pass (a step's residual, say).
    pub(crate) fn operator_then(
        &self,
        weights: &[f64],
        connections: &Connections,
        inside: impl Fn(usize) -> bool + Sync,
        u: &[DVec3],
        finish: impl Fn(usize, DVec3) -> DVec3 + Sync,
    ) -> Vec<DVec3> {
        // `u` read as zero outside, masked once rather than at each of the
        // connections' reads.
        let u: Vec<DVec3> = u
            .par_iter()
            .enumerate()
            .map(|(i, &u)| if inside(i) { u } else { DVec3::ZERO })
            .collect();
        let at = |i: usize| u[i];
        let slots = |i: usize| slots(connections, i);
        let Self {
            own,
            mirrored,
            sums,
        } = self;
        // Per particle `z_i = W_i (g_i . u)`.
        let z: Vec<f64> = (0..u.len())
            .into_par_iter()
            .map(|i| {
                if weights[i] == 0.0 {
                    return 0.0;
                }
                let (ui, range) = (at(i), slots(i));
                let change: f64 = connections.indices[range.clone()]
                    .iter()
                    .zip(&own[range])
                    .map(|(&j, g)| (at(j as usize) - ui).dot(g.as_dvec3()))
                    .sum();
                weights[i] * change
            })
            .collect();
        // The Laplacian's part and `1/2 sum_i z_i g_i` at `k`, gathered:
        // `g_i`'s entry at `k` is the mirrored slot, `g_k`'s at `k` minus
        // the sum of its own.
        (0..u.len())
            .into_par_iter()
            .map(|k| {
                if !inside(k) {
                    return finish(k, DVec3::ZERO);
                }
                let (uk, range) = (at(k), slots(k));
                let (mut laplacian, mut pressures) = (DVec3::ZERO, DVec3::ZERO);
                for (&i, h) in connections.indices[range.clone()]
                    .iter()
                    .zip(&mirrored[range])
                {
                    let i = i as usize;
                    laplacian += uk - at(i);
                    pressures += z[i] * h.as_dvec3();
                }
                finish(k, laplacian + 0.5 * (pressures - z[k] * sums[k]))
            })
            .collect()
    }
}

/// Per particle `P^T g_i`: the aggregates its volume gradient reaches and
/// the sum of its entries at each, in the order they were met (what the
/// elastic coarse matrix's assembly reads). Particle `i`'s are
/// `offsets[i]..offsets[i + 1]` of `items`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Parts {
    offsets: Vec<usize>,
    items: Vec<(u32, DVec3)>,
}

impl Parts {
    /// Particle `i`'s aggregates and sums.
    pub(crate) fn of(&self, i: usize) -> &[(u32, DVec3)] {
        &self.items[self.offsets[i]..self.offsets[i + 1]]
    }
}

/// Particles one task of [`own_entries`] takes.
const CHUNK: usize = 256;

/// `g_i`'s entry at `j` in the slot of `j` in `i`'s row, in `f32`
/// ([`Entries::own`]), and with `aggregate` (each particle's, or
/// [`OUTSIDE`]) each particle's [`Parts`] from the same entries in `f64`,
/// so that each is formed once (empty where it has no volume weight).
/// Chunk by chunk of particles, each task writing its rows in place and
/// its parts into a vector of its own.
pub(crate) fn own_entries(
    rest: &[Vec3],
    connections: &Connections,
    linearisation: &VolumeLinearisation,
    aggregate: Option<&[u32]>,
) -> (Vec<Vec3>, Parts) {
    let n = rest.len();
    let mut own = vec![Vec3::ZERO; connections.indices.len()];
    let mut pieces: Vec<&mut [Vec3]> = Vec::with_capacity(n.div_ceil(CHUNK));
    let mut left = own.as_mut_slice();
    for first in (0..n).step_by(CHUNK) {
        let last = n.min(first + CHUNK);
        let length = (connections.offsets[last] - connections.offsets[first]) as usize;
        let (piece, tail) = left.split_at_mut(length);
        pieces.push(piece);
        left = tail;
    }
    let weights = &linearisation.weights;
    // Each chunk's parts, its offsets from its own start.
    let chunks: Vec<Parts> = pieces
        .into_par_iter()
        .enumerate()
        .map(|(chunk, piece)| {
            let first = chunk * CHUNK;
            let base = connections.offsets[first] as usize;
            let Parts {
                mut offsets,
                mut items,
            } = Parts::default();
            for i in first..n.min(first + CHUNK) {
                let start = items.len();
                let parted = aggregate.filter(|_| weights[i] != 0.0);
                for (slot, &j) in slots(connections, i).zip(connections.of(i)) {
                    let g = linearisation.entry(rest, i, j as usize);
                    piece[slot - base] = g.as_vec3();
                    if let Some(aggregate) = parted {
                        for (a, v) in [(aggregate[j as usize], g), (aggregate[i], -g)] {
                            if a == OUTSIDE {
                                continue;
                            }
                            match items[start..].iter_mut().find(|(b, _)| *b == a) {
                                Some((_, w)) => *w += v,
                                None => items.push((a, v)),
                            }
                        }
                    }
                }
                if aggregate.is_some() {
                    offsets.push(items.len());
                }
            }
            Parts { offsets, items }
        })
        .collect();
    let mut parts = Parts::default();
    if aggregate.is_some() {
        parts.offsets.reserve(n + 1);
        parts.offsets.push(0);
        parts
            .items
            .reserve(chunks.iter().map(|chunk| chunk.items.len()).sum());
        for chunk in chunks {
            let base = parts.items.len();
            parts
                .offsets
                .extend(chunk.offsets.iter().map(|end| base + end));
            parts.items.extend(chunk.items);
        }
    }
    (own, parts)
}

/// The slots of particle `i`'s connections (where its entries are).
pub(crate) fn slots(connections: &Connections, i: usize) -> std::ops::Range<usize> {
    connections.offsets[i] as usize..connections.offsets[i + 1] as usize
}
