//! `tissue deform` with an observation without correspondence: a surface
//! of another triangulation matched by the skin, and the inputs it refuses.
#![allow(clippy::unwrap_used, reason = "tests")]

mod common;

use common::{json, s, sampled_model, text, tissue, vtp_array};
use tissue::{SurfaceMesh, Vec3};

/// `mesh` with every triangle cut into four: the same surface in another
/// triangulation.
fn subdivided(mesh: &SurfaceMesh) -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::cut_in_four(&mesh.vertices, &mesh.triangles);
    SurfaceMesh::new(vertices, triangles)
}

/// The phantom's chest wall: its rest vertices on the plane z = 0.
fn chest_wall(model: &tissue::ParticleModel) -> Vec<Vec3> {
    model
        .surface
        .vertices
        .iter()
        .filter(|v| v.z <= 1e-4)
        .copied()
        .collect()
}

/// The phantom's chest wall as points in `dir/wall.csv`: the
/// `--fixed-region` file.
fn chest_wall_file(dir: &std::path::Path, model: &tissue::ParticleModel) -> std::path::PathBuf {
    let path = dir.join("wall.csv");
    tissue::save_points(&chest_wall(model), &path).unwrap();
    path
}

/// The phantom's sag in another triangulation: `deform` says it has no
/// correspondence, holds the rest vertices that lie on it (the chest
/// wall), matches the skin to it, and reports the match; the skin lands
/// on it.
#[test]
fn deform_matches_a_surface_of_another_triangulation() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = tissue::deform::deform_surface(&model.surface, &tissue::deform::Sag::default());
    let other = dir.path().join("other.obj");
    tissue::save_surface(&subdivided(&sagged), &other).unwrap();
    // `deform` onto the other triangulation with `extra` options.
    let deform = |extra: &[&str], out_dir: &std::path::Path| {
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&other),
            "--backend",
            "cpu",
            "--output-dir",
            s(out_dir),
        ];
        args.extend(extra);
        tissue(&args)
    };
    let out_dir = dir.path().join("out");
    let out = deform(&[], &out_dir);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(said.contains("no correspondence"), "{said}");
    assert!(said.contains("matched without correspondence"), "{said}");
    let report = json(&out_dir.join("report.json"));
    let observation = &report["observation"];
    assert_eq!(observation["kind"], "surface");
    assert_eq!(observation["pulled"], observation["skin"]);
    let rms = observation["residual_rms_mm"].as_f64().unwrap();
    let size = common::size(&model) as f64;
    assert!(rms < 2e-3 * size, "residual {rms}, size {size}");
    assert_eq!(report["status"], "converged");
    assert!(report["observed"]["vertices"].as_u64().unwrap() > 0);

    // Paired with the nearest point instead: the same skin, to a fraction
    // of the residual.
    let nearest_dir = dir.path().join("nearest");
    let out = deform(&["--surface-smoothing", "0"], &nearest_dir);
    assert!(out.status.success(), "{}", text(&out));
    let nearest = json(&nearest_dir.join("report.json"));
    assert_eq!(nearest["status"], "converged");
    let other_rms = nearest["observation"]["residual_rms_mm"].as_f64().unwrap();
    assert!(other_rms < 2e-3 * size, "residual {other_rms}, size {size}");
    assert_ne!(
        nearest["iterations"], report["iterations"],
        "another pairing, another iteration"
    );
}

/// A scan of the sag in another frame (turned 15 degrees about an oblique
/// axis and shifted 20 mm) with four chest-wall fiducials in both frames:
/// put back by them, it gives the points of the scan in the model's frame
/// within a hundredth of a millimetre, and the report says the motion;
/// without them it is refused, and fiducials out of order are refused by
/// what is wrong.
#[test]
fn deform_puts_a_scan_in_the_models_frame_by_fiducials() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = tissue::deform::deform_surface(&model.surface, &tissue::deform::Sag::default());
    let points: Vec<Vec3> = sagged
        .vertices
        .iter()
        .filter(|v| v.z > 10.0)
        .copied()
        .collect();
    let turn =
        glam::Mat3::from_axis_angle(Vec3::new(0.3, -1.0, 0.4).normalize(), 15f32.to_radians());
    let shift = Vec3::new(16.0, 0.0, -12.0);
    let moved = |p: &Vec3| turn * *p + shift;
    let wall = chest_wall(&model);
    let fiducials: Vec<Vec3> = (0..4).map(|k| wall[k * wall.len() / 4]).collect();
    let save = |name: &str, points: &[Vec3]| {
        let path = dir.path().join(name);
        tissue::save_points(points, &path).unwrap();
        path
    };
    let scan = save("scan.csv", &points);
    let scan_moved = save(
        "scan-moved.csv",
        &points.iter().map(moved).collect::<Vec<_>>(),
    );
    let model_fiducials = save("fiducials-model.csv", &fiducials);
    let scan_fiducials = save(
        "fiducials-scan.csv",
        &fiducials.iter().map(moved).collect::<Vec<_>>(),
    );
    let mut reordered = fiducials.iter().map(moved).collect::<Vec<_>>();
    reordered.swap(0, 2);
    let scan_reordered = save("fiducials-reordered.csv", &reordered);
    let targets = save(
        "targets.csv",
        &[Vec3::new(0.0, 0.0, 25.0), Vec3::new(10.0, -5.0, 15.0)],
    );
    let fixed = chest_wall_file(dir.path(), &model);
    let run = |out: &str, extra: &[&str]| {
        let out_dir = dir.path().join(out);
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--fixed-region",
            s(&fixed),
            "--points",
            s(&targets),
            "--backend",
            "cpu",
            "--output-dir",
            s(&out_dir),
        ];
        args.extend(extra);
        (tissue(&args), out_dir)
    };
    let (out, plain) = run("plain", &["--cloud", s(&scan)]);
    assert!(out.status.success(), "{}", text(&out));
    let (out, aligned) = run(
        "aligned",
        &[
            "--cloud",
            s(&scan_moved),
            "--fiducials",
            s(&model_fiducials),
            s(&scan_fiducials),
        ],
    );
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains("put in the model's frame by 4 fiducials"),
        "{said}"
    );
    let alignment = &json(&aligned.join("report.json"))["observation"]["alignment"];
    assert_eq!(alignment["fiducials"], 4);
    assert!((alignment["angle_degrees"].as_f64().unwrap() - 15.0).abs() < 0.01);
    assert!(alignment["residual_rms_mm"].as_f64().unwrap() < 1e-3);
    let carried = |dir: &std::path::Path| tissue::load_points(&dir.join("points.csv")).unwrap();
    for (a, b) in carried(&plain).iter().zip(carried(&aligned)) {
        assert!(a.distance(b) < 0.01, "{a} against {b}");
    }
    let (out, _) = run("refused", &["--cloud", s(&scan_moved)]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let (out, _) = run(
        "reordered",
        &[
            "--cloud",
            s(&scan_moved),
            "--fiducials",
            s(&model_fiducials),
            s(&scan_reordered),
        ],
    );
    let said = text(&out);
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(
        said.contains("same order") && !said.contains("panicked"),
        "{said}"
    );

    // `track --clouds` of the scans in the other frame, by the same
    // fiducials: each frame where the scans in the model's frame put it.
    let half = tissue::deform::interpolate(&model.surface, &sagged, 0.5).unwrap();
    let upper = |mesh: &SurfaceMesh| -> Vec<Vec3> {
        mesh.vertices
            .iter()
            .filter(|v| v.z > 10.0)
            .copied()
            .collect()
    };
    for (folder, turned) in [("scans", false), ("scans-moved", true)] {
        std::fs::create_dir(dir.path().join(folder)).unwrap();
        for (k, mesh) in [(1, &half), (2, &sagged)] {
            let points: Vec<Vec3> = upper(mesh)
                .iter()
                .map(|p| if turned { moved(p) } else { *p })
                .collect();
            save(&format!("{folder}/c-{k}.csv"), &points);
        }
    }
    let track = |folder: &str, extra: &[&str]| {
        let out_dir = dir.path().join(format!("track-{folder}"));
        let pattern = dir.path().join(folder).join("*.csv");
        let mut args = vec![
            "track",
            "--model",
            s(&model_path),
            "--clouds",
            s(&pattern),
            "--fixed-region",
            s(&fixed),
            "--points",
            s(&targets),
            "--backend",
            "cpu",
            "-o",
            s(&out_dir),
            "--quiet",
        ];
        args.extend(extra);
        let out = tissue(&args);
        assert!(out.status.success(), "{}", text(&out));
        out_dir
    };
    let plain = track("scans", &[]);
    let aligned = track(
        "scans-moved",
        &["--fiducials", s(&model_fiducials), s(&scan_fiducials)],
    );
    for k in 1..=2 {
        let frame = |dir: &std::path::Path| dir.join(format!("frame-{k:04}"));
        let report = json(&frame(&aligned).join("report.json"));
        assert_eq!(report["observation"]["alignment"]["fiducials"], 4);
        for (a, b) in carried(&frame(&plain))
            .iter()
            .zip(carried(&frame(&aligned)))
        {
            assert!(a.distance(b) < 0.01, "frame {k}: {a} against {b}");
        }
    }
}

/// What an observation without correspondence cannot come with is refused
/// with the reason: a cloud without the held region, the held region or
/// a noise with the rest surface's own frame, a cloud in metres or
/// micrometres of an organ in millimetres, a cloud 20 mm away from the
/// chest wall or into the organ (the organ would have to grow or shrink
/// by a third), a surface 20 mm off the chest wall it holds.
#[test]
fn deform_refuses_what_a_match_cannot_take() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = tissue::deform::deform_surface(&model.surface, &tissue::deform::Sag::default());
    let (frame, other) = (dir.path().join("frame.obj"), dir.path().join("other.obj"));
    tissue::save_surface(&sagged, &frame).unwrap();
    tissue::save_surface(&subdivided(&sagged), &other).unwrap();
    let points: Vec<Vec3> = sagged
        .vertices
        .iter()
        .filter(|v| v.z > 0.0)
        .copied()
        .collect();
    let cloud = dir.path().join("cloud.csv");
    tissue::save_points(&points, &cloud).unwrap();
    let metres: Vec<Vec3> = points.iter().map(|&p| p * 1e-3).collect();
    let cloud_m = dir.path().join("metres.csv");
    tissue::save_points(&metres, &cloud_m).unwrap();
    let microns: Vec<Vec3> = points.iter().map(|&p| p * 1e3).collect();
    let cloud_um = dir.path().join("microns.csv");
    tissue::save_points(&microns, &cloud_um).unwrap();
    // 20 mm away from the chest wall (z = 0), 20 mm into the organ.
    let lifted = |mesh: &SurfaceMesh, by: f32| SurfaceMesh {
        vertices: mesh.vertices.iter().map(|&v| v + Vec3::Z * by).collect(),
        ..mesh.clone()
    };
    let away: Vec<Vec3> = points.iter().map(|&p| p + Vec3::Z * 20.0).collect();
    let cloud_away = dir.path().join("away.csv");
    tissue::save_points(&away, &cloud_away).unwrap();
    let into: Vec<Vec3> = points.iter().map(|&p| p - Vec3::Z * 20.0).collect();
    let cloud_into = dir.path().join("into.csv");
    tissue::save_points(&into, &cloud_into).unwrap();
    let surface_away = dir.path().join("away.obj");
    tissue::save_surface(&lifted(&subdivided(&sagged), 20.0), &surface_away).unwrap();
    let fixed = chest_wall_file(dir.path(), &model);
    let out_dir = dir.path().join("out");
    let refused = |extra: &[&str], says: &[&str]| {
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--output-dir",
            s(&out_dir),
        ];
        args.extend(extra);
        let out = tissue(&args);
        let said = text(&out);
        assert_eq!(out.status.code(), Some(1), "{extra:?}: {said}");
        for part in says {
            assert!(said.contains(part), "{extra:?}: {said}");
        }
        assert!(!said.contains("panicked"), "{said}");
    };
    refused(&["--cloud", s(&cloud)], &["--fixed-region"]);
    refused(
        &["--surface", s(&other), "--surface-smoothing", "9"],
        &["--surface-smoothing is 9", "0 to 8"],
    );
    refused(
        &[
            "--cloud",
            s(&cloud),
            "--fixed-region",
            s(&fixed),
            "--surface-smoothing",
            "1",
        ],
        &["--surface-smoothing is for a surface"],
    );
    refused(
        &["--surface", s(&frame), "--surface-smoothing", "1"],
        &["moved vertices", "--surface-smoothing"],
    );
    refused(
        &["--surface", s(&frame), "--noise", "0.5"],
        &["moved vertices", "without correspondence"],
    );
    refused(
        &["--surface", s(&frame), "--fixed-region", s(&fixed)],
        &[
            "moved vertices",
            "--fixed-region without the posture options",
        ],
    );
    refused(
        &["--cloud", s(&cloud_m), "--fixed-region", s(&fixed)],
        &["metres"],
    );
    refused(
        &["--cloud", s(&cloud_um), "--fixed-region", s(&fixed)],
        &["a thousand times too large"],
    );
    refused(
        &["--cloud", s(&cloud_away), "--fixed-region", s(&fixed)],
        &[
            "grow by about",
            "shifted away from the held region",
            "units",
        ],
    );
    refused(
        &["--cloud", s(&cloud_into), "--fixed-region", s(&fixed)],
        &["shrink by about", "shifted into the organ"],
    );
    refused(
        &["--surface", s(&surface_away), "--fixed-region", s(&fixed)],
        &[
            "the held region (the chest wall) lies 20.0",
            "another coordinate frame",
        ],
    );
}

/// With the posture options: the skin matched without gravity first, the
/// stiffness fitted to where it went, then matched again with the deformed
/// posture's gravity inside: the skin lands on the observation, the fit
/// within a factor of two of the one from the frame itself (the phantom's
/// sag is a map, not gravity: the skin slides otherwise than the frame's
/// vertices went, 4.6 against 6.6 kPa; the shared cases, made by gravity,
/// are fitted within 4 % of the truth: `tests/observations.rs`).
#[test]
fn deform_matches_with_the_postures() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = tissue::deform::deform_surface(&model.surface, &tissue::deform::Sag::default());
    let (frame, other) = (dir.path().join("frame.obj"), dir.path().join("other.obj"));
    tissue::save_surface(&sagged, &frame).unwrap();
    tissue::save_surface(&subdivided(&sagged), &other).unwrap();
    let run = |surface: &std::path::Path, name: &str| {
        let out_dir = dir.path().join(name);
        let out = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(surface),
            "--gravity-rest",
            "0,0,-1",
            "--gravity-deformed",
            "0,-1,0",
            "--backend",
            "cpu",
            "--output-dir",
            s(&out_dir),
            "--quiet",
        ]);
        assert!(out.status.success(), "{name}: {}", text(&out));
        json(&out_dir.join("report.json"))
    };
    let framed = run(&frame, "frame");
    let matched = run(&other, "match");
    assert_eq!(matched["status"], "converged");
    assert_eq!(matched["stiffness_fitted"], true);
    let (a, b) = (
        framed["stiffness_kpa"].as_f64().unwrap(),
        matched["stiffness_kpa"].as_f64().unwrap(),
    );
    assert!(
        (a / b).ln().abs() < 2f64.ln(),
        "{a} kPa from the frame, {b} matched"
    );
    assert_eq!(
        matched["observation"]["pulled"],
        matched["observation"]["skin"]
    );
    let rms = matched["observation"]["residual_rms_mm"].as_f64().unwrap();
    assert!(rms < 2e-3 * common::size(&model) as f64, "residual {rms}");
}

/// `track` of observations without correspondence: the phantom's sag in
/// three steps of 4 mm, as surfaces of another triangulation and as scans
/// of the upper skin. Every frame is matched (its report in `track.json`),
/// each after the first from the last one's answer, and the last lands
/// where `deform` puts it from rest (but for a particle at a scan's edge),
/// and where a run resumed at it puts it;
/// the held region found without `--fixed-region` is what lies on every
/// frame. A sequence mixing frames
/// of the rest surface with other surfaces, and scans without the held
/// region, are refused, as is a later scan in metres before the first
/// frame is solved.
#[test]
fn track_matches_sequences_without_correspondence() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let size = common::size(&model);
    for folder in ["surfaces", "scans", "mixed"] {
        std::fs::create_dir(dir.path().join(folder)).unwrap();
    }
    for k in 1..=3 {
        let sag = tissue::deform::Sag {
            magnitude_mm: 4.0 * k as f32,
            ..Default::default()
        };
        let sagged = tissue::deform::deform_surface(&model.surface, &sag);
        let other = subdivided(&sagged);
        let surfaces = dir.path().join(format!("surfaces/s-{k}.obj"));
        tissue::save_surface(&other, &surfaces).unwrap();
        let upper: Vec<Vec3> = sagged
            .vertices
            .iter()
            .filter(|v| v.z > 0.0)
            .copied()
            .collect();
        tissue::save_points(&upper, &dir.path().join(format!("scans/c-{k}.csv"))).unwrap();
        let mixed = dir.path().join(format!("mixed/m-{k}.obj"));
        if k == 1 {
            tissue::save_surface(&sagged, &mixed).unwrap();
        } else {
            tissue::save_surface(&other, &mixed).unwrap();
        }
    }
    let fixed = chest_wall_file(dir.path(), &model);
    // The subcommand, then the model and its options.
    let run = |args: &[&str]| {
        let mut all = vec![
            args[0],
            "--model",
            s(&model_path),
            "--backend",
            "cpu",
            "--quiet",
        ];
        all.extend(&args[1..]);
        tissue(&all)
    };
    let points =
        |path: &std::path::Path| vtp_array(&std::fs::read_to_string(path).unwrap(), "Points");
    // The 95th percentile and the largest of the distances between two
    // sets of points.
    let apart = |a: &[f32], b: &[f32]| {
        assert_eq!(a.len(), b.len());
        let mut d: Vec<f32> = a
            .chunks(3)
            .zip(b.chunks(3))
            .map(|(p, q)| Vec3::from_slice(p).distance(Vec3::from_slice(q)))
            .collect();
        d.sort_by(f32::total_cmp);
        (d[(d.len() - 1) * 95 / 100], d[d.len() - 1])
    };
    let pattern = |p: &str| dir.path().join(p).display().to_string();
    for (kind, option, files, fixed_region) in [
        ("surface", "--frames", pattern("surfaces/*.obj"), None),
        (
            "surface",
            "--frames",
            pattern("surfaces/*.obj"),
            Some(&fixed),
        ),
        ("cloud", "--clouds", pattern("scans/*.csv"), Some(&fixed)),
    ] {
        let out_dir = dir
            .path()
            .join(format!("track-{kind}-{}", fixed_region.is_some()));
        let mut args = vec!["track", option, &files, "--output-dir", s(&out_dir)];
        if let Some(region) = fixed_region {
            args.extend(["--fixed-region", s(region)]);
        }
        let out = run(&args);
        assert!(out.status.success(), "{kind}: {}", text(&out));
        let summary = json(&out_dir.join("track.json"));
        let frames = summary["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 3);
        for frame in frames {
            let observation = &frame["observation"];
            assert_eq!(observation["kind"], kind, "{frame}");
            // Tens of iterations a frame; a skin dithering at an edge of
            // the observed surface ran a frame to thousands.
            let iterations = frame["iterations"].as_u64().unwrap();
            assert!(iterations <= 200, "{kind}: {iterations} iterations");
            let pulled = observation["pulled"].as_u64().unwrap() as f64;
            let skin = observation["skin"].as_u64().unwrap() as f64;
            assert!(pulled >= 0.95 * skin, "{frame}");
            let rms = observation["residual_rms_mm"].as_f64().unwrap();
            assert!(rms < 2e-3 * f64::from(size), "{kind}: residual {rms}");
        }
        if fixed_region.is_some() {
            // The uncertainty's re-solves between frames leave no trace
            // on the frames: each frame's particles and iterations the
            // same as without them.
            let uncertain_dir = out_dir.with_extension("uncertain");
            let mut uncertain = args.clone();
            uncertain[4] = s(&uncertain_dir);
            uncertain.extend(["--uncertainty", "2"]);
            let out = run(&uncertain);
            assert!(out.status.success(), "{kind}: {}", text(&out));
            let iterations = |dir: &std::path::Path| {
                json(&dir.join("track.json"))["frames"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|f| f["iterations"].as_u64())
                    .collect::<Vec<_>>()
            };
            assert_eq!(iterations(&uncertain_dir), iterations(&out_dir), "{kind}");
            for k in 1..=3 {
                let frame = |dir: &std::path::Path| {
                    points(&dir.join(format!("frame-{k:04}/particles.vtp")))
                };
                let (p95, largest) = apart(&frame(&uncertain_dir), &frame(&out_dir));
                assert_eq!((p95, largest), (0.0, 0.0), "{kind}: frame {k}");
            }
        }
        let Some(region) = fixed_region else {
            // The held region lies on every frame: at most what the
            // first frame alone holds.
            let first = dir.path().join("first");
            let out = run(&[
                "deform",
                "--surface",
                &pattern("surfaces/s-1.obj"),
                "--output-dir",
                s(&first),
            ]);
            assert!(out.status.success(), "{}", text(&out));
            let alone = json(&first.join("report.json"))["observed"]["vertices"]
                .as_u64()
                .unwrap();
            let held = json(&out_dir.join("frame-0001/report.json"))["observed"]["vertices"]
                .as_u64()
                .unwrap();
            assert!(
                held > 0 && held <= alone,
                "{held} held, {alone} by the first"
            );
            continue;
        };
        let last = if kind == "surface" {
            pattern("surfaces/s-3.obj")
        } else {
            pattern("scans/c-3.csv")
        };
        let alone = dir.path().join(format!("deform-{kind}"));
        let out = run(&[
            "deform",
            if kind == "surface" {
                "--surface"
            } else {
                "--cloud"
            },
            &last,
            "--fixed-region",
            s(region),
            "--output-dir",
            s(&alone),
        ]);
        assert!(out.status.success(), "{}", text(&out));
        let tracked = points(&out_dir.join("frame-0003/particles.vtp"));
        let from_rest = points(&alone.join("particles.vtp"));
        // A scan's edge may set one particle aside on one path and pull
        // it on the other: its largest distance is not held.
        let (p95, largest) = apart(&tracked, &from_rest);
        assert!(
            p95 < 1e-3 * size,
            "{kind}: {p95} (p95) from deform's answer"
        );
        if kind == "surface" {
            assert!(
                largest < 1e-3 * size,
                "{kind}: {largest} from deform's answer"
            );
        }
        // Resumed at the last frame (its folder gone, as after a kill):
        // the matches before are replayed, the last frame is the same.
        let last_particles = out_dir.join("frame-0003/particles.vtp");
        let written = std::fs::read(&last_particles).unwrap();
        std::fs::remove_dir_all(out_dir.join("frame-0003")).unwrap();
        args.push("--resume");
        let out = run(&args);
        assert!(out.status.success(), "{kind} resumed: {}", text(&out));
        assert_eq!(std::fs::read(&last_particles).unwrap(), written, "{kind}");
    }
    let refused = |args: &[&str], says: &str| {
        let out_dir = dir.path().join("refused");
        let mut all = args.to_vec();
        all.extend(["--output-dir", s(&out_dir)]);
        let out = run(&all);
        let said = text(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {said}");
        assert!(said.contains(says), "{args:?}: {said}");
    };
    refused(&["track", "--frames", &pattern("mixed/*.obj")], "mixes");
    refused(
        &[
            "track",
            "--frames",
            &pattern("surfaces/*.obj"),
            "--surface-smoothing",
            "9",
        ],
        "--surface-smoothing is 9",
    );
    refused(
        &[
            "track",
            "--clouds",
            &pattern("scans/*.csv"),
            "--fixed-region",
            s(&fixed),
            "--surface-smoothing",
            "1",
        ],
        "--surface-smoothing is for surfaces",
    );
    // A later scan in metres is refused before the first frame is solved.
    std::fs::create_dir(dir.path().join("metres")).unwrap();
    for k in 1..=2 {
        let mut points = tissue::observation::load_cloud(
            &dir.path().join(format!("scans/c-{k}.csv")),
            Default::default(),
        )
        .unwrap();
        if k == 2 {
            points.iter_mut().for_each(|p| *p *= 1e-3);
        }
        tissue::save_points(&points, &dir.path().join(format!("metres/c-{k}.csv"))).unwrap();
    }
    refused(
        &[
            "track",
            "--clouds",
            &pattern("metres/*.csv"),
            "--fixed-region",
            s(&fixed),
        ],
        "c-2.csv: the point cloud spans",
    );
    assert!(!dir.path().join("refused/frame-0001").exists());
    // Scans are checked side by side: of two bad ones the first in the
    // sequence's order is named.
    std::fs::create_dir(dir.path().join("both")).unwrap();
    for (k, scale) in [(1, 1e-3), (2, 1e3)] {
        let mut points = tissue::observation::load_cloud(
            &dir.path().join(format!("scans/c-{k}.csv")),
            Default::default(),
        )
        .unwrap();
        points.iter_mut().for_each(|p| *p *= scale);
        tissue::save_points(&points, &dir.path().join(format!("both/c-{k}.csv"))).unwrap();
    }
    refused(
        &[
            "track",
            "--clouds",
            &pattern("both/*.csv"),
            "--fixed-region",
            s(&fixed),
        ],
        "c-1.csv: the point cloud spans",
    );
    refused(
        &["track", "--clouds", &pattern("scans/*.csv")],
        "--fixed-region FILE",
    );
}
