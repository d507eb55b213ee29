//! The shared cases' scanner clouds (`observed_cloud.csv`: the anterior half
//! of the deformed skin, 3 mm apart, 0.5 mm of noise, 1 % outliers) read
//! and fitted: their spacing, and normals that follow the true deformed
//! skin's.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use tissue::field::{Side, SurfaceField};
use tissue::io::space::Space;
use tissue::observation::{CLOUD_NOISE, Cloud, Observation, load_cloud, rigid_fit};

#[test]
fn the_cases_clouds_have_their_spacing_and_the_skins_normals() {
    for name in ["breast_c", "breast_d", "breast_e"] {
        let Some(case) = common::shared_case(name) else {
            return;
        };
        let rest = tissue::load_closed_surface(&case.join("rest.obj")).unwrap();
        let deformed = tissue::load_closed_surface(&case.join("deformed.obj")).unwrap();
        let points = load_cloud(&case.join("observed_cloud.csv"), Space::Lps).unwrap();
        let count = points.len();
        let centre = rest.vertices.iter().sum::<tissue::Vec3>() / rest.vertices.len() as f32;
        let cloud = Cloud::new(points).unwrap().oriented_from(centre);
        assert!(
            (2.2..3.4).contains(&cloud.spacing()),
            "{name}: spacing {} mm, the scan's is about 3",
            cloud.spacing()
        );
        // Each point's normal against the true skin's at its nearest point.
        let skin = SurfaceField::new(&deformed, 2.0, 3.0).unwrap();
        let mut angles: Vec<f32> = cloud
            .points()
            .iter()
            .zip(cloud.normals())
            .filter_map(|(p, n)| match skin.query(*p) {
                Side::Near(near) => Some(n.dot(near.normal).clamp(-1.0, 1.0).acos().to_degrees()),
                _ => None,
            })
            .collect();
        assert!(
            angles.len() * 100 >= count * 98,
            "{name}: {} of {count} points near the skin",
            angles.len()
        );
        angles.sort_by(f32::total_cmp);
        let median = angles[angles.len() / 2];
        let ninetieth = angles[angles.len() * 9 / 10];
        eprintln!(
            "{name}: {count} points, spacing {:.2} mm, normals off the skin's by {median:.1} degrees (median), {ninetieth:.1} (90th percentile)",
            cloud.spacing()
        );
        assert!(
            median < 6.0 && ninetieth < 12.0,
            "{name}: normals off by {median:.1} (median) and {ninetieth:.1} degrees (90th percentile)"
        );
        // A scan's patch: no point lies on a line of points, so every
        // normal is the scan's own.
        assert!(cloud.lines().is_empty(), "{name}: {:?}", cloud.lines());
    }
}

/// A case's cloud in another frame (turned 15 degrees about an oblique axis
/// through its centre and shifted 20 mm) is fitted back onto the deformed
/// skin it was scanned from.
/// The shared cases' clouds (about 2.6 mm apart) are moved onto their
/// neighbours' planes, which bend under them by a quarter of their noise,
/// and lie a little inside the true skin for it; every fourth point of
/// them (3.6-3.9 mm apart, the planes bending under them by most of the
/// noise) is kept as scanned, and lies on the skin on average.
#[test]
fn a_cases_cloud_thinned_for_its_skins_bend_is_kept_as_scanned() {
    for name in ["breast_c", "breast_d", "breast_e"] {
        let Some(case) = common::shared_case(name) else {
            return;
        };
        let deformed = tissue::load_closed_surface(&case.join("deformed.obj")).unwrap();
        let skin = SurfaceField::new(&deformed, 2.0, 3.0).unwrap();
        let points = load_cloud(&case.join("observed_cloud.csv"), Space::Lps).unwrap();
        let thinned: Vec<tissue::Vec3> = points.iter().step_by(4).copied().collect();
        // The mean signed distance from the true skin of the points kept,
        // over those near it (the outliers 3-8 mm off are set aside).
        let shift = |points: &[tissue::Vec3]| {
            let near: Vec<f32> = points
                .iter()
                .filter_map(|p| match skin.query(*p) {
                    Side::Near(near) if near.distance.abs() < 2.0 => Some(near.distance),
                    _ => None,
                })
                .collect();
            near.iter().sum::<f32>() / near.len() as f32
        };
        for (points, flattened) in [(points, true), (thinned, false)] {
            let count = points.len();
            let spacing = Cloud::new(points.clone()).unwrap().spacing();
            let cleaned = Cloud::new(points)
                .unwrap()
                .cleaned(CLOUD_NOISE * spacing)
                .unwrap();
            let (bend, noise) = cleaned.bend;
            let moved = shift(cleaned.cloud.points());
            eprintln!(
                "{name}: {count} points, bend {bend:.3} over noise {noise:.3}, kept points {moved:+.3} mm from the skin"
            );
            assert_eq!(cleaned.flattened, flattened, "{name}, {count} points");
            if flattened {
                assert!((-0.3..-0.05).contains(&moved), "{name}: {moved}");
            } else {
                assert!(moved.abs() < 0.1, "{name}: {moved}");
            }
        }
    }
}

#[test]
fn a_cases_cloud_in_another_frame_is_fitted_back_onto_the_skin() {
    for name in ["breast_c", "breast_e"] {
        let Some(case) = common::shared_case(name) else {
            return;
        };
        let deformed = tissue::load_closed_surface(&case.join("deformed.obj")).unwrap();
        let points = load_cloud(&case.join("observed_cloud.csv"), Space::Lps).unwrap();
        let centre = points.iter().sum::<tissue::Vec3>() / points.len() as f32;
        let turn = tissue::advanced::model::rotation_of(glam::Mat3::from_axis_angle(
            glam::Vec3::new(0.3, -1.0, 0.4).normalize(),
            15f32.to_radians(),
        ));
        let shift = glam::Vec3::new(16.0, 0.0, -12.0);
        let moved: Vec<glam::Vec3> = points
            .iter()
            .map(|&p| turn * (p - centre) + centre + shift)
            .collect();
        let skin = SurfaceField::new(&deformed, 2.0, 3.0).unwrap();
        let fit = rigid_fit(&moved, &skin, 30.0).unwrap();
        let worst = points
            .iter()
            .zip(&moved)
            .map(|(p, q)| (fit.apply(*q) - *p).length())
            .fold(0.0f32, f32::max);
        // Fitted where it was scanned, the cloud moves too: 0.5 mm of noise
        // on a near half-ellipsoid fixes its turn about its axis loosely.
        // Both fits must put the points at the same place.
        let unmoved = rigid_fit(&points, &skin, 30.0).unwrap();
        let apart = points
            .iter()
            .zip(&moved)
            .map(|(p, q)| (fit.apply(*q) - unmoved.apply(*p)).length())
            .fold(0.0f32, f32::max);
        eprintln!(
            "{name}: {fit:?}, points back within {worst:.3} mm, {apart:.4} mm from the unmoved cloud's fit"
        );
        assert!(
            apart < 0.05,
            "{name}: the two fits put the points {apart} mm apart"
        );
        assert!(
            fit.converged && (fit.angle_degrees - 15.0).abs() < 0.3 && worst < 0.6,
            "{name}: {fit:?}, points back within {worst:.3} mm"
        );
        // The 1 % outliers, and no more than a few others, set aside.
        assert!(
            (points.len() / 200..points.len() / 20).contains(&fit.set_aside),
            "{name}: {fit:?}"
        );
    }
}

/// A cloud's noise scale where none is given: the larger of a fifth of
/// its spacing and its points' own scatter about their neighbours' planes.
/// A dense scan with 1 mm of noise (points 1.3 mm apart on a dome of
/// radius 50 mm) gets most of it (the nearest neighbours, picked in 3-D,
/// lean to the point's side of the surface, so the scatter reads low
/// where the noise nears the spacing: 0.72 mm here), not a fifth of its
/// spacing (0.26 mm), so a good match to it is not flagged as far above
/// its noise; the same points without noise get a fifth of their
/// spacing.
#[test]
fn a_clouds_noise_scale_is_its_own_scatter_at_least_a_fifth_of_its_spacing() {
    let count = 10_000;
    let dome = |noise: f32| -> Vec<glam::Vec3> {
        let mut uniform = tissue_testkit::xorshift(7);
        let golden = std::f32::consts::PI * (3.0 - 5.0_f32.sqrt());
        (0..count)
            .map(|k| {
                let z = 1.0 - (k as f32 + 0.5) / count as f32;
                let ring = (1.0 - z * z).sqrt();
                let turn = golden * k as f32;
                let direction = glam::Vec3::new(ring * turn.cos(), ring * turn.sin(), z);
                // A normal deviate from two uniform ones (Box-Muller).
                let (u, v) = (0.5 * (uniform() + 1.0), 0.5 * (uniform() + 1.0));
                let u = u.max(1e-7);
                let deviate = (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos();
                direction * (50.0 + noise * deviate)
            })
            .collect()
    };
    let inside = glam::Vec3::ZERO;
    let noisy = Cloud::new(dome(1.0)).unwrap();
    let spacing = noisy.spacing();
    let scale = Observation::cloud(&noisy, None, inside)
        .unwrap()
        .cloud_noise()
        .unwrap();
    assert!(
        (0.6..1.2).contains(&scale) && scale > 2.0 * CLOUD_NOISE * spacing,
        "noise 1: the scale {scale}, the spacing {spacing}"
    );
    let clean = Cloud::new(dome(0.0)).unwrap();
    let observation = Observation::cloud(&clean, None, inside).unwrap();
    let fifth = CLOUD_NOISE * observation.cloud_spacing().unwrap();
    assert_eq!(observation.cloud_noise(), Some(fifth));
    // The caller's noise is taken as it is.
    let given = Observation::cloud(&noisy, Some(0.3), inside).unwrap();
    assert_eq!(given.cloud_noise(), Some(0.3));
}
