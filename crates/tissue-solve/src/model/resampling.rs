//! The interior's motion as a displacement field on a regular grid, in the
//! resampling direction that 3D Slicer's grid transforms and ITK's
//! displacement fields store: at a point `y` of the deformed
//! configuration, `x - y`, with `x` where the tissue at `y` is at rest. It
//! warps a pre-operative image (at rest) into the deformed state; points
//! are moved from rest to deformed by its inverse.
//!
//! `x` is carried back from the deformed particles as landmarks are carried
//! forward from the rest ones ([`crate::model::structures`]): bound to the
//! `CARRIERS` nearest deformed particles with the same weights, `x = sum_k
//! w_k (p_k + G_k (y - q_k))`, with `p_k` rest, `q_k` deformed and `G_k`
//! the inverse of the particle's least-squares gradient `F_k = M_k A_k^-1`
//! ([`crate::model::elastic`]), so that a stretch is undone as well as a turn; a
//! particle whose neighbourhood is flat, or whose gradient is nearly
//! singular or turned inside out, uses its rotation's inverse `R_k^T`
//! instead. Off the organ the field is extrapolated the same way up to
//! [`FULL_SPACINGS`] grid spacings outside the deformed surface, then
//! fades linearly to zero at [`FADE_SPACINGS`]; the grid reaches that far
//! beyond the surface's bounding box, so its outer points are zero.

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::FieldError;
use tissue_core::displacement::DisplacementField;
use tissue_core::field::{Side, SurfaceField};
use tissue_core::{Connections, SurfaceMesh};

use crate::model::elastic::{is_round, moment, moment_inverse, offsets_product};
use crate::model::structures::{carriers_of, typical_spacing};
use crate::stage1::grid::grid_build;

/// Up to this many grid spacings outside the deformed surface the field is
/// the particles' (extrapolated) displacement, in full: the eight grid
/// points around any point of the organ are at most `sqrt(3)` spacings
/// from it.
pub const FULL_SPACINGS: f32 = 2.0;
/// Here the field has faded to zero, and the grid ends.
pub const FADE_SPACINGS: f32 = 4.0;
/// A particle's gradient with a smaller determinant (volume ratio) than
/// this is not inverted; its rotation is used instead.
pub const MIN_VOLUME_RATIO: f32 = 0.1;
/// The most grid points a field may have (8 Mi: 96 MiB of vectors).
pub const MAX_GRID_POINTS: usize = 1 << 23;

/// Why a displacement field cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FieldGridError {
    /// The spacing is not a positive length.
    #[error("the field spacing {0} is not a positive length")]
    Spacing(f32),
    /// The deformed surface has no vertices.
    #[error("the deformed surface has no vertices")]
    NoVertices,
    /// A spacing too coarse to say anything of the interior (more likely a
    /// unit mistake).
    #[error(
        "the field spacing {spacing} would give fewer than {MIN_GRID_STEPS} grid steps across \
         the organ ({extent} across at its widest): choose a spacing of at most {most} in the \
         model's units"
    )]
    TooCoarse {
        /// The spacing asked for.
        spacing: f32,
        /// The surface's largest extent.
        extent: f32,
        /// The largest spacing accepted.
        most: f32,
    },
    /// A grid of more than [`MAX_GRID_POINTS`].
    #[error(
        "a grid of spacing {spacing} around the surface would have {points:.0} points (at most \
         {MAX_GRID_POINTS}): choose a larger field spacing"
    )]
    TooManyPoints {
        /// The spacing asked for.
        spacing: f32,
        /// Points the grid would have.
        points: f64,
    },
    /// The particles' arrays disagree in length, or are empty.
    #[error("{rest} rest positions, {current} current positions and {rotations} rotations")]
    Lengths {
        /// Rest positions.
        rest: usize,
        /// Current positions.
        current: usize,
        /// Rotations.
        rotations: usize,
    },
    /// The deformed surface's distance field cannot be made.
    #[error(transparent)]
    Surface(#[from] FieldError),
}

/// The resampling displacement field of particles moved from `rest` to
/// `current` with `rotations` (rest offsets onto current offsets) and
/// `connections`, on a grid of `spacing` around `deformed` (the surface the
/// particles follow, closed and outward, as a solve checks it).
///
/// Fails for a spacing that is not positive, a grid of more than
/// [`MAX_GRID_POINTS`], or a surface the distance field cannot use.
pub fn resampling_field(
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
    connections: &Connections,
    deformed: &SurfaceMesh,
    spacing: f32,
) -> Result<DisplacementField, FieldGridError> {
    if rest.len() != current.len() || rest.len() != rotations.len() || rest.is_empty() {
        return Err(FieldGridError::Lengths {
            rest: rest.len(),
            current: current.len(),
            rotations: rotations.len(),
        });
    }
    let (origin, dims) = field_grid(deformed, spacing)?;
    let inverse_gradients = inverse_gradients(rest, current, rotations, connections);
    let surface = SurfaceField::new(deformed, spacing, FADE_SPACINGS * spacing)?;
    let grid = grid_build(current, typical_spacing(current));
    let mut field = DisplacementField {
        origin,
        spacing,
        dims,
        values: Vec::new(),
    };
    field.values = (0..field.len())
        .into_par_iter()
        .map(|index| {
            let y = field.point(index);
            let weight = fade(&surface, y, spacing);
            if weight == 0.0 {
                return Vec3::ZERO;
            }
            let x: Vec3 = carriers_of(&grid, current, y)
                .iter()
                .map(|&(k, w)| {
                    let k = k as usize;
                    w * (rest[k] + inverse_gradients[k] * (y - current[k]))
                })
                .sum();
            weight * (x - y)
        })
        .collect();
    Ok(field)
}

/// Per particle, `G_k` of the module's doc: `F_k^-1`, or `R_k^T`.
fn inverse_gradients(
    rest: &[Vec3],
    current: &[Vec3],
    rotations: &[Mat3],
    connections: &Connections,
) -> Vec<Mat3> {
    (0..rest.len())
        .into_par_iter()
        .map(|k| {
            let a = moment(rest, connections, k);
            if is_round(a) {
                let f = offsets_product(rest, current, connections, k) * moment_inverse(a);
                let ratio = f.determinant();
                if ratio.is_finite() && ratio >= MIN_VOLUME_RATIO {
                    return f.inverse();
                }
            }
            rotations[k].transpose()
        })
        .collect()
}

/// The fewest grid steps a displacement field may have across the organ
/// at its widest.
pub const MIN_GRID_STEPS: f32 = 4.0;

/// The grid of a field of `spacing` around `deformed`: its origin and
/// points along each axis, reaching [`FADE_SPACINGS`] beyond the surface's
/// bounding box. Fails for a spacing that is not a positive length, one longer than a [`MIN_GRID_STEPS`]th of the surface's
/// largest extent (a grid too coarse to say anything of the interior:
/// more likely a unit mistake), or a grid of more than
/// [`MAX_GRID_POINTS`]: a check to make before a solve.
pub fn field_grid(
    deformed: &SurfaceMesh,
    spacing: f32,
) -> Result<(Vec3, [usize; 3]), FieldGridError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(FieldGridError::Spacing(spacing));
    }
    let (lo, hi) = deformed.bounds().ok_or(FieldGridError::NoVertices)?;
    let extent = (hi - lo).max_element();
    if spacing > extent / MIN_GRID_STEPS {
        return Err(FieldGridError::TooCoarse {
            spacing,
            extent,
            most: extent / MIN_GRID_STEPS,
        });
    }
    let pad = Vec3::splat(FADE_SPACINGS * spacing);
    let origin = lo - pad;
    let steps = ((hi + pad - origin) / spacing).ceil();
    let total = f64::from(steps.x + 1.0) * f64::from(steps.y + 1.0) * f64::from(steps.z + 1.0);
    if total.is_nan() || total > MAX_GRID_POINTS as f64 {
        return Err(FieldGridError::TooManyPoints {
            spacing,
            points: total,
        });
    }
    let dims = [
        steps.x as usize + 1,
        steps.y as usize + 1,
        steps.z as usize + 1,
    ];
    Ok((origin, dims))
}

/// 1 inside the surface and up to [`FULL_SPACINGS`] outside it, 0 from
/// [`FADE_SPACINGS`] on, linear between.
fn fade(surface: &SurfaceField, y: Vec3, spacing: f32) -> f32 {
    let distance = match surface.query(y) {
        Side::DeepInside => return 1.0,
        Side::DeepOutside => return 0.0,
        Side::Near(nearest) => nearest.distance,
    };
    ((FADE_SPACINGS * spacing - distance) / ((FADE_SPACINGS - FULL_SPACINGS) * spacing))
        .clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;
    use crate::model::svd3::rotation_of;
    use tissue_core::phantom::{TumourPhantom, tumour};

    fn sphere(radius: f32, subdivisions: u32) -> SurfaceMesh {
        tumour(&TumourPhantom {
            centre: Vec3::ZERO,
            radii: Vec3::splat(radius),
            subdivisions,
        })
    }

    /// A ball of particles on a lattice, moved by a smooth map that turns,
    /// shears and bends it, with each particle's rotation the polar part of
    /// the map's gradient: the field at each moved particle, interpolated,
    /// is its rest minus moved position to 1 % of the largest displacement.
    #[test]
    fn the_field_at_the_moved_particles_takes_them_back_to_rest() {
        let radius = 20.0;
        let step = 2.0;
        let n = (radius / step) as i32;
        let rest: Vec<Vec3> = (-n..=n)
            .flat_map(|i| (-n..=n).flat_map(move |j| (-n..=n).map(move |k| (i, j, k))))
            .map(|(i, j, k)| Vec3::new(i as f32, j as f32, k as f32) * step)
            .filter(|p| p.length() <= radius)
            .collect();
        let turn = Mat3::from_axis_angle(Vec3::new(0.2, 0.3, 1.0).normalize(), 0.3);
        let map = |p: Vec3| {
            turn * Vec3::new(
                p.x + 0.004 * p.y * p.y,
                p.y + 0.1 * p.z,
                p.z - 0.003 * p.x * p.x,
            ) + Vec3::new(3.0, -2.0, 5.0)
        };
        let gradient = |p: Vec3| {
            let e = 1e-2;
            let column = |d: Vec3| (map(p + d * e) - map(p - d * e)) / (2.0 * e);
            Mat3::from_cols(column(Vec3::X), column(Vec3::Y), column(Vec3::Z))
        };
        let current: Vec<Vec3> = rest.iter().map(|&p| map(p)).collect();
        let rotations: Vec<Mat3> = rest.iter().map(|&p| rotation_of(gradient(p))).collect();
        // Each particle joined to those within 1.5 steps (18 neighbours inside).
        let pairs = (0..rest.len()).flat_map(|i| {
            let rest = &rest;
            (i + 1..rest.len())
                .filter(move |&j| rest[i].distance(rest[j]) < 1.5 * step)
                .map(move |j| (i as u32, j as u32))
        });
        let connections = Connections::from_pairs(rest.len(), pairs);
        let sphere = sphere(radius + 0.5 * step, 3);
        let deformed = SurfaceMesh::new(
            sphere.vertices.iter().map(|&p| map(p)).collect(),
            sphere.triangles.clone(),
        );
        let field =
            resampling_field(&rest, &current, &rotations, &connections, &deformed, step).unwrap();
        let largest = rest
            .iter()
            .zip(&current)
            .map(|(p, q)| p.distance(*q))
            .fold(0.0, f32::max);
        let mut worst = 0.0_f32;
        for (i, (&p, &q)) in rest.iter().zip(&current).enumerate() {
            let d = field.interpolate(q).unwrap();
            let error = d.distance(p - q);
            assert!(
                error <= 0.01 * largest,
                "particle {i}: field {d}, rest minus moved {}, error {error} > 1 % of {largest}",
                p - q
            );
            worst = worst.max(error);
        }
        eprintln!("worst {worst} of largest displacement {largest}");
        // The grid's outer points are zero.
        let [nx, ny, nz] = field.dims;
        for index in [
            0,
            field.index([nx - 1, ny - 1, nz - 1]),
            field.index([nx / 2, 0, nz / 2]),
        ] {
            assert_eq!(field.values[index], Vec3::ZERO, "grid point {index}");
        }
    }

    #[test]
    fn a_grid_too_fine_or_a_spacing_that_is_not_a_length_is_refused() {
        let sphere = sphere(10.0, 1);
        let one = [Vec3::ZERO];
        let turn = [Mat3::IDENTITY];
        let none = Connections::from_pairs(1, []);
        let err = resampling_field(&one, &one, &turn, &none, &sphere, 1e-3).unwrap_err();
        assert!(matches!(err, FieldGridError::TooManyPoints { .. }), "{err}");
        assert!(
            err.to_string().contains("choose a larger field spacing"),
            "{err}"
        );
        for spacing in [0.0, -1.0, f32::NAN] {
            let err = resampling_field(&one, &one, &turn, &none, &sphere, spacing).unwrap_err();
            assert!(err.to_string().contains("not a positive length"), "{err}");
        }
        // About 20 across: at most 5 a step.
        for spacing in [5.1, 1e9, f32::INFINITY] {
            let err = field_grid(&sphere, spacing).unwrap_err();
            let expected = if spacing.is_finite() {
                "fewer than 4 grid steps across the organ"
            } else {
                "not a positive length"
            };
            assert!(err.to_string().contains(expected), "{spacing}: {err}");
        }
        assert!(field_grid(&sphere, 4.0).is_ok());
    }
}
