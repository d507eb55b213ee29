//! The `tissue` binary as a user runs it.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use common::{assets, s, text, tissue};

#[test]
fn the_bundled_phantom_is_what_the_code_makes() {
    let dir = tempfile::tempdir().unwrap();
    let out = tissue(&["phantom", "--output-dir", s(dir.path())]);
    assert!(out.status.success(), "{}", text(&out));
    for name in [
        "phantom-breast.obj",
        "phantom-tumour.obj",
        "phantom-sag.obj",
        "phantom-indentation.obj",
    ] {
        let made = std::fs::read(dir.path().join(name)).unwrap();
        let bundled = std::fs::read(assets().join(name)).unwrap();
        assert!(
            made == bundled,
            "assets/{name} is stale: rerun `tissue phantom --output-dir assets`"
        );
    }
}

/// The README's picture is the demo's: the same scene, at most a few
/// pixels apart (a rounding change may move a disc's edge, a stale picture
/// moves whole regions).
#[test]
fn the_readme_picture_is_what_the_demo_draws() {
    let dir = tempfile::tempdir().unwrap();
    let out = tissue(&[
        "demo",
        "--backend",
        "cpu",
        "-q",
        "--output-dir",
        s(dir.path()),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let drawn = tiny_skia::Pixmap::load_png(dir.path().join("demo.png")).unwrap();
    let shown = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/demo.png");
    let shown = tiny_skia::Pixmap::load_png(shown).unwrap();
    assert_eq!(
        (drawn.width(), drawn.height()),
        (shown.width(), shown.height())
    );
    let apart = drawn
        .pixels()
        .iter()
        .zip(shown.pixels())
        .filter(|(a, b)| {
            let (a, b) = (a.demultiply(), b.demultiply());
            [
                (a.red(), b.red()),
                (a.green(), b.green()),
                (a.blue(), b.blue()),
            ]
            .iter()
            .any(|&(x, y)| x.abs_diff(y) > 24)
        })
        .count();
    assert!(
        apart < 2_000,
        "docs/demo.png is stale ({apart} pixels differ): rerun `tissue demo --backend cpu` and copy \
         tissue-demo/demo.png there"
    );
}

#[test]
fn sample_writes_a_model_that_reads_back_and_a_json_report() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.vtp");
    let report = dir.path().join("report.json");
    let breast = assets().join("phantom-breast.obj");
    let out = tissue(&[
        "sample",
        s(&breast),
        "--particles",
        "2000",
        "--seed",
        "3",
        "--output",
        s(&model),
        "--report",
        s(&report),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("sampled 2000 particles in"),
        "{}",
        text(&out)
    );

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    for key in [
        "particles",
        "iterations",
        "seconds",
        "converged",
        "nn_cv",
        "connections",
        "surface_particles",
        "coverage",
        "max_outside",
    ] {
        assert!(json.get(key).is_some(), "report lacks {key}: {json}");
    }
    assert_eq!(json["particles"], 2000);
    assert!(json["connections"]["median"].as_f64().unwrap() >= 10.0);

    let loaded = tissue::load_model(&model).unwrap();
    assert_eq!(loaded.len(), 2000);
    assert_eq!(
        loaded.attachments.iter().filter(|a| a.is_some()).count() as u64,
        json["surface_particles"].as_u64().unwrap()
    );

    // Positions alone as CSV: a header and one row per particle.
    let csv = dir.path().join("points.csv");
    let out = tissue(&["sample", s(&breast), "-n", "500", "-o", s(&csv), "--quiet"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(out.stdout.is_empty(), "--quiet printed {}", text(&out));
    let rows = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(rows.lines().next(), Some("x,y,z"));
    assert_eq!(rows.lines().count(), 501);
}

#[test]
fn bad_input_fails_with_a_message_and_no_panic() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("m.vtp");
    let breast = assets().join("phantom-breast.obj");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "sample".into(),
                "/no/such/file.obj".into(),
                "-n".into(),
                "100".into(),
                "-o".into(),
                s(&out_file).into(),
            ],
            "/no/such/file.obj",
        ),
        (
            vec![
                "sample".into(),
                s(&breast).into(),
                "-n".into(),
                "100".into(),
                "-o".into(),
                "model.xyz".into(),
            ],
            "cannot write",
        ),
        (
            vec![
                "sample".into(),
                s(&breast).into(),
                "-n".into(),
                "1".into(),
                "-o".into(),
                s(&out_file).into(),
            ],
            "particles",
        ),
        (
            vec![
                "sample".into(),
                s(&breast).into(),
                "-n".into(),
                "100".into(),
                "-o".into(),
                s(&out_file).into(),
                "--connection-ratio".into(),
                "NaN".into(),
            ],
            "connection_ratio",
        ),
    ];
    for (args, expect) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = tissue(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let message = text(&out);
        assert!(
            message.contains(expect),
            "{args:?}: expected `{expect}` in {message}"
        );
        assert!(
            !message.contains("panicked"),
            "{args:?} panicked: {message}"
        );
    }

    let empty = dir.path().join("empty.stl");
    std::fs::write(&empty, b"").unwrap();
    let out = tissue(&["sample", s(&empty), "-n", "100", "-o", s(&out_file)]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).contains("empty.stl"), "{}", text(&out));

    let params = dir.path().join("params.json");
    std::fs::write(&params, r#"{"not_a_parameter": 1}"#).unwrap();
    let out = tissue(&[
        "sample",
        s(&breast),
        "-n",
        "100",
        "-o",
        s(&out_file),
        "--params",
        s(&params),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).contains("not_a_parameter"), "{}", text(&out));
}

#[test]
fn params_file_and_presets_reach_the_sampler() {
    let dir = tempfile::tempdir().unwrap();
    let breast = assets().join("phantom-breast.obj");
    let report = dir.path().join("r.json");
    let params = dir.path().join("p.json");
    let run = |ratio: &str| {
        std::fs::write(&params, format!(r#"{{"connection_ratio": {ratio}}}"#)).unwrap();
        tissue(&[
            "sample",
            s(&breast),
            "-n",
            "1000",
            "-o",
            s(&dir.path().join("m.csv")),
            "--params",
            s(&params),
            "--report",
            s(&report),
        ])
    };
    // A wider threshold than the default 0.9: more connections.
    let out = run("1.0");
    assert!(out.status.success(), "{}", text(&out));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let median = json["connections"]["median"].as_f64().unwrap();
    assert!(
        median > 12.0,
        "ratio 1.0 connects more than 0.9's 12: {median}"
    );
    // The paper's 0.6 connects nothing: the model is refused, not written.
    let out = run("0.6");
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out).contains("cannot carry rotations"),
        "{}",
        text(&out)
    );
}

/// A surface file of several closed shells (an organ exported with a
/// stray speck) is refused, the error naming `--largest-shell`; with it,
/// the largest shell is sampled and the dropped one is said.
#[test]
fn largest_shell_samples_the_organ_and_drops_the_speck() {
    let dir = tempfile::tempdir().unwrap();
    let breast = std::fs::read_to_string(assets().join("phantom-breast.obj")).unwrap();
    let vertices = breast.lines().filter(|l| l.starts_with("v ")).count();
    // A tetrahedron 200 mm off the phantom, its faces wound outward.
    let mut two = breast.clone();
    for v in ["200 0 0", "201 0 0", "200 1 0", "200 0 1"] {
        two.push_str(&format!("v {v}\n"));
    }
    for [a, b, c] in [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
        let [a, b, c] = [a, b, c].map(|k| vertices + 1 + k);
        two.push_str(&format!("f {a} {b} {c}\n"));
    }
    let path = dir.path().join("two-shells.obj");
    std::fs::write(&path, two).unwrap();
    let run = |extra: &[&str]| {
        let model = dir.path().join("m.vtp");
        let mut args = vec!["sample", s(&path), "-n", "1000", "-o", s(&model)];
        args.extend(extra);
        tissue(&args)
    };
    let refused = run(&[]);
    assert_eq!(refused.status.code(), Some(1), "{}", text(&refused));
    assert!(
        text(&refused).contains("2 disconnected shells")
            && text(&refused).contains("--largest-shell"),
        "{}",
        text(&refused)
    );
    assert!(!dir.path().join("m.vtp").exists());
    let kept = run(&["--largest-shell"]);
    assert!(kept.status.success(), "{}", text(&kept));
    assert!(
        text(&kept).contains("kept the largest of 2 shells")
            && text(&kept).contains("dropped 1 shell"),
        "{}",
        text(&kept)
    );
    let model = tissue::load_model(&dir.path().join("m.vtp")).unwrap();
    assert!(
        model.positions.iter().all(|p| p.x < 100.0),
        "no particle in the speck"
    );
}
