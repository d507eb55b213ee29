//! A rigid motion that puts a point cloud on a surface: iterative closest
//! points, each step a Gauss-Newton step on the squared distances
//! (docs/METHOD.md, "Observations without correspondence", *Rigid fit*).

use glam::{DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::ObservationError;
use tissue_core::field::SurfaceField;

use crate::model::svd3::best_rotation;

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

/// A paired-point fit's residual above this share of the fiducials'
/// spread (their RMS distance from their centroid) says the points do not
/// correspond ([`fiducial_fit`]): a fiducial localised to 1-2 mm over a
/// spread of 40-80 mm leaves a few percent.
pub const FIDUCIAL_MISFIT: f32 = 0.05;

/// The rigid motion that puts fiducials given in an observation's frame
/// onto the same fiducials in the model's ([`fiducial_fit`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiducialFit {
    /// The motion's rotation: a point `p` goes to `rotation * p + translation`.
    pub rotation: Mat3,
    /// The motion's translation.
    pub translation: Vec3,
    /// The angle of the rotation, in degrees.
    pub angle_degrees: f32,
    /// The fiducials paired.
    pub count: usize,
    /// Root mean square and largest distance between the moved fiducials
    /// and the model's (the fiducial registration error).
    pub rms: f32,
    /// See `rms`.
    pub max: f32,
}

impl FiducialFit {
    /// Where the motion puts `p`.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }
}

/// The rigid motion that best puts the fiducials `from` (in an
/// observation's frame) onto `to` (the same fiducials, in the same order,
/// in the model's frame): least squares over the pairs, the rotation by
/// orthogonal Procrustes about the centroids (Arun, Huang and Blostein
/// 1987).
///
/// # Errors
///
/// [`ObservationError::Fiducials`] for fewer than three pairs, lists of
/// different lengths, a non-finite point, fiducials on one line (no
/// rotation about it is pinned), spreads that differ by more than a
/// quarter (another unit, or other points), or a fit that leaves them
/// farther apart than [`FIDUCIAL_MISFIT`] of their spread (the points do
/// not correspond: another order).
pub fn fiducial_fit(from: &[Vec3], to: &[Vec3]) -> Result<FiducialFit, ObservationError> {
    let refuse = |reason: String| Err(ObservationError::Fiducials { reason });
    if from.len() != to.len() {
        return refuse(format!(
            "{} in the observation's frame against {} in the model's; each fiducial is given \
             in both, in the same order",
            from.len(),
            to.len()
        ));
    }
    if from.len() < 3 {
        return refuse(format!(
            "{} pairs; at least three, not on one line, pin a rigid motion",
            from.len()
        ));
    }
    if let Some((k, p)) = from
        .iter()
        .chain(to)
        .enumerate()
        .find(|(_, p)| !p.is_finite())
    {
        return refuse(format!("point {} is not finite: {p}", k % from.len()));
    }
    let centre = |points: &[Vec3]| points.iter().copied().sum::<Vec3>() / points.len() as f32;
    let (c_from, c_to) = (centre(from), centre(to));
    let a: Vec<Vec3> = from.iter().map(|p| *p - c_from).collect();
    let b: Vec<Vec3> = to.iter().map(|p| *p - c_to).collect();
    let spread = |offsets: &[Vec3]| {
        (offsets.iter().map(|v| v.length_squared()).sum::<f32>() / offsets.len() as f32).sqrt()
    };
    let (s_from, s_to) = (spread(&a), spread(&b));
    if !(s_from > 0.0 && s_to > 0.0 && (0.8..=1.25).contains(&(s_from / s_to))) {
        return refuse(format!(
            "they spread {s_from:.3} in the observation's frame and {s_to:.3} in the model's \
             (RMS from their centroid); a rigid motion keeps distances: other units, or other \
             points"
        ));
    }
    // Off the line through the centroid along the farthest fiducial.
    let far = a.iter().copied().fold(Vec3::ZERO, |m, v| {
        if v.length_squared() > m.length_squared() {
            v
        } else {
            m
        }
    });
    let axis = far.normalize_or_zero();
    let off_line = a.iter().map(|v| v.cross(axis).length()).fold(0.0, f32::max);
    if off_line < FIDUCIAL_MISFIT * s_from {
        return refuse(
            "they lie on one line: no rotation about it is pinned; give a third fiducial off it"
                .to_string(),
        );
    }
    let rotation = best_rotation(&a, &b);
    let translation = c_to - rotation * c_from;
    let distances: Vec<f32> = from
        .iter()
        .zip(to)
        .map(|(p, q)| (rotation * *p + translation).distance(*q))
        .collect();
    let rms = (distances.iter().map(|d| d * d).sum::<f32>() / distances.len() as f32).sqrt();
    let max = distances.iter().copied().fold(0.0, f32::max);
    if rms > FIDUCIAL_MISFIT * s_to {
        return refuse(format!(
            "after the best rigid motion they lie {rms:.3} apart (RMS, the largest {max:.3}) \
             against a spread of {s_to:.3}: they do not correspond (check that both lists give \
             the fiducials in the same order)"
        ));
    }
    let angle_degrees = ((rotation.x_axis.x + rotation.y_axis.y + rotation.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    Ok(FiducialFit {
        rotation,
        translation,
        angle_degrees,
        count: from.len(),
        rms,
        max,
    })
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
        assert_eq!(FIDUCIAL_MISFIT, 0.05);
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

    /// Fiducials turned 15 degrees and shifted 20 mm, each moved by up to
    /// half a millimetre (their localisation): the motion back is found
    /// within the noise; too few, mismatched, collinear, rescaled or
    /// reordered fiducials are refused, each by what is wrong.
    #[test]
    fn fiducials_give_the_motion_back_and_bad_ones_are_refused() {
        let model = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(60.0, 0.0, 0.0),
            Vec3::new(0.0, 50.0, 0.0),
            Vec3::new(10.0, 20.0, 40.0),
            Vec3::new(-30.0, 10.0, 15.0),
        ];
        let turn = Mat3::from_axis_angle(Vec3::new(0.3, -1.0, 0.4).normalize(), 15f32.to_radians());
        let shift = Vec3::new(16.0, 0.0, -12.0);
        let mut random = Pcg64::seed_from_u64(3);
        let scan: Vec<Vec3> = model
            .iter()
            .map(|&p| {
                let jitter = Vec3::new(
                    random.random_range(-0.5..0.5),
                    random.random_range(-0.5..0.5),
                    random.random_range(-0.5..0.5),
                );
                turn * p + shift + jitter
            })
            .collect();
        let fit = fiducial_fit(&scan, &model).unwrap();
        assert!(
            (fit.angle_degrees - 15.0).abs() < 1.5,
            "{}",
            fit.angle_degrees
        );
        assert!(fit.rms < 0.6 && fit.max >= fit.rms, "{fit:?}");
        for &p in &model {
            assert!(fit.apply(turn * p + shift).distance(p) < 1.0);
        }
        let reason = |from: &[Vec3], to: &[Vec3]| match fiducial_fit(from, to) {
            Err(ObservationError::Fiducials { reason }) => reason,
            other => panic!("not refused: {other:?}"),
        };
        assert!(reason(&scan[..2], &model[..2]).contains("at least three"));
        assert!(reason(&scan, &model[..4]).contains("same order"));
        let line: Vec<Vec3> = (0..4).map(|k| Vec3::X * k as f32 * 10.0).collect();
        assert!(reason(&line, &line).contains("one line"));
        let metres: Vec<Vec3> = scan.iter().map(|p| *p * 0.001).collect();
        assert!(reason(&metres, &model).contains("other units"));
        let mut shuffled = scan.clone();
        shuffled.swap(0, 3);
        assert!(reason(&shuffled, &model).contains("same order"));
        let mut bad = scan.clone();
        bad[1] = Vec3::NAN;
        assert!(reason(&bad, &model).contains("not finite"));
    }
}
