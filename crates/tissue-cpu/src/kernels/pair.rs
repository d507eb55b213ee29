//! Twin of `shaders/pair.wgsl`: each paired particle's spring set towards
//! the observation's plane at its nearest point
//! (`tissue_solve::stage2::pairing`).

use glam::{Vec3, Vec4};
use rayon::prelude::*;
use tissue_core::field::SurfaceField;
use tissue_solve::stage2::{Pairing, paired_spring, pairing_plane};

/// The shader this module is the twin of.
pub const SHADER: &str = "pair";

/// Writes into `springs` (one per particle) the spring of every particle
/// `pairing` pairs, from its position in `current` and its nearest point
/// on `field`; the others' springs are left as they are.
pub fn pair(field: &SurfaceField, pairing: &Pairing, current: &[Vec3], springs: &mut [Vec4]) {
    let paired: Vec<Vec4> = pairing
        .skin
        .par_iter()
        .map(|&i| {
            let x = current[i as usize];
            let (point, normal) = pairing_plane(field, x, &pairing.rule);
            paired_spring(x, point, normal, &pairing.rule)
        })
        .collect();
    for (&i, spring) in pairing.skin.iter().zip(paired) {
        springs[i as usize] = spring;
    }
}
