//! A rigid motion written as an ITK transform file, read back by a parser
//! written here from ITK's text format (`TxtTransformIO`) and applied as
//! ITK applies an `AffineTransform`: `T(x) = A (x - c) + c + t`, with `A`
//! the first nine parameters row by row, `t` the last three and `c` the
//! fixed parameters. The file is the resampling transform, moved to rest,
//! in LPS.
#![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

use glam::{DMat3, DVec3};
use tissue_core::io::itk::{Affine, save_motion_tfm};
use tissue_core::io::space::Space;

/// The transform of an ITK text transform file: (A, t, c).
fn read_tfm(text: &str) -> (DMat3, DVec3, DVec3) {
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("#Insight Transform File V1.0"));
    assert_eq!(lines.next(), Some("#Transform 0"));
    assert_eq!(lines.next(), Some("Transform: AffineTransform_double_3_3"));
    let numbers = |line: Option<&str>, key: &str| -> Vec<f64> {
        let line = line.unwrap();
        let rest = line.strip_prefix(key).unwrap_or_else(|| panic!("{line}"));
        rest.split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect()
    };
    let p = numbers(lines.next(), "Parameters:");
    let c = numbers(lines.next(), "FixedParameters:");
    assert_eq!((p.len(), c.len()), (12, 3));
    let a =
        DMat3::from_cols_array(&[p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]]).transpose();
    (
        a,
        DVec3::new(p[9], p[10], p[11]),
        DVec3::new(c[0], c[1], c[2]),
    )
}

#[test]
fn the_tfm_maps_moved_points_back_to_rest_in_lps() {
    // 30 degrees about a tilted axis, then 5 mm right, 3 back, 12 up.
    let rotation = glam::Mat3::from_axis_angle(
        glam::Vec3::new(0.2, -0.5, 1.0).normalize(),
        30f32.to_radians(),
    );
    let translation = glam::Vec3::new(5.0, -3.0, 12.0);
    let r = rotation.transpose().to_cols_array_2d(); // rows
    let rows = [
        [r[0][0], r[0][1], r[0][2], translation.x],
        [r[1][0], r[1][1], r[1][2], translation.y],
        [r[2][0], r[2][1], r[2][2], translation.z],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let motion = |x: DVec3| rotation.as_dmat3() * x + translation.as_dvec3();
    let dir = tempfile::tempdir().unwrap();
    for space in [Space::Lps, Space::Ras] {
        let path = dir.path().join(format!("tumour-{space}.tfm"));
        save_motion_tfm(&Affine::from_rows(&rows), space, &path).unwrap();
        let (a, t, c) = read_tfm(&std::fs::read_to_string(&path).unwrap());
        let itk = |y: DVec3| a * (y - c) + c + t;
        let to_lps = |p: DVec3| p * space.signs_to(Space::Lps);
        for x in [
            DVec3::ZERO,
            DVec3::new(15.0, -10.0, 25.0),
            DVec3::new(-40.0, 7.5, 3.0),
        ] {
            let moved = motion(x);
            let back = itk(to_lps(moved));
            assert!(
                back.distance(to_lps(x)) < 1e-5,
                "{space}: rest {x}, moved {moved}: the file takes it (LPS) to {back}, not {}",
                to_lps(x)
            );
        }
    }
}
