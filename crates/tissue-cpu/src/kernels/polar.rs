//! The warm-started polar rotation (Müller et al. 2016, "A Robust Method to
//! Extract the Rotational Part of Deformations"), the default way each
//! particle's rotation is found.

use glam::{Mat3, Quat};
use tissue_solve::model::rotation_of;
use wide::f32x8;

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

/// How many rotations [`warm_rotations`] updates side by side. One
/// particle's update is a chain of dependent operations the core waits on;
/// eight in the lanes of `f32x8` (two SSE registers where there is no AVX)
/// run at once.
pub const LANES: usize = 8;

/// [`warm_rotation`] for up to [`LANES`] matrices at once: `out[l]` is the
/// polar rotation of `m[l]` from `start[l]`, by the updates
/// [`polar_update`] makes (to rounding), and the SVD where they do not
/// settle.
pub fn warm_rotations(m: &[Mat3], start: &[Mat3], out: &mut [Mat3]) {
    let count = m.len().min(start.len()).min(out.len()).min(LANES);
    let mut ms = [Mat3::ZERO; LANES];
    let mut starts = [Mat3::IDENTITY; LANES];
    ms[..count].copy_from_slice(&m[..count]);
    starts[..count].copy_from_slice(&start[..count]);
    let (rotations, settled) =
        polar_update_lanes(&ms, &starts, POLAR_ITERATIONS, POLAR_MOST_ITERATIONS);
    for l in 0..count {
        out[l] = if settled[l] {
            rotations[l]
        } else {
            rotation_of(m[l])
        };
    }
}

/// [`polar_update`] on [`LANES`] matrices side by side: each lane makes
/// the updates [`polar_update`] would make for it and stops where it
/// would (the others go on; a stopped lane's rotation no longer changes).
pub fn polar_update_lanes(
    m: &[Mat3; LANES],
    start: &[Mat3; LANES],
    least: usize,
    most: usize,
) -> ([Mat3; LANES], [bool; LANES]) {
    let lanes = |f: &dyn Fn(usize) -> f32| f32x8::new(std::array::from_fn(f));
    // Each lane's matrix scaled to its largest entry; a lane with nothing
    // to rotate towards keeps its start, as `polar_update` does.
    let scales: [f32; LANES] = std::array::from_fn(|l| {
        m[l].to_cols_array()
            .iter()
            .fold(0.0f32, |a, x| a.max(x.abs()))
    });
    let kept: [bool; LANES] = std::array::from_fn(|l| scales[l] == 0.0 || !scales[l].is_finite());
    let scaled: [[f32; 9]; LANES] = std::array::from_fn(|l| {
        if kept[l] {
            [0.0; 9]
        } else {
            (m[l] * (1.0 / scales[l])).to_cols_array()
        }
    });
    let a: [f32x8; 9] = std::array::from_fn(|k| lanes(&|l| scaled[l][k]));
    let starts: [Quat; LANES] = std::array::from_fn(|l| Quat::from_mat3(&start[l]).normalize());
    let (mut x, mut y, mut z, mut w) = (
        lanes(&|l| starts[l].x),
        lanes(&|l| starts[l].y),
        lanes(&|l| starts[l].z),
        lanes(&|l| starts[l].w),
    );
    // A mask with no lane set.
    let none = f32x8::ZERO;
    let mut active = lanes(&|l| if kept[l] { 0.0 } else { 1.0 }).simd_gt(f32x8::ZERO);
    let mut settled = !active;
    for k in 0..most {
        if !active.any() {
            break;
        }
        let settling = f32x8::splat(if k < least {
            POLAR_SETTLED
        } else {
            POLAR_SETTLED_LATE
        });
        // `Mat3::from_quat`, column by column.
        let (x2, y2, z2) = (x + x, y + y, z + z);
        let (xx, xy, xz) = (x * x2, x * y2, x * z2);
        let (yy, yz, zz) = (y * y2, y * z2, z * z2);
        let (wx, wy, wz) = (w * x2, w * y2, w * z2);
        let one = f32x8::ONE;
        let r = [
            [one - (yy + zz), xy + wz, xz - wy],
            [xy - wz, one - (xx + zz), yz + wx],
            [xz + wy, yz - wx, one - (xx + yy)],
        ];
        // The sums over the columns of `r_c x m_c` and `r_c . m_c`.
        let (mut cx, mut cy, mut cz, mut dot) =
            (f32x8::ZERO, f32x8::ZERO, f32x8::ZERO, f32x8::ZERO);
        for (c, r) in r.iter().enumerate() {
            let (m0, m1, m2) = (a[3 * c], a[3 * c + 1], a[3 * c + 2]);
            cx += r[1] * m2 - r[2] * m1;
            cy += r[2] * m0 - r[0] * m2;
            cz += r[0] * m1 - r[1] * m0;
            dot += r[0] * m0 + r[1] * m1 + r[2] * m2;
        }
        let inverse = one / (dot.abs() + f32x8::splat(1e-9));
        let (ox, oy, oz) = (cx * inverse, cy * inverse, cz * inverse);
        let angle = (ox * ox + oy * oy + oz * oz).sqrt();
        let is_settled = dot.simd_gt(f32x8::ZERO) & angle.simd_lt(settling);
        let moves = active & angle.simd_ge(f32x8::splat(1e-9));
        settled = active.select(is_settled, settled);
        // `(Quat(omega / 2, 1) * q).normalize()`.
        let half = f32x8::splat(0.5);
        let (hx, hy, hz) = (half * ox, half * oy, half * oz);
        let nx = x + hx * w + hy * z - hz * y;
        let ny = y - hx * z + hy * w + hz * x;
        let nz = z + hx * y - hy * x + hz * w;
        let nw = w - hx * x - hy * y - hz * z;
        let norm = one / (nx * nx + ny * ny + nz * nz + nw * nw).sqrt();
        x = moves.select(nx * norm, x);
        y = moves.select(ny * norm, y);
        z = moves.select(nz * norm, z);
        w = moves.select(nw * norm, w);
        let stops = if k + 1 >= least { is_settled } else { none };
        active = moves & !stops;
    }
    let (x, y, z, w) = (x.to_array(), y.to_array(), z.to_array(), w.to_array());
    let settled = settled.to_bitmask();
    let rotations = std::array::from_fn(|l| {
        if kept[l] {
            start[l]
        } else {
            Mat3::from_quat(Quat::from_xyzw(x[l], y[l], z[l], w[l]))
        }
    });
    (rotations, std::array::from_fn(|l| settled & (1 << l) != 0))
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
            let svd = crate::model::svd3(m);
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

    /// The lanes make each matrix's updates as [`polar_update`] makes them
    /// alone, whatever the others in the batch need: the same settling,
    /// and the same rotation to rounding (`f32x8` adds and multiplies as
    /// glam does, but for the quaternion's product and normalisation).
    #[test]
    fn the_lanes_update_each_matrix_as_it_is_updated_alone() {
        let matrices = tissue_testkit::matrices(4_000);
        let starts: Vec<Mat3> = matrices
            .iter()
            .enumerate()
            .map(|(k, m)| match k % 4 {
                0 => rotation_of(*m),
                1 => {
                    Mat3::from_axis_angle(
                        Vec3::new(1.0, (k % 5) as f32 - 2.0, 0.5).normalize(),
                        0.05,
                    ) * rotation_of(*m)
                }
                2 => Mat3::IDENTITY,
                _ => Mat3::from_rotation_y(2.8),
            })
            .collect();
        let (mut same, mut apart) = (0, 0);
        let mut worst = 0.0f32;
        for (m, start) in matrices.chunks(LANES).zip(starts.chunks(LANES)) {
            let (Ok(m), Ok(start)) = (
                <&[Mat3; LANES]>::try_from(m),
                <&[Mat3; LANES]>::try_from(start),
            ) else {
                panic!("4,000 matrices come in whole chunks of {LANES}");
            };
            let (lanes, settled) =
                polar_update_lanes(m, start, POLAR_ITERATIONS, POLAR_MOST_ITERATIONS);
            for l in 0..LANES {
                let (alone, alone_settled) =
                    polar_update(m[l], start[l], POLAR_ITERATIONS, POLAR_MOST_ITERATIONS);
                if settled[l] != alone_settled {
                    apart += 1;
                    continue;
                }
                same += 1;
                if !alone_settled {
                    // Unsettled, the SVD answers instead (`warm_rotations`).
                    continue;
                }
                let off = (lanes[l] - alone)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f32, |a, x| a.max(x.abs()));
                worst = worst.max(off);
            }
        }
        // A last turn within rounding of the threshold may settle on one
        // side only; none did here.
        assert!(
            apart <= 4,
            "{apart} of {} settled differently",
            same + apart
        );
        assert!(
            worst < 1e-5,
            "the lanes' rotations {worst:e} from the one-at-a-time ones"
        );
        // Zero, and a batch shorter than the lanes, keep their start.
        let mut out = [Mat3::ZERO; 3];
        let few = [Mat3::ZERO, matrices[1], matrices[2]];
        let from = [Mat3::from_rotation_x(0.3), starts[1], starts[2]];
        warm_rotations(&few, &from, &mut out);
        assert_eq!(out[0], from[0]);
        for l in 1..3 {
            assert_eq!(out[l], warm_rotation(few[l], from[l]), "lane {l}");
        }
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
