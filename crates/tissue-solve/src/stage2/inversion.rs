//! Particles a solve turned inside out: the check that a converged solve
//! is also a plausible one.
//!
//! A particle's neighbourhood maps from rest to now by its least-squares
//! gradient `F_i = M_i A_i^-1` ([`crate::model::elastic`]); its local volume ratio
//! is `J_i = det F_i = det M_i / det A_i`. Tissue is never turned inside
//! out, so `J_i <= 0` means the solve found an impossible state (a surface
//! pushed through the organ, a frame with crossed vertices): the particle
//! is *inverted*. Only neighbourhoods that span three dimensions at rest
//! ([`crate::model::elastic::is_round`]) are judged; a flat one has no volume to
//! turn.

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use tissue_core::Connections;

use crate::model::elastic::{is_round, moment, moment_unit, offsets_product};

/// The local volume ratio at or below which a particle counts as inverted.
pub const INVERTED_VOLUME_RATIO: f32 = 0.0;

/// The inverted particles of one solve.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Inversions {
    /// How many particles have `J_i <= INVERTED_VOLUME_RATIO`.
    pub count: usize,
    /// The first of them (by index), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first: Option<usize>,
    /// The smallest `J_i` over every judged particle (1 at rest).
    pub min_volume_ratio: f32,
}

/// Judges every particle of `current` against `rest` (see the module's doc).
pub fn inversions(rest: &[Vec3], current: &[Vec3], connections: &Connections) -> Inversions {
    let ratios: Vec<Option<f32>> = (0..rest.len().min(current.len()))
        .into_par_iter()
        .map(|i| {
            let a = moment(rest, connections, i);
            if !is_round(a) {
                return None;
            }
            // Both in units of A's (is_round found it): a ratio of sixth
            // powers of lengths, formed where they stay in range.
            let unit = moment_unit(a)?;
            let m = offsets_product(rest, current, connections, i);
            Some((m / unit).determinant() / (a / unit).determinant())
        })
        .collect();
    // NaN (a non-finite particle) counts as inverted.
    let inverted = |r: &Option<f32>| r.is_some_and(|r| r.is_nan() || r <= INVERTED_VOLUME_RATIO);
    Inversions {
        count: ratios.iter().filter(|r| inverted(r)).count(),
        first: ratios.iter().position(inverted),
        min_volume_ratio: ratios
            .iter()
            .flatten()
            .fold(f32::INFINITY, |m, &r| m.min(r)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4x4x4 lattice of unit spacing, pairs within 1.8 connected.
    fn lattice() -> (Vec<Vec3>, Connections) {
        let mut positions = Vec::new();
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..4 {
                    positions.push(Vec3::new(x as f32, y as f32, z as f32));
                }
            }
        }
        let mut pairs = Vec::new();
        for i in 0..positions.len() {
            for j in i + 1..positions.len() {
                if positions[i].distance(positions[j]) < 1.8 {
                    pairs.push((i as u32, j as u32));
                }
            }
        }
        let connections = Connections::from_pairs(positions.len(), pairs);
        (positions, connections)
    }

    #[test]
    fn rigid_motions_and_stretches_invert_nothing() {
        let (rest, connections) = lattice();
        let turn = glam::Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 2.0);
        let moved: Vec<Vec3> = rest
            .iter()
            .map(|&p| turn * (p * Vec3::new(1.5, 0.7, 1.0)) + Vec3::splat(5.0))
            .collect();
        let judged = inversions(&rest, &moved, &connections);
        assert_eq!(judged.count, 0, "{judged:?}");
        assert!((judged.min_volume_ratio - 1.05).abs() < 1e-3, "{judged:?}");
        assert_eq!(inversions(&rest, &rest, &connections).min_volume_ratio, 1.0);
    }

    #[test]
    fn a_mirrored_region_is_inverted_and_named() {
        let (rest, connections) = lattice();
        // Mirror the half x >= 2 through x = 2: those neighbourhoods turn
        // inside out; the particles at x = 1 see their x = 2 neighbours
        // fold back onto x = 2 and their x = 0 ones in place.
        let moved: Vec<Vec3> = rest
            .iter()
            .map(|&p| {
                if p.x >= 2.0 {
                    Vec3::new(4.0 - p.x, p.y, p.z)
                } else {
                    p
                }
            })
            .collect();
        let judged = inversions(&rest, &moved, &connections);
        assert!(judged.count > 0, "{judged:?}");
        let first = judged.first.unwrap_or(usize::MAX);
        assert!(
            rest[first].x >= 2.0,
            "{judged:?}: particle {first} at {}",
            rest[first]
        );
        assert!(judged.min_volume_ratio < 0.0, "{judged:?}");
    }

    #[test]
    fn a_collapsed_particle_counts_and_a_non_finite_one_too() {
        let (rest, connections) = lattice();
        // Every particle on one point: J = 0 everywhere.
        let collapsed = vec![Vec3::ONE; rest.len()];
        let judged = inversions(&rest, &collapsed, &connections);
        let round = (0..rest.len())
            .filter(|&i| is_round(moment(&rest, &connections, i)))
            .count();
        assert_eq!(judged.count, round);
        let mut broken = rest.clone();
        broken[21] = Vec3::NAN;
        assert!(inversions(&rest, &broken, &connections).count > 0);
    }
}
