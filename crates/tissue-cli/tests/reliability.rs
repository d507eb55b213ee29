//! What issue 15 asks of every run: no output replaces an input, every
//! implausible result is flagged with its own exit code, output folders hold
//! only this run's files, and quiet runs are quiet.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use common::{assets, json, s, sampled_model, text, tissue};
use tissue::Vec3;

/// No output may replace an input (issue 15): each run below names an
/// input as an output, is refused before any work with both named, and
/// leaves every input byte for byte as it was.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let sag = d("sag.obj");
    std::fs::copy(assets().join("phantom-sag.obj"), &sag).unwrap();
    let breast = d("breast.obj");
    std::fs::copy(assets().join("phantom-breast.obj"), &breast).unwrap();
    // The points file sits where `deform -o <dir>` writes its moved points.
    std::fs::create_dir(d("results")).unwrap();
    let points = d("results/points.csv");
    std::fs::write(&points, "x,y,z\n1,2,30\n").unwrap();
    // The tumour sits where `track -o <dir>` writes the first frame's.
    std::fs::create_dir(d("results/frame-0001")).unwrap();
    let tumour = d("results/frame-0001/tumour.obj");
    std::fs::copy(assets().join("phantom-tumour.obj"), &tumour).unwrap();
    let inputs = [&model, &sag, &breast, &points, &tumour];
    let before: Vec<Vec<u8>> = inputs.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let results = d("results");
    let cases: Vec<(Vec<&str>, [&str; 2])> = vec![
        (
            vec![
                "deform",
                "--model",
                &model,
                "--surface",
                &sag,
                "--points",
                &points,
                "-o",
                &results,
            ],
            ["results/points.csv", "the points file"],
        ),
        (
            vec![
                "deform",
                "--model",
                &model,
                "--surface",
                &sag,
                "-o",
                &results,
                "--report",
                &model,
            ],
            ["would overwrite the model", "model.vtp"],
        ),
        (
            vec![
                "track",
                "--model",
                &model,
                "--frames",
                &sag,
                "--structure",
                &tumour,
                "-o",
                &results,
            ],
            ["frame-0001/tumour.obj", "would overwrite the structure"],
        ),
        (
            vec![
                "sample", &breast, "-n", "300", "-o", &model, "--report", &breast,
            ],
            ["would overwrite the surface", "breast.obj"],
        ),
    ];
    for (args, expected) in &cases {
        let out = tissue(args);
        let message = text(&out);
        assert!(!out.status.success(), "{args:?} was accepted: {message}");
        for expect in expected {
            assert!(
                message.contains(expect),
                "{args:?}: expected `{expect}` in {message}"
            );
        }
        assert!(!message.contains("panicked"), "{message}");
    }
    for (path, old) in inputs.iter().zip(&before) {
        assert_eq!(&std::fs::read(path).unwrap(), old, "{path} changed");
    }
}

/// A solve that does not converge writes its results, says so in
/// `report.json` / `track.json` (`status`), warns, and exits 2, so that a
/// script can tell (issue 15); a converged one says `converged` and exits 0.
#[test]
fn an_unconverged_solve_exits_2_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    for (command, cap, code, status) in [
        ("deform", "2", Some(2), "not_converged"),
        ("deform", "5000", Some(0), "converged"),
        ("track", "2", Some(2), "not_converged"),
    ] {
        let out_dir = d(&format!("{command}-{cap}"));
        let frames_flag = if command == "deform" {
            "--surface"
        } else {
            "--frames"
        };
        let out = tissue(&[
            command,
            "--model",
            &model,
            frames_flag,
            &sag,
            "--max-iterations",
            cap,
            "-o",
            &out_dir,
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), code, "{command} cap {cap}: {message}");
        let report = if command == "deform" {
            json(&Path::new(&out_dir).join("report.json"))
        } else {
            json(&Path::new(&out_dir).join("track.json"))["totals"].clone()
        };
        assert_eq!(report["status"], status, "{report}");
        if code == Some(2) {
            assert!(message.contains("NOT converge"), "{message}");
            assert!(Path::new(&out_dir).exists());
        }
    }
}

/// A landmark far outside the organ (a wrong frame or units) is carried by
/// extrapolation: the results are written, the report's `outside` counts it,
/// `status` says `flagged`, and the run exits 4 with a warning (issue 15).
/// Points inside give none of that.
#[test]
fn a_landmark_outside_the_organ_is_flagged_and_exits_4() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    std::fs::write(d("far.csv"), "x,y,z\n15,-10,25\n200,0,0\n").unwrap();
    std::fs::write(d("near.csv"), "x,y,z\n15,-10,25\n").unwrap();
    for (points, code, status, outside) in [
        ("far.csv", Some(4), "flagged", 1),
        ("near.csv", Some(0), "converged", 0),
    ] {
        let out_dir = d(&format!("out-{points}"));
        let out = tissue(&[
            "deform",
            "--model",
            &model,
            "--surface",
            &sag,
            "--points",
            &d(points),
            "-o",
            &out_dir,
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), code, "{points}: {message}");
        let report = json(&Path::new(&out_dir).join("report.json"));
        assert_eq!(report["status"], status, "{report}");
        assert_eq!(report["points"]["outside"]["count"], outside, "{report}");
        if outside > 0 {
            // 200 mm in x from the phantom's skin: about 130 mm outside.
            let max = report["points"]["outside"]["max_mm"].as_f64().unwrap();
            assert!(max > 100.0, "{report}");
            assert!(
                message.contains("outside the model's rest surface"),
                "{message}"
            );
            assert!(Path::new(&out_dir).join("points.csv").exists());
        }
    }
}

/// A hand-edited model (a particle moved far outside, a surface particle
/// moved off its attachment) is refused before any work, naming the
/// particle, and exits 1; the model as sampled is accepted (issue 15).
#[test]
fn a_hand_edited_model_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let free = (0..model.len()).find(|&i| !model.is_surface(i)).unwrap();
    let surface = (0..model.len()).find(|&i| model.is_surface(i)).unwrap();
    let mut far = model.clone();
    far.positions[free].x = 9999.0;
    let mut off = model.clone();
    off.positions[surface] += Vec3::splat(5.0 * model.mean_connection_length());
    for (name, edited, says) in [
        ("far.vtp", &far, format!("particle {free} at")),
        ("off.vtp", &off, format!("surface particle {surface} at")),
    ] {
        let path = dir.path().join(name);
        tissue::save_model(edited, &path).unwrap();
        let out = tissue(&[
            "deform",
            "--model",
            s(&path),
            "--surface",
            &sag,
            "-o",
            s(&dir.path().join(format!("out-{name}"))),
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {message}");
        assert!(
            message.contains(&says),
            "{name}: expected `{says}` in {message}"
        );
        assert!(message.contains("edited or damaged"), "{message}");
        assert!(!dir.path().join(format!("out-{name}")).exists());
    }
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        &sag,
        "-o",
        s(&dir.path().join("out-good")),
        "-q",
    ]);
    assert!(out.status.success(), "{}", text(&out));
}

/// A rerun of `track` with fewer frames into the same folder leaves no
/// frame folder or summary of the earlier run (issue 15): only this run's
/// frames and its own `track.json`; a folder the user put there stays.
#[test]
fn a_shorter_rerun_of_track_leaves_no_stale_frames() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let (three, one) = (dir.path().join("three"), dir.path().join("one"));
    std::fs::create_dir(&three).unwrap();
    std::fs::create_dir(&one).unwrap();
    for (k, name) in [
        "phantom-sag.obj",
        "phantom-indentation.obj",
        "phantom-sag.obj",
    ]
    .iter()
    .enumerate()
    {
        std::fs::copy(assets().join(name), three.join(format!("f{k}.obj"))).unwrap();
    }
    std::fs::copy(assets().join("phantom-indentation.obj"), one.join("f0.obj")).unwrap();
    let out = dir.path().join("out");
    let run = |frames: &Path| {
        let pattern = frames.join("*.obj");
        let result = tissue(&[
            "track",
            "--model",
            &model,
            "--frames",
            s(&pattern),
            "-o",
            s(&out),
            "-q",
        ]);
        assert!(result.status.success(), "{}", text(&result));
    };
    run(&three);
    assert!(out.join("frame-0003/report.json").exists());
    std::fs::create_dir(out.join("frame-9999")).unwrap();
    std::fs::write(out.join("frame-9999/notes.txt"), "mine").unwrap();
    run(&one);
    assert!(out.join("frame-0001/report.json").exists());
    assert!(!out.join("frame-0002").exists());
    assert!(!out.join("frame-0003").exists());
    assert!(out.join("frame-9999/notes.txt").exists(), "not ours: kept");
    let summary = json(&out.join("track.json"));
    assert_eq!(summary["frames"].as_array().unwrap().len(), 1, "{summary}");
}

/// A quiet run prints nothing (issue 15): on a headless machine Mesa's
/// Vulkan device-selection layer says `XDG_RUNTIME_DIR is invalid` while
/// the adapters are listed; that goes to the log (`RUST_LOG=info`), not to
/// the terminal. Both stages run on the default `auto` backend and on the
/// GPU, so the adapters are listed both ways.
#[test]
fn a_quiet_run_prints_nothing_on_a_headless_machine() {
    let dir = tempfile::tempdir().unwrap();
    let run = |backend: &str| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_tissue"));
        command
            .args(["demo", "-q", "-n", "1500", "--backend", backend, "-o"])
            .arg(dir.path().join(format!("demo-{backend}")))
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("WAYLAND_DISPLAY")
            .env_remove("DISPLAY")
            .env_remove("RUST_LOG");
        command.output().unwrap()
    };
    for backend in ["auto", "gpu"] {
        if backend == "gpu" && !common::gpu("a_quiet_run_prints_nothing_on_a_headless_machine") {
            continue;
        }
        let out = run(backend);
        assert!(out.status.success(), "--backend {backend}: {}", text(&out));
        assert!(
            out.stdout.is_empty() && out.stderr.is_empty(),
            "--backend {backend} -q printed: {}",
            text(&out)
        );
    }
}
