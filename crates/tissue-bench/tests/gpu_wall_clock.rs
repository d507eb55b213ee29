//! `tissue-bench --no-timestamps` times the GPU kernels by the wall clock,
//! the path taken on adapters without timestamp queries (lavapipe has them,
//! so without the flag CI would never run it).

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{SYMMETRIC_GPU_PASSES, check_breakdown, gpu_ran, run_bench};

#[test]
fn no_timestamps_times_each_kernel_by_the_wall_clock() {
    let (_, report, _) = run_bench(&[
        "--quick",
        "--sizes",
        "1000",
        "--backends",
        "gpu",
        "--no-timestamps",
        "--force",
        "symmetric",
    ]);
    let gpu = &report["gpu"];
    if !gpu_ran(gpu) {
        return;
    }
    assert_eq!(gpu["status"], "available");
    assert_eq!(gpu["timestamps_used"], false, "--no-timestamps was given");
    let size = &report["sizes"][0];
    let b = &size["backends"][0];
    assert_eq!(b["backend"], "gpu");
    assert_eq!(b["status"], "ran", "{}", b["reason"]);
    let stages = &b["stage2"]["stages"];
    check_breakdown(
        stages,
        "wall_clock_submit_wait",
        &SYMMETRIC_GPU_PASSES,
        "gpu, 1000 particles",
    );
    let note = stages["note"].as_str().expect("a note");
    assert!(note.contains("wall clock"), "the note says how: {note}");
}
