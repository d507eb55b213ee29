//! The table of `docs/METHOD.md`: stage 1 on the bundled phantom with each
//! choice of the paper's gaps changed one at a time.
//!
//! `cargo run --release --example ablation [particles]`

use tissue::InitialPlacement;
use tissue::{SamplingParams, SurfaceMode, phantom};

fn main() -> Result<(), tissue::Error> {
    let particles = match std::env::args().nth(1) {
        Some(text) => text.parse().unwrap_or(10_000),
        None => 10_000,
    };
    let base = SamplingParams::with_particles(particles);
    let variants: Vec<(&str, SamplingParams)> = vec![
        ("defaults", base.clone()),
        (
            "random start",
            base.clone().with(|p| {
                p.initial = InitialPlacement::Random;
            }),
        ),
        (
            "force cutoff 1.2",
            base.clone().with(|p| {
                p.force_cutoff = 1.2;
            }),
        ),
        (
            "force cutoff 1.4",
            base.clone().with(|p| {
                p.force_cutoff = 1.4;
            }),
        ),
        (
            "wall not in compression",
            base.clone().with(|p| {
                p.wall_in_compression = false;
            }),
        ),
        (
            "paper surface force, mu = 30",
            base.clone().with(|p| {
                p.surface_mode = SurfaceMode::PaperForce { mu: 30.0 };
                p.wall_in_compression = false;
            }),
        ),
        (
            "eta = 0.003",
            base.clone().with(|p| {
                p.eta = 0.003;
            }),
        ),
        (
            "eta = 0.03",
            base.clone().with(|p| {
                p.eta = 0.03;
            }),
        ),
        (
            "connection ratio 0.6 (paper)",
            base.clone().with(|p| {
                p.connection_ratio = 0.6;
            }),
        ),
        (
            "connection ratio 0.75",
            base.clone().with(|p| {
                p.connection_ratio = 0.75;
            }),
        ),
        (
            "connection ratio 1.0",
            base.clone().with(|p| {
                p.connection_ratio = 1.0;
            }),
        ),
        ("paper preset", SamplingParams::paper(particles)),
    ];
    let mesh = phantom::default_breast();
    println!(
        "| setting | iterations | converged | seconds | nn_cv | connections p5/median/p95 | surface | coverage | surface/interior radius |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, params) in variants {
        let s = tissue::sample(&mesh, &params)?;
        let r = &s.report;
        let mean = |surface: bool| {
            let radii: Vec<f32> = (0..s.model.len())
                .filter(|&i| s.model.is_surface(i) == surface)
                .map(|i| s.model.radii[i])
                .collect();
            radii.iter().sum::<f32>() / radii.len().max(1) as f32
        };
        println!(
            "| {name} | {} | {} | {:.2} | {:.4} | {}/{}/{} | {} | {:.2} | {:.2} |",
            r.iterations,
            if r.converged { "yes" } else { "no" },
            r.seconds,
            r.nn_cv,
            r.connections.p5,
            r.connections.median,
            r.connections.p95,
            r.surface_particles,
            r.coverage,
            mean(true) / mean(false),
        );
    }
    Ok(())
}
