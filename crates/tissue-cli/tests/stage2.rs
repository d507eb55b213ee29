//! `tissue deform`, `track` and `demo` as a user runs them.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use common::{assets, json, s, sampled_model, size, text, tissue, vec3, vtp_array};

use serde_json::Value;
use tissue::deform::{Rigid, Sag, deform_surface, interpolate};
use tissue::{SurfaceMesh, Vec3, phantom};

fn triples(values: &[f32]) -> Vec<Vec3> {
    values
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect()
}

fn structure<'a>(report: &'a Value, kind: &str) -> &'a Value {
    report["structures"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["kind"] == kind)
        .unwrap_or_else(|| panic!("no {kind} structure in {report}"))
}

#[test]
fn demo_writes_everything_and_the_tumour_sags_towards_the_feet() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = tissue(&["demo", "--particles", "2000", "--output-dir", s(&out_dir)]);
    assert!(out.status.success(), "{}", text(&out));
    let printed = text(&out);
    for expect in [
        "sampled 2000 particles",
        "sag:",
        "indentation:",
        "tumour-rigid.obj (rigid)",
        "turned",
    ] {
        assert!(printed.contains(expect), "no `{expect}` in {printed}");
    }
    for file in [
        "model.vtp",
        "breast.obj",
        "tumour.obj",
        "breast-sag.obj",
        "breast-indentation.obj",
        "demo.json",
        "sag/particles.vtp",
        "sag/tumour.obj",
        "sag/tumour-rigid.obj",
        "sag/report.json",
        "indentation/particles.vtp",
        "indentation/tumour.obj",
        "indentation/tumour-rigid.obj",
        "indentation/report.json",
        "demo.png",
        "demo-indentation.png",
    ] {
        assert!(out_dir.join(file).is_file(), "demo did not write {file}");
    }
    // The picture: the tumour moved (red) and the largest displacement
    // (the colour map's yellow end) are in it; where they are is checked
    // by the picture's own tests.
    let picture = tiny_skia::Pixmap::load_png(out_dir.join("demo.png")).unwrap();
    assert_eq!((picture.width(), picture.height()), (1400, 700));
    let colours: Vec<[u8; 3]> = picture
        .pixels()
        .iter()
        .map(|p| {
            let c = p.demultiply();
            [c.red(), c.green(), c.blue()]
        })
        .collect();
    let red = colours
        .iter()
        .filter(|c| c[0] > 150 && c[1] < 110 && c[2] < 110)
        .count();
    let yellow = colours
        .iter()
        .filter(|c| c[0] > 200 && c[1] > 200 && c[2] < 90)
        .count();
    assert!(red > 500, "{red} red pixels: no moved tumour");
    assert!(yellow > 100, "{yellow} yellow pixels: no colour bar or sag");

    let summary = json(&out_dir.join("demo.json"));
    assert_eq!(summary["particles"], 2000);
    let cases = summary["cases"].as_array().unwrap();
    assert_eq!(cases.len(), 2);
    for case in cases {
        assert_eq!(case["converged"], true, "{case}");
        assert!(case["iterations"].as_u64().unwrap() > 0);
        for kind in ["deformable", "rigid"] {
            let tumour = structure(case, kind);
            let moved = vec3(&tumour["moved_centroid"]) - vec3(&tumour["rest_centroid"]);
            let distance = tumour["displacement_mm"].as_f64().unwrap() as f32;
            assert!((moved.length() - distance).abs() < 1e-4, "{tumour}");
            match case["name"].as_str().unwrap() {
                "sag" => {
                    assert!(
                        (1.0..12.0).contains(&distance),
                        "sag moved the {kind} tumour {distance} mm"
                    );
                    assert!(
                        -moved.y > 0.9 * distance,
                        "sag moved the {kind} tumour by {moved}, not mostly along -y"
                    );
                }
                "indentation" => {
                    // The probe pushes along about -z, 8 mm at the skin, 20 mm above the tumour.
                    assert!(distance < 8.0, "{kind}: {distance} mm");
                    assert!(
                        moved.z < 0.0,
                        "indentation moved the {kind} tumour by {moved}"
                    );
                }
                other => panic!("unexpected case {other}"),
            }
        }
        let rigid = structure(case, "rigid");
        assert!(
            rigid["rotation_degrees"].as_f64().unwrap() < 30.0,
            "{rigid}"
        );
        assert_eq!(rigid["transform"].as_array().unwrap().len(), 4);
    }

    // particles.vtp: moved positions whose displacement leads back to the rest model.
    let model = tissue::load_model(&out_dir.join("model.vtp")).unwrap();
    let vtp = std::fs::read_to_string(out_dir.join("sag/particles.vtp")).unwrap();
    let points = triples(&vtp_array(&vtp, "Points"));
    let displacement = triples(&vtp_array(&vtp, "displacement"));
    let flags = vtp_array(&vtp, "surface");
    let n = model.len();
    let v = model.surface.vertices.len();
    assert_eq!(points.len(), n + v);
    assert_eq!(displacement.len(), n + v);
    assert_eq!(flags.len(), n + v);
    for i in 0..n {
        let back = points[i] - displacement[i];
        assert!(
            back.distance(model.positions[i]) < 1e-4,
            "particle {i}: {} - {} is not the rest position {}",
            points[i],
            displacement[i],
            model.positions[i]
        );
        assert_eq!(flags[i], f32::from(u8::from(model.is_surface(i))));
    }
    let skin = tissue::load_surface(&out_dir.join("breast-sag.obj")).unwrap();
    for k in 0..v {
        assert!(points[n + k].distance(skin.vertices[k]) < 1e-4);
        assert_eq!(flags[n + k], 2.0);
    }
    assert!(
        tissue::load_model(&out_dir.join("sag/particles.vtp")).is_err(),
        "particles.vtp must not pass for a rest model"
    );
}

#[test]
fn deform_follows_a_rigid_motion_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let rigid = Rigid::about_axis(
        Vec3::new(0.3, 1.0, 0.2),
        25f32.to_radians(),
        Vec3::new(0.0, -5.0, 20.0),
        Vec3::new(6.0, -4.0, 3.0),
    );
    let deformed = deform_surface(&model.surface, &rigid);
    let surface = dir.path().join("moved.obj");
    tissue::save_surface(&deformed, &surface).unwrap();
    let tumour_path = dir.path().join("tumour.obj");
    tissue::save_surface(&phantom::default_tumour(), &tumour_path).unwrap();
    // As the CLI reads it (the OBJ reader numbers vertices by first use).
    let tumour = tissue::load_surface(&tumour_path).unwrap();
    let landmarks = [Vec3::new(15.0, -10.0, 25.0), Vec3::new(-20.0, 10.0, 12.5)];
    let points_path = dir.path().join("landmarks.csv");
    tissue::save_points(&landmarks, &points_path).unwrap();

    let out_dir = dir.path().join("out");
    let report_path = dir.path().join("elsewhere/report.json");
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&surface),
        "--structure",
        s(&tumour_path),
        "--rigid-structure",
        s(&tumour_path),
        "--points",
        s(&points_path),
        "--output-dir",
        s(&out_dir),
        "--report",
        s(&report_path),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("converged"), "{}", text(&out));
    let tolerance = 1e-3 * size(&model);

    let report = json(&report_path);
    for key in [
        "iterations",
        "residual",
        "seconds",
        "converged",
        "residual_history",
        "structures",
    ] {
        assert!(report.get(key).is_some(), "report lacks {key}: {report}");
    }
    assert_eq!(report["converged"], true);
    assert_eq!(
        report["residual_history"].as_array().unwrap().len() as u64,
        report["iterations"].as_u64().unwrap()
    );
    assert!(
        !out_dir.join("report.json").exists(),
        "--report was ignored"
    );

    let rest_centroid =
        tumour.vertices.iter().copied().sum::<Vec3>() / tumour.vertices.len() as f32;
    let expected = rigid.apply(rest_centroid);
    for (kind, file) in [("deformable", "tumour.obj"), ("rigid", "tumour-rigid.obj")] {
        let entry = structure(&report, kind);
        assert_eq!(entry["name"], file);
        let moved = vec3(&entry["moved_centroid"]);
        assert!(
            moved.distance(expected) < tolerance,
            "{kind}: centroid at {moved}, the rigid map puts it at {expected} (tolerance {tolerance})"
        );
        let distance = entry["displacement_mm"].as_f64().unwrap() as f32;
        assert!((distance - expected.distance(rest_centroid)).abs() < tolerance);
        let written = tissue::load_surface(&out_dir.join(file)).unwrap();
        assert_eq!(written.triangles, tumour.triangles);
        for (k, (&x, &y)) in tumour.vertices.iter().zip(&written.vertices).enumerate() {
            assert!(
                y.distance(rigid.apply(x)) < tolerance,
                "{file} vertex {k}: {y} vs {}",
                rigid.apply(x)
            );
        }
    }

    // The rigid structure's 4x4 transform is the rigid map.
    let rows: Vec<Vec<f32>> = structure(&report, "rigid")["transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|row| {
            row.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32)
                .collect()
        })
        .collect();
    assert_eq!(rows[3], [0.0, 0.0, 0.0, 1.0]);
    let transform = |x: Vec3| {
        Vec3::new(
            rows[0][0] * x.x + rows[0][1] * x.y + rows[0][2] * x.z + rows[0][3],
            rows[1][0] * x.x + rows[1][1] * x.y + rows[1][2] * x.z + rows[1][3],
            rows[2][0] * x.x + rows[2][1] * x.y + rows[2][2] * x.z + rows[2][3],
        )
    };
    for &x in tumour.vertices.iter().chain(&model.surface.vertices) {
        assert!(
            transform(x).distance(rigid.apply(x)) < tolerance,
            "transform takes {x} to {}, the rigid map to {}",
            transform(x),
            rigid.apply(x)
        );
    }
    let angle = structure(&report, "rigid")["rotation_degrees"]
        .as_f64()
        .unwrap();
    assert!((angle - 25.0).abs() < 0.1, "turned {angle} degrees, not 25");

    let moved_points = tissue::load_points(&out_dir.join("points.csv")).unwrap();
    assert_eq!(moved_points.len(), landmarks.len());
    for (&x, &y) in landmarks.iter().zip(&moved_points) {
        assert!(y.distance(rigid.apply(x)) < tolerance, "{x} went to {y}");
    }
    let vtp = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
    let points = triples(&vtp_array(&vtp, "Points"));
    for (i, (&q, &p)) in points.iter().zip(&model.positions).enumerate() {
        assert!(
            q.distance(rigid.apply(p)) < tolerance,
            "particle {i}: {q} vs {}",
            rigid.apply(p)
        );
    }
}

/// Sampling turns an inward-facing surface outward; the deformed skins from
/// the same source face inward too, and must still be taken as the same mesh.
#[test]
fn deform_accepts_an_inward_facing_skin_like_the_one_sampled() {
    let dir = tempfile::tempdir().unwrap();
    let mut inward = phantom::default_breast();
    for t in &mut inward.triangles {
        t.swap(1, 2);
    }
    let rest_path = dir.path().join("inward.obj");
    tissue::save_surface(&inward, &rest_path).unwrap();
    let model_path = dir.path().join("model.vtp");
    let out = tissue(&["sample", s(&rest_path), "-n", "2000", "-o", s(&model_path)]);
    assert!(out.status.success(), "{}", text(&out));
    let rigid = Rigid::about_axis(Vec3::X, 0.2, Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0));
    let moved_path = dir.path().join("inward-moved.obj");
    tissue::save_surface(&deform_surface(&inward, &rigid), &moved_path).unwrap();
    let tumour_path = dir.path().join("tumour.obj");
    tissue::save_surface(&phantom::default_tumour(), &tumour_path).unwrap();
    let out_dir = dir.path().join("out");
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&moved_path),
        "--rigid-structure",
        s(&tumour_path),
        "--output-dir",
        s(&out_dir),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(out.stdout.is_empty(), "--quiet printed {}", text(&out));
    let entry = structure(&json(&out_dir.join("report.json")), "rigid").clone();
    let expected = rigid.apply(Vec3::new(15.0, -10.0, 25.0));
    let model = tissue::load_model(&model_path).unwrap();
    assert!(
        vec3(&entry["moved_centroid"]).distance(expected) < 1e-3 * size(&model),
        "{entry}"
    );
}

#[test]
fn track_solves_every_frame_in_order_and_writes_each() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged: SurfaceMesh = deform_surface(&model.surface, &Sag::default());
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    // Named so that plain string order would be wrong: 2 before 10.
    for (k, name) in [(1, "skin-1.obj"), (2, "skin-2.obj"), (3, "skin-10.obj")] {
        let frame = interpolate(&model.surface, &sagged, k as f32 / 3.0).unwrap();
        tissue::save_surface(&frame, &frames.join(name)).unwrap();
    }
    std::fs::write(frames.join("notes.txt"), "not a frame").unwrap();
    let tumour_path = dir.path().join("tumour.obj");
    tissue::save_surface(&phantom::default_tumour(), &tumour_path).unwrap();
    let points_path = dir.path().join("points.csv");
    std::fs::write(&points_path, "x,y,z\n15,-10,25\n").unwrap();

    let out_dir = dir.path().join("out");
    let pattern = frames.join("*.obj");
    let out = tissue(&[
        "track",
        "--model",
        s(&model_path),
        "--frames",
        s(&pattern),
        "--rigid-structure",
        s(&tumour_path),
        "--points",
        s(&points_path),
        "--output-dir",
        s(&out_dir),
        "--picture",
        s(&dir.path().join("last.png")),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let printed = text(&out);
    for k in 1..=3 {
        assert!(printed.contains(&format!("frame {k}/3")), "{printed}");
    }
    assert!(printed.contains("last.png"), "{printed}");
    let picture = tiny_skia::Pixmap::load_png(dir.path().join("last.png")).unwrap();
    assert_eq!((picture.width(), picture.height()), (1400, 700));
    assert!(printed.contains(" ms"), "{printed}");

    // The frames' particles as one ParaView animation: frame k at time k,
    // each file there.
    let collection = std::fs::read_to_string(out_dir.join("track.pvd")).unwrap();
    assert!(
        collection.contains(r#"<VTKFile type="Collection""#),
        "{collection}"
    );
    let listed: Vec<&str> = collection
        .lines()
        .filter_map(|l| l.split("file=\"").nth(1))
        .filter_map(|rest| rest.split('"').next())
        .collect();
    assert_eq!(
        listed,
        [
            "frame-0001/particles.vtp",
            "frame-0002/particles.vtp",
            "frame-0003/particles.vtp"
        ]
    );
    for (k, file) in listed.iter().enumerate() {
        assert!(out_dir.join(file).is_file(), "{file}");
        assert!(collection.contains(&format!(r#"timestep="{}""#, k + 1)));
    }
    let summary = json(&out_dir.join("track.json"));
    let entries = summary["frames"].as_array().unwrap();
    assert_eq!(entries.len(), 3);
    let mut last = 0.0;
    for (k, (entry, name)) in entries
        .iter()
        .zip(["skin-1.obj", "skin-2.obj", "skin-10.obj"])
        .enumerate()
    {
        assert!(
            entry["frame"].as_str().unwrap().ends_with(name),
            "frame {k} is {}, expected {name}",
            entry["frame"]
        );
        for key in ["iterations", "seconds", "converged", "residual"] {
            assert!(entry.get(key).is_some(), "frame {k} lacks {key}: {entry}");
        }
        assert_eq!(entry["converged"], true, "{entry}");
        let folder = out_dir.join(format!("frame-{:04}", k + 1));
        for file in ["particles.vtp", "tumour.obj", "points.csv", "report.json"] {
            assert!(
                folder.join(file).is_file(),
                "no {file} in {}",
                folder.display()
            );
        }
        let report = json(&folder.join("report.json"));
        assert_eq!(report["iterations"], entry["iterations"]);
        let moved = structure(&report, "rigid")["displacement_mm"]
            .as_f64()
            .unwrap();
        assert!(
            moved > last,
            "frame {k}: the tumour moved {moved} mm, after {last}"
        );
        last = moved;
    }
    let totals = &summary["totals"];
    assert_eq!(totals["frames"], 3);
    assert_eq!(
        totals["iterations"].as_u64().unwrap(),
        entries
            .iter()
            .map(|e| e["iterations"].as_u64().unwrap())
            .sum::<u64>()
    );
    assert_eq!(totals["converged"], true);
}

#[test]
/// Whether the bundled skins are what the code makes is checked with the
/// other assets in `cli.rs`.
fn deform_accepts_the_bundled_deformed_skins() {
    let dir = tempfile::tempdir().unwrap();
    // A model sampled from the bundled breast takes the bundled skins as they are.
    let (model_path, _) = sampled_model(dir.path());
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&assets().join("phantom-indentation.obj")),
        "--rigid-structure",
        s(&assets().join("phantom-tumour.obj")),
        "--output-dir",
        s(&dir.path().join("out")),
        "--picture",
        s(&dir.path().join("pictures/cut.png")),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(dir.path().join("out/phantom-tumour.obj").is_file());
    let report = json(&dir.path().join("out/report.json"));
    let files = report["files"].as_array().unwrap();
    assert!(
        files
            .iter()
            .any(|f| f.as_str().unwrap().ends_with("pictures/cut.png")),
        "{files:?}"
    );
    let picture = tiny_skia::Pixmap::load_png(dir.path().join("pictures/cut.png")).unwrap();
    assert_eq!((picture.width(), picture.height()), (1400, 700));
}

/// `--observed` takes the observed patch by position: the whole rest skin
/// (the OBJ file the model was sampled from, whose vertex numbers reading
/// renumbers) changes nothing; the lower half as points frees the upper
/// skin, which then no longer follows the sag exactly.
#[test]
fn deform_takes_the_observed_skin_by_position() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = assets().join("phantom-sag.obj");
    let deform = |name: &str, observed: Option<&Path>| -> Vec<Vec3> {
        let out_dir = dir.path().join(name);
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&sag),
            "--output-dir",
            s(&out_dir),
            "--quiet",
        ];
        if let Some(file) = observed {
            args.extend(["--observed", s(file)]);
        }
        let out = tissue(&args);
        assert!(out.status.success(), "{name}: {}", text(&out));
        let vtp = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
        triples(&vtp_array(&vtp, "Points"))
    };
    let all = deform("all", None);
    let skin = deform("skin", Some(&assets().join("phantom-breast.obj")));
    assert_eq!(all, skin);
    let mut heights: Vec<f32> = model.surface.vertices.iter().map(|v| v.z).collect();
    heights.sort_by(f32::total_cmp);
    let median = heights[heights.len() / 2];
    let lower: Vec<Vec3> = model
        .surface
        .vertices
        .iter()
        .copied()
        .filter(|v| v.z <= median)
        .collect();
    let lower_path = dir.path().join("lower.csv");
    tissue::save_points(&lower, &lower_path).unwrap();
    let half = deform("half", Some(&lower_path));
    let report = json(&dir.path().join("half/report.json"));
    assert_eq!(report["observed"]["vertices"], lower.len());
    assert_eq!(report["observed"]["of"], model.surface.vertices.len());
    assert!(
        json(&dir.path().join("all/report.json"))
            .get("observed")
            .is_none()
    );
    let moved = all
        .iter()
        .zip(&half)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0f32, f32::max);
    assert!(
        moved > 1e-3 * size(&model),
        "freeing half the skin moved nothing ({moved})"
    );
}

/// A deformed surface written by another tool in its own vertex order (the
/// same triangles in the same order) is matched to the rest surface by its
/// triangles: the same solve as the surface in the model's order.
#[test]
fn deform_matches_a_surface_written_in_another_vertex_order() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = deform_surface(&model.surface, &Sag::default());
    let n = sagged.vertices.len() as u32;
    // Vertex i goes to place n - 1 - i.
    let place = |i: u32| n - 1 - i;
    let mut vertices = vec![Vec3::ZERO; n as usize];
    for (i, &v) in sagged.vertices.iter().enumerate() {
        vertices[place(i as u32) as usize] = v;
    }
    let triangles = sagged.triangles.iter().map(|t| t.map(place)).collect();
    let shuffled = SurfaceMesh::new(vertices, triangles);
    let (ordered_path, shuffled_path) =
        (dir.path().join("sag.ply"), dir.path().join("shuffled.ply"));
    tissue::save_surface(&sagged, &ordered_path).unwrap();
    tissue::save_surface(&shuffled, &shuffled_path).unwrap();
    let deform = |surface: &Path, name: &str| -> Vec<Vec3> {
        let out_dir = dir.path().join(name);
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(surface),
            "--output-dir",
            s(&out_dir),
            "--quiet",
        ]);
        assert!(out.status.success(), "{name}: {}", text(&out));
        let vtp = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
        triples(&vtp_array(&vtp, "Points"))
    };
    assert_eq!(
        deform(&ordered_path, "ordered"),
        deform(&shuffled_path, "shuffled")
    );
}

#[test]
fn bad_stage2_input_fails_with_a_message_and_no_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let tumour = s(&assets().join("phantom-tumour.obj")).to_owned();
    std::fs::write(d("empty.csv"), "").unwrap();
    std::fs::write(d("nan.csv"), "x,y,z\n1,2,3\n4,NaN,6\n").unwrap();
    std::fs::write(d("a-file"), "").unwrap();
    // The rest surface with one vertex too many (an unused one is welded
    // away on reading, so add a triangle that uses it).
    let mut wrong = tissue::load_model(Path::new(&model)).unwrap().surface;
    wrong.vertices.push(Vec3::new(0.0, 0.0, 200.0));
    let last = (wrong.vertices.len() - 1) as u32;
    wrong.triangles.push([0, 1, last]);
    tissue::save_surface(&wrong, Path::new(&d("wrong.obj"))).unwrap();
    let mut not_finite = deform_surface(
        &tissue::load_model(Path::new(&model)).unwrap().surface,
        &Sag::default(),
    );
    not_finite.vertices[5].y = f32::NAN;
    tissue::save_surface(&not_finite, Path::new(&d("nan-skin.obj"))).unwrap();
    std::fs::write(d("observed-none.csv"), "x,y,z\n").unwrap();
    std::fs::write(d("observed-word.csv"), "x,y,z\n1,2,3\n4,5,three\n").unwrap();
    std::fs::write(d("observed-far.csv"), "x,y,z\n0,0,500\n").unwrap();
    // Three vertices of the rest surface only: too few for any particle's triangle.
    let rest = tissue::load_model(Path::new(&model)).unwrap().surface;
    let few: Vec<Vec3> = rest.vertices[..3].to_vec();
    tissue::save_points(&few, Path::new(&d("observed-few.csv"))).unwrap();
    // The tumour in metres (18 mm across becomes 0.018), inside the organ.
    let mut metres = tissue::phantom::default_tumour();
    for v in &mut metres.vertices {
        *v = *v * 1e-3 + Vec3::new(15.0, -10.0, 25.0);
    }
    tissue::save_surface(&metres, Path::new(&d("tumour-m.obj"))).unwrap();

    let deform = |extra: &[&str]| -> Vec<String> {
        let mut args: Vec<String> = vec!["deform".into(), "--model".into(), model.clone()];
        args.extend(extra.iter().map(|a| (*a).to_owned()));
        if !extra.contains(&"--output-dir") {
            args.extend(["--output-dir".into(), d("out")]);
        }
        args
    };
    let wrong_path = d("wrong.obj");
    let nan_skin = d("nan-skin.obj");
    let empty = d("empty.csv");
    let nan = d("nan.csv");
    let blocked = d("a-file/out");
    let nothing = d("frames/*.obj");
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (
            deform(&["--surface", &tumour]),
            vec![
                "phantom-tumour.obj",
                "642 vertices",
                "same mesh with moved vertices",
            ],
        ),
        (
            deform(&["--surface", &wrong_path]),
            vec!["wrong.obj", "vertices", "same mesh with moved vertices"],
        ),
        (
            deform(&["--surface", &nan_skin]),
            vec!["nan-skin.obj", "not finite"],
        ),
        (
            deform(&["--surface", &sag, "--rigid-structure", &d("tumour-m.obj")]),
            vec!["tumour-m.obj", "less than a hundredth", "another unit"],
        ),
        (
            deform(&["--surface", &sag, "--points", &empty]),
            vec!["empty.csv", "no points"],
        ),
        (
            deform(&["--surface", &sag, "--points", &nan]),
            vec!["nan.csv", "line 3", "NaN"],
        ),
        (
            deform(&["--surface", &sag, "--output-dir", &blocked]),
            vec!["a-file", "creating"],
        ),
        (
            deform(&["--surface", &sag, "--tolerance", "NaN"]),
            vec!["tolerance"],
        ),
        (
            deform(&["--surface", &sag, "--observed", &d("observed-none.csv")]),
            vec!["observed-none.csv"],
        ),
        (
            deform(&["--surface", &sag, "--observed", &d("observed-word.csv")]),
            vec!["observed-word.csv", "line 3"],
        ),
        (
            deform(&["--surface", &sag, "--observed", &d("observed-far.csv")]),
            vec![
                "observed-far.csv",
                "point 1",
                "nearest vertex of the model's rest surface",
            ],
        ),
        (
            deform(&["--surface", &sag, "--observed", &d("observed-few.csv")]),
            vec!["no surface particle is observed", "3 of the surface's"],
        ),
        (
            deform(&["--surface", &sag, "--observed", "/no/such/observed.csv"]),
            vec!["/no/such/observed.csv"],
        ),
        (
            deform(&["--surface", "/no/such/skin.obj"]),
            vec!["/no/such/skin.obj"],
        ),
        (
            vec![
                "deform".into(),
                "--model".into(),
                "/no/such/model.vtp".into(),
                "--surface".into(),
                sag.clone(),
                "--output-dir".into(),
                d("out"),
            ],
            vec!["/no/such/model.vtp"],
        ),
        (
            vec![
                "deform".into(),
                "--model".into(),
                sag.clone(),
                "--surface".into(),
                sag.clone(),
                "--output-dir".into(),
                d("out"),
            ],
            vec!["phantom-sag.obj", ".vtp"],
        ),
        (
            vec![
                "track".into(),
                "--model".into(),
                model.clone(),
                "--frames".into(),
                nothing.clone(),
                "--output-dir".into(),
                d("out"),
            ],
            vec![nothing.as_str(), "matches no file"],
        ),
        (
            vec![
                "track".into(),
                "--model".into(),
                "/no/such/model.vtp".into(),
                "--frames".into(),
                sag.clone(),
                "--output-dir".into(),
                d("out"),
            ],
            vec!["/no/such/model.vtp"],
        ),
        (
            vec![
                "track".into(),
                "--model".into(),
                model.clone(),
                "--frames".into(),
                sag.clone(),
                "--history".into(),
                "17".into(),
                "--output-dir".into(),
                d("out"),
            ],
            vec!["history is 17", "0 to 16 frames"],
        ),
        (
            vec![
                "deform".into(),
                "--model".into(),
                model.clone(),
                "--surface".into(),
                sag.clone(),
                "--force".into(),
                "elastic".into(),
                "--poisson".into(),
                "0.5".into(),
                "--output-dir".into(),
                d("out"),
            ],
            vec!["poisson is 0.5", "[0, 0.499]", "incompressible"],
        ),
        (
            deform(&["--surface", &sag, "--picture", &d("cut.jpg")]),
            vec!["cut.jpg", "PNG", ".png"],
        ),
    ];
    for (args, expected) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = tissue(&args);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {message}");
        for expect in expected {
            assert!(
                message.contains(expect),
                "{args:?}: expected `{expect}` in {message}"
            );
        }
        assert!(
            !message.contains("panicked"),
            "{args:?} panicked: {message}"
        );
        // stdout holds at most the `backend:` line of `--backend auto`.
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.lines().count() == 1 && stderr.starts_with("error: "),
            "{args:?}: expected one error line, got {message}"
        );
        assert!(
            stdout.lines().all(|l| l.starts_with("backend: ")),
            "{args:?}: expected nothing but the backend line on stdout, got {stdout}"
        );
    }
    assert!(
        !dir.path().join("out").exists(),
        "a failed run left an output folder"
    );
}
