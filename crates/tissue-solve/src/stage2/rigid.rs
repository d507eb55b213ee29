//! A rigid motion that puts a point cloud on a surface: iterative closest
//! points, each step a Gauss-Newton step on the squared distances
//! (docs/METHOD.md, "Observations without correspondence", *Rigid fit*).

use glam::{DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::ObservationError;
use tissue_core::field::SurfaceField;

/// How a rigid fit ([`rigid_fit`]) stops: after this many steps at most,
/// or once the share of the Gauss-Newton step it takes is below
/// [`RIGID_SHARE`]. A mesh's normals jump from triangle to triangle, so
/// full steps end circling the best motion rather than shrinking to
/// nothing: each step that raises the residual goes back to the best
/// motion and halves the share.
pub const RIGID_STEPS: u32 = 100;
/// See [`RIGID_STEPS`].
pub const RIGID_SHARE: f64 = 1.0 / 64.0;
/// Points whose residual is more than this many robust deviations (1.4826
/// times the median absolute residual) are set aside in each step.
pub const RIGID_TRIM: f64 = 3.0;

/// The rigid motion that puts a cloud on a surface, and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidFit {
    /// The motion's rotation: a point `p` goes to `rotation * p + translation`.
    pub rotation: Mat3,
    /// The motion's translation.
    pub translation: Vec3,
    /// The angle of the rotation, in degrees.
    pub angle_degrees: f32,
    /// Root mean square of the kept points' distances to the surface after
    /// the motion.
    pub rms: f32,
    /// Points set aside in the last step (outliers, or beyond the reach).
    pub set_aside: usize,
    /// Steps taken.
    pub steps: u32,
    /// Whether the fit stopped on [`RIGID_SHARE`] before [`RIGID_STEPS`].
    pub converged: bool,
}

impl RigidFit {
    /// Where the motion puts `p`.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }
}

/// The rigid motion that best puts `points` on `surface` (a surface's or
/// a cloud's field), starting from none: iterative closest points, each
/// step a Gauss-Newton step for a small rotation and a translation on the
/// sum of the points' squared distances to the surface, each distance
/// linearised along the direction to its nearest surface point (the
/// distance's gradient: point-to-plane, with a plane that does not jump
/// from one triangle's normal to the next's). Points farther than `reach`
/// from the surface, or with a distance beyond [`RIGID_TRIM`] robust
/// deviations, are set aside in each step.
///
/// # Errors
///
/// [`ObservationError::TooFew`] where fewer than six points are kept in a
/// step (six unknowns), [`ObservationError::NotFinite`] for a non-finite
/// point.
pub fn rigid_fit(
    points: &[Vec3],
    surface: &SurfaceField,
    reach: f32,
) -> Result<RigidFit, ObservationError> {
    if let Some((index, &value)) = points.iter().enumerate().find(|(_, p)| !p.is_finite()) {
        return Err(ObservationError::NotFinite { index, value });
    }
    let extent = points
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    let extent = f64::from((extent.1 - extent.0).max_element().max(f32::MIN_POSITIVE));
    let mut rotation = DMat3::IDENTITY;
    let mut translation = DVec3::ZERO;
    let mut fit = RigidFit {
        rotation: Mat3::IDENTITY,
        translation: Vec3::ZERO,
        angle_degrees: 0.0,
        rms: f32::INFINITY,
        set_aside: 0,
        steps: 0,
        converged: false,
    };
    // The best motion so far: its residual, rotation, translation, points
    // set aside, and the points it kept.
    let mut best = (f32::INFINITY, rotation, translation, 0, Vec::new());
    // The share of the Gauss-Newton step taken: halved each time a step
    // raised the residual, the motion then going back to the best one.
    let mut share = 1.0;
    for step in 0..=RIGID_STEPS {
        fit.steps = step;
        let (kept, rms, set_aside) =
            residuals(points, surface, reach, rotation, translation, extent)?;
        if rms < best.0 {
            best = (rms, rotation, translation, set_aside, kept);
        } else {
            share *= 0.5;
            (rotation, translation) = (best.1, best.2);
        }
        if share < RIGID_SHARE || step == RIGID_STEPS {
            fit.converged = share < RIGID_SHARE;
            break;
        }
        let kept = &best.4;
        // Normal equations of sum (r + w . (q x n) + d . n)^2, about the
        // points' centroid so the rotation and the shift stay apart.
        let centre = kept.iter().map(|(q, ..)| *q).sum::<DVec3>() / kept.len() as f64;
        let mut a = [[0.0f64; 6]; 6];
        let mut b = [0.0f64; 6];
        for (q, n, r) in kept {
            let row = {
                let c = (*q - centre).cross(*n);
                [c.x, c.y, c.z, n.x, n.y, n.z]
            };
            for i in 0..6 {
                for j in 0..6 {
                    a[i][j] += row[i] * row[j];
                }
                b[i] -= row[i] * r;
            }
        }
        let Some(x) = solve6(a, b) else {
            break;
        };
        let turn = share * DVec3::new(x[0], x[1], x[2]);
        let shift = share * DVec3::new(x[3], x[4], x[5]);
        let small = DMat3::from_axis_angle(turn.normalize_or_zero(), turn.length());
        // q -> small (q - centre) + centre + shift.
        rotation = small * rotation;
        translation = small * (translation - centre) + centre + shift;
    }
    let rotation;
    (fit.rms, rotation, translation, fit.set_aside, _) = best;
    fit.rotation = rotation.as_mat3();
    fit.translation = translation.as_vec3();
    let trace = (rotation.x_axis.x + rotation.y_axis.y + rotation.z_axis.z).clamp(-1.0, 3.0);
    fit.angle_degrees = ((trace - 1.0) / 2.0).acos().to_degrees() as f32;
    Ok(fit)
}

/// A point moved, the direction to it from its nearest surface point, and
/// its distance along it.
type Pair = (DVec3, DVec3, f64);

/// Per point kept, the point moved by the motion, the direction to it
/// from its nearest surface point and its distance along it; their root mean square, and
/// how many points were set aside (beyond `reach`, or more than
/// [`RIGID_TRIM`] robust deviations off).
fn residuals(
    points: &[Vec3],
    surface: &SurfaceField,
    reach: f32,
    rotation: DMat3,
    translation: DVec3,
    extent: f64,
) -> Result<(Vec<Pair>, f32, usize), ObservationError> {
    let pairs: Vec<Pair> = points
        .par_iter()
        .filter_map(|p| {
            let q = rotation * p.as_dvec3() + translation;
            let near = surface.nearest(q.as_vec3());
            let offset = q - near.point.as_dvec3();
            // The distance's gradient, continuous across the mesh's
            // triangles where their normals jump; the surface's normal
            // where the point is on the surface.
            let normal = if offset.length() > 1e-6 * extent {
                offset.normalize()
            } else {
                near.normal.as_dvec3()
            };
            (near.distance.abs() <= reach).then_some((q, normal, offset.dot(normal)))
        })
        .collect();
    let mut deviations: Vec<f64> = pairs.iter().map(|&(_, _, r)| r.abs()).collect();
    let scale = if deviations.is_empty() {
        0.0
    } else {
        let middle = deviations.len() / 2;
        1.4826 * *deviations.select_nth_unstable_by(middle, f64::total_cmp).1
    };
    let limit = RIGID_TRIM * scale.max(1e-9 * extent);
    let kept: Vec<Pair> = pairs
        .into_iter()
        .filter(|(_, _, r)| r.abs() <= limit)
        .collect();
    if kept.len() < 6 {
        return Err(ObservationError::TooFew {
            count: kept.len(),
            least: 6,
        });
    }
    let rms = (kept.iter().map(|(_, _, r)| r * r).sum::<f64>() / kept.len() as f64).sqrt() as f32;
    let set_aside = points.len() - kept.len();
    Ok((kept, rms, set_aside))
}

/// `a x = b` for a symmetric positive semi-definite `a` by Gaussian
/// elimination with partial pivoting; `None` where `a` is singular to
/// rounding (the points do not fix the motion: a plane, a sphere).
fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    let scale = (0..6).map(|i| a[i][i]).fold(0.0, f64::max);
    for k in 0..6 {
        let pivot = (k..6).max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))?;
        if a[pivot][k].is_nan() || a[pivot][k].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(k, pivot);
        b.swap(k, pivot);
        let top = a[k];
        for i in k + 1..6 {
            let f = a[i][k] / top[k];
            for (x, t) in a[i][k..].iter_mut().zip(&top[k..]) {
                *x -= f * t;
            }
            b[i] -= f * b[k];
        }
    }
    let mut x = [0.0; 6];
    for k in (0..6).rev() {
        let sum: f64 = (k + 1..6).map(|j| a[k][j] * x[j]).sum();
        x[k] = (b[k] - sum) / a[k][k];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    use super::*;

    #[test]
    fn the_defaults_are_pinned() {
        // docs/METHOD.md, "Observations without correspondence".
        assert_eq!(RIGID_TRIM, 3.0);
        assert_eq!(RIGID_SHARE, 1.0 / 64.0);
        assert_eq!(RIGID_STEPS, 100);
    }

    /// A cloud of the phantom's upper half (its vertices above the middle,
    /// noise and a few outliers along the normals) turned 15 degrees and
    /// shifted 20 mm comes back onto the phantom.
    #[test]
    fn a_turned_and_shifted_cloud_is_fitted_back_onto_its_surface() {
        let phantom = tissue_core::phantom::default_breast();
        let field = SurfaceField::new(&phantom, 2.0, 4.0).unwrap();
        let (lo, hi) = phantom.bounds().unwrap();
        let middle = 0.5 * (lo.z + hi.z);
        let mut rng = Pcg64::seed_from_u64(11);
        let seen: Vec<Vec3> = phantom
            .vertices
            .iter()
            .filter(|p| p.z > middle)
            .enumerate()
            .map(|(i, &p)| {
                let normal = field.nearest(p).normal;
                let off = if i % 100 == 0 {
                    5.0
                } else {
                    0.4 * (rng.random::<f32>() - 0.5)
                };
                p + normal * off
            })
            .collect();
        let turn = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 15f32.to_radians());
        let shift = Vec3::new(12.0, -16.0, 0.0);
        let centre = seen.iter().sum::<Vec3>() / seen.len() as f32;
        let moved: Vec<Vec3> = seen
            .iter()
            .map(|&p| turn * (p - centre) + centre + shift)
            .collect();
        let fit = rigid_fit(&moved, &field, 40.0).unwrap();
        assert!(fit.converged, "{fit:?}");
        let worst = seen
            .iter()
            .zip(&moved)
            .map(|(p, q)| (fit.apply(*q) - *p).length())
            .fold(0.0f32, f32::max);
        assert!(
            (fit.angle_degrees - 15.0).abs() < 0.1 && worst < 0.15,
            "turned back {:.3} degrees, the points within {worst:.3} mm: {fit:?}",
            fit.angle_degrees
        );
        assert!(
            fit.set_aside >= seen.len() / 100 && fit.rms < 0.2,
            "{fit:?}"
        );
    }
}
