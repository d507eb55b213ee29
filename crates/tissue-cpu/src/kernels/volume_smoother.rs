//! Twin of `shaders/volume_smoother.wgsl`: the residual the volume smoother
//! starts from (`elastic_residual`, `smoother_residual`'s twin); the
//! smoothed step itself, written once for the host, is
//! `tissue_solve::coarse::ElasticCoarse::smoothed_step` (its
//! pressures' sweeps `tissue_solve::coarse::VolumeSmoother`).

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use tissue_solve::coarse::OUTSIDE;
use tissue_solve::stage2::Spring;

use crate::kernels::integrate::applied;

pub use tissue_solve::coarse::VolumeSmoother;

/// The shader this module is the twin of.
pub const SHADER: &str = "volume_smoother";

/// The elastic phase's residual for the volume smoother: half the force,
/// loads and springs' pulls included ([`crate::kernels::integrate::applied`]),
/// at the particles inside an aggregate (`K e = -r` for the error `e`
/// while the rotations are held), in `f64`; zero elsewhere.
pub fn elastic_residual(
    force: &[Vec3],
    current: &[Vec3],
    loads: &[Vec3],
    springs: &[Spring],
    aggregate: &[u32],
) -> Vec<DVec3> {
    force
        .par_iter()
        .zip(aggregate)
        .enumerate()
        .map(|(i, (&f, &a))| {
            if a == OUTSIDE {
                return DVec3::ZERO;
            }
            0.5 * (f + applied(i, current[i], loads, springs)).as_dvec3()
        })
        .collect()
}
