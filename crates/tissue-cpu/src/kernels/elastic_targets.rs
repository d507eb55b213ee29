//! Twin of `shaders/elastic_targets.wgsl`: the elastic model's terms with
//! each particle's rotation (`elastic_terms`), the elastic force gathered
//! over them (`elastic_force`), and each particle's part of the potential
//! the force descends (`elastic_potential`).

use glam::{Mat3, Mat3A, Vec3};
use rayon::prelude::*;
use tissue_core::Connections;
use tissue_solve::model::{Elastic, ElasticTerms, EnergySums, rotation_of};
use tissue_solve::stage2::Spring;
use tissue_solve::stage2::{RotationMethod, spring_potential};

use super::polar::{LANES, warm_rotations};

/// The shader this module is the twin of.
pub const SHADER: &str = "elastic_targets";

/// Per particle, the elastic model's terms ([`Elastic::terms`]) and its
/// rotation: the polar rotation of its gradient `F_i`, or of `M_i` for a
/// flat neighbourhood, by `method` (warm polar from `rotations`, the last
/// iteration's). The elastic phase's rotations pass: the rotations of the
/// `M_i` alone are not needed in it.
pub fn elastic_terms(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    rotations: &[Mat3],
    elastic: &Elastic,
    method: RotationMethod,
) -> (Vec<ElasticTerms>, Vec<Mat3>) {
    let (mut terms, mut turned) = (Vec::new(), Vec::new());
    elastic_terms_into(
        rest,
        current,
        connections,
        rotations,
        elastic,
        method,
        (&mut terms, &mut turned),
    );
    (terms, turned)
}

/// [`elastic_terms`] into `into` (the terms, the rotations), each
/// overwritten: the solver's iterations keep the two buffers rather than
/// make and fill new ones each time.
pub fn elastic_terms_into(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    rotations: &[Mat3],
    elastic: &Elastic,
    method: RotationMethod,
    into: (&mut Vec<ElasticTerms>, &mut Vec<Mat3>),
) {
    let blank = ElasticTerms {
        target: Mat3A::ZERO,
        stress: Mat3A::ZERO,
    };
    let (terms, turned) = into;
    terms.resize(rest.len(), blank);
    turned.resize(rest.len(), Mat3::IDENTITY);
    terms
        .par_chunks_mut(LANES)
        .zip(turned.par_chunks_mut(LANES))
        .zip(rotations.par_chunks(LANES))
        .enumerate()
        .for_each(|(chunk, ((terms, turned), previous))| {
            let (first, count) = (chunk * LANES, terms.len());
            let mut products = [Mat3::ZERO; LANES];
            let mut of = [Mat3::ZERO; LANES];
            for l in 0..count {
                let i = first + l;
                let (m, n) = elastic.products(rest, current, connections, i);
                products[l] = m;
                of[l] = elastic.turned_of(i, m, n);
            }
            match method {
                RotationMethod::Svd => {
                    for (turned, &of) in turned.iter_mut().zip(&of) {
                        *turned = rotation_of(of);
                    }
                }
                RotationMethod::WarmPolar => warm_rotations(&of[..count], previous, turned),
            }
            for (l, terms) in terms.iter_mut().enumerate() {
                // The gradient the rotation was found for, not made again.
                *terms = elastic.terms_of_gradient(first + l, products[l], of[l], turned[l]);
            }
        });
}

/// The elastic force on every particle ([`Elastic::force_on`]), gathered
/// over its connections from the terms of [`elastic_terms`].
pub fn elastic_force(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    terms: &[ElasticTerms],
    elastic: &Elastic,
) -> Vec<Vec3> {
    (0..rest.len())
        .into_par_iter()
        .map(|k| elastic.force_on(k, rest, current, connections, terms))
        .collect()
}

/// Per particle its part of the potential the elastic force descends,
/// `E_i / 2 - b_i . q_i + P_i` (`b_i` its body force from `loads`, none
/// where `loads` is empty, and `P_i` its spring's part from `springs`,
/// [`tissue_solve::stage2::spring_potential`], none where `springs` is
/// empty; free particles only), `E_i` by
/// [`Elastic::particle_energy_turned`] in `f64`, its rotation the polar
/// update of its gradient (of `M_i` where flat) warm-started from
/// `rotations` (the last iteration's, which stay as they are): the
/// potential is their sum, in index order. Where `held` has springs (the
/// pairing a kept state had), also each part with its spring's part from
/// them instead ([`tissue_solve::stage2::Potential::held`]); else the
/// second list is empty.
#[allow(
    clippy::too_many_arguments,
    reason = "the state and what acts on it, as the shader binds them"
)]
pub fn elastic_potential(
    rest: &[Vec3],
    current: &[Vec3],
    connections: &Connections,
    elastic: &Elastic,
    loads: &[Vec3],
    springs: &[Spring],
    held: &[Spring],
    free: &[bool],
    rotations: &[Mat3],
) -> (Vec<f64>, Vec<f64>) {
    let mut parts = vec![0.0; current.len()];
    let mut held_parts = vec![0.0; current.len()];
    parts
        .par_chunks_mut(LANES)
        .zip(held_parts.par_chunks_mut(LANES))
        .zip(rotations.par_chunks(LANES))
        .enumerate()
        .for_each(|(chunk, ((parts, held_parts), previous))| {
            let (first, count) = (chunk * LANES, parts.len());
            let mut of = [Mat3::ZERO; LANES];
            let mut sums = [EnergySums::ZERO; LANES];
            for (l, (of, sums)) in of.iter_mut().zip(&mut sums).enumerate().take(count) {
                let i = first + l;
                *sums = elastic.energy_sums(i, rest, current, connections);
                *of = elastic.turned_of(i, sums.offsets.as_mat3(), sums.multipliers.as_mat3());
            }
            let mut turned = [Mat3::IDENTITY; LANES];
            warm_rotations(&of[..count], previous, &mut turned);
            for (l, part) in parts.iter_mut().enumerate() {
                let i = first + l;
                let work = match loads.get(i) {
                    Some(b) if free[i] => f64::from(b.dot(current[i])),
                    _ => 0.0,
                };
                let pull = |springs: &[Spring]| match springs.get(i) {
                    Some(&spring) if free[i] => spring_potential(spring, current[i]),
                    _ => 0.0,
                };
                let energy = elastic.energy_of(i, &sums[l], turned[l]);
                let base = 0.5 * energy - work;
                *part = base + pull(springs);
                held_parts[l] = base + pull(held);
            }
        });
    if held.is_empty() {
        held_parts.clear();
    }
    (parts, held_parts)
}
