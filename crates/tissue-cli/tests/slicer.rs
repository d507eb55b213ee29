//! 3D Slicer's files through `tissue deform`: markups in and out.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use common::{json, s, sampled_model, size, text, tissue};

use serde_json::Value;
use tissue::deform::{Rigid, deform_surface};
use tissue::io::space::Space;
use tissue::{ParticleModel, Vec3};

/// A rigid motion of the phantom's skin, written as `moved.obj` in `dir`.
fn rigid_motion(dir: &Path, model: &ParticleModel) -> (Rigid, std::path::PathBuf) {
    let rigid = Rigid::about_axis(
        Vec3::new(0.3, 1.0, 0.2),
        20f32.to_radians(),
        Vec3::new(0.0, -5.0, 20.0),
        Vec3::new(6.0, -4.0, 3.0),
    );
    let surface = dir.join("moved.obj");
    tissue::save_surface(&deform_surface(&model.surface, &rigid), &surface).unwrap();
    (rigid, surface)
}

/// A point list in `system` with `points` (in that system) labelled `labels`.
fn markups_file(system: &str, points: &[Vec3], labels: &[&str]) -> String {
    let control_points: Vec<Value> = points
        .iter()
        .zip(labels)
        .enumerate()
        .map(|(k, (p, label))| {
            serde_json::json!({
                "id": (k + 1).to_string(),
                "label": label,
                "description": "",
                "associatedNodeID": "vtkMRMLModelNode4",
                "position": [p.x, p.y, p.z],
                "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
                "selected": true,
                "locked": false,
                "visibility": true,
                "positionStatus": "defined"
            })
        })
        .collect();
    serde_json::json!({
        "@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#",
        "markups": [{
            "type": "Fiducial",
            "coordinateSystem": system,
            "coordinateUnits": "mm",
            "controlPoints": control_points,
            "measurements": [],
            "display": {"visibility": true, "color": [0.4, 1.0, 1.0], "glyphType": "Sphere3D"}
        }]
    })
    .to_string()
}

fn positions(markups: &Value) -> Vec<Vec3> {
    markups["markups"][0]["controlPoints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| common::vec3(&c["position"]))
        .collect()
}

/// Landmarks in RAS with LPS surfaces (`--space` left at its default) and
/// RAS surfaces (`--space ras`): the moved points are where the rigid motion
/// of the surfaces' space takes them, written back in the file's system.
#[test]
fn markups_are_carried_in_their_coordinate_system_with_their_labels() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let (rigid, surface) = rigid_motion(dir.path(), &model);
    let tolerance = 1e-3 * size(&model);
    let landmarks = [Vec3::new(15.0, -10.0, 25.0), Vec3::new(-20.0, 10.0, 12.5)];
    let labels = ["tumour", "clip-1"];
    for (space, file_system) in [
        ("lps", "RAS"),
        ("ras", "RAS"),
        ("lps", "LPS"),
        ("ras", "LPS"),
    ] {
        let surfaces: Space = space.parse().unwrap();
        let system: Space = file_system.parse().unwrap();
        // The landmarks are in the surfaces' space; the file holds them in its own.
        let in_file: Vec<Vec3> = landmarks
            .iter()
            .map(|&p| surfaces.convert(system, p))
            .collect();
        let input = dir.path().join(format!("F-{space}-{file_system}.mrk.json"));
        std::fs::write(&input, markups_file(file_system, &in_file, &labels)).unwrap();
        let out_dir = dir.path().join(format!("out-{space}-{file_system}"));
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&surface),
            "--points",
            s(&input),
            "--space",
            space,
            "--output-dir",
            s(&out_dir),
        ]);
        assert!(out.status.success(), "{}", text(&out));
        assert!(!out_dir.join("points.csv").exists());
        let written = json(&out_dir.join("points.mrk.json"));
        let markup = &written["markups"][0];
        assert_eq!(markup["coordinateSystem"], file_system);
        assert_eq!(markup["display"]["glyphType"], "Sphere3D");
        assert_eq!(
            markup["controlPoints"][1]["associatedNodeID"],
            "vtkMRMLModelNode4"
        );
        let written_labels: Vec<&str> = markup["controlPoints"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["label"].as_str().unwrap())
            .collect();
        assert_eq!(written_labels, labels);
        for (k, (&x, y)) in landmarks.iter().zip(positions(&written)).enumerate() {
            let expected = surfaces.convert(system, rigid.apply(x));
            assert!(
                y.distance(expected) < tolerance,
                "--space {space}, a {file_system} file: point {k} at {y}, expected {expected}"
            );
        }
        let report = json(&out_dir.join("report.json"));
        let files: Vec<&str> = report["files"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_str().unwrap())
            .collect();
        assert!(
            files.iter().any(|f| f.ends_with("points.mrk.json")),
            "{files:?}"
        );
    }
}

/// Bad markups files are refused (exit 1) before any solve, naming the
/// file and the defect, and nothing is written.
#[test]
fn bad_markups_are_refused_naming_the_defect() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let (_, surface) = rigid_motion(dir.path(), &model);
    let good = markups_file("LPS", &[Vec3::new(15.0, -10.0, 25.0)], &["a"]);
    let cases = [
        ("not-json", "this is not JSON".to_owned(), "not a JSON file"),
        (
            "no-points",
            good.replace(r#""controlPoints":[{"#, r#""controlPoints":[],"x":[{"#),
            "no control points with a position",
        ),
        (
            "two-numbers",
            good.replace("[15.0,-10.0,25.0]", "[15.0,-10.0]"),
            "position [15.0,-10.0] is not 3 numbers",
        ),
        (
            "nan",
            good.replace("[15.0,-10.0,25.0]", "[15.0,NaN,25.0]"),
            "not a JSON file",
        ),
        (
            "system",
            good.replace(r#""LPS""#, r#""IJK""#),
            "unknown coordinateSystem `IJK`",
        ),
    ];
    for (name, content, expected) in cases {
        assert_ne!(content, good, "{name}: the replacement did not apply");
        let input = dir.path().join(format!("{name}.mrk.json"));
        std::fs::write(&input, &content).unwrap();
        let out_dir = dir.path().join(format!("out-{name}"));
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&surface),
            "--points",
            s(&input),
            "--output-dir",
            s(&out_dir),
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {message}");
        assert!(
            message.contains(expected) && message.contains(&format!("{name}.mrk.json")),
            "{name}: `{message}` lacks `{expected}` or the file's name"
        );
        assert!(!message.contains("panicked"), "{name}: {message}");
        assert!(!out_dir.join("report.json").exists(), "{name}");
    }
}
