//! The warm-started polar rotation (Müller et al. 2016, "A Robust Method to
//! Extract the Rotational Part of Deformations"), the default way each
//! particle's rotation is found.

use glam::Mat3;
use tissue_solve::svd3::rotation_of;

/// Iterations of the warm-started polar update per solver iteration; the
/// solver's own iterations refine it further.
const POLAR_ITERATIONS: usize = 3;

/// The polar rotation of `m` from `start` by the warm update; where that has
/// not settled (far from `start`, or near a saddle of `trace(R^T m)`), the SVD.
pub fn warm_rotation(m: Mat3, start: Mat3) -> Mat3 {
    match polar_rotation(m, start, POLAR_ITERATIONS) {
        (r, true) => r,
        (_, false) => rotation_of(m),
    }
}

/// The last turn of a settled polar update is below this (radians).
const POLAR_SETTLED: f32 = 1e-3;

/// Rotates `start` towards the polar rotation of `m` (the rotation `R`
/// maximising `trace(R^T m)`): each step turns `R` about
/// `sum_c r_c x m_c / |sum_c r_c . m_c|` (Müller et al. 2016, eq. 13).
/// Returns the rotation and whether it settled: its last turn was below
/// `POLAR_SETTLED` while `trace(R^T m) > 0` (so not at a saddle).
pub fn polar_rotation(m: Mat3, start: Mat3, iterations: usize) -> (Mat3, bool) {
    let scale = m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return (start, true);
    }
    let m = m * (1.0 / scale);
    let mut q = glam::Quat::from_mat3(&start).normalize();
    let mut settled = false;
    for _ in 0..iterations {
        let r = Mat3::from_quat(q);
        let cross = r.x_axis.cross(m.x_axis) + r.y_axis.cross(m.y_axis) + r.z_axis.cross(m.z_axis);
        let dot = r.x_axis.dot(m.x_axis) + r.y_axis.dot(m.y_axis) + r.z_axis.dot(m.z_axis);
        let omega = cross * (1.0 / (dot.abs() + 1e-9));
        let angle = omega.length();
        settled = dot > 0.0 && angle < POLAR_SETTLED;
        if angle < 1e-9 {
            break;
        }
        q = (glam::Quat::from_axis_angle(omega / angle, angle) * q).normalize();
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
}
