//! `tissue-bench --force elastic` on the GPU: the kernel breakdown of the
//! elastic phase's smoothed iteration, the longest the GPU runs. Its
//! timestamp query set was once sized for the plain step's correction, and
//! the breakdown failed ("Query 24 is out of bounds for a query set of size
//! 24").

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{check_breakdown, gpu_ran, run_bench};

/// The GPU kernels of one elastic iteration with the defaults (warm
/// rotations, the elastic two-level solve with the volume smoother), in
/// the order of their first dispatch; the pressures' force, dispatched
/// twice, is one row.
const SMOOTHED_PASSES: [&str; 15] = [
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

#[test]
fn the_gpu_breakdown_covers_the_smoothed_elastic_iteration() {
    let (_, report, _) = run_bench(&[
        "--quick",
        "--sizes",
        "1000",
        "--backends",
        "gpu",
        "--force",
        "elastic",
    ]);
    let gpu = &report["gpu"];
    if !gpu_ran(gpu) {
        return;
    }
    let b = &report["sizes"][0]["backends"][0];
    assert_eq!(b["backend"], "gpu");
    assert_eq!(b["status"], "ran", "{}", b["reason"]);
    let method = if gpu["timestamps_used"] == true {
        "timestamp_queries"
    } else {
        "wall_clock_submit_wait"
    };
    check_breakdown(
        &b["stage2"]["stages"],
        method,
        &SMOOTHED_PASSES,
        "gpu elastic, 1000 particles",
    );
}
