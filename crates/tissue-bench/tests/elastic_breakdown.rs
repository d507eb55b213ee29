//! `tissue-bench --force elastic` on the GPU: the kernel breakdown of the
//! elastic phase's smoothed iteration, the longest the GPU runs. Its
//! timestamp query set was once sized for the plain step's correction, and
//! the breakdown failed ("Query 24 is out of bounds for a query set of size
//! 24").

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{GPU_PASSES, check_breakdown, gpu_ran, run_bench};

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
        &GPU_PASSES,
        "gpu elastic, 1000 particles",
    );
}
