//! `tissue deform --uncertainty`: every output says how sure it is, the
//! landmark on the held chest wall is sure, an answer matched without
//! correspondence has its regions too, and what the estimate cannot take
//! is refused.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use common::{assets, json, s, sampled_model, text, tissue, vtp_array};

/// Two landmarks in `dir/targets.csv`: one deep inside the phantom, one
/// on its chest wall (a rest vertex at its lowest height).
fn landmarks(dir: &std::path::Path, model: &tissue::ParticleModel) -> std::path::PathBuf {
    let low = model
        .surface
        .vertices
        .iter()
        .map(|v| v.z)
        .fold(f32::INFINITY, f32::min);
    let wall = model
        .surface
        .vertices
        .iter()
        .find(|v| v.z < low + 1e-3)
        .copied()
        .unwrap();
    let points = dir.join("targets.csv");
    std::fs::write(
        &points,
        format!("x,y,z\n0,0,25\n{},{},{}\n", wall.x, wall.y, wall.z),
    )
    .unwrap();
    points
}

/// The sagged phantom with landmarks (one deep inside, one on the chest
/// wall) and the tumour: the report holds each landmark's and the
/// tumour's 95 % region, `points.csv` its radius as a fourth column,
/// `particles.vtp` each particle's; the chest-wall landmark's region is
/// smaller than the deep one's, and the spread's solves all converged.
#[test]
fn deform_writes_each_target_region() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let points = landmarks(dir.path(), &model);
    let out_dir = dir.path().join("out");
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&assets().join("phantom-sag.obj")),
        "--points",
        s(&points),
        "--structure",
        s(&assets().join("phantom-tumour.obj")),
        "--uncertainty",
        "4",
        "--backend",
        "cpu",
        "-o",
        s(&out_dir),
        "--picture",
        s(&dir.path().join("sure.png")),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("uncertainty:"), "{}", text(&out));
    // The picture gains its lower half: 1400 x 1400 (the PNG header's
    // width and height, big-endian, after the signature and IHDR's tag).
    let png = std::fs::read(dir.path().join("sure.png")).unwrap();
    let word = |at: usize| u32::from_be_bytes([png[at], png[at + 1], png[at + 2], png[at + 3]]);
    assert_eq!((word(16), word(20)), (1400, 1400));
    let report = json(&out_dir.join("report.json"));
    let uncertainty = &report["uncertainty"];
    assert_eq!(uncertainty["converged"], true);
    assert_eq!(uncertainty["priors"]["samples"], 4);
    let radius = |k: usize| uncertainty["points"][k]["radius_mm"].as_f64().unwrap();
    assert!(radius(0) > 0.05, "the deep landmark: {}", radius(0));
    assert!(
        radius(1) < 0.5 * radius(0),
        "the chest wall's: {}",
        radius(1)
    );
    let tumour = &uncertainty["structures"][0];
    assert_eq!(tumour["name"], "phantom-tumour.obj");
    assert!(tumour["centroid"]["radius_mm"].as_f64().unwrap() > 0.0);
    assert!(tumour["centroid"]["dominant"].is_string());

    let csv = std::fs::read_to_string(out_dir.join("points.csv")).unwrap();
    assert!(csv.starts_with("x,y,z,uncertainty_95\n"), "{csv}");
    let first: Vec<f64> = csv
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!((first[3] - radius(0)).abs() < 1e-4, "{first:?}");
    // The moved points read back as points.
    assert_eq!(
        tissue::load_points(&out_dir.join("points.csv"))
            .unwrap()
            .len(),
        2
    );
    let vtp = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
    let radii = vtp_array(&vtp, "uncertainty_95");
    assert_eq!(radii.len(), model.len() + model.surface.vertices.len());
    let largest = radii.iter().copied().fold(0.0, f32::max);
    let median = uncertainty["particles"]["median_radius_mm"]
        .as_f64()
        .unwrap();
    assert!(median > 0.0 && f64::from(largest) >= median);
}

/// Priors out of range are refused before anything is solved, each
/// naming what is wrong.
#[test]
fn deform_refuses_what_the_uncertainty_cannot_take() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let run = |extra: &[&str]| {
        let out_dir = dir.path().join("out");
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--backend",
            "cpu",
            "-o",
            s(&out_dir),
            "--uncertainty",
        ];
        args.extend_from_slice(extra);
        let out = tissue(&args);
        assert!(!out.status.success());
        assert!(!out_dir.join("report.json").exists());
        text(&out)
    };
    let sag = assets().join("phantom-sag.obj");
    let bad = run(&["--surface", s(&sag), "--poisson-range", "0.4,0.6"]);
    assert!(bad.contains("poisson"), "{bad}");
    let bad = run(&["--surface", s(&sag), "--surface-noise=-1"]);
    assert!(bad.contains("surface_noise"), "{bad}");
}

/// Another triangulation of the sagged skin (no correspondence: the skin
/// matched inside the solve, the chest wall held where the surfaces
/// meet): the estimate re-solves with the skin paired with the
/// observation as the match paired it, its solves converge, the deep landmark has a region and the chest wall's is
/// smaller, and the answer's points are those of the same run without it.
#[test]
fn deform_spreads_a_match_without_correspondence() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = assets().join("phantom-sag.obj");
    let remeshed = dir.path().join("remeshed.obj");
    let sagged = tissue::load_surface(&sag).unwrap();
    let (vertices, triangles) = tissue_testkit::cut_in_four(&sagged.vertices, &sagged.triangles);
    tissue::save_surface(&tissue::SurfaceMesh::new(vertices, triangles), &remeshed).unwrap();
    let points = landmarks(dir.path(), &model);
    let run = |out: &str, extra: &[&str]| {
        let out_dir = dir.path().join(out);
        let mut args = vec![
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&remeshed),
            "--points",
            s(&points),
            "--backend",
            "cpu",
            "-o",
            s(&out_dir),
        ];
        args.extend_from_slice(extra);
        let done = tissue(&args);
        assert!(done.status.success(), "{}", text(&done));
        out_dir
    };
    let plain = run("plain", &[]);
    let sure = run("sure", &["--uncertainty", "4"]);
    let report = json(&sure.join("report.json"));
    let uncertainty = &report["uncertainty"];
    assert_eq!(uncertainty["converged"], true);
    let radius = |k: usize| uncertainty["points"][k]["radius_mm"].as_f64().unwrap();
    assert!(radius(0) > 0.05, "the deep landmark: {}", radius(0));
    assert!(
        radius(1) < 0.5 * radius(0),
        "the chest wall's: {}",
        radius(1)
    );
    let moved = |dir: &std::path::Path| tissue::load_points(&dir.join("points.csv")).unwrap();
    assert_eq!(moved(&plain), moved(&sure), "the same answer");
}

/// `tissue track --uncertainty`: every frame's report and points carry
/// their regions, the regions grow with the sag, a resumed run gives the
/// last frame to the bit, and a sequence matched without correspondence
/// has its regions too.
#[test]
fn track_writes_each_frame_regions() {
    use tissue::deform::{Sag, deform_surface, interpolate};
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sagged = deform_surface(&model.surface, &Sag::default());
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    for k in 1..=2 {
        let frame = interpolate(&model.surface, &sagged, k as f32 / 2.0).unwrap();
        tissue::save_surface(&frame, &frames.join(format!("skin-{k}.obj"))).unwrap();
    }
    let points = dir.path().join("targets.csv");
    std::fs::write(&points, "x,y,z\n0,0,25\n").unwrap();
    let out_dir = dir.path().join("out");
    let pattern = frames.join("*.obj");
    // The run, with `extra` options after its own.
    let run = |extra: &[&str]| {
        let mut args = vec![
            "track",
            "--model",
            s(&model_path),
            "--frames",
            s(&pattern),
            "--points",
            s(&points),
            "--uncertainty",
            "2",
            "--backend",
            "cpu",
            "-o",
            s(&out_dir),
            "--quiet",
        ];
        args.extend_from_slice(extra);
        tissue(&args)
    };
    let out = run(&[]);
    assert!(out.status.success(), "{}", text(&out));
    let radius = |k: usize| {
        let report = json(&out_dir.join(format!("frame-{k:04}")).join("report.json"));
        assert_eq!(report["uncertainty"]["converged"], true);
        let csv = std::fs::read_to_string(out_dir.join(format!("frame-{k:04}/points.csv")));
        assert!(csv.unwrap().starts_with("x,y,z,uncertainty_95"));
        report["uncertainty"]["points"][0]["radius_mm"]
            .as_f64()
            .unwrap()
    };
    let (half, whole) = (radius(1), radius(2));
    assert!(0.0 < half && half < whole, "{half} then {whole}");
    // The second frame makes 2 of its 10 re-solves (two other Poisson
    // ratios, two samples, three unmodelled postures at the answer's ratio
    // and three at the range's lower end) and carries 8.
    let counts = |k: usize| {
        let report = json(&out_dir.join(format!("frame-{k:04}")).join("report.json"));
        let u = &report["uncertainty"];
        (u["solves"].as_u64(), u["carried"].as_u64())
    };
    assert_eq!(counts(1), (Some(10), None));
    assert_eq!(counts(2), (Some(2), Some(8)));

    // Resumed at the last frame (its folder gone, as after a kill): the
    // first frame and its spread replayed, the last the same to the bit;
    // a resume with other priors, or another refresh, is refused.
    let last = out_dir.join("frame-0002");
    let written = |name: &str| std::fs::read(last.join(name)).unwrap();
    let (particles, points_csv) = (written("particles.vtp"), written("points.csv"));
    std::fs::remove_dir_all(&last).unwrap();
    let other = run(&["--resume", "--surface-noise", "0.25"]);
    assert!(!other.status.success(), "{}", text(&other));
    let other = run(&["--resume", "--uncertainty-refresh", "all"]);
    assert!(!other.status.success(), "{}", text(&other));
    let again = run(&["--resume"]);
    assert!(again.status.success(), "{}", text(&again));
    assert_eq!(written("particles.vtp"), particles);
    assert_eq!(written("points.csv"), points_csv);

    // The same skins cut in four: matched without correspondence, each
    // frame's regions from its skin paired with the frame again.
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    for k in 1..=2 {
        let frame = interpolate(&model.surface, &sagged, k as f32 / 2.0).unwrap();
        let (vertices, triangles) = tissue_testkit::cut_in_four(&frame.vertices, &frame.triangles);
        let cut = tissue::SurfaceMesh::new(vertices, triangles);
        tissue::save_surface(&cut, &other.join(format!("skin-{k}.obj"))).unwrap();
    }
    let matched = dir.path().join("matched");
    let out = tissue(&[
        "track",
        "--model",
        s(&model_path),
        "--frames",
        s(&other.join("*.obj")),
        "--points",
        s(&points),
        "--uncertainty",
        "2",
        "--backend",
        "cpu",
        "-o",
        s(&matched),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    for k in 1..=2 {
        let report = json(&matched.join(format!("frame-{k:04}")).join("report.json"));
        assert!(report["observation"].is_object(), "frame {k} matched");
        assert_eq!(report["uncertainty"]["converged"], true);
        let radius = report["uncertainty"]["points"][0]["radius_mm"]
            .as_f64()
            .unwrap();
        assert!(radius > 0.0, "frame {k}: {radius}");
    }
}
