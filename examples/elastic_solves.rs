//! The elastic solve's two descents compared from rest, on the CPU: the
//! Chebyshev-accelerated two-level iteration with its energy watch
//! (`ElasticSolve::Chebyshev`) and the preconditioned conjugate gradient
//! (`ElasticSolve::ConjugateGradient`, or after Chebyshev's phase
//! `ElasticSolve::ChebyshevThenConjugateGradient`, the default, with
//! `--against`; docs/METHOD.md, "Elastic model", *The conjugate-gradient
//! phase*).
//!
//! Cases: the bench's sag and indentation, its 16 probes (15-30 mm deep,
//! 8-35 mm wide, at the phantom's tip), any shared case given (its
//! `deformed.obj` with correspondence), and the phantom hanging under its
//! weight (2 kPa, 1,000 kg/m^3, the chest wall held) towards its feet, its
//! back and its side. Printed per case: each solve's iterations, whether
//! it converged, its retries and steps back (the conjugate gradient's
//! halved steps) and seconds; how the conjugate gradient stopped, whether
//! every state it accepted lowered the potential; the largest distance
//! between the two answers over the model's size; and the particles each
//! answer turned inside out.
//!
//! `cargo run --release --example elastic_solves [particles] [CASE_DIR...]
//! [--only TEXT] [--against conjugate-gradient|chebyshev-then-conjugate-gradient]`
//! (`--against`: the descent compared with Chebyshev's, by default the
//! conjugate gradient; `--only`: the cases whose name holds `TEXT`;
//! `RUST_LOG=tissue_solve::stage2::tracker::conjugate=debug` also prints
//! how each conjugate-gradient phase went: its potentials measured, halved
//! steps and new linearisations).

use glam::Vec3;
use std::path::PathBuf;
use std::time::Instant;
use tissue::advanced::model::gravity_load;
use tissue::advanced::stage2::ElasticSolve;
use tissue::deform::{Indentation, deform_surface, indented_breast, sagged_breast};
use tissue::deformation::{DeformParams, Deformer, inversions};
use tissue::{ParticleModel, SamplingParams, SurfaceMesh, phantom};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    env_logger::init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let particles = args
        .first()
        .and_then(|t| t.parse().ok())
        .unwrap_or(10_000usize);
    // The descent Chebyshev's is compared with: the conjugate gradient, or
    // with `--against chebyshev-then-conjugate-gradient` the two in turn.
    let against =
        match args.iter().position(|a| a == "--against") {
            Some(k) => match args.get(k + 1).map(String::as_str) {
                Some("conjugate-gradient") => ElasticSolve::ConjugateGradient,
                Some("chebyshev-then-conjugate-gradient") => {
                    ElasticSolve::ChebyshevThenConjugateGradient
                }
                other => return Err(format!(
                    "--against {other:?}: conjugate-gradient or chebyshev-then-conjugate-gradient"
                )
                .into()),
            },
            None => ElasticSolve::ConjugateGradient,
        };
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|k| args.get(k + 1))
        .cloned();
    let case_dirs: Vec<PathBuf> = args
        .iter()
        .enumerate()
        .skip(1)
        .filter(|&(k, a)| {
            !a.starts_with("--") && args[k - 1] != "--only" && args[k - 1] != "--against"
        })
        .map(|(_, a)| PathBuf::from(a))
        .collect();
    let sampling = SamplingParams::with_particles(particles);
    let model = tissue::sample(&phantom::default_breast(), &sampling)?.model;
    let params = DeformParams::default().with(|p| p.tuning.extrapolate = false);
    let mut cases: Vec<(String, ParticleModel, SurfaceMesh, DeformParams)> = vec![
        ("sag".into(), model.clone(), sagged_breast(), params.clone()),
        (
            "indentation".into(),
            model.clone(),
            indented_breast(),
            params.clone(),
        ),
    ];
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            if let Some(probe) = Indentation::down_at_top(&model.surface, depth, width) {
                cases.push((
                    format!("probe {depth}x{width}"),
                    model.clone(),
                    deform_surface(&model.surface, &probe),
                    params.clone(),
                ));
            }
        }
    }
    for dir in &case_dirs {
        let rest = tissue::load_surface(&dir.join("rest.obj"))?;
        let case_model = tissue::sample(&rest, &sampling)?.model;
        let deformed = tissue::load_surface_as_written(&dir.join("deformed.obj"))?
            .as_frame_of(&case_model.surface, false);
        let name = dir
            .file_name()
            .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
        cases.push((name, case_model, deformed, params.clone()));
    }
    let held: Vec<bool> = model
        .surface
        .vertices
        .iter()
        .map(|v| v.z.abs() < 1e-3)
        .collect();
    for (towards, gravity) in [
        ("feet", Vec3::NEG_Y),
        ("back", Vec3::NEG_Z),
        ("side", Vec3::X),
    ] {
        let load = gravity_load(gravity, 1000.0, 2.0, params.poisson, 1e-3)?;
        cases.push((
            format!("hanging {towards}"),
            model.clone(),
            model.surface.clone(),
            params.clone().with(|p| {
                p.observed = Some(held.clone());
                p.load = load;
            }),
        ));
    }
    println!(
        "| case | Chebyshev: iterations | converged | retries | steps back | s | conjugate gradient: iterations | converged | stopped by | retries | halved steps | s | every step lowered | apart / size | inverted (Chebyshev, conjugate gradient) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, model, surface, params) in &cases {
        if only.as_ref().is_some_and(|o| !name.contains(o.as_str())) {
            continue;
        }
        let mut out = Vec::new();
        for solve in [ElasticSolve::Chebyshev, against] {
            let p = params.clone().with(|p| p.tuning.elastic_solve = solve);
            let mut d = Deformer::new(model, p)?;
            d.set_surface(surface)?;
            let t = Instant::now();
            let report = d.solve();
            let s = t.elapsed().as_secs_f64();
            out.push((report, s, d.positions().to_vec()));
        }
        let (a, b) = (&out[0], &out[1]);
        let size = {
            let (l, h) = model
                .positions
                .iter()
                .fold((Vec3::MAX, Vec3::MIN), |(l, h), &p| (l.min(p), h.max(p)));
            (h - l).length()
        };
        let apart =
            a.2.iter()
                .zip(&b.2)
                .map(|(x, y)| x.distance(*y))
                .fold(0.0f32, f32::max)
                / size;
        println!(
            "| {name} | {} | {} | {} | {} | {:.3} | {} | {} | {:?} | {} | {} | {:.3} | {} | {:.1e} | {}, {} |",
            a.0.iterations,
            a.0.converged,
            a.0.elastic_retries,
            a.0.backtracks,
            a.1,
            b.0.iterations,
            b.0.converged,
            b.0.stopped_by,
            b.0.elastic_retries,
            b.0.backtracks,
            b.1,
            b.0.potentials_fell(),
            apart,
            inversions(&model.positions, &a.2, &model.connections).count,
            inversions(&model.positions, &b.2, &model.connections).count
        );
    }
    Ok(())
}
