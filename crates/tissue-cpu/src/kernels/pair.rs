//! Twin of `shaders/pair.wgsl`: each paired particle's spring set towards
//! the observation at its nearest point (`tissue_solve::stage2::pairing`).

use rayon::prelude::*;
use tissue_core::field::SurfaceField;
use tissue_solve::stage2::{Pairing, Spring, paired_point, paired_spring};

/// The shader this module is the twin of.
pub const SHADER: &str = "pair";

/// Writes into `springs` (one per particle) the spring of every particle
/// `pairing` pairs, from its position in `current` and its nearest point
/// on `field`; the others' springs are left as they are.
pub fn pair(
    field: &SurfaceField,
    pairing: &Pairing,
    current: &[glam::Vec3],
    springs: &mut [Spring],
) {
    let paired: Vec<Spring> = pairing
        .skin
        .par_iter()
        .map(|&i| {
            let x = current[i as usize];
            paired_spring(x, &paired_point(field, x, &pairing.rule), &pairing.rule)
        })
        .collect();
    for (&i, spring) in pairing.skin.iter().zip(paired) {
        springs[i as usize] = spring;
    }
}
