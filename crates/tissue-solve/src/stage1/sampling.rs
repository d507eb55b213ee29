//! Stage 1's device-neutral parts (the paper's Section 2): the initial
//! radius and placement, the state the iterations work on, and the finish
//! (surface particles placed and attached, connections by eq. (9)). The
//! iterations themselves are each device's kernels.

use std::time::Instant;

use glam::{Vec3, Vec4};
use rand::{Rng, SeedableRng, seq::index};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use tissue_core::field::{Side, SurfaceField};
use tissue_core::params::InitialPlacement;
use tissue_core::{
    Attachment, Connections, Error, ParticleModel, SamplingError, SamplingParams, SamplingReport,
    StageSeconds, SurfaceMesh,
};

use crate::stage1::grid::{grid_build, neighbour_rows};

/// Field cell edge in initial radii `r0`: about 2.4 cells per particle inside.
/// Smaller cells mean fewer candidate triangles per query (the hot path) and
/// a slower build (docs/METHOD.md, "Neighbours and the surface field").
pub const FIELD_CELL_IN_R0: f32 = 1.0;

/// Verlet skin of the neighbour rows, in `r0`: rows are rebuilt when a particle
/// moved (or its radius grew) by more than half of it. A wider skin rebuilds
/// less often but makes every row longer; this one keeps the rows short for
/// the GPU path (docs/METHOD.md, "Neighbours and the surface field").
pub const SKIN_IN_R0: f32 = 1.2;

/// Smallest exact-query margin of the surface field, in `r0`.
pub const FIELD_MARGIN_IN_R0: f32 = 0.25;

/// Per-axis jitter of the initial lattice, in lattice spacings.
const LATTICE_JITTER: f32 = 0.1;

/// Where a sampling run is; passed to the progress callback every iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Iterations done.
    pub iteration: usize,
    /// The iteration cap.
    pub max_iterations: usize,
    /// RMS step of interior particles in the last iteration, in `r0`.
    pub step_rms: f32,
    /// RMS change of `ln r` in the last iteration.
    pub radius_rms: f32,
}

/// The state stage 1 iterates on.
#[derive(Debug, Clone)]
pub struct SamplingState {
    /// Particle positions.
    pub positions: Vec<Vec3>,
    /// Balloon radii.
    pub radii: Vec<f32>,
    /// The wall's reaction in the last move: outward normal in `xyz`, and in
    /// `w` the force the wall took away by moving the particle back onto the
    /// surface (penetration depth times `m / r0`), zero when it stayed inside.
    pub contact: Vec<Vec4>,
}

/// Force on each particle and the compression of its balloon.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ForceOut {
    /// Force `F_i` of eq. (2) that moves the particle (in projection mode the
    /// wall acts in `integrate` instead).
    pub force: Vec3,
    /// `|F_compress,i|` of eq. (6).
    pub compression: f32,
}

/// The initial radius `r0 = (sqrt(2) V / N)^(1/3) / 1.5`: N close-packed spheres
/// at `d = 0.75 (r_i + r_j)` fill the volume V.
pub fn initial_radius(volume: f64, particles: usize) -> f32 {
    ((2f64.sqrt() * volume / particles as f64).cbrt() / 1.5) as f32
}

/// Initial particles inside the surface, by `params.initial`.
pub fn initial_positions(
    mesh: &SurfaceMesh,
    field: &SurfaceField,
    params: &SamplingParams,
    r0: f32,
) -> Result<Vec<Vec3>, Error> {
    let mut rng = Pcg64::seed_from_u64(params.seed);
    let (lo, hi) = mesh.bounds().ok_or(SamplingError::NoVertices)?;
    match params.initial {
        InitialPlacement::Random => {
            let mut points = Vec::with_capacity(params.particles);
            let attempts = 1000 * params.particles;
            for _ in 0..attempts {
                let p = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random());
                if field.is_inside(p) {
                    points.push(p);
                    if points.len() == params.particles {
                        return Ok(points);
                    }
                }
            }
            Err(SamplingError::RandomPlacement {
                placed: points.len(),
                attempts,
            }
            .into())
        }
        InitialPlacement::Lattice => lattice(field, lo, hi, params, r0, &mut rng),
    }
}

/// A jittered face-centred cubic lattice at the density of `r0`, its spacing
/// adjusted until at least `N` points fall inside, then the surplus dropped at
/// random (the kept points stay in lattice order, which is spatially coherent).
fn lattice(
    field: &SurfaceField,
    lo: Vec3,
    hi: Vec3,
    params: &SamplingParams,
    r0: f32,
    rng: &mut Pcg64,
) -> Result<Vec<Vec3>, Error> {
    let n = params.particles;
    let shift = Vec3::new(rng.random(), rng.random(), rng.random());
    let seed: u64 = rng.random();
    let points_at = |edge: f32| -> Vec<Vec3> {
        let spacing = edge / 2f32.sqrt();
        let cells = ((hi - lo) / edge).ceil().as_uvec3() + 1;
        let basis = [
            Vec3::ZERO,
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::new(0.5, 0.0, 0.5),
            Vec3::new(0.0, 0.5, 0.5),
        ];
        (0..cells.z)
            .into_par_iter()
            .flat_map_iter(|z| {
                let mut local =
                    Pcg64::seed_from_u64(seed ^ u64::from(z).wrapping_mul(0x9e3779b97f4a7c15));
                let mut out = Vec::new();
                for y in 0..cells.y {
                    for x in 0..cells.x {
                        for b in basis {
                            let jitter = Vec3::new(
                                local.random::<f32>() - 0.5,
                                local.random::<f32>() - 0.5,
                                local.random::<f32>() - 0.5,
                            ) * (2.0 * LATTICE_JITTER * spacing);
                            let cell = Vec3::new(x as f32, y as f32, z as f32);
                            let p = lo + (cell + b + shift - 0.5) * edge + jitter;
                            if field.is_inside(p) {
                                out.push(p);
                            }
                        }
                    }
                }
                out
            })
            .collect()
    };
    // Close packing at d = 1.5 r0 is a face-centred cubic lattice of cube edge d sqrt(2).
    let mut edge = 1.5 * r0 * 2f32.sqrt();
    let mut best: Option<Vec<Vec3>> = None;
    for _ in 0..12 {
        let points = points_at(edge);
        let count = points.len();
        if count >= n {
            let done = count <= n + n / 100 + 1;
            if best.as_ref().is_none_or(|b| count < b.len()) {
                best = Some(points);
            }
            if done {
                break;
            }
        }
        // Density goes as edge^-3: aim a little above N.
        let ratio = (count.max(1) as f32 / (n as f32 * 1.005)).cbrt();
        edge *= ratio.clamp(0.7, 1.3);
    }
    let Some(points) = best else {
        return Err(SamplingError::LatticePlacement { particles: n }.into());
    };
    let mut keep = index::sample(rng, points.len(), n).into_vec();
    keep.sort_unstable();
    Ok(keep.into_iter().map(|i| points[i]).collect())
}

/// The outcome of stage 1.
#[derive(Debug, Clone)]
pub struct Sampled {
    /// The relaxed particle model.
    pub model: ParticleModel,
    /// Its quality numbers.
    pub report: SamplingReport,
}

/// What the iterations of stage 1 start from: shared by the CPU and GPU paths.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// The initial radius.
    pub r0: f32,
    /// The surface field the iterations query.
    pub field: SurfaceField,
    /// Initial positions in grid-cell order, radii `r0`, no contact.
    pub state: SamplingState,
    /// Seconds spent on the field and the initial placement.
    pub stages: StageSeconds,
}

/// Checks the parameters and the volume, builds the surface field and places
/// the initial particles (the part of [`sample`] before the iterations).
pub fn prepare(mesh: &SurfaceMesh, params: &SamplingParams) -> Result<Prepared, Error> {
    params.validate()?;
    let volume = mesh.signed_volume();
    if !(volume.is_finite() && volume > 0.0) {
        return Err(SamplingError::NoVolume { volume }.into());
    }
    let r0 = initial_radius(volume, params.particles);
    let mut stages = StageSeconds::default();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut f64| {
        *slot += clock.elapsed().as_secs_f64();
        clock = Instant::now();
    };
    // Exact answers are needed within the contact tolerance and the surface
    // band of the final placement; a wider margin costs build time.
    let margin = (2.0 * params.surface_band).max(FIELD_MARGIN_IN_R0) * r0;
    let field =
        SurfaceField::new(mesh, FIELD_CELL_IN_R0 * r0, margin).map_err(SamplingError::Field)?;
    lap(&mut stages.field);
    let positions = initial_positions(mesh, &field, params, r0)?;
    // Particles in grid-cell order: neighbours then sit close in memory, which
    // makes every pass over neighbour rows cache-friendly.
    let positions: Vec<Vec3> = grid_build(&positions, 2.0 * r0)
        .particles
        .iter()
        .map(|&i| positions[i as usize])
        .collect();
    lap(&mut stages.initial);
    let n = positions.len();
    Ok(Prepared {
        r0,
        field,
        state: SamplingState {
            positions,
            radii: vec![r0; n],
            contact: vec![Vec4::ZERO; n],
        },
        stages,
    })
}

/// Surface particles (within `surface_band` radii of the surface, or outside)
/// are placed exactly on it and attached; connections are built (eq. (9)).
pub fn finish(
    mesh: &SurfaceMesh,
    field: &SurfaceField,
    state: SamplingState,
    params: &SamplingParams,
) -> ParticleModel {
    let (positions, attachments) = place_surface_particles(field, &state, params);
    let radii = state.radii;
    let (offsets, indices) = neighbour_rows(&positions, &radii, params.connection_ratio, 0.0, true);
    ParticleModel {
        positions,
        radii,
        attachments,
        connections: Connections { offsets, indices },
        surface: mesh.clone(),
    }
}

/// The placement step of [`finish`]: each particle within `surface_band` of
/// its radius of the surface (or outside) moved onto its nearest surface
/// point and attached there; the others stay where they are.
pub fn place_surface_particles(
    field: &SurfaceField,
    state: &SamplingState,
    params: &SamplingParams,
) -> (Vec<Vec3>, Vec<Option<Attachment>>) {
    let placed: Vec<(Vec3, Option<Attachment>)> = state
        .positions
        .par_iter()
        .zip(&state.radii)
        .map(|(&p, &r)| match field.query(p) {
            // A balloon grown beyond the field's margin: ask exactly.
            Side::DeepInside if params.surface_band * r > field.margin => {
                let n = field.nearest(p);
                if n.distance > -params.surface_band * r {
                    (
                        n.point,
                        Some(Attachment {
                            triangle: n.triangle,
                            barycentric: n.barycentric,
                        }),
                    )
                } else {
                    (p, None)
                }
            }
            Side::DeepOutside => {
                let n = field.nearest(p);
                (
                    n.point,
                    Some(Attachment {
                        triangle: n.triangle,
                        barycentric: n.barycentric,
                    }),
                )
            }
            Side::Near(n) if n.distance > -params.surface_band * r => (
                n.point,
                Some(Attachment {
                    triangle: n.triangle,
                    barycentric: n.barycentric,
                }),
            ),
            _ => (p, None),
        })
        .collect();
    placed.into_iter().unzip()
}

/// Stage 1's convergence rule, the same on every device, after one more
/// iteration (`done` before it) whose RMS step of interior particles (in
/// `r0`) and RMS change of `ln r` are given: reports the progress and says
/// whether the run has converged; a non-finite change is an error.
pub fn converged_after(
    done: usize,
    step_rms: f32,
    radius_rms: f32,
    params: &SamplingParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<bool, Error> {
    if !(step_rms.is_finite() && radius_rms.is_finite()) {
        return Err(SamplingError::Unstable { iteration: done }.into());
    }
    progress(&Progress {
        iteration: done + 1,
        max_iterations: params.max_iterations,
        step_rms,
        radius_rms,
    });
    Ok(step_rms < params.step_tolerance && radius_rms < params.radius_tolerance)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_radius_fills_the_volume_at_close_packing() {
        // N spheres of close packing at spacing 1.5 r0 occupy d^3 / sqrt(2) each.
        let r0 = initial_radius(1000.0, 500);
        let d = 1.5 * r0;
        let volume = 500.0 * d.powi(3) / 2f32.sqrt();
        assert!((volume - 1000.0).abs() < 1e-2, "{volume}");
    }
}
