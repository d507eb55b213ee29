//! The shared cases' scanner clouds (`observed_cloud.csv`: the anterior half
//! of the deformed skin, 3 mm apart, 0.5 mm of noise, 1 % outliers) read
//! and fitted: their spacing, and normals that follow the true deformed
//! skin's.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use tissue::field::{Side, SurfaceField};
use tissue::io::space::Space;
use tissue::observation::{Cloud, load_cloud, rigid_fit};

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
    }
}

/// A case's cloud in another frame (turned 15 degrees about an oblique axis
/// through its centre and shifted 20 mm) is fitted back onto the deformed
/// skin it was scanned from.
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
