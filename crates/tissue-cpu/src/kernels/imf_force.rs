//! Twin of `shaders/imf_force.wgsl`: eqs. (2)-(6), the IMF pair forces over
//! a particle's neighbour row, the surface's force or reaction, and the
//! balloon's compression.

use glam::Vec3;
use rayon::prelude::*;
use tissue_core::field::{Side, SurfaceField};
use tissue_core::{SamplingParams, SurfaceMode};
use tissue_solve::stage1::{ForceOut, SamplingState};

/// The shader this module is the twin of.
pub const SHADER: &str = "imf_force";

/// Pair force of eqs. (4)-(5) on `i` from `j`, as a signed magnitude along the
/// unit vector from `j` to `i` (positive repels).
#[inline]
pub fn imf_pair(distance: f32, radius_sum: f32, alpha: f32) -> f32 {
    let h = 1.0 / (alpha * distance / radius_sum + (1.0 - alpha));
    let h3 = h * h * h;
    h3 * h3 - h3
}

/// Particles per block of [`ForceRows::filter`]'s parallel loop.
const FILTER_BLOCK: usize = 256;

/// The entries of neighbour rows (CSR) near enough to their particle for
/// the force, in the rows' order, a block of [`FILTER_BLOCK`] particles'
/// rows in each buffer (kept between filters).
///
/// A force pass over these rows is the pass over the full rows, to the bit,
/// while no particle has moved (or grown, times the cutoff) by more than
/// half of the skin they were filtered with since
/// ([`needs_rebuild`](super::needs_rebuild::needs_rebuild) with that skin):
/// every pair within the cutoff is still in them, in the same order, and the
/// pairs left out are ones the pass skips. The full rows carry a wide skin,
/// so that the grid search is rare; these a narrow one, so that the force's
/// loop meets few pairs it skips.
#[derive(Debug, Clone, Default)]
pub struct ForceRows {
    blocks: Vec<RowBlock>,
}

/// The rows of one block of particles: row `k` is
/// `entries[starts[k]..starts[k + 1]]`.
#[derive(Debug, Clone, Default)]
struct RowBlock {
    starts: Vec<u32>,
    entries: Vec<u32>,
}

impl ForceRows {
    /// Keeps the entries of the rows `offsets`, `neighbours` within `cutoff
    /// (r_i + r_j) + skin` of their particle in `state`.
    pub fn filter(
        &mut self,
        state: &SamplingState,
        offsets: &[u32],
        neighbours: &[u32],
        cutoff: f32,
        skin: f32,
    ) {
        let count = state.positions.len();
        self.blocks
            .resize_with(count.div_ceil(FILTER_BLOCK), RowBlock::default);
        self.blocks
            .par_iter_mut()
            .enumerate()
            .for_each(|(b, block)| {
                let particles = b * FILTER_BLOCK..((b + 1) * FILTER_BLOCK).min(count);
                block.starts.clear();
                block.starts.push(0);
                block.entries.clear();
                for i in particles {
                    let p = state.positions[i];
                    let base = cutoff * state.radii[i] + skin;
                    let row = &neighbours[offsets[i] as usize..offsets[i + 1] as usize];
                    // Every entry written, the kept ones advanced over: no
                    // branch to mispredict on the distance test.
                    let mut kept = block.entries.len();
                    block.entries.resize(kept + row.len(), 0);
                    for &j in row {
                        let limit = base + cutoff * state.radii[j as usize];
                        let near =
                            (p - state.positions[j as usize]).length_squared() < limit * limit;
                        block.entries[kept] = j;
                        kept += usize::from(near);
                    }
                    block.entries.truncate(kept);
                    block.starts.push(kept as u32);
                }
            });
    }

    /// Row `i`.
    fn row(&self, i: usize) -> &[u32] {
        let block = &self.blocks[i / FILTER_BLOCK];
        let k = i % FILTER_BLOCK;
        &block.entries[block.starts[k] as usize..block.starts[k + 1] as usize]
    }
}

/// Eqs. (2)-(6): the IMF pair forces over a particle's neighbour row, the
/// surface's force or reaction, and the balloon's compression.
pub fn imf_force(
    state: &SamplingState,
    offsets: &[u32],
    neighbours: &[u32],
    field: &SurfaceField,
    params: &SamplingParams,
) -> Vec<ForceOut> {
    forces_over(
        state,
        |i| &neighbours[offsets[i] as usize..offsets[i + 1] as usize],
        field,
        params,
    )
}

/// [`imf_force`] over the rows `near` filtered from the full rows: the
/// same forces, to the bit, while `near` holds every pair within the cutoff.
pub fn imf_force_near(
    state: &SamplingState,
    near: &ForceRows,
    field: &SurfaceField,
    params: &SamplingParams,
) -> Vec<ForceOut> {
    forces_over(state, |i| near.row(i), field, params)
}

fn forces_over<'a>(
    state: &SamplingState,
    row: impl Fn(usize) -> &'a [u32] + Sync,
    field: &SurfaceField,
    params: &SamplingParams,
) -> Vec<ForceOut> {
    let cutoff = params.force_cutoff;
    (0..state.positions.len())
        .into_par_iter()
        .map(|i| {
            let p = state.positions[i];
            let r = state.radii[i];
            let mut force = Vec3::ZERO;
            let mut magnitudes = 0.0f32;
            for &j in row(i) {
                let offset = p - state.positions[j as usize];
                let radius_sum = r + state.radii[j as usize];
                let d2 = offset.length_squared();
                if d2 >= (cutoff * radius_sum) * (cutoff * radius_sum) || d2 == 0.0 {
                    continue;
                }
                let d = d2.sqrt();
                let f = imf_pair(d, radius_sum, params.alpha);
                force += offset * (f / d);
                magnitudes += f.abs();
            }
            // eq. (6): |F_compress| = sum |F_j| - |sum F_j|. When counted, the
            // surface's force is one more term on both sides.
            let (wall, moves) = match params.surface_mode {
                // The wall's reaction from the last move: it counts in the
                // compression, but the move itself is left to the projection.
                SurfaceMode::Projection => {
                    (-state.contact[i].w * state.contact[i].truncate(), false)
                }
                // eq. (3): -n while outside, weighted by mu in eq. (2).
                SurfaceMode::PaperForce { mu } => match field.query(p) {
                    Side::Near(nearest) if nearest.distance > 0.0 => (-mu * nearest.normal, true),
                    Side::DeepOutside => (-mu * field.nearest(p).normal, true),
                    _ => (Vec3::ZERO, true),
                },
            };
            let compression = if params.wall_in_compression {
                magnitudes + wall.length() - (force + wall).length()
            } else {
                magnitudes - force.length()
            };
            ForceOut {
                force: if moves { force + wall } else { force },
                compression: compression.max(0.0),
            }
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use glam::Vec4;
    use tissue_core::SurfaceMesh;
    use tissue_solve::stage1::neighbour_rows;
    use tissue_testkit::{cloud, octahedron, xorshift};

    use super::*;

    #[test]
    fn force_rows_give_the_full_rows_forces_to_the_bit_until_half_their_skin_is_used() {
        let (vertices, triangles) = octahedron();
        let field = SurfaceField::new(&SurfaceMesh::new(vertices, triangles), 0.1, 0.05).unwrap();
        let (positions, radii) = cloud(600, 5, Vec3::splat(0.6));
        let count = positions.len();
        let mut state = SamplingState {
            positions: positions.iter().map(|p| *p - Vec3::splat(0.3)).collect(),
            radii,
            contact: vec![Vec4::ZERO; count],
        };
        let params = SamplingParams::default();
        let (cutoff, wide, narrow) = (params.force_cutoff, 0.06, 0.02);
        let (offsets, entries) =
            neighbour_rows(&state.positions, &state.radii, cutoff, wide, false);
        let mut near = ForceRows::default();
        near.filter(&state, &offsets, &entries, cutoff, narrow);
        let kept: usize = near.blocks.iter().map(|b| b.entries.len()).sum();
        assert!(
            kept < entries.len() / 2,
            "the narrow rows keep {kept} of {} entries",
            entries.len()
        );
        // Every particle moved by just under a quarter of the narrow skin
        // (so no pair came nearer by half of it), and some radii grew.
        let mut next = xorshift(11);
        let mut jitter = || 2.0 * next() - 1.0;
        for (p, r) in state.positions.iter_mut().zip(&mut state.radii) {
            let step = Vec3::new(jitter(), jitter(), jitter()).normalize_or_zero();
            *p += step * (0.24 * narrow);
            *r += 0.001 * jitter().abs() * narrow;
        }
        let full = imf_force(&state, &offsets, &entries, &field, &params);
        let filtered = imf_force_near(&state, &near, &field, &params);
        let bits = |f: &[ForceOut]| -> Vec<[u32; 4]> {
            f.iter()
                .map(|o| {
                    let [x, y, z] = o.force.to_array().map(f32::to_bits);
                    [x, y, z, o.compression.to_bits()]
                })
                .collect()
        };
        assert_eq!(bits(&full), bits(&filtered));
        assert!(full.iter().any(|o| o.force != Vec3::ZERO));
    }

    #[test]
    fn pair_force_is_zero_at_contact_repulsive_inside_attractive_outside() {
        let alpha = 0.5;
        assert!(imf_pair(1.0, 1.0, alpha).abs() < 1e-6);
        for d in [0.05, 0.3, 0.6, 0.75, 0.99] {
            assert!(imf_pair(d, 1.0, alpha) > 0.0, "d = {d} should repel");
        }
        for d in [1.01, 1.2, 2.0, 5.0] {
            assert!(imf_pair(d, 1.0, alpha) < 0.0, "d = {d} should attract");
        }
        // Decays towards zero far away (the attraction tail).
        assert!(imf_pair(50.0, 1.0, alpha).abs() < 1e-3);
        // At d = 0 it is 2^6 - 2^3 = 56 for alpha = 0.5.
        assert!((imf_pair(0.0, 1.0, alpha) - 56.0).abs() < 1e-4);
    }
}
