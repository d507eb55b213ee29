//! A point cloud as an observation of the organ's surface without
//! correspondence (a surface scanner's or a stereo camera's points): its
//! spacing, a normal at every point fitted to its neighbours, and the grid
//! that finds a point's nearest observed point on either device
//! (docs/METHOD.md, "Observations without correspondence").

use glam::{DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;
use rstar::RTree;
use rstar::primitives::GeomWithData;
use tissue_core::ObservationError;
use tissue_core::field::{SMOOTH_REACH, SurfaceField};

use crate::stage2::pairing::CLOUD_SMOOTHING;

use crate::model::svd3;

/// The range of a scan's bounding-box diagonal over the organ's that
/// [`Cloud::check_against`] accepts: from a stylus's patch of the skin (a
/// fiftieth of the organ's size) to the whole organ and what lies around it
/// (five times its size). A scan in metres of an organ in millimetres lies
/// below, one in micrometres or centimetres against millimetres above; a
/// whole scan in centimetres against millimetres (a tenth) looks like a
/// patch, and is left to the solve's residual.
pub const SCAN_SCALE: (f32, f32) = (0.02, 5.0);

/// How many points (the point itself and its nearest others) each normal
/// is fitted to: the plane of least squares through them.
pub const NORMAL_NEIGHBOURS: usize = 12;

/// A point cloud with a unit normal at every point.
#[derive(Debug, Clone, PartialEq)]
pub struct Cloud {
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    spacing: f32,
}

impl Cloud {
    /// The cloud of `points`: its spacing (the median distance from a point
    /// to its nearest other point) and its normals, each the normal of the
    /// least-squares plane through the point and its
    /// [`NORMAL_NEIGHBOURS`]` - 1` nearest others, turned away from the
    /// points' centroid ([`Cloud::oriented_from`] turns them by another
    /// centre).
    ///
    /// # Errors
    ///
    /// [`ObservationError::TooFew`] below [`NORMAL_NEIGHBOURS`] points,
    /// [`ObservationError::NotFinite`] for a NaN or infinite coordinate,
    /// [`ObservationError::Degenerate`] where the points lie on one line.
    pub fn new(points: Vec<Vec3>) -> Result<Self, ObservationError> {
        if points.len() < NORMAL_NEIGHBOURS {
            return Err(ObservationError::TooFew {
                count: points.len(),
                least: NORMAL_NEIGHBOURS,
            });
        }
        if let Some((index, &value)) = points.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(ObservationError::NotFinite { index, value });
        }
        let centroid = points.iter().sum::<Vec3>() / points.len() as f32;
        let spread = svd3(covariance(points.iter().copied(), centroid)).sigma;
        // A plane needs two directions of spread.
        if spread.y <= 1e-10 * spread.x {
            return Err(ObservationError::Degenerate);
        }
        let tree = indexed_tree(&points);
        let (normals, nearest): (Vec<Vec3>, Vec<f32>) = points
            .par_iter()
            .map(|&p| {
                let near: Vec<Vec3> = tree
                    .nearest_neighbor_iter(p.to_array())
                    .take(NORMAL_NEIGHBOURS)
                    .map(|n| points[n.data])
                    .collect();
                let mean = near.iter().sum::<Vec3>() / near.len() as f32;
                let fit = svd3(covariance(near.iter().copied(), mean));
                // The direction of least spread: `u`'s last column.
                let normal = fit.u.z_axis;
                let normal = if normal.dot(p - centroid) < 0.0 {
                    -normal
                } else {
                    normal
                };
                // The first neighbour is the point itself (or a copy of it).
                let other = near.get(1).map_or(0.0, |q| (*q - p).length());
                (normal, other)
            })
            .unzip();
        Ok(Self {
            spacing: median(nearest),
            points,
            normals,
        })
    }

    /// The cloud without its outliers and with its noise across the
    /// surface averaged out, and how many points were set aside. Each
    /// point's plane is the least-squares plane of its
    /// [`NORMAL_NEIGHBOURS`]` - 1` nearest others; a point farther from its
    /// plane than [`RIGID_TRIM`] times the larger of `noise` and the robust
    /// deviation of all points' distances (1.4826 times their median) is
    /// set aside. Each kept point then moves onto the plane of its kept
    /// nearest others, and the normals are fitted again (turned away from
    /// the kept points' centroid).
    ///
    /// # Errors
    ///
    /// As [`Cloud::new`] for what is kept.
    pub fn cleaned(&self, noise: f32) -> Result<(Self, usize), ObservationError> {
        let planes = neighbour_planes(&self.points);
        let deviation = 1.4826 * median(planes.iter().map(|(offset, _)| offset.abs()).collect());
        let limit = RIGID_TRIM as f32 * deviation.max(noise);
        let kept: Vec<Vec3> = self
            .points
            .iter()
            .zip(&planes)
            .filter(|(_, (offset, _))| offset.abs() <= limit)
            .map(|(&p, _)| p)
            .collect();
        let set_aside = self.points.len() - kept.len();
        if kept.len() < NORMAL_NEIGHBOURS {
            return Err(ObservationError::TooFew {
                count: kept.len(),
                least: NORMAL_NEIGHBOURS,
            });
        }
        let projected = neighbour_planes(&kept)
            .iter()
            .zip(&kept)
            .map(|(&(offset, normal), &p)| p - offset * normal)
            .collect();
        Ok((Self::new(projected)?, set_aside))
    }

    /// The same cloud with every normal turned to point away from `centre`
    /// (the organ's inside, say): outward where the cloud is the skin.
    #[must_use]
    pub fn oriented_from(mut self, centre: Vec3) -> Self {
        for (n, p) in self.normals.iter_mut().zip(&self.points) {
            if n.dot(*p - centre) < 0.0 {
                *n = -*n;
            }
        }
        self
    }

    /// The points.
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Each point's unit normal.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// The median distance from a point to its nearest other point.
    pub fn spacing(&self) -> f32 {
        self.spacing
    }

    /// The grid that finds a query point's nearest observed point, exactly,
    /// wherever one lies within `margin` of it (and nothing beyond): cells
    /// of one spacing, queried on either device as the surface field is
    /// ([`SurfaceField::of_cloud`]); its cells also list every point within
    /// [`SMOOTH_REACH`] times [`CLOUD_SMOOTHING`] spacings, for the
    /// smoothed plane ([`SurfaceField::smooth_plane`]).
    ///
    /// # Errors
    ///
    /// [`ObservationError::Field`] where the margin is not a length or the
    /// grid would be absurdly large (a margin of thousands of spacings).
    pub fn field(&self, margin: f32) -> Result<SurfaceField, ObservationError> {
        // Points at one place have no spacing: a cell from their spread.
        let cell = if self.spacing > 0.0 {
            self.spacing
        } else {
            self.extent() * 1e-3
        };
        Ok(SurfaceField::of_cloud_within(
            &self.points,
            &self.normals,
            cell,
            margin,
            SMOOTH_REACH * CLOUD_SMOOTHING * cell,
        )?)
    }

    /// Refuses a cloud that cannot be a scan of an organ whose rest surface
    /// spans the box `[lo, hi]`: one whose bounding-box diagonal is outside
    /// [`SCAN_SCALE`] times the organ's (another unit; the error names the
    /// unit a power of ten explains), or whose centroid lies farther than
    /// the organ's diagonal from its box (another coordinate frame).
    ///
    /// # Errors
    ///
    /// [`ObservationError::Scale`] and [`ObservationError::Elsewhere`].
    pub fn check_against(&self, lo: Vec3, hi: Vec3) -> Result<(), ObservationError> {
        let size = (hi - lo).length();
        let (cloud_lo, cloud_hi) = self.bounds();
        let ratio = (cloud_hi - cloud_lo).length() / size;
        if !(SCAN_SCALE.0..=SCAN_SCALE.1).contains(&ratio) {
            // Millimetres against centimetres, metres, or micrometres.
            let hint = [(10.0, "ten"), (1000.0, "a thousand")]
                .iter()
                .find_map(|&(factor, words): &(f32, &str)| {
                    let off = |r: f32| (r.ln() - factor.ln()).abs() < 1.5f32.ln() * 2.0;
                    if off(ratio) {
                        Some(format!(
                            ": {words} times too large, as a scan in smaller units than the \
                             organ's (millimetres against {})",
                            if factor == 10.0 {
                                "centimetres"
                            } else {
                                "metres"
                            }
                        ))
                    } else if off(1.0 / ratio) {
                        Some(format!(
                            ": {words} times too small, as a scan in larger units than the \
                             organ's ({} against millimetres)",
                            if factor == 10.0 {
                                "centimetres"
                            } else {
                                "metres"
                            }
                        ))
                    } else {
                        None
                    }
                })
                .unwrap_or_default();
            return Err(ObservationError::Scale { ratio, hint });
        }
        let centroid = self.points.iter().sum::<Vec3>() / self.points.len() as f32;
        let distance = (centroid - centroid.clamp(lo, hi)).length();
        if distance > size {
            return Err(ObservationError::Elsewhere { distance, size });
        }
        Ok(())
    }

    /// The points' bounding box.
    fn bounds(&self) -> (Vec3, Vec3) {
        let lo = self.points.iter().copied().fold(Vec3::INFINITY, Vec3::min);
        let hi = self
            .points
            .iter()
            .copied()
            .fold(Vec3::NEG_INFINITY, Vec3::max);
        (lo, hi)
    }

    /// The largest side of the points' bounding box.
    pub fn extent(&self) -> f32 {
        let (lo, hi) = self.bounds();
        (hi - lo).max_element()
    }
}

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

/// `sum (p - mean)(p - mean)^T` over `points`.
fn covariance(points: impl Iterator<Item = Vec3>, mean: Vec3) -> Mat3 {
    points.fold(Mat3::ZERO, |sum, p| {
        let d = p - mean;
        sum + Mat3::from_cols(d * d.x, d * d.y, d * d.z)
    })
}

/// The points in an R*-tree, each with its index: their nearest
/// neighbours.
fn indexed_tree(points: &[Vec3]) -> RTree<GeomWithData<[f32; 3], usize>> {
    RTree::bulk_load(
        points
            .iter()
            .enumerate()
            .map(|(i, p)| GeomWithData::new(p.to_array(), i))
            .collect(),
    )
}

/// Per point, its signed distance from the least-squares plane of its
/// [`NORMAL_NEIGHBOURS`]` - 1` nearest other points, and that plane's unit
/// normal.
fn neighbour_planes(points: &[Vec3]) -> Vec<(f32, Vec3)> {
    let tree = indexed_tree(points);
    (0..points.len())
        .into_par_iter()
        .map(|i| {
            let p = points[i];
            let near: Vec<Vec3> = tree
                .nearest_neighbor_iter(p.to_array())
                .filter(|n| n.data != i)
                .take(NORMAL_NEIGHBOURS - 1)
                .map(|n| points[n.data])
                .collect();
            let mean = near.iter().sum::<Vec3>() / near.len().max(1) as f32;
            let normal = svd3(covariance(near.iter().copied(), mean)).u.z_axis;
            (normal.dot(p - mean), normal)
        })
        .collect()
}

/// The median (the upper one of an even count).
fn median(mut values: Vec<f32>) -> f32 {
    let middle = values.len() / 2;
    *values.select_nth_unstable_by(middle, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Points on the upper half of a sphere of radius 50 centred at the
    /// origin, about `spacing` apart on a jittered lattice, with Gaussian
    /// noise of `sigma` along the radius.
    fn cap(spacing: f32, sigma: f32) -> Vec<Vec3> {
        let mut rng = Pcg64::seed_from_u64(7);
        let mut points = Vec::new();
        let steps = (50.0 * std::f32::consts::FRAC_PI_2 / spacing) as usize;
        for i in 0..=steps {
            let polar = i as f32 * spacing / 50.0;
            let around =
                ((2.0 * std::f32::consts::PI * 50.0 * polar.sin() / spacing) as usize).max(1);
            for j in 0..around {
                let azimuth = (j as f32 + rng.random::<f32>() * 0.3) / around as f32
                    * 2.0
                    * std::f32::consts::PI;
                let direction = Vec3::new(
                    polar.sin() * azimuth.cos(),
                    polar.sin() * azimuth.sin(),
                    polar.cos(),
                );
                // Box-Muller.
                let (u, v): (f32, f32) = (rng.random::<f32>().max(1e-7), rng.random());
                let noise = (-2.0 * u.ln()).sqrt() * (2.0 * std::f32::consts::PI * v).cos();
                points.push(direction * (50.0 + sigma * noise));
            }
        }
        points
    }

    /// A noisy cap with a few points pushed 5 mm off: the cleaning sets
    /// those aside, and of the others only the noise's far tail (beyond
    /// three deviations: a few in a thousand), and brings the kept points
    /// closer to the sphere than the noise put them (0.49 to 0.26 RMS).
    #[test]
    fn cleaning_sets_the_outliers_aside_and_averages_the_noise_out() {
        let mut points = cap(3.0, 0.5);
        let outliers: Vec<usize> = (0..points.len()).step_by(97).collect();
        for &k in &outliers {
            points[k] *= 1.0 + 5.0 / 50.0;
        }
        let cloud = Cloud::new(points.clone()).unwrap();
        let (cleaned, set_aside) = cloud.cleaned(0.5).unwrap();
        let tail = set_aside - outliers.len().min(set_aside);
        assert!(
            set_aside >= outliers.len() && tail <= points.len() / 200,
            "{set_aside} set aside of {} points, {} pushed off",
            points.len(),
            outliers.len()
        );
        assert_eq!(cleaned.points().len(), points.len() - set_aside);
        let farthest = cleaned
            .points()
            .iter()
            .map(|p| (p.length() - 50.0).abs())
            .fold(0.0f32, f32::max);
        assert!(farthest < 2.5, "a kept point {farthest} off the sphere");
        let rms = |p: &[Vec3]| {
            (p.iter().map(|p| (p.length() - 50.0).powi(2)).sum::<f32>() / p.len() as f32).sqrt()
        };
        let kept: Vec<Vec3> = (0..points.len())
            .filter(|k| !outliers.contains(k))
            .map(|k| points[k])
            .collect();
        let (before, after) = (rms(&kept), rms(cleaned.points()));
        assert!(after < 0.6 * before, "{before} -> {after} off the sphere");
    }

    #[test]
    fn a_caps_normals_follow_its_radius_and_point_away_from_the_centre() {
        let points = cap(3.0, 0.0);
        let cloud = Cloud::new(points).unwrap().oriented_from(Vec3::ZERO);
        assert!((cloud.spacing() - 3.0).abs() < 0.6, "{}", cloud.spacing());
        let worst = cloud
            .points()
            .iter()
            .zip(cloud.normals())
            .map(|(p, n)| n.dot(p.normalize()))
            .fold(1.0f32, f32::min);
        // The plane through a point and its neighbours on a sphere of 50 mm
        // turns from the radius by about spacing / radius at the rim.
        assert!(
            worst > 0.99,
            "the worst normal is {:.2} degrees off the radius",
            worst.acos().to_degrees()
        );
    }

    #[test]
    fn a_noisy_caps_normals_stay_near_its_radius() {
        // The shared cases' scanner: 3 mm apart, 0.5 mm of noise.
        let cloud = Cloud::new(cap(3.0, 0.5)).unwrap().oriented_from(Vec3::ZERO);
        let mut cosines: Vec<f32> = cloud
            .points()
            .iter()
            .zip(cloud.normals())
            .map(|(p, n)| n.dot(p.normalize()))
            .collect();
        cosines.sort_by(f32::total_cmp);
        let median = cosines[cosines.len() / 2].acos().to_degrees();
        let tenth = cosines[cosines.len() / 10].acos().to_degrees();
        assert!(
            median < 5.0 && tenth < 9.0,
            "median {median:.1} degrees, 90th percentile {tenth:.1}"
        );
        assert!(cosines[0] > 0.0, "a normal points inwards");
    }

    #[test]
    fn the_field_finds_the_nearest_point_of_the_cloud() {
        let cloud = Cloud::new(cap(3.0, 0.5)).unwrap();
        let field = cloud.field(10.0).unwrap();
        for q in [Vec3::new(3.0, -4.0, 52.0), Vec3::new(30.0, 10.0, 35.0)] {
            let nearest = cloud
                .points()
                .iter()
                .map(|p| (*p - q).length())
                .fold(f32::INFINITY, f32::min);
            match field.query(q) {
                tissue_core::field::Side::Near(n) => {
                    assert!(
                        (n.distance.abs() - nearest).abs() < 1e-4,
                        "{n:?} against {nearest}"
                    );
                }
                other => panic!("{q} is {nearest} from the cloud, answered {other:?}"),
            }
        }
        // Nothing within the margin: no answer.
        assert_eq!(
            field.query(Vec3::new(0.0, 0.0, 20.0)),
            tissue_core::field::Side::DeepOutside
        );
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

    #[test]
    fn a_cloud_in_other_units_or_another_frame_is_refused_with_its_cause() {
        let points = cap(3.0, 0.5);
        // The organ: the cap's sphere, radius 50.
        let (lo, hi) = (Vec3::new(-50.0, -50.0, -50.0), Vec3::splat(50.0));
        Cloud::new(points.clone())
            .unwrap()
            .check_against(lo, hi)
            .unwrap();
        let scaled =
            |factor: f32| Cloud::new(points.iter().map(|p| *p * factor).collect()).unwrap();
        for (factor, says) in [
            (1000.0, "a thousand times too large"),
            (0.001, "a thousand times too small"),
            (10.0, "ten times too large"),
        ] {
            let err = scaled(factor)
                .check_against(lo, hi)
                .unwrap_err()
                .to_string();
            assert!(err.contains(says), "scaled by {factor}: {err}");
        }
        // Neither a unit nor a plausible scan: no hint.
        let err = scaled(40.0).check_against(lo, hi).unwrap_err().to_string();
        assert!(
            err.contains("times the organ's size") && !err.contains("units"),
            "{err}"
        );
        // A patch of a tenth of the cap is a scan.
        let patch: Vec<Vec3> = points.iter().copied().filter(|p| p.z > 49.6).collect();
        Cloud::new(patch).unwrap().check_against(lo, hi).unwrap();
        let far: Vec<Vec3> = points
            .iter()
            .map(|p| *p + Vec3::new(400.0, 0.0, 0.0))
            .collect();
        let err = Cloud::new(far).unwrap().check_against(lo, hi).unwrap_err();
        assert!(matches!(err, ObservationError::Elsewhere { .. }), "{err}");
        assert!(
            err.to_string().contains("another coordinate frame"),
            "{err}"
        );
    }

    #[test]
    fn the_defaults_are_pinned() {
        // docs/METHOD.md, "Observations without correspondence".
        assert_eq!(NORMAL_NEIGHBOURS, 12);
        assert_eq!(RIGID_TRIM, 3.0);
        assert_eq!(RIGID_SHARE, 1.0 / 64.0);
        assert_eq!(RIGID_STEPS, 100);
        assert_eq!(SCAN_SCALE, (0.02, 5.0));
    }

    #[test]
    fn clouds_that_show_no_surface_are_refused() {
        let few: Vec<Vec3> = (0..5).map(|i| Vec3::splat(i as f32)).collect();
        assert_eq!(
            Cloud::new(few).unwrap_err().to_string(),
            "the point cloud has 5 points; at least 12 are needed to estimate its normals"
        );
        let line: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new(i as f32, 2.0 * i as f32, 1.0))
            .collect();
        assert_eq!(Cloud::new(line).unwrap_err(), ObservationError::Degenerate);
        let mut points = cap(5.0, 0.0);
        points[17] = Vec3::new(1.0, f32::NAN, 0.0);
        let err = Cloud::new(points).unwrap_err();
        assert!(
            matches!(err, ObservationError::NotFinite { index: 17, .. }),
            "{err}"
        );
    }
}
