//! `tissue-bench --quick --json` runs to the end and writes every number.

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use std::time::Duration;

use common::{CPU_PASSES, GPU_PASSES, check_breakdown, check_sampling, positive, run_bench};
use serde_json::Value;

fn check_stage2(stage2: &Value, context: &str) {
    let it = &stage2["iteration"]["per_iteration"];
    for key in ["median_ms", "min_ms", "max_ms", "p99_ms"] {
        positive(&it[key], &format!("{context} iteration {key}"));
    }
    let converge = stage2["converge"]
        .as_array()
        .unwrap_or_else(|| panic!("{context}: no converge array"));
    let cases: Vec<&str> = converge.iter().filter_map(|c| c["case"].as_str()).collect();
    assert_eq!(cases, ["rotate_30", "sag", "indentation"], "{context}");
    for c in converge {
        positive(&c["seconds"], &format!("{context} {} seconds", c["case"]));
        positive(
            &c["iterations"],
            &format!("{context} {} iterations", c["case"]),
        );
        assert_eq!(c["converged"], true, "{context} {}", c["case"]);
    }
    let latency = &stage2["tracking"]["latency"];
    assert_eq!(latency["samples"], 10, "{context} tracking frames");
    positive(&latency["median_ms"], &format!("{context} tracking p50"));
    positive(&latency["p99_ms"], &format!("{context} tracking p99"));
}

#[test]
fn quick_run_writes_a_complete_json_report() {
    let (stdout, report, took) = run_bench(&["--quick"]);
    // The binary follows the dev profile (opt-level 0) in a plain `cargo
    // test`: the time budget is the release build's.
    assert!(
        cfg!(debug_assertions) || took < Duration::from_secs(60),
        "--quick took {took:?}, expected well under a minute"
    );
    for table in ["## Stage 1", "Where the sampling time goes", "pass by pass"] {
        assert!(stdout.contains(table), "no {table:?} on stdout:\n{stdout}");
    }
    for key in ["cpu_model", "rayon_threads", "git_commit"] {
        assert!(!report["machine"][key].is_null(), "machine.{key} missing");
    }
    positive(&report["machine"]["rayon_threads"], "rayon_threads");
    let gpu = &report["gpu"];
    let gpu_available = match gpu["status"].as_str() {
        Some("available") => {
            for key in ["name", "backend", "device_type", "driver"] {
                assert!(gpu["adapter"][key].is_string(), "gpu.adapter.{key} missing");
            }
            assert_eq!(
                gpu["timestamps_used"], gpu["adapter"]["timestamp_queries"],
                "timestamps are used wherever the adapter offers them"
            );
            eprintln!(
                "GPU: {} (timestamp queries: {})",
                gpu["adapter"]["name"], gpu["adapter"]["timestamp_queries"]
            );
            true
        }
        Some("skipped") => {
            assert!(gpu["reason"].is_string(), "a skipped GPU says why");
            // A GPU check never passes silently without a GPU in CI.
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "no GPU adapter under CI=true: {}",
                gpu["reason"]
            );
            eprintln!("GPU skipped: {}", gpu["reason"]);
            false
        }
        other => panic!("gpu.status is {other:?}"),
    };

    let sizes = report["sizes"].as_array().expect("sizes array");
    let requested: Vec<u64> = sizes
        .iter()
        .filter_map(|s| s["particles_requested"].as_u64())
        .collect();
    assert_eq!(requested, [1000, 5000]);
    for size in sizes {
        let n = size["particles"].as_u64().unwrap_or(0);
        assert!(n > 0, "no particles");
        check_sampling(size);
        positive(
            &size["cpu_model_bytes"]["per_particle"],
            "CPU bytes per particle",
        );
        if cfg!(target_os = "linux") {
            positive(&size["peak_resident_bytes"], "peak RSS");
        }
        let backends = size["backends"].as_array().expect("backends array");
        let names: Vec<&str> = backends
            .iter()
            .filter_map(|b| b["backend"].as_str())
            .collect();
        assert_eq!(names, ["cpu", "gpu"]);
        for b in backends {
            let context = format!("{n} particles, {}", b["backend"]);
            let ran = b["status"] == "ran";
            if b["backend"] == "cpu" || gpu_available {
                assert!(ran, "{context}: {}", b["reason"]);
            } else {
                assert_eq!(b["status"], "skipped", "{context}");
                assert!(b["reason"].is_string(), "{context}: a skip says why");
                continue;
            }
            check_stage2(&b["stage2"], &context);
            positive(
                &b["floor"]["bytes_per_iteration"],
                &format!("{context} floor"),
            );
            positive(
                &b["floor"]["effective_gb_per_s"],
                &format!("{context} bandwidth"),
            );
            let stages = &b["stage2"]["stages"];
            if b["backend"] == "cpu" {
                check_breakdown(stages, "wall_clock", &CPU_PASSES, &context);
                // The CPU solves two-level by default.
                assert!(
                    b["stage2"]["coarse_aggregates"].as_u64() > Some(0),
                    "{context}: {}",
                    b["stage2"]
                );
            } else {
                let method = if gpu["timestamps_used"] == true {
                    "timestamp_queries"
                } else {
                    "wall_clock_submit_wait"
                };
                check_breakdown(stages, method, &GPU_PASSES, &context);
            }
            if b["backend"] == "gpu" {
                let bytes = &b["stage2"]["gpu_state_bytes"];
                positive(&bytes["state_total"], &format!("{context} GPU bytes"));
                positive(&bytes["state_per_particle"], &format!("{context} GPU B/p"));
            }
        }
    }
}
