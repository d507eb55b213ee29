//! Twin of `shaders/pair.wgsl`: each paired particle's spring set towards
//! the observation at its nearest point (`tissue_solve::stage2::pairing`).

use tissue_core::field::SurfaceField;
use tissue_solve::stage2::{Pairing, Spring};

/// The shader this module is the twin of.
pub const SHADER: &str = "pair";

/// Writes into `springs` (one per particle) the spring of every particle
/// `pairing` pairs, from its position in `current` and its nearest point
/// on `field`; the others' springs are left as they are
/// ([`Pairing::pair_into`]).
pub fn pair(
    field: &SurfaceField,
    pairing: &Pairing,
    current: &[glam::Vec3],
    springs: &mut [Spring],
) {
    pairing.pair_into(field, current, springs);
}
