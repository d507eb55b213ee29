//! `tissue-bench --mesh FILE` benchmarks that surface, not the bundled
//! phantom, with its sag and indentation scaled to it.

#![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]

mod common;

use common::{CPU_PASSES, check_breakdown, check_sampling, positive, run_bench};

#[test]
fn mesh_option_benchmarks_the_given_surface() {
    let mesh = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../assets/phantom-tumour.obj"
    );
    let (stdout, report, _) = run_bench(&[
        "--quick",
        "--sizes",
        "800,1500",
        "--backends",
        "cpu",
        "--mesh",
        mesh,
    ]);
    assert_eq!(report["mesh"], mesh, "the report names the mesh");
    assert!(
        stdout.contains(&format!("mesh: {mesh}")),
        "stdout names the mesh:\n{stdout}"
    );
    assert!(report["gpu"].is_null(), "no GPU was asked for");

    let cases: Vec<&str> = report["cases"]
        .as_array()
        .expect("cases array")
        .iter()
        .filter_map(|c| c.as_str())
        .collect();
    assert!(
        cases.starts_with(&["rotate_30", "sag"]),
        "cases on the tumour: {cases:?}"
    );

    let sizes = report["sizes"].as_array().expect("sizes array");
    let requested: Vec<u64> = sizes
        .iter()
        .filter_map(|s| s["particles_requested"].as_u64())
        .collect();
    assert_eq!(requested, [800, 1500]);
    let mut particles = Vec::new();
    for size in sizes {
        let n = size["particles"].as_u64().expect("particle count");
        // The sampler lands near the count asked for, on any closed surface.
        let asked = size["particles_requested"].as_u64().unwrap_or(0);
        assert!(
            n.abs_diff(asked) * 10 <= asked,
            "{n} particles for {asked} asked"
        );
        particles.push(n);
        check_sampling(size);
        let backends = size["backends"].as_array().expect("backends array");
        assert_eq!(backends.len(), 1, "only the CPU was asked for");
        let cpu = &backends[0];
        assert_eq!(cpu["backend"], "cpu");
        assert_eq!(cpu["status"], "ran", "{}", cpu["reason"]);
        let stage2 = &cpu["stage2"];
        let context = format!("tumour, {n} particles");
        positive(
            &stage2["iteration"]["per_iteration"]["median_ms"],
            &format!("{context} ms / iteration"),
        );
        let solved: Vec<&str> = stage2["converge"]
            .as_array()
            .expect("converge array")
            .iter()
            .map(|c| {
                assert_eq!(c["converged"], true, "{context}: {c}");
                positive(
                    &c["iterations"],
                    &format!("{context} {} iterations", c["case"]),
                );
                c["case"].as_str().unwrap_or("")
            })
            .collect();
        assert_eq!(solved, cases, "{context}: every case solved");
        check_breakdown(&stage2["stages"], "wall_clock", &CPU_PASSES, &context);
    }
    assert!(particles[0] < particles[1], "sizes in order: {particles:?}");
}
