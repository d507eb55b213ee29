//! `--backend auto|gpu|cpu` on `demo`, `deform` and `track`: the GPU and the
//! CPU put the tumour in the same place, `auto` says what it took, and a
//! missing adapter is an error message, not a panic. Without an adapter the
//! GPU tests print "SKIPPED: no GPU adapter", and fail under `CI=true`.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;
use std::process::Command;

use common::{assets, gpu, json, s, text, tissue, vec3};
use serde_json::Value;
use tissue::Vec3;

/// Bounding-box diagonal of the bundled breast phantom (~190 mm).
fn phantom_size() -> f32 {
    let breast = tissue::load_surface(&assets().join("phantom-breast.obj")).unwrap();
    let (lo, hi) = breast.vertices.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    (hi - lo).length()
}

/// `tissue demo -n 2000 --backend <backend>` into `dir`, and its `demo.json`.
fn demo(dir: &Path, backend: &str) -> (String, Value) {
    let out = tissue(&[
        "demo",
        "--particles",
        "2000",
        "--backend",
        backend,
        "-o",
        s(dir),
    ]);
    let printed = text(&out);
    assert!(out.status.success(), "--backend {backend}: {printed}");
    assert!(!printed.contains("panicked"), "{printed}");
    (printed, json(&dir.join("demo.json")))
}

/// The moved centroid of each (case, structure kind) in `demo.json`.
fn centroids(demo: &Value) -> Vec<(String, Vec3)> {
    let mut all = Vec::new();
    for case in demo["cases"].as_array().unwrap() {
        for structure in case["structures"].as_array().unwrap() {
            let key = format!(
                "{} {}",
                case["name"].as_str().unwrap(),
                structure["kind"].as_str().unwrap()
            );
            all.push((key, vec3(&structure["moved_centroid"])));
        }
    }
    all
}

#[test]
fn demo_on_the_gpu_puts_the_tumour_where_the_cpu_does() {
    if !gpu("demo --backend gpu") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (_, cpu) = demo(&dir.path().join("cpu"), "cpu");
    let (printed, gpu) = demo(&dir.path().join("gpu"), "gpu");
    assert!(printed.contains("backend: gpu ("), "{printed}");
    assert_eq!(cpu["backend"], "cpu");
    let name = gpu["backend"].as_str().unwrap();
    assert!(!name.is_empty() && name != "cpu", "GPU backend {name:?}");
    let sag = json(&dir.path().join("gpu/sag/report.json"));
    assert_eq!(sag["backend"], name, "report.json names the adapter too");

    // Both stages ran on the GPU: the sampling is the CPU's (the kernels are
    // twins; on lavapipe the runs are identical, a hardware GPU's rounding
    // may move a particle by an ulp and the iteration count a little).
    let (c, g) = (&cpu["sampling"], &gpu["sampling"]);
    eprintln!(
        "sampling: CPU {} iterations, nn_cv {}; GPU {} iterations, nn_cv {}",
        c["iterations"], c["nn_cv"], g["iterations"], g["nn_cv"]
    );
    let iterations = |r: &Value| r["iterations"].as_f64().unwrap();
    assert!(
        (iterations(c) - iterations(g)).abs() <= 0.1 * iterations(c),
        "sampling iterations: CPU {c} vs GPU {g}"
    );
    let nn_cv = |r: &Value| r["nn_cv"].as_f64().unwrap();
    assert!(
        (nn_cv(c) - nn_cv(g)).abs() <= 0.005,
        "sampling nn_cv: CPU {c} vs GPU {g}"
    );

    let (cpu, gpu) = (centroids(&cpu), centroids(&gpu));
    let keys: Vec<&str> = cpu.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(
        keys,
        [
            "sag deformable",
            "sag rigid",
            "indentation deformable",
            "indentation rigid"
        ]
    );
    let tolerance = 1e-3 * phantom_size();
    for ((key, c), (_, g)) in cpu.iter().zip(&gpu) {
        let off = c.distance(*g);
        eprintln!("{key}: CPU {c}, GPU {g}, {off:.2e} mm apart");
        assert!(
            off <= tolerance,
            "{key}: tumour centroid on the GPU {g} vs the CPU {c}: {off:e} mm > tolerance {tolerance:e} mm (1e-3 of the size)"
        );
    }
}

#[test]
fn auto_says_which_backend_it_took() {
    let dir = tempfile::tempdir().unwrap();
    let (printed, report) = demo(dir.path(), "auto");
    let line = printed
        .lines()
        .find(|l| l.starts_with("backend: "))
        .unwrap_or_else(|| panic!("no `backend:` line in {printed}"));
    eprintln!("{line}");
    let took_gpu = line.starts_with("backend: gpu (");
    assert!(took_gpu || line.starts_with("backend: cpu ("), "{line}");
    assert_eq!(report["backend"] == "cpu", !took_gpu, "{line} vs {report}");
}

#[test]
fn quiet_prints_no_backend_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = tissue(&[
        "demo",
        "-n",
        "2000",
        "--backend",
        "auto",
        "--quiet",
        "-o",
        s(dir.path()),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.trim().is_empty(), "--quiet printed: {stdout}");
}

#[test]
fn a_missing_adapter_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_tissue"))
        .args([
            "demo",
            "-n",
            "2000",
            "--backend",
            "gpu",
            "-o",
            s(dir.path()),
        ])
        .env("WGPU_ADAPTER_NAME", "no-such-adapter")
        .output()
        .unwrap();
    let printed = text(&out);
    assert_eq!(out.status.code(), Some(1), "{printed}");
    assert!(!printed.contains("panicked"), "{printed}");
    assert!(
        printed.contains("error: the GPU backend: no GPU adapter")
            && printed.contains("no-such-adapter"),
        "{printed}"
    );
    assert!(
        !dir.path().join("model.vtp").exists(),
        "it failed before sampling"
    );
}

#[test]
fn deform_and_track_on_the_gpu_match_the_cpu() {
    if !gpu("deform and track --backend gpu") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.vtp");
    let breast = assets().join("phantom-breast.obj");
    let out = tissue(&["sample", s(&breast), "-n", "2000", "-o", s(&model), "-q"]);
    assert!(out.status.success(), "{}", text(&out));
    let (sag, tumour) = (
        assets().join("phantom-sag.obj"),
        assets().join("phantom-tumour.obj"),
    );
    let tolerance = 1e-3 * phantom_size();
    let mut moved = Vec::new();
    for backend in ["cpu", "gpu"] {
        let out_dir = dir.path().join(format!("deform-{backend}"));
        let out = tissue(&[
            "deform",
            "--model",
            s(&model),
            "--surface",
            s(&sag),
            "--rigid-structure",
            s(&tumour),
            "--backend",
            backend,
            "-o",
            s(&out_dir),
        ]);
        assert!(
            out.status.success(),
            "deform --backend {backend}: {}",
            text(&out)
        );
        let report = json(&out_dir.join("report.json"));
        assert_eq!(report["backend"] == "cpu", backend == "cpu", "{report}");
        moved.push(vec3(&report["structures"][0]["moved_centroid"]));

        let frames = dir.path().join("frames");
        std::fs::create_dir_all(&frames).unwrap();
        std::fs::copy(&sag, frames.join("f1.obj")).unwrap();
        std::fs::copy(
            assets().join("phantom-indentation.obj"),
            frames.join("f2.obj"),
        )
        .unwrap();
        let out_dir = dir.path().join(format!("track-{backend}"));
        let pattern = frames.join("*.obj");
        let out = tissue(&[
            "track",
            "--model",
            s(&model),
            "--frames",
            s(&pattern),
            "--backend",
            backend,
            "-q",
            "-o",
            s(&out_dir),
        ]);
        assert!(
            out.status.success(),
            "track --backend {backend}: {}",
            text(&out)
        );
        let track = json(&out_dir.join("track.json"));
        assert_eq!(track["backend"] == "cpu", backend == "cpu", "{track}");
        assert_eq!(track["totals"]["converged"], true, "{track}");
    }
    let off = moved[0].distance(moved[1]);
    assert!(
        off <= tolerance,
        "deform: rigid tumour centroid on the CPU {} vs the GPU {}: {off:e} mm > {tolerance:e} mm",
        moved[0],
        moved[1]
    );
}

/// The two-level solve (`--coarse`) on both backends: fewer iterations than
/// without it on each, the tumour where the other backend puts it, and a
/// cell under one connection length refused.
#[test]
fn the_two_level_solve_runs_on_both_backends_and_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.vtp");
    let breast = assets().join("phantom-breast.obj");
    let out = tissue(&["sample", s(&breast), "-n", "1500", "-o", s(&model), "-q"]);
    assert!(out.status.success(), "{}", text(&out));
    let sag = assets().join("phantom-sag.obj");
    let tumour = assets().join("phantom-tumour.obj");
    let deform = |backend: &str, coarse: &str, out_dir: &Path| {
        tissue(&[
            "deform",
            "--model",
            s(&model),
            "--surface",
            s(&sag),
            "--rigid-structure",
            s(&tumour),
            "--coarse",
            coarse,
            "--backend",
            backend,
            "-q",
            "-o",
            s(out_dir),
        ])
    };
    // Per backend: (iterations, moved tumour centroid) without and with the
    // two-level solve.
    let run = |backend: &str| {
        ["0", "2"].map(|coarse| {
            let out_dir = dir.path().join(format!("{backend}-{coarse}"));
            let out = deform(backend, coarse, &out_dir);
            let printed = text(&out);
            assert!(out.status.success(), "{backend}, {coarse}: {printed}");
            assert!(!printed.contains("panicked"), "{printed}");
            let report = json(&out_dir.join("report.json"));
            assert_eq!(report["converged"], true, "{report}");
            (
                report["iterations"].as_u64().unwrap(),
                vec3(&report["structures"][0]["moved_centroid"]),
            )
        })
    };
    let cpu = run("cpu");
    assert!(cpu[1].0 < cpu[0].0, "CPU iterations: {cpu:?}");
    let out = deform("cpu", "0.5", &dir.path().join("absurd"));
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).contains("coarse is 0.5"), "{}", text(&out));

    if !gpu("deform --backend gpu --coarse 2") {
        return;
    }
    let on_gpu = run("gpu");
    eprintln!("(iterations, tumour centroid), coarse 0 and 2: CPU {cpu:?}, GPU {on_gpu:?}");
    assert!(on_gpu[1].0 < on_gpu[0].0, "GPU iterations: {on_gpu:?}");
    // Each solve stops within about its tolerance (3e-5 of the size) of the answer.
    let tolerance = 3.0 * 3e-5 * phantom_size();
    let off = cpu[1].1.distance(on_gpu[1].1);
    assert!(
        off <= tolerance,
        "two-level tumour centroid: CPU {} vs GPU {}, {off:e} mm > {tolerance:e} mm",
        cpu[1].1,
        on_gpu[1].1
    );
}

/// `deform --force elastic` runs on the GPU too (it refused the elastic
/// force until its kernels landed) and puts the tumour where the CPU does.
#[test]
fn the_elastic_force_runs_on_both_backends_and_agrees() {
    if !gpu("deform --force elastic --backend gpu") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.vtp");
    let breast = assets().join("phantom-breast.obj");
    let out = tissue(&["sample", s(&breast), "-n", "1500", "-o", s(&model), "-q"]);
    assert!(out.status.success(), "{}", text(&out));
    let run = |backend: &str| {
        let out_dir = dir.path().join(backend);
        let out = tissue(&[
            "deform",
            "--model",
            s(&model),
            "--surface",
            s(&assets().join("phantom-sag.obj")),
            "--rigid-structure",
            s(&assets().join("phantom-tumour.obj")),
            "--force",
            "elastic",
            "--backend",
            backend,
            "-q",
            "-o",
            s(&out_dir),
        ]);
        let printed = text(&out);
        assert!(out.status.success(), "{backend}: {printed}");
        assert!(!printed.contains("panicked"), "{printed}");
        let report = json(&out_dir.join("report.json"));
        assert_eq!(report["converged"], true, "{report}");
        (
            report["iterations"].as_u64().unwrap(),
            vec3(&report["structures"][0]["moved_centroid"]),
        )
    };
    let (cpu, on_gpu) = (run("cpu"), run("gpu"));
    eprintln!("elastic (iterations, tumour centroid): CPU {cpu:?}, GPU {on_gpu:?}");
    // Each solve stops within about its tolerance of the answer, as in the
    // test above.
    let tolerance = 3.0 * 3e-5 * phantom_size();
    let off = cpu.1.distance(on_gpu.1);
    assert!(
        off <= tolerance,
        "elastic tumour centroid: CPU {} vs GPU {}, {off:e} mm > {tolerance:e} mm",
        cpu.1,
        on_gpu.1
    );
}
