//! The elastic operator's volume part per connection slot, for the CPU's
//! products with `K` ([`super::ElasticCoarse`], the volume smoother).

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use tissue_core::Connections;

use crate::elastic::{NO_MIRROR, VolumeLinearisation};

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
    pub(crate) fn new(
        rest: &[Vec3],
        connections: &Connections,
        mirrors: &[u32],
        linearisation: &VolumeLinearisation,
    ) -> Self {
        let slots = |i: usize| slots(connections, i);
        // Row by row into one vector (an indexed split: each thread
        // writes its own rows where they belong).
        let mut own = vec![Vec3::ZERO; connections.indices.len()];
        let mut rows: Vec<&mut [Vec3]> = Vec::with_capacity(rest.len());
        let mut left = own.as_mut_slice();
        for i in 0..rest.len() {
            let (row, tail) = left.split_at_mut(connections.of(i).len());
            rows.push(row);
            left = tail;
        }
        rows.into_par_iter().enumerate().for_each(|(i, row)| {
            for (g, &j) in row.iter_mut().zip(connections.of(i)) {
                *g = linearisation.entry(rest, i, j as usize).as_vec3();
            }
        });
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
        let sums = (0..rest.len())
            .into_par_iter()
            .map(|i| own[slots(i)].iter().map(|g| g.as_dvec3()).sum())
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
        let at = |i: usize| if inside(i) { u[i] } else { DVec3::ZERO };
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

/// The slots of particle `i`'s connections (where its entries are).
pub(crate) fn slots(connections: &Connections, i: usize) -> std::ops::Range<usize> {
    connections.offsets[i] as usize..connections.offsets[i + 1] as usize
}
