//! Running `tissue-bench` and reading its JSON report, shared by the tests.

#![allow(
    dead_code,
    reason = "each test binary compiles this module and uses part of it"
)]

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::Value;

/// `value` as a positive, finite number; panics naming `what` otherwise.
pub fn positive(value: &Value, what: &str) -> f64 {
    let x = value
        .as_f64()
        .unwrap_or_else(|| panic!("{what} is not a number: {value}"));
    assert!(x > 0.0 && x.is_finite(), "{what} is {x}, expected positive");
    x
}

/// Runs `tissue-bench` with `args` and `--json FILE`; returns stdout, the
/// parsed report and the wall time. Panics with both outputs on failure.
pub fn run_bench(args: &[&str]) -> (String, Value, Duration) {
    let dir = tempfile::tempdir().expect("temporary directory");
    let json = dir.path().join("bench.json");
    let started = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_tissue-bench"))
        .args(args)
        .arg("--json")
        .arg(&json)
        .output()
        .expect("running tissue-bench");
    let took = started.elapsed();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "tissue-bench {args:?} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (stdout, read_json(&json), took)
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).expect("the JSON report");
    serde_json::from_str(&text).expect("valid JSON")
}

/// The sampling numbers of one size, its stage seconds included.
pub fn check_sampling(size: &Value) {
    let s = &size["sampling"];
    for key in [
        "seconds",
        "iterations",
        "nn_cv",
        "coverage",
        "connections_median",
    ] {
        positive(&s[key], &format!("sampling {key}"));
    }
    let stages = &s["stage_seconds"];
    for key in ["field", "iterations"] {
        positive(&stages[key], &format!("sampling stage_seconds.{key}"));
    }
    for key in ["initial", "neighbours", "connections", "report"] {
        let x = stages[key]
            .as_f64()
            .unwrap_or_else(|| panic!("stage_seconds.{key} is not a number"));
        assert!(x >= 0.0, "stage_seconds.{key} is {x}");
    }
    let total: f64 = ["field", "initial", "iterations", "connections", "report"]
        .iter()
        .filter_map(|k| stages[k].as_f64())
        .sum();
    let seconds = s["seconds"].as_f64().unwrap_or(0.0);
    assert!(
        total <= seconds * 1.01 + 1e-3,
        "the sampling stages add up to {total} s, more than the whole {seconds} s"
    );
}

/// One iteration pass by pass: `passes` named in order, each positive, and
/// the method `method`.
pub fn check_breakdown(stages: &Value, method: &str, passes: &[&str], context: &str) {
    assert_eq!(stages["method"], method, "{context} breakdown method");
    assert!(
        stages["note"].is_string(),
        "{context}: the method is explained"
    );
    let rows = stages["stages"]
        .as_array()
        .unwrap_or_else(|| panic!("{context}: no stages array"));
    let names: Vec<&str> = rows.iter().filter_map(|r| r["stage"].as_str()).collect();
    assert_eq!(names, passes, "{context} passes");
    let mut sum = 0.0;
    for r in rows {
        sum += positive(
            &r["time"]["median_ms"],
            &format!("{context} {}", r["stage"]),
        );
    }
    let reported = positive(&stages["sum_of_medians_ms"], &format!("{context} sum"));
    assert!(
        (reported - sum).abs() <= 1e-9 * sum.max(1.0),
        "{context} sum"
    );
    positive(
        &stages["iteration"]["median_ms"],
        &format!("{context} iteration"),
    );
}

/// The CPU passes of one iteration with the defaults (the elastic force's
/// smoothed iteration: warm rotations, the elastic two-level solve with
/// the volume smoother).
pub const CPU_PASSES: [&str; 5] = [
    "elastic_targets_warm",
    "elastic_force",
    "smoothed step (factored)",
    "chebyshev",
    "step_norms (update)",
];

/// The GPU kernels of one iteration with the defaults, in the order of
/// their first dispatch; the pressures' force, dispatched twice, is one
/// row.
pub const GPU_PASSES: [&str; 15] = [
    "elastic_targets_warm",
    "elastic_force",
    "smoother_residual",
    "pressure_start",
    "pressure_forces ×2",
    "pressure_sweep",
    "smoothed_step",
    "elastic_change_of",
    "elastic_residual_of",
    "elastic_restrict",
    "elastic_forward",
    "elastic_backward",
    "elastic_apply",
    "chebyshev",
    "step_norms (update)",
];

/// The GPU kernels of one iteration of the symmetric force (warm polar
/// rotations, the two-level solve), in dispatch order.
pub const SYMMETRIC_GPU_PASSES: [&str; 10] = [
    "local_rotations_warm",
    "deformation_force",
    "integrate",
    "coarse_residual",
    "coarse_restrict",
    "coarse_forward",
    "coarse_backward",
    "coarse_apply",
    "chebyshev",
    "step_norms (update)",
];

/// Whether the report's `gpu` section ran; a skipped one fails under
/// `CI=true` (a GPU check never passes silently there) and is reported
/// otherwise.
pub fn gpu_ran(gpu: &Value) -> bool {
    if gpu["status"] != "skipped" {
        return true;
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "no GPU adapter under CI=true: {}",
        gpu["reason"]
    );
    eprintln!("GPU skipped: {}", gpu["reason"]);
    false
}
