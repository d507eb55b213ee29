//! The tracking table of `docs/METHOD.md`: iterations per frame over
//! sequences of small surface changes, against a tight reference solve of
//! every frame.
//!
//! `cargo run --release --example tracking [particles] [coarse] [history] [sequence]`
//! (`sequence`: only the sequences whose name contains it)
//!
//! For every frame it prints the iterations the solve took, the "oracle"
//! (the fewest iterations after which the true error is below the
//! tolerance; `1000+k` when the solve stopped after `k` with the true
//! error still above it) and the true error at the stop, as a fraction of
//! the model's size; and per frame the surface's largest move and the
//! prediction's error (where the solve starts). The reference is the same frame solved from the same
//! start to a tolerance of 1e-7.

use glam::Vec3;
use tissue::deform::{Rigid, deform_surface, indented_breast, interpolate, sagged_breast};
use tissue::deformation::{DeformParams, Deformer};
use tissue::{ParticleModel, SamplingParams, SurfaceMesh, phantom};

fn main() -> Result<(), tissue::Error> {
    let mut args = std::env::args().skip(1);
    let particles = args.next().and_then(|t| t.parse().ok()).unwrap_or(10_000);
    let defaults = DeformParams::default();
    let coarse = args
        .next()
        .and_then(|t| t.parse().ok())
        .unwrap_or(defaults.tuning.coarse);
    let mut number = |default: usize| args.next().and_then(|t| t.parse().ok()).unwrap_or(default);
    let params = defaults.clone().with(|p| {
        p.tuning.coarse = coarse;
        p.tuning.history = number(defaults.tuning.history);
    });
    let only = args.next().unwrap_or_default();
    let breast = phantom::default_breast();
    let model = tissue::sample(&breast, &SamplingParams::with_particles(particles))?.model;
    let deformer = Deformer::new(&model, params.clone())?;
    println!(
        "{} particles, size {:.1} mm, coarse cell {} ({} aggregates), history {}, tolerance {:e}",
        model.len(),
        deformer.size(),
        params.tuning.coarse,
        deformer.coarse().map_or(0, |c| c.count()),
        params.tuning.history,
        params.tolerance
    );
    println!();
    println!(
        "| sequence | iterations per frame | oracle | worst error / size | largest surface move per frame, % of size | prediction's error, 1e-5 of size |"
    );
    println!("|---|---|---|---|---|---|");

    let sag = sagged_breast();
    let indentation = indented_breast();
    let between = |to: &SurfaceMesh, t: f32| {
        interpolate(&breast, to, t).unwrap_or_else(|e| panic!("the bundled skins differ: {e}"))
    };
    let sequences: Vec<(String, Vec<SurfaceMesh>)> = vec![
        (
            "sag growing 2 % of its 12 mm per frame".into(),
            (0..10)
                .map(|k| between(&sag, 0.5 + 0.02 * k as f32))
                .collect(),
        ),
        (
            "sag in 3 mm steps (1.6 % of the size)".into(),
            (0..8).map(|k| between(&sag, 0.25 * k as f32)).collect(),
        ),
        rotation(&breast, 1.0),
        rotation(&breast, 3.0),
        (
            "indentation growing 1.6 mm per frame".into(),
            (0..8)
                .map(|k| between(&indentation, 0.2 * k as f32))
                .collect(),
        ),
        (
            "sag breathing in and out (accelerating)".into(),
            (0..12)
                .map(|k| between(&sag, 0.5 - 0.5 * (0.5 * k as f32).cos()))
                .collect(),
        ),
        (
            "sag and indentation out of step".into(),
            (0..12)
                .map(|k| {
                    let t = k as f32;
                    mixed(
                        &breast,
                        &sag,
                        0.5 - 0.5 * (0.5 * t).cos(),
                        &indentation,
                        0.5 - 0.5 * (0.8 * t).cos(),
                    )
                })
                .collect(),
        ),
    ];
    for (name, surfaces) in sequences.iter().filter(|(name, _)| name.contains(&only)) {
        let frames = track(&model, surfaces, &params)?;
        let moves = std::iter::once(&breast)
            .chain(surfaces)
            .zip(surfaces)
            .map(|(a, b)| {
                format!(
                    "{:.1}",
                    100.0 * max_distance(&a.vertices, &b.vertices) / deformer.size()
                )
            })
            .collect::<Vec<_>>()
            .join(", ");
        let worst = frames
            .iter()
            .skip(2)
            .map(|f| f.error)
            .fold(0.0f32, f32::max);
        let list = |f: fn(&Frame) -> usize| {
            frames
                .iter()
                .map(|frame| f(frame).to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let starts = frames
            .iter()
            .map(|f| format!("{:.0}", f.start * 1e5))
            .collect::<Vec<_>>()
            .join(", ");
        println!(
            "| {name} | {} | {} | {worst:.1e} | {moves} | {starts} |",
            list(|f| f.iterations),
            list(|f| f.oracle)
        );
    }
    println!();
    println!("(worst error over the frames after the first two)");
    Ok(())
}

struct Frame {
    /// The prediction's error, as a fraction of the size.
    start: f32,
    iterations: usize,
    oracle: usize,
    error: f32,
}

/// Tracks `frames` in order and measures every frame against a reference.
fn track(
    model: &ParticleModel,
    frames: &[SurfaceMesh],
    params: &DeformParams,
) -> Result<Vec<Frame>, tissue::Error> {
    let mut deformer = Deformer::new(model, params.clone())?;
    let size = deformer.size();
    let mut measured = Vec::new();
    for surface in frames {
        deformer.set_surface(surface)?;
        let mut reference = deformer.clone();
        reference.set_params(params.clone().with(|p| {
            p.tolerance = 1e-7;
        }))?;
        reference.solve();
        let error = |d: &Deformer| max_distance(d.positions(), reference.positions()) / size;
        let start = error(&deformer);
        let mut oracle = 0;
        for cap in 1..300 {
            let mut capped = deformer.clone();
            capped.set_params(params.clone().with(|p| {
                p.max_iterations = cap;
            }))?;
            let report = capped.solve();
            if error(&capped) < params.tolerance {
                oracle = cap;
                break;
            }
            if report.converged {
                oracle = 1000 + cap;
                break;
            }
        }
        let report = deformer.solve();
        measured.push(Frame {
            start,
            iterations: report.iterations,
            oracle,
            error: error(&deformer),
        });
    }
    Ok(measured)
}

fn rotation(breast: &SurfaceMesh, degrees: f32) -> (String, Vec<SurfaceMesh>) {
    let Some((low, high)) = breast.bounds() else {
        panic!("the phantom is empty");
    };
    let frames = (1..=10)
        .map(|k| {
            let turn = Rigid::about_axis(
                Vec3::new(1.0, 0.3, 0.2),
                (degrees * k as f32).to_radians(),
                0.5 * (low + high),
                Vec3::ZERO,
            );
            deform_surface(breast, &turn)
        })
        .collect();
    (format!("rotation, {degrees}° per frame"), frames)
}

/// `rest + a (first - rest) + b (second - rest)`, vertex by vertex.
fn mixed(
    rest: &SurfaceMesh,
    first: &SurfaceMesh,
    a: f32,
    second: &SurfaceMesh,
    b: f32,
) -> SurfaceMesh {
    let vertices = rest
        .vertices
        .iter()
        .zip(&first.vertices)
        .zip(&second.vertices)
        .map(|((&p, &f), &s)| p + a * (f - p) + b * (s - p))
        .collect();
    SurfaceMesh::new(vertices, rest.triangles.clone())
}

fn max_distance(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| x.distance(*y))
        .fold(0.0, f32::max)
}
