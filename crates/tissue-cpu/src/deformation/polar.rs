//! The warm-started polar rotation (Müller et al. 2016, "A Robust Method to
//! Extract the Rotational Part of Deformations"), the default way each
//! particle's rotation is found.

use glam::{Mat3, Quat};
use tissue_solve::svd3::rotation_of;

/// Iterations of the warm-started polar update per solver iteration; the
/// solver's own iterations refine it further.
pub const POLAR_ITERATIONS: usize = 3;

/// The most updates a rotation that has not settled after
/// [`POLAR_ITERATIONS`] gets before the SVD is asked instead: an update
/// costs about a twentieth of the SVD, and on random stretched rotations
/// started 0.05 rad off, 54 % settle in three updates and all in four.
pub const POLAR_MOST_ITERATIONS: usize = 6;

/// The polar rotation of `m` from `start` by the warm update; where that has
/// not settled (far from `start`, or near a saddle of `trace(R^T m)`), the SVD.
pub fn warm_rotation(m: Mat3, start: Mat3) -> Mat3 {
    match polar_update(m, start, POLAR_ITERATIONS, POLAR_MOST_ITERATIONS) {
        (r, true) => r,
        (_, false) => rotation_of(m),
    }
}

/// The last turn of a settled polar update is below this (radians).
pub const POLAR_SETTLED: f32 = 1e-3;

/// The same for an update past the first [`POLAR_ITERATIONS`]: a rotation
/// that needs more converges slowly (its singular values far apart), and
/// is then several times its last turn from the polar rotation. With
/// `POLAR_SETTLED` there, 7 of the 3,000 test matrices of
/// `a_warm_rotation_is_the_svd_rotation_from_any_start` settled 1.3e-3 to
/// 2.7e-3 from the SVD's rotation; with 2e-4 none.
pub const POLAR_SETTLED_LATE: f32 = 2e-4;

/// Rotates `start` towards the polar rotation of `m` (the rotation `R`
/// maximising `trace(R^T m)`) by `iterations` updates, each about
/// `omega = sum_c r_c x m_c / |sum_c r_c . m_c|` (Müller et al. 2016, eq. 13).
/// Returns the rotation and whether it settled: its last turn was below
/// `POLAR_SETTLED` while `trace(R^T m) > 0` (so not at a saddle).
pub fn polar_rotation(m: Mat3, start: Mat3, iterations: usize) -> (Mat3, bool) {
    polar_update(m, start, iterations, iterations)
}

/// [`polar_rotation`] with `least` updates, and more while the last has not
/// settled (below [`POLAR_SETTLED_LATE`] past `least`), to `most`. Each update turns by the quaternion `(omega / 2, 1)`,
/// normalised: about `omega`'s axis by `2 atan(|omega| / 2)`, which is
/// `|omega|` to third order and needs no sine or cosine (Müller et al.
/// turn by `|omega|` exactly; the rotation the updates settle at is the
/// same, and an update costs 60 % of theirs).
pub fn polar_update(m: Mat3, start: Mat3, least: usize, most: usize) -> (Mat3, bool) {
    let scale = m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return (start, true);
    }
    let m = m * (1.0 / scale);
    let mut q = Quat::from_mat3(&start).normalize();
    let mut settled = false;
    for k in 0..most {
        let r = Mat3::from_quat(q);
        let cross = r.x_axis.cross(m.x_axis) + r.y_axis.cross(m.y_axis) + r.z_axis.cross(m.z_axis);
        let dot = r.x_axis.dot(m.x_axis) + r.y_axis.dot(m.y_axis) + r.z_axis.dot(m.z_axis);
        let omega = cross * (1.0 / (dot.abs() + 1e-9));
        let angle = omega.length();
        let settling = if k < least {
            POLAR_SETTLED
        } else {
            POLAR_SETTLED_LATE
        };
        settled = dot > 0.0 && angle < settling;
        if angle < 1e-9 {
            break;
        }
        let half = 0.5 * omega;
        q = (Quat::from_xyzw(half.x, half.y, half.z, 1.0) * q).normalize();
        if settled && k + 1 >= least {
            break;
        }
    }
    (Mat3::from_quat(q), settled)
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    #[test]
    fn a_warm_rotation_is_the_svd_rotation_from_any_start() {
        let mut checked = 0;
        let starts = [
            Mat3::IDENTITY,
            Mat3::from_rotation_x(3.1),
            Mat3::from_axis_angle(Vec3::new(1.0, 1.0, 0.0).normalize(), 1.5),
        ];
        for (k, m) in tissue_testkit::matrices(3_000).into_iter().enumerate() {
            let svd = crate::svd3::svd3(m);
            // Where the two smallest singular values nearly cancel the
            // maximum is nearly flat and any nearby rotation is as good.
            if (svd.sigma.y + svd.sigma.z).abs() < 0.05 {
                continue;
            }
            let r = warm_rotation(m, starts[k % 3]);
            let exact = rotation_of(m);
            let off = (r - exact)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            assert!(off < 1e-3, "{m:?}: off by {off}");
            assert!((r.determinant() - 1.0).abs() < 1e-5);
            checked += 1;
        }
        assert!(checked > 1_000);
    }

    #[test]
    fn the_warm_polar_update_keeps_a_rotation_that_is_already_right() {
        for m in tissue_testkit::matrices(500) {
            let exact = rotation_of(m);
            let (r, settled) = polar_rotation(m, exact, 3);
            assert!(settled);
            let off = (r - exact)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            assert!(off < 1e-4, "drifted by {off}");
        }
        assert_eq!(
            polar_rotation(Mat3::ZERO, Mat3::IDENTITY, 3).0,
            Mat3::IDENTITY
        );
    }

    #[test]
    fn an_unsettled_rotation_gets_more_updates_before_the_svd() {
        let (mut extended, mut same) = (0, 0);
        for (k, m) in tissue_testkit::matrices(3_000).into_iter().enumerate() {
            let exact = rotation_of(m);
            let axis = Vec3::new(1.0, (k % 5) as f32 - 2.0, 0.5).normalize();
            let start = Mat3::from_axis_angle(axis, 0.05) * exact;
            let three = polar_rotation(m, start, POLAR_ITERATIONS);
            let more = polar_update(m, start, POLAR_ITERATIONS, POLAR_MOST_ITERATIONS);
            if three.1 {
                // Settled in three: the same three updates.
                assert_eq!(three.0, more.0);
                assert!(more.1);
                same += 1;
            } else if more.1 {
                let off = (more.0 - exact)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f32, |a, x| a.max(x.abs()));
                assert!(off < 1e-3, "{m:?}: settled late {off} from the SVD's");
                extended += 1;
            }
        }
        // 36 and 225 of the 3,000 (many of them nearly singular).
        assert!(
            same > 20 && extended > 100,
            "{same} settled in three, {extended} later"
        );
    }
}
