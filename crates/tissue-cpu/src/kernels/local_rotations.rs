//! Twin of `shaders/local_rotations.wgsl`: each particle's rotation from
//! its `M_i`, by the SVD (`local_rotations`) or warm-started by the polar
//! update (`local_rotations_warm`, with [`super::polar`]).

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::Connections;
use tissue_solve::model::{offsets_product, rotation_of};

use super::polar::{LANES, warm_rotations};

/// The shader this module is the twin of.
pub const SHADER: &str = "local_rotations";

/// Per particle, the rotation that best maps rest offsets onto current
/// offsets: the polar rotation of `M_i = sum_j (q_j - q_i)(p_j - p_i)^T`.
pub fn local_rotations(rest: &[Vec3], current: &[Vec3], connections: &Connections) -> Vec<Mat3> {
    (0..rest.len())
        .into_par_iter()
        .map(|i| rotation_of(offsets_product(rest, current, connections, i)))
        .collect()
}

/// [`local_rotations`] by Müller et al.'s polar iteration, warm-started
/// from `previous`, eight particles side by side ([`warm_rotations`]) (rest offsets onto current offsets, like `local_rotations`).
pub fn local_rotations_warm(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    previous: &[Mat3],
) -> Vec<Mat3> {
    let mut rotations = vec![Mat3::IDENTITY; rest.len()];
    rotations
        .par_chunks_mut(LANES)
        .zip(previous.par_chunks(LANES))
        .enumerate()
        .for_each(|(chunk, (out, previous))| {
            let first = chunk * LANES;
            let m: [Mat3; LANES] = std::array::from_fn(|l| {
                if l < out.len() {
                    offsets_product(rest, current, connections, first + l)
                } else {
                    Mat3::ZERO
                }
            });
            warm_rotations(&m[..out.len()], previous, out);
        });
    rotations
}
