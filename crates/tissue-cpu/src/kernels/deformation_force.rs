//! Twin of `shaders/deformation_force.wgsl`: the paper's or the symmetric
//! force on every particle, gathered over its connections.

use glam::{Mat3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;
use tissue_core::Connections;
use tissue_solve::stage2::ForceModel;

/// The shader this module is the twin of.
pub const SHADER: &str = "deformation_force";

/// The force on every particle, gathered over its connections (the paper's
/// and the symmetric force; the elastic force is [`elastic_force`]).
pub fn deformation_force(
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
    connections: &Connections,
    model: ForceModel,
) -> Vec<Vec3> {
    (0..rest.len())
        .into_par_iter()
        .map(|j| {
            // In 4-lane vectors (`Vec3A`, `Mat3A`): the products and sums
            // `Vec3` makes, three at a time.
            let at = |v: &[Vec3], i: usize| Vec3A::from(v[i]);
            let (rj, cj, turn_j) = (at(rest, j), at(current, j), Mat3A::from(rotations[j]));
            let mut f = Vec3A::ZERO;
            for &i in connections.of(j) {
                let i = i as usize;
                let d = rj - at(rest, i);
                let c = cj - at(current, i);
                let turn_i = Mat3A::from(rotations[i]);
                f += match model {
                    ForceModel::Paper => turn_i * d - c,
                    // (The elastic force is gathered by [`elastic_force`].)
                    ForceModel::Symmetric | ForceModel::Elastic => (turn_i + turn_j) * d - 2.0 * c,
                };
            }
            Vec3::from(f)
        })
        .collect()
}
