//! `tissue sample --backend gpu|cpu`: stage 1's iterations on the GPU give a
//! model with the CPU's quality numbers. Without an adapter the GPU test
//! prints "SKIPPED: no GPU adapter", and fails under `CI=true`.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use common::{assets, gpu, json, s, text, tissue};

#[test]
fn sample_on_the_gpu_matches_the_cpu_by_its_report() {
    if !gpu("sample --backend gpu") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let breast = assets().join("phantom-breast.obj");
    let mut reports = Vec::new();
    for backend in ["cpu", "gpu"] {
        let model = dir.path().join(format!("{backend}.vtp"));
        let report = dir.path().join(format!("{backend}.json"));
        let out = tissue(&[
            "sample",
            s(&breast),
            "-n",
            "1500",
            "-o",
            s(&model),
            "--report",
            s(&report),
            "--backend",
            backend,
        ]);
        let printed = text(&out);
        assert!(out.status.success(), "--backend {backend}: {printed}");
        if backend == "gpu" {
            assert!(printed.contains("backend: gpu ("), "{printed}");
        }
        reports.push(json(&report));
    }
    let (cpu, gpu) = (&reports[0], &reports[1]);
    assert_eq!(cpu["converged"], gpu["converged"]);
    let number = |v: &serde_json::Value, key: &str| v[key].as_f64().unwrap();
    let iterations = number(cpu, "iterations");
    assert!(
        (number(gpu, "iterations") - iterations).abs() <= 0.25 * iterations + 10.0,
        "iterations: GPU {} vs CPU {iterations}",
        gpu["iterations"]
    );
    let nn_cv = number(cpu, "nn_cv");
    assert!(
        (number(gpu, "nn_cv") - nn_cv).abs() <= 0.1 * nn_cv + 0.005,
        "nn_cv: GPU {} vs CPU {nn_cv}",
        gpu["nn_cv"]
    );
    assert!(
        number(gpu, "max_outside") <= 0.01,
        "max_outside {}",
        gpu["max_outside"]
    );
}
