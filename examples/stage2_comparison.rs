//! The stage 2 table of `docs/METHOD.md` and `BENCHMARKS.md`: the paper's
//! force against the symmetric one, plain against Chebyshev, from rest.
//!
//! `cargo run --release --example stage2_comparison [particles]`

use glam::{Mat3, Vec3};
use tissue::deform::{Affine, PointMap, Rigid, deform_surface, indented_breast, sagged_breast};
use tissue::deformation::{DeformParams, Deformer, ForceModel};
use tissue::{SamplingParams, SurfaceMesh, phantom};

fn main() -> Result<(), tissue::Error> {
    let particles = std::env::args()
        .nth(1)
        .and_then(|t| t.parse().ok())
        .unwrap_or(10_000);
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(particles),
    )?
    .model;
    let rigid = Rigid::about_axis(
        Vec3::new(1.0, 2.0, 0.5),
        30f32.to_radians(),
        Vec3::new(0.0, 0.0, 25.0),
        Vec3::ZERO,
    );
    let stretch = Affine {
        matrix: Mat3::from_diagonal(Vec3::new(1.2, 1.0, 0.85)),
        translation: Vec3::ZERO,
        centre: Vec3::new(0.0, 0.0, 25.0),
    };
    let cases: Vec<(&str, SurfaceMesh, Option<&dyn PointMap>)> = vec![
        (
            "rotate 30°",
            deform_surface(&model.surface, &rigid),
            Some(&rigid),
        ),
        (
            "stretch (1.2, 1, 0.85)",
            deform_surface(&model.surface, &stretch),
            Some(&stretch),
        ),
        ("sag 12 mm", sagged_breast(), None),
        ("indentation 8 mm", indented_breast(), None),
    ];
    println!(
        "| deformation | force | acceleration | iterations | converged | seconds | ms/iteration | max error / size |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, surface, exact) in &cases {
        for force in [ForceModel::Paper, ForceModel::Symmetric] {
            for chebyshev in [false, true] {
                let params = DeformParams::default().with(|p| {
                    p.force = force;
                    p.tuning.chebyshev = chebyshev;
                    p.max_iterations = 5_000;
                });
                let mut deformer = Deformer::new(&model, params)?;
                deformer.set_surface(surface)?;
                let report = deformer.solve();
                let error = exact.map_or("n/a".to_string(), |map| {
                    let worst = (0..model.len())
                        .map(|i| (deformer.positions()[i] - map.apply(model.positions[i])).length())
                        .fold(0.0f32, f32::max);
                    format!("{:.1e}", worst / deformer.size())
                });
                println!(
                    "| {name} | {force:?} | {} | {} | {} | {:.3} | {:.2} | {error} |",
                    if chebyshev { "Chebyshev" } else { "plain" },
                    report.iterations,
                    if report.converged { "yes" } else { "no" },
                    report.seconds,
                    1e3 * report.seconds / report.iterations.max(1) as f64,
                );
            }
        }
    }
    Ok(())
}
