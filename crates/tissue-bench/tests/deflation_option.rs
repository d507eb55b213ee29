//! `tissue-bench --deflation M`: stage 2 with the lowest modes deflated, its
//! preparation time and the deflate passes reported, on the CPU and the GPU.

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{GPU_DEFLATED_PASSES, check_breakdown, gpu_ran, positive, run_bench};

#[test]
fn deflation_is_measured_on_the_cpu() {
    let (stdout, report, _) = run_bench(&[
        "--quick",
        "--sizes",
        "1500",
        "--backends",
        "cpu",
        "--deflation",
        "8",
        // The CPU's two-level solve would replace deflation.
        "--coarse",
        "0",
    ]);
    assert!(
        stdout.contains("8 modes deflated, prepared in"),
        "the table says so:\n{stdout}"
    );
    let cpu = &report["sizes"][0]["backends"][0];
    assert_eq!(cpu["status"], "ran", "{}", cpu["reason"]);
    let stage2 = &cpu["stage2"];
    assert_eq!(stage2["deflation"], 8);
    positive(&stage2["prepare_seconds"], "preparation seconds");
    for case in stage2["converge"].as_array().expect("converge array") {
        assert_eq!(case["converged"], true, "{case}");
    }
    check_breakdown(
        &stage2["stages"],
        "wall_clock",
        &[
            "local_rotations_warm (warm polar)",
            "deformation_force",
            "integrate + chebyshev_combine",
            "deflate (8 modes)",
            "step norms",
        ],
        "1500 particles, 8 modes",
    );
}

/// On the GPU (without the two-level solve, which replaces deflation on
/// both devices) the deflated iteration's kernels are timed one by one, the
/// deflate passes between integrate and the combine.
#[test]
fn deflation_is_measured_on_the_gpu() {
    let (stdout, report, _) = run_bench(&[
        "--quick",
        "--sizes",
        "1500",
        "--backends",
        "gpu",
        "--deflation",
        "8",
        "--coarse",
        "0",
    ]);
    let gpu = &report["gpu"];
    if !gpu_ran(gpu) {
        return;
    }
    assert!(
        stdout.contains("8 modes deflated, prepared in"),
        "the table says so:\n{stdout}"
    );
    let b = &report["sizes"][0]["backends"][0];
    assert_eq!(b["backend"], "gpu");
    assert_eq!(b["status"], "ran", "{}", b["reason"]);
    let stage2 = &b["stage2"];
    assert_eq!(stage2["deflation"], 8);
    positive(&stage2["prepare_seconds"], "preparation seconds");
    for case in stage2["converge"].as_array().expect("converge array") {
        assert_eq!(case["converged"], true, "{case}");
    }
    let method = stage2["stages"]["method"].as_str().expect("a method");
    check_breakdown(
        &stage2["stages"],
        method,
        &GPU_DEFLATED_PASSES,
        "gpu, 1500 particles, 8 modes",
    );
}
