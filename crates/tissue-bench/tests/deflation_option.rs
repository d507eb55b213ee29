//! `tissue-bench --deflation M`: stage 2 with the lowest modes deflated, its
//! preparation time and the deflate pass reported; refused with the GPU.

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use std::process::Command;

use common::{check_breakdown, positive, run_bench};

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

#[test]
fn deflation_with_the_gpu_is_refused_before_any_work() {
    let out = Command::new(env!("CARGO_BIN_EXE_tissue-bench"))
        .args(["--quick", "--deflation", "8"])
        .output()
        .expect("running tissue-bench");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("--deflation 8 runs on the CPU path only") && !stderr.contains("panicked"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("tissue-bench: 1000 particles"),
        "it stopped before sampling: {stderr}"
    );
}
