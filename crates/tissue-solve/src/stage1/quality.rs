//! The quality numbers of a sampled model (the `SamplingReport`).

use glam::Vec3;
use rayon::prelude::*;
use tissue_core::field::{Side, SurfaceField};
use tissue_core::{ConnectionStats, ParticleModel, SamplingReport};

use crate::stage1::grid::{Grid, grid_build};

/// Surface points per mean spacing along each triangle edge when measuring coverage.
const COVERAGE_SAMPLES_PER_SPACING: f32 = 3.0;

/// Distance from each particle to its nearest other particle.
pub fn nearest_neighbour_distances(positions: &[Vec3]) -> Vec<f32> {
    if positions.len() < 2 {
        return vec![f32::INFINITY; positions.len()];
    }
    // A cell of about two mean spacings: the nearest neighbour is almost
    // always in the 27 cells around; otherwise the search widens.
    let (lo, hi) = bounds(positions);
    let volume = (hi - lo).max(Vec3::splat(1e-12)).element_product();
    let spacing = (volume / positions.len() as f32).cbrt();
    let grid = grid_build(positions, spacing);
    positions
        .par_iter()
        .enumerate()
        .map(|(i, &p)| nearest_in_grid(&grid, positions, p, Some(i as u32)).1)
        .collect()
}

fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// Nearest point of `grid` to `p` (excluding `skip`), searching shells of
/// cells outward until no closer point can exist. Returns `(index, distance)`.
pub fn nearest_in_grid(grid: &Grid, positions: &[Vec3], p: Vec3, skip: Option<u32>) -> (u32, f32) {
    let centre = grid.cell_of(p);
    let mut best = (u32::MAX, f32::INFINITY);
    for shell in 0..=grid.max_shell() {
        grid.for_each_in_shell(centre, shell, |j| {
            if Some(j) == skip {
                return;
            }
            let d = (positions[j as usize] - p).length();
            if d < best.1 || (d == best.1 && j < best.0) {
                best = (j, d);
            }
        });
        if best.1 <= shell as f32 * grid.cell {
            break;
        }
    }
    best
}

/// The `q`-quantile (0..1) of sorted values, nearest rank.
fn quantile(sorted: &[f32], q: f32) -> f32 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (q * (sorted.len() - 1) as f32).round() as usize;
    sorted[rank.min(sorted.len() - 1)]
}

/// Points spread over the surface, about `spacing / COVERAGE_SAMPLES_PER_SPACING` apart.
fn surface_samples(model: &ParticleModel, spacing: f32) -> Vec<Vec3> {
    let step = spacing / COVERAGE_SAMPLES_PER_SPACING;
    (0..model.surface.triangles.len())
        .into_par_iter()
        .flat_map_iter(|t| {
            let [a, b, c] = model.surface.corners(t);
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            let k = ((longest / step).ceil() as usize).clamp(1, 4096);
            let mut out = Vec::with_capacity((k + 1) * (k + 2) / 2);
            for i in 0..=k {
                for j in 0..=k - i {
                    let (u, v) = (i as f32 / k as f32, j as f32 / k as f32);
                    out.push(a + (b - a) * u + (c - a) * v);
                }
            }
            out
        })
        .collect()
}

/// Computes the report of a sampled model.
pub fn quality_report(
    model: &ParticleModel,
    field: &SurfaceField,
    iterations: usize,
    converged: bool,
    seconds: f64,
) -> SamplingReport {
    let nn = nearest_neighbour_distances(&model.positions);
    let finite: Vec<f32> = nn.iter().copied().filter(|d| d.is_finite()).collect();
    let mean_spacing =
        finite.iter().map(|&d| f64::from(d)).sum::<f64>() as f32 / finite.len().max(1) as f32;

    let interior: Vec<usize> = (0..model.len()).filter(|&i| !model.is_surface(i)).collect();
    let nn_interior: Vec<f64> = interior
        .iter()
        .map(|&i| f64::from(nn[i]))
        .filter(|d| d.is_finite())
        .collect();
    let nn_cv = if nn_interior.len() < 2 {
        0.0
    } else {
        let mean = nn_interior.iter().sum::<f64>() / nn_interior.len() as f64;
        let var =
            nn_interior.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / nn_interior.len() as f64;
        (var.sqrt() / mean) as f32
    };

    let mut counts: Vec<f32> = interior
        .iter()
        .map(|&i| model.connections.of(i).len() as f32)
        .collect();
    counts.sort_by(f32::total_cmp);
    let connections = ConnectionStats {
        median: quantile(&counts, 0.5),
        p5: quantile(&counts, 0.05),
        p95: quantile(&counts, 0.95),
    };

    let surface: Vec<Vec3> = (0..model.len())
        .filter(|&i| model.is_surface(i))
        .map(|i| model.positions[i])
        .collect();
    let coverage = if surface.is_empty() || mean_spacing <= 0.0 {
        f32::INFINITY
    } else {
        let grid = grid_build(&surface, mean_spacing);
        surface_samples(model, mean_spacing)
            .par_iter()
            .map(|&s| nearest_in_grid(&grid, &surface, s, None).1)
            .reduce(|| 0.0, f32::max)
            / mean_spacing
    };

    let max_outside = model
        .positions
        .par_iter()
        .map(|&p| match field.query(p) {
            Side::Near(n) => n.distance.max(0.0),
            Side::DeepOutside => field.nearest(p).distance.max(0.0),
            Side::DeepInside => 0.0,
        })
        .reduce(|| 0.0, f32::max)
        / mean_spacing.max(f32::MIN_POSITIVE);

    let surface_crossing = tissue_core::crossing::first_crossing(&model.surface);
    if let Some([a, b]) = surface_crossing {
        log::warn!(
            "the surface passes through itself (triangles {a} and {b} cross, near {}): the \
             inside is ambiguous there, and particles near it may sit on the wrong side of a \
             sheet; repair the surface (remove its self-intersections) for a clean model",
            model.surface.corners(a)[0]
        );
    }
    SamplingReport {
        particles: model.len(),
        iterations,
        seconds,
        converged,
        nn_cv,
        connections,
        surface_particles: surface.len(),
        coverage,
        max_outside,
        mean_spacing,
        neighbour_rebuilds: 0,
        surface_crossing,
        stage_seconds: Default::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_neighbours_match_brute_force() {
        let mut s = 12345u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut p: Vec<Vec3> = (0..777)
            .map(|_| Vec3::new(next(), next() * 0.1, next()))
            .collect();
        p.push(Vec3::splat(40.0)); // a far outlier forces the widening search
        let nn = nearest_neighbour_distances(&p);
        for i in 0..p.len() {
            let brute = (0..p.len())
                .filter(|&j| j != i)
                .map(|j| (p[j] - p[i]).length())
                .fold(f32::INFINITY, f32::min);
            assert_eq!(nn[i], brute, "particle {i}");
        }
    }

    #[test]
    fn quantiles_are_nearest_rank() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(quantile(&v, 0.5), 3.0);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert_eq!(quantile(&v, 1.0), 5.0);
    }
}

/// The largest share of particles (in %) that may lack the connections to
/// carry a rotation before [`check_usable`] refuses a model.
pub const MAX_WEAK_PERCENT: f64 = 5.0;

/// Refuses a model whose particles all lie on the surface (stage 2 would
/// move nothing), or in which more than [`MAX_WEAK_PERCENT`] of the particles
/// have fewer than 3 connections or all of them in one plane
/// (`det A / (tr A / 3)^3` below [`crate::model::elastic::FLAT_NEIGHBOURHOOD`] for
/// the moment matrix `A` of their offsets): such a particle has no
/// rotation to find, and stage 2 would move it as if it had none. Too few
/// particles for the shape (`--particles 10`, or a slab one particle
/// thick) is what makes them.
pub fn check_usable(model: &ParticleModel) -> Result<(), tissue_core::SamplingError> {
    if model.attachments.iter().all(Option::is_some) {
        return Err(tissue_core::SamplingError::NoInterior {
            particles: model.len(),
        });
    }
    let flat: Vec<usize> = (0..model.len())
        .into_par_iter()
        .filter(|&i| {
            !crate::model::elastic::is_round(crate::model::elastic::moment(
                &model.positions,
                &model.connections,
                i,
            ))
        })
        .collect();
    let (weak, particles) = (flat.len(), model.len());
    let percent = 100.0 * weak as f64 / particles.max(1) as f64;
    if percent > MAX_WEAK_PERCENT {
        let example = flat[0];
        return Err(tissue_core::SamplingError::TooFewConnections {
            weak,
            example,
            at: model.positions[example].to_array(),
            particles,
            percent,
            limit: MAX_WEAK_PERCENT,
        });
    }
    Ok(())
}

#[cfg(test)]
mod usable_tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use tissue_core::{Attachment, Connections, SamplingError, SurfaceMesh};

    use super::*;

    /// A 4x4x4 lattice of unit spacing, pairs closer than `reach` connected;
    /// `surface` marks the outer layer attached.
    fn lattice(reach: f32, flat: bool, surface: bool) -> ParticleModel {
        let mut positions = Vec::new();
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..if flat { 1 } else { 4 } {
                    positions.push(Vec3::new(x as f32, y as f32, z as f32));
                }
            }
        }
        let n = positions.len();
        let mut pairs = Vec::new();
        for i in 0..n {
            for j in i + 1..n {
                if positions[i].distance(positions[j]) < reach {
                    pairs.push((i as u32, j as u32));
                }
            }
        }
        let on = Some(Attachment {
            triangle: 0,
            barycentric: [1.0, 0.0, 0.0],
        });
        let attachments = positions
            .iter()
            .map(|p| {
                let outer = p.x == 0.0 || p.x == 3.0 || p.y == 0.0 || p.y == 3.0;
                if surface || outer { on } else { None }
            })
            .collect();
        ParticleModel {
            radii: vec![0.5; n],
            attachments,
            connections: Connections::from_pairs(n, pairs),
            surface: SurfaceMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]),
            positions,
        }
    }

    #[test]
    fn a_model_that_cannot_carry_rotations_is_refused() {
        // Connected in 3D: usable.
        assert!(check_usable(&lattice(1.5, false, false)).is_ok());
        // Every particle attached to the surface: nothing to move.
        assert!(matches!(
            check_usable(&lattice(1.5, false, true)),
            Err(SamplingError::NoInterior { particles: 64 })
        ));
        // One layer thick: every neighbourhood is flat.
        let err = check_usable(&lattice(1.5, true, false)).unwrap_err();
        assert!(
            matches!(err, SamplingError::TooFewConnections { weak: 16, .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("sample more particles"), "{err}");
        // It points at the thin part: particle 0 of the slab, at the origin.
        assert!(
            err.to_string().contains("particle 0 at [0.0, 0.0, 0.0]"),
            "{err}"
        );
        // Too short a reach: no connections at all.
        assert!(matches!(
            check_usable(&lattice(0.5, false, false)),
            Err(SamplingError::TooFewConnections { weak: 64, .. })
        ));
    }
}
