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

/// An ITK text transform file as ITK applies it: `T(x) = A (x - c) + c + t`
/// with `A` the first nine `Parameters` row by row, `t` the last three and
/// `c` the `FixedParameters`.
fn itk_transform(text: &str) -> impl Fn(glam::DVec3) -> glam::DVec3 + use<> {
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "#Insight Transform File V1.0");
    assert_eq!(lines[2], "Transform: AffineTransform_double_3_3");
    let numbers = |key: &str| -> Vec<f64> {
        let line = lines.iter().find(|l| l.starts_with(key)).unwrap();
        line[key.len()..]
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect()
    };
    let p = numbers("Parameters:");
    let c = numbers("FixedParameters:");
    let a = glam::DMat3::from_cols_array(&[p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]])
        .transpose();
    let t = glam::DVec3::new(p[9], p[10], p[11]);
    let c = glam::DVec3::new(c[0], c[1], c[2]);
    move |x| a * (x - c) + c + t
}

/// A rigid structure's motion is written beside it as `<stem>-rigid.tfm`:
/// the resampling transform in LPS, which takes each moved vertex (as the
/// report's 4x4 puts it) back to its rest place, for LPS and RAS surfaces.
#[test]
fn a_rigid_structure_s_motion_is_written_as_an_itk_transform() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let (rigid, surface) = rigid_motion(dir.path(), &model);
    let tumour_path = dir.path().join("tumour.obj");
    tissue::save_surface(&tissue::phantom::default_tumour(), &tumour_path).unwrap();
    let tumour = tissue::load_surface(&tumour_path).unwrap();
    let tolerance = 1e-3 * size(&model);
    for space in ["lps", "ras"] {
        let signs = space.parse::<Space>().unwrap().signs_to(Space::Lps);
        let out_dir = dir.path().join(format!("out-{space}"));
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&surface),
            "--rigid-structure",
            s(&tumour_path),
            "--space",
            space,
            "--output-dir",
            s(&out_dir),
        ]);
        assert!(out.status.success(), "{}", text(&out));
        let report = json(&out_dir.join("report.json"));
        let entry = &report["structures"][0];
        assert_eq!(entry["transform_file"], "tumour-rigid.tfm");
        assert!(
            report["files"]
                .as_array()
                .unwrap()
                .iter()
                .any(|f| f.as_str().unwrap().ends_with("tumour-rigid.tfm")),
            "{report}"
        );
        let rows: Vec<Vec<f64>> = entry["transform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                r.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            })
            .collect();
        let report_map = |x: glam::DVec3| {
            glam::DVec3::new(
                rows[0][0] * x.x + rows[0][1] * x.y + rows[0][2] * x.z + rows[0][3],
                rows[1][0] * x.x + rows[1][1] * x.y + rows[1][2] * x.z + rows[1][3],
                rows[2][0] * x.x + rows[2][1] * x.y + rows[2][2] * x.z + rows[2][3],
            )
        };
        let file =
            itk_transform(&std::fs::read_to_string(out_dir.join("tumour-rigid.tfm")).unwrap());
        for &x in &tumour.vertices {
            let x = x.as_dvec3();
            let moved = report_map(x);
            // The known motion, as a check on the report itself.
            assert!(moved.as_vec3().distance(rigid.apply(x.as_vec3())) < tolerance);
            let back = file(moved * signs);
            assert!(
                back.distance(x * signs) < 1e-4,
                "--space {space}: the .tfm takes the moved {moved} (LPS {}) to {back}, not {}",
                moved * signs,
                x * signs
            );
        }
    }
}

/// A NRRD file as its specification describes it, read here without our
/// writer's code: the header's fields (`key: value`) and key/value pairs
/// (`key:=value`), then the data (raw or gzip).
struct Nrrd {
    fields: std::collections::HashMap<String, String>,
    pairs: std::collections::HashMap<String, String>,
    data: Vec<f32>,
}

impl Nrrd {
    fn read(path: &Path) -> Self {
        use std::io::Read;
        let bytes = std::fs::read(path).unwrap();
        let end = bytes
            .windows(2)
            .position(|w| w == b"\n\n")
            .expect("a blank line ends the header");
        let header = std::str::from_utf8(&bytes[..end]).unwrap();
        let mut lines = header.lines();
        assert!(lines.next().unwrap().starts_with("NRRD000"));
        let (pairs, fields): (Vec<&str>, Vec<&str>) = lines
            .filter(|l| !l.starts_with('#'))
            .partition(|l| l.contains(":="));
        let pairs = pairs
            .into_iter()
            .filter_map(|l| l.split_once(":="))
            .map(|(key, value)| (key.to_owned(), value.to_owned()))
            .collect();
        let fields = fields
            .into_iter()
            .map(|l| {
                let (key, value) = l.split_once(": ").unwrap_or_else(|| panic!("{l}"));
                (key.to_owned(), value.to_owned())
            })
            .collect::<std::collections::HashMap<_, _>>();
        let body = &bytes[end + 2..];
        let raw = match fields["encoding"].as_str() {
            "raw" => body.to_vec(),
            "gzip" | "gz" => {
                let mut out = Vec::new();
                flate2::read::GzDecoder::new(body)
                    .read_to_end(&mut out)
                    .unwrap();
                out
            }
            other => panic!("encoding {other}"),
        };
        assert_eq!(fields["type"], "float");
        assert_eq!(fields["endian"], "little");
        let data = raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Self {
            fields,
            pairs,
            data,
        }
    }

    fn numbers(text: &str) -> Vec<f64> {
        text.split(|c: char| "(), ".contains(c))
            .filter(|t| !t.is_empty())
            .map(|t| t.parse().unwrap())
            .collect()
    }

    /// Trilinear interpolation at `p` (LPS) of a vector field whose space
    /// directions are diagonal.
    fn interpolate(&self, p: Vec3) -> Vec3 {
        let sizes: Vec<usize> = self.fields["sizes"]
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let origin = Self::numbers(&self.fields["space origin"]);
        let directions = Self::numbers(self.fields["space directions"].trim_start_matches("none"));
        let step = [directions[0], directions[4], directions[8]];
        let n = [sizes[1], sizes[2], sizes[3]];
        let mut base = [0usize; 3];
        let mut t = [0f64; 3];
        for a in 0..3 {
            let g = (f64::from(p[a]) - origin[a]) / step[a];
            assert!(g >= 0.0 && g <= (n[a] - 1) as f64, "{p} is off the grid");
            base[a] = (g.floor() as usize).min(n[a] - 2);
            t[a] = g - base[a] as f64;
        }
        let mut sum = [0f64; 3];
        for corner in 0..8 {
            let mut w = 1.0;
            let mut at = base;
            for a in 0..3 {
                let up = corner >> a & 1 == 1;
                w *= if up { t[a] } else { 1.0 - t[a] };
                at[a] += usize::from(up);
            }
            let index = 3 * ((at[2] * n[1] + at[1]) * n[0] + at[0]);
            for (c, s) in sum.iter_mut().enumerate() {
                *s += w * f64::from(self.data[index + c]);
            }
        }
        Vec3::new(sum[0] as f32, sum[1] as f32, sum[2] as f32)
    }
}

/// `deform --displacement-field` on the bundled sag: the NRRD file, read by
/// the reader above, interpolated at each moved particle (in LPS), gives
/// its rest minus moved position (the resampling direction) within 1 % of
/// the largest displacement, for LPS and RAS surfaces.
#[test]
fn the_displacement_field_takes_the_moved_particles_back_to_rest() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = common::assets().join("phantom-sag.obj");
    let n = model.len();
    for space in ["lps", "ras"] {
        let signs = space
            .parse::<Space>()
            .unwrap()
            .signs_to(Space::Lps)
            .as_vec3();
        let out_dir = dir.path().join(format!("out-{space}"));
        let field_path = dir.path().join(format!("field-{space}.nrrd"));
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&sag),
            "--space",
            space,
            "--displacement-field",
            s(&field_path),
            "--output-dir",
            s(&out_dir),
        ]);
        assert!(out.status.success(), "{}", text(&out));
        let report = json(&out_dir.join("report.json"));
        assert_eq!(report["displacement_field"]["file"], s(&field_path));
        assert!(
            report["files"]
                .as_array()
                .unwrap()
                .iter()
                .any(|f| f == s(&field_path)),
            "{report}"
        );
        let nrrd = Nrrd::read(&field_path);
        for (key, value) in [
            ("dimension", "4"),
            ("space", "left-posterior-superior"),
            ("kinds", "vector domain domain domain"),
            ("measurement frame", "(1,0,0) (0,1,0) (0,0,1)"),
        ] {
            assert_eq!(nrrd.fields[key], value);
        }
        // What makes 3D Slicer load it as a grid transform, not a volume
        // (qSlicerTransformsReader), and in which direction.
        assert_eq!(nrrd.pairs["intent_code"], "1006");
        assert_eq!(nrrd.pairs["displacement field type"], "resampling");
        let vtp = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
        let moved: Vec<Vec3> = common::vtp_array(&vtp, "Points")
            .chunks_exact(3)
            .take(n)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        let largest = model
            .positions
            .iter()
            .zip(&moved)
            .map(|(p, q)| p.distance(*q))
            .fold(0.0, f32::max);
        assert!(largest > 5.0, "the sag moved particles {largest} mm");
        let mut worst = 0.0_f32;
        for (i, (&p, &q)) in model.positions.iter().zip(&moved).enumerate() {
            let got = nrrd.interpolate(q * signs);
            let expected = (p - q) * signs;
            let error = got.distance(expected);
            worst = worst.max(error);
            if error > 0.01 * largest {
                eprintln!("{i} {p} {q} err {error}");
            }
            assert!(
                error <= 0.01 * largest,
                "--space {space}, particle {i}: the field gives {got}, rest minus moved is \
                 {expected} (LPS), error {error} > 1 % of {largest}"
            );
        }
        eprintln!("--space {space}: worst {worst} mm of {largest} mm");
    }
}

/// A displacement field that cannot be written as asked is refused before
/// the solve (exit 1), naming the option's file and the defect.
#[test]
fn bad_displacement_field_options_are_refused_before_the_solve() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let sag = common::assets().join("phantom-sag.obj");
    for (file, spacing, expected) in [
        ("field.vtk", "2", "name it <name>.nrrd"),
        ("field.nrrd", "0", "not a positive length"),
        ("field.nrrd", "-3", "not a positive length"),
        ("field.nrrd", "0.01", "choose a larger field spacing"),
        // Larger than a quarter of the organ: other units, or a typo.
        (
            "field.nrrd",
            "1e9",
            "fewer than 4 grid steps across the organ",
        ),
        // An existing folder of that name.
        ("taken.nrrd", "2", "it is a folder"),
    ] {
        let field = dir.path().join(file);
        if file == "taken.nrrd" {
            std::fs::create_dir_all(&field).unwrap();
        }
        let out_dir = dir.path().join("out");
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&sag),
            "--displacement-field",
            s(&field),
            &format!("--field-spacing={spacing}"),
            "--output-dir",
            s(&out_dir),
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{file} {spacing}: {message}");
        assert!(
            message.contains(expected) && message.contains(file),
            "{file} {spacing}: `{message}` lacks `{expected}`"
        );
        assert!(!message.contains("iterations"), "{message}");
        assert!(field.is_dir() || !field.exists(), "{file}");
        for left in ["report.json", "particles.vtp"] {
            assert!(
                !out_dir.join(left).exists(),
                "{file} {spacing}: {left} left"
            );
        }
    }
}
