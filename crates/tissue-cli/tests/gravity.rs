//! The posture options of `deform` and `track`: gravity in both scans,
//! the organ's unloaded shape, the stiffness given or fitted, the held
//! region; the report's fields; refusals.

#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use common::{assets, json, s, sampled_model, text, tissue};
use serde_json::Value;

/// `tissue deform` of the bundled phantom's model into `out` with `extra`
/// options, its tumour carried rigidly; the report.
fn deform(model: &Path, out: &Path, extra: &[&str]) -> (std::process::Output, Option<Value>) {
    let sag = assets().join("phantom-sag.obj");
    let tumour = assets().join("phantom-tumour.obj");
    let mut args = vec![
        "deform",
        "--model",
        s(model),
        "--surface",
        s(&sag),
        "--rigid-structure",
        s(&tumour),
        "-o",
        s(out),
        "--backend",
        "cpu",
    ];
    args.extend_from_slice(extra);
    let output = tissue(&args);
    let report = out.join("report.json");
    let report = report.exists().then(|| json(&report));
    (output, report)
}

const POSTURES: [&str; 4] = ["--gravity-rest", "0,0,-1", "--gravity-deformed", "0,-1,0"];

/// With the stiffness given: the unloaded shape from the rest scan (the
/// chest wall held, found by `auto`), the deformed posture solved from it
/// with its gravity inside by the elastic force; the report's fields.
#[test]
fn the_postures_solve_from_the_unloaded_shape() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = sampled_model(dir.path());
    let out = dir.path().join("given");
    let mut extra = POSTURES.to_vec();
    extra.extend(["--stiffness", "3"]);
    let (output, report) = deform(&model, &out, &extra);
    assert!(output.status.success(), "{}", text(&output));
    let r = report.unwrap();
    assert_eq!(r["status"], "converged");
    assert_eq!(r["params"]["force"], "elastic", "the postures imply it");
    assert_eq!(r["gravity"]["rest"], serde_json::json!([0.0, 0.0, -1.0]));
    assert_eq!(r["gravity"]["density_kg_m3"], 1000.0);
    assert_eq!(r["gravity"]["unit"], "mm");
    assert_eq!(r["gravity"]["held"]["from"], "auto");
    let held = r["gravity"]["held"]["vertices"].as_u64().unwrap();
    let of = r["gravity"]["held"]["of"].as_u64().unwrap();
    assert!(held > 0 && held < of, "{held} of {of} held");
    assert_eq!(r["stiffness_kpa"], 3.0);
    assert_eq!(r["stiffness_fitted"], false);
    assert!(r["fit_residual_mm"].is_null());
    let unloaded = r["unloaded_residual_mm"].as_f64().unwrap();
    assert!(unloaded <= 0.1, "{unloaded}");
    assert_eq!(r["unloaded_converged"], true);
    // What happened in the posture's solves, counted.
    assert!(r["solves"].as_u64().unwrap() >= 1);
    assert!(r["posture_elastic_retries"].is_u64(), "{r}");
    assert!(r["posture_backtracks"].is_u64(), "{r}");
    // The load of 1 g along -y on tissue of 3 kPa at 0.49, per mm:
    // rho g / (2 mu) with mu = E / (2 (1 + nu)).
    let load = r["params"]["load"].as_array().unwrap();
    let expected = 1000.0 * 9.806_65 / (2.0 * 3000.0 / 2.98) * 1e-3;
    let got = load[1].as_f64().unwrap();
    assert!(
        (got + expected).abs() <= 1e-4 * expected,
        "{got} vs -{expected}"
    );
    // The tumour moved, measured from the rest scan.
    let tumour = &r["structures"][0];
    assert!(
        tumour["displacement_mm"].as_f64().unwrap() > 0.5,
        "{tumour}"
    );
    // The same without gravity lands elsewhere.
    let plain = dir.path().join("plain");
    let (output, report) = deform(&model, &plain, &["--force", "elastic"]);
    assert!(output.status.success(), "{}", text(&output));
    let plain = report.unwrap();
    assert!(plain.get("gravity").is_none() && plain.get("stiffness_kpa").is_none());
    let (a, b) = (
        tumour["moved_centroid"].as_array().unwrap(),
        plain["structures"][0]["moved_centroid"].as_array().unwrap(),
    );
    let apart: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x.as_f64().unwrap() - y.as_f64().unwrap()).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(apart > 0.05, "gravity moved the tumour by only {apart} mm");
}

/// Without `--stiffness` it is fitted from the skin: the trials and the
/// residual are in the report, and the solve uses the fitted value.
#[test]
fn the_stiffness_is_fitted_from_the_skin_when_not_given() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = sampled_model(dir.path());
    let out = dir.path().join("fitted");
    let (output, report) = deform(&model, &out, &POSTURES);
    assert!(output.status.success(), "{}", text(&output));
    let r = report.unwrap();
    assert_eq!(r["stiffness_fitted"], true);
    let e = r["stiffness_kpa"].as_f64().unwrap();
    assert!(e > 0.1 && e < 100.0, "{e}");
    let trials = r["fit_trials"].as_array().unwrap();
    // The first trial, then at least one small-strain estimate.
    assert!(trials.len() >= 2, "{trials:?}");
    let best = trials
        .iter()
        .filter_map(|t| t["residual_mm"].as_f64())
        .fold(f64::INFINITY, f64::min);
    let residual = r["fit_residual_mm"].as_f64().unwrap();
    assert_eq!(residual, best, "the fit keeps its best trial");
    assert!(
        trials
            .iter()
            .any(|t| t["stiffness_kpa"].as_f64() == Some(e)),
        "{e} among {trials:?}"
    );
    assert!(text(&output).contains("fitted in"), "{}", text(&output));
    // A model of 2,000 particles is fitted on itself (the coarse model's
    // default is 4,000, used from twice as many).
    assert_eq!(r["fit_particles"], 2000);
    assert!(r["posture_seconds"].as_f64().unwrap() > 0.0);
    // `--fit-particles 500`: fitted on 500 particles of the same surface,
    // the model's own unloaded shape then found at that stiffness.
    let coarse = dir.path().join("coarse");
    let extra = [&POSTURES[..], &["--fit-particles", "500"]].concat();
    let (output, report) = deform(&model, &coarse, &extra);
    assert!(output.status.success(), "{}", text(&output));
    let c = report.unwrap();
    assert_eq!(c["fit_particles"], 500);
    assert!(
        text(&output).contains("on 500 particles"),
        "{}",
        text(&output)
    );
    assert!(c["unloaded_residual_mm"].as_f64().unwrap() <= 0.1, "{c}");
    let e_coarse = c["stiffness_kpa"].as_f64().unwrap();
    assert!(
        (e_coarse / e).ln().abs() < 0.25,
        "{e_coarse} kPa on 500 particles, {e} on the model"
    );
}

/// The same gravity in both postures: the skin says nothing about the
/// stiffness, no load is fitted, and the solve is the elastic one without
/// gravity, to the bit.
#[test]
fn no_change_of_gravity_fits_no_load() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = sampled_model(dir.path());
    let same = dir.path().join("same");
    let (output, report) = deform(
        &model,
        &same,
        &["--gravity-rest", "0,0,-1", "--gravity-deformed", "0,0,-1"],
    );
    assert!(output.status.success(), "{}", text(&output));
    let r = report.unwrap();
    assert!(r["stiffness_kpa"].is_null(), "{}", r["stiffness_kpa"]);
    assert_eq!(r["gravity"]["change"], 0.0);
    assert_eq!(r["params"]["load"], serde_json::json!([0.0, 0.0, 0.0]));
    let plain = dir.path().join("plain");
    let (output, _) = deform(&model, &plain, &["--force", "elastic"]);
    assert!(output.status.success(), "{}", text(&output));
    let particles = |dir: &Path| std::fs::read_to_string(dir.join("particles.vtp")).unwrap();
    assert_eq!(particles(&same), particles(&plain));
}

/// A gravity not 1 g long (a 45-degree direction written as `0,-1,-1`,
/// 1.41 g) loads the tissue as given, with a warning naming the option and
/// its length; a unit one is not warned of.
#[test]
fn a_gravity_not_one_g_long_is_warned_of() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = sampled_model(dir.path());
    // The rest posture 1 g along -z, the deformed one `deformed`, the
    // stiffness given.
    let postures = |deformed| {
        [
            "--gravity-rest",
            "0,0,-1",
            "--gravity-deformed",
            deformed,
            "--stiffness",
            "3",
        ]
    };
    let tilted = dir.path().join("tilted");
    let (output, report) = deform(&model, &tilted, &postures("0,-1,-1"));
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(said.contains("--gravity-deformed is 1.41 g long"), "{said}");
    assert!(!said.contains("--gravity-rest is"), "{said}");
    assert_eq!(
        report.unwrap()["gravity"]["deformed"],
        serde_json::json!([0.0, -1.0, -1.0])
    );
    let unit = dir.path().join("unit");
    let (output, _) = deform(&model, &unit, &postures("0,-0.7071068,-0.7071068"));
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(!said.contains("g long"), "{said}");
}

/// Bad posture options are refused before any work, each naming the
/// problem.
#[test]
fn bad_posture_options_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = sampled_model(dir.path());
    let out = dir.path().join("out");
    let missing = dir.path().join("missing.csv");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--gravity-rest", "0,0,-1"], "--gravity-deformed"),
        (vec!["--stiffness", "3"], "--gravity-rest"),
        (
            [&POSTURES[..], &["--force", "symmetric"]].concat(),
            "need the elastic force",
        ),
        (
            vec!["--gravity-rest", "0,-1", "--gravity-deformed", "0,-1,0"],
            "expected three numbers",
        ),
        (
            vec!["--gravity-rest", "0,0,-50", "--gravity-deformed", "0,-1,0"],
            "gravity_rest",
        ),
        ([&POSTURES[..], &["--density", "-5"]].concat(), "density"),
        // The likely unit mistakes, each named: m/s^2, g/cm^3, centimetres.
        (
            vec![
                "--gravity-rest",
                "0,0,-9.81",
                "--gravity-deformed",
                "0,-1,0",
            ],
            "m/s^2?",
        ),
        (
            [&POSTURES[..], &["--density", "1"]].concat(),
            "1 g/cm^3 is 1000 kg/m^3",
        ),
        ([&POSTURES[..], &["--unit", "cm"]].concat(), "--unit mm"),
        // The fit's solves all stopped by the cap: the cap is named.
        (
            [&POSTURES[..], &["--max-iterations", "3"]].concat(),
            "raise --max-iterations",
        ),
        ([&POSTURES[..], &["--stiffness", "0"]].concat(), "stiffness"),
        (
            [&POSTURES[..], &["--fit-particles", "100"]].concat(),
            "fit_particles",
        ),
        (
            [
                &POSTURES[..],
                &["--fit-particles", "500", "--stiffness", "3"],
            ]
            .concat(),
            "cannot be used with",
        ),
        (
            [&POSTURES[..], &["--fixed-region", s(&missing)]].concat(),
            "missing.csv",
        ),
    ];
    for (extra, expected) in cases {
        let (output, _) = deform(&model, &out, &extra);
        assert!(!output.status.success(), "{extra:?} was accepted");
        let said = text(&output);
        assert!(said.contains(expected), "{extra:?}: {said}");
        assert!(
            !out.join("report.json").exists(),
            "{extra:?} wrote a report"
        );
    }
}

/// A deformed surface whose every vertex moved (no chest wall to hold) is
/// refused with a way out: `--fixed-region FILE`.
#[test]
fn a_surface_with_nothing_held_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let mut shifted = model.surface.clone();
    shifted
        .vertices
        .iter_mut()
        .for_each(|v| *v += tissue::Vec3::new(0.0, 0.0, 0.5));
    let moved = dir.path().join("moved.obj");
    tissue::save_surface(&shifted, &moved).unwrap();
    let out = dir.path().join("out");
    let mut args = vec![
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&moved),
        "-o",
        s(&out),
        "--backend",
        "cpu",
    ];
    args.extend_from_slice(&POSTURES);
    let output = tissue(&args);
    assert!(!output.status.success());
    let said = text(&output);
    assert!(
        said.contains("no surface vertex is held") && said.contains("--fixed-region"),
        "{said}"
    );
}

/// `tissue track` takes the same options: the unloaded shape once, from
/// the first frame, every frame solved from it with the deformed posture's
/// gravity; `track.json` says so.
#[test]
fn track_solves_every_frame_from_one_unloaded_shape() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = tissue::load_surface_as_written(&assets().join("phantom-sag.obj")).unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    for (k, t) in [0.9f32, 1.0].iter().enumerate() {
        let frame = tissue::deform::interpolate(&model.surface, &sag, *t).unwrap();
        tissue::save_surface(&frame, &frames.join(format!("f{k}.obj"))).unwrap();
    }
    let out = dir.path().join("tracked");
    let glob = frames.join("*.obj");
    let mut args = vec![
        "track",
        "--model",
        s(&model_path),
        "--frames",
        s(&glob),
        "-o",
        s(&out),
        "--backend",
        "cpu",
        "--stiffness",
        "3",
    ];
    args.extend_from_slice(&POSTURES);
    let output = tissue(&args);
    assert!(output.status.success(), "{}", text(&output));
    let summary = json(&out.join("track.json"));
    assert_eq!(summary["stiffness_kpa"], 3.0);
    assert_eq!(summary["unloaded_converged"], true);
    assert_eq!(summary["totals"]["frames"], 2);
    assert_eq!(summary["totals"]["converged"], true);
    assert!(summary["plan"]["gravity"]["gravity_rest"].is_array());
    for k in 1..=2 {
        let frame = json(&out.join(format!("frame-{k:04}/report.json")));
        assert_eq!(frame["stiffness_kpa"], 3.0, "frame {k}");
        assert_eq!(frame["params"]["force"], "elastic", "frame {k}");
    }
}

/// A fit that the postures cannot explain is flagged, not reported as a
/// plain success: gravity pointing against the observed sag
/// (`--gravity-deformed 0,1,0`) leaves the free skin further from the
/// observed than it moved, so the run exits 4 with `status: flagged` and
/// says why. A held region that moves between the scans is refused.
#[test]
fn a_fit_the_postures_cannot_explain_is_flagged_and_a_moving_held_region_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let out = dir.path().join("against");
    let (output, report) = deform(
        &model_path,
        &out,
        &["--gravity-rest", "0,0,-1", "--gravity-deformed", "0,1,0"],
    );
    assert_eq!(output.status.code(), Some(4), "{}", text(&output));
    let r = report.unwrap();
    assert_eq!(r["status"], "flagged", "{r}");
    let fit = r["fit_residual_mm"].as_f64().unwrap();
    let motion = r["skin_motion_mm"].as_f64().unwrap();
    assert!(fit > motion, "fit {fit} mm, the skin moved {motion} mm");
    assert!(
        text(&output).contains("does not explain the deformed skin"),
        "{}",
        text(&output)
    );

    // Every rest vertex as the held region: the sagged skin moved.
    let all = dir.path().join("all.csv");
    tissue::save_points(&model.surface.vertices, &all).unwrap();
    let out = dir.path().join("held");
    let extra = [&POSTURES[..], &["--fixed-region", s(&all)]].concat();
    let (output, report) = deform(&model_path, &out, &extra);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    assert!(report.is_none());
    for word in ["all.csv", "move between the rest and the deformed surface"] {
        assert!(text(&output).contains(word), "{}", text(&output));
    }
}
