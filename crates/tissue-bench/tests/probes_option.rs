//! `tissue-bench --probes` adds the probe sweep: 16 solves from rest under
//! probes at the phantom's tip, each with its iterations, retries, how it
//! ended and the particles it left inverted, in the JSON and in a table.

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{positive, run_bench};

#[test]
fn probes_option_solves_the_sweep_of_probes_from_rest() {
    let args = [
        "--quick",
        "--sizes",
        "1000",
        "--backends",
        "cpu",
        "--force",
        "elastic",
    ];
    let (stdout, report, _) = run_bench(&[&args[..], &["--probes"]].concat());
    assert!(
        stdout.contains("## Probes from rest"),
        "no probe table on stdout:\n{stdout}"
    );
    let probes = report["sizes"][0]["backends"][0]["stage2"]["probes"]
        .as_array()
        .expect("a probes array");
    // Four depths by four widths, on the phantom's own millimetres.
    assert_eq!(probes.len(), 16);
    let grid: Vec<(f64, f64)> = probes
        .iter()
        .map(|p| {
            (
                p["depth_mm"].as_f64().expect("depth_mm"),
                p["width_mm"].as_f64().expect("width_mm"),
            )
        })
        .collect();
    assert_eq!(grid[0], (15.0, 8.0));
    assert_eq!(grid[15], (30.0, 35.0));
    for (k, p) in probes.iter().enumerate() {
        positive(&p["iterations"], &format!("probe {k} iterations"));
        positive(&p["seconds"], &format!("probe {k} seconds"));
        assert!(p["stopped_by"].is_string(), "probe {k}: {p}");
        assert!(
            p["retries"].is_u64() && p["inverted"].is_u64(),
            "probe {k}: {p}"
        );
    }
    // The shallowest, widest probe needs no retry.
    assert_eq!(probes[3]["retries"], 0, "{}", probes[3]);
    assert_eq!(probes[3]["stopped_by"], "Tolerance", "{}", probes[3]);

    // Without the option, no sweep and no table.
    let (stdout, report, _) = run_bench(&args);
    assert!(!stdout.contains("## Probes from rest"), "{stdout}");
    let probes = report["sizes"][0]["backends"][0]["stage2"]["probes"]
        .as_array()
        .expect("a probes array");
    assert!(probes.is_empty());
}
