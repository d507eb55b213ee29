//! Hard posture changes made by forward solves, then recovered
//! (docs/METHOD.md, "Gravity and the unloaded shape"): an organ's unloaded
//! shape, sampled, is loaded with one posture's gravity (the rest scan)
//! and another's (the deformed scan), the chest wall held and the rest of
//! the skin free, at a known stiffness. The posture search then sees only
//! the two scans' surfaces, the two gravities and the density, and finds
//! the stiffness and the unloaded shape; this prints how far each is from
//! what made the scans, how many solves it took and how long.
//!
//! `cargo run --release --example posture_cases -- [--fit-particles N] [PARTICLES] [E_KPA] [SURFACE.obj ...]`
//!
//! Without surfaces it runs on the bundled phantom; with them, each is an
//! unloaded shape whose chest wall is the plane of its smallest `z`. Each
//! surface is taken prone to supine (gravity `+z`, then `-z`: a 2 g
//! change) and supine to lateral (`-z`, then `+x`).
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "an example")]

use std::time::Instant;

use glam::Vec3;
use tissue::backend::{Device, Solver};
use tissue::deformation::{DeformParams, Deformer, ForceModel};
use tissue::gravity::{Gravity, unload};
use tissue::structures::Embedding;
use tissue::{ParticleModel, SamplingParams, SurfaceMesh};

/// The model's surface vertices carried to where the particles moved, the
/// held ones where they were (the solve held them there).
fn surface_at(model: &ParticleModel, d: &Deformer, held: &[bool]) -> SurfaceMesh {
    let embedding = Embedding::new(&model.positions, &model.surface.vertices);
    let moved = embedding.moved(&model.positions, d.positions(), d.rotations());
    SurfaceMesh {
        vertices: moved
            .iter()
            .zip(&model.surface.vertices)
            .zip(held)
            .map(|((m, v), &h)| if h { *v } else { *m })
            .collect(),
        ..model.surface.clone()
    }
}

fn rms(a: &[Vec3], b: &[Vec3], on: impl Fn(usize) -> bool) -> f32 {
    let (s, n) = a
        .iter()
        .zip(b)
        .enumerate()
        .filter(|(i, _)| on(*i))
        .fold((0.0f64, 0usize), |(s, n), (_, (p, q))| {
            (s + f64::from(p.distance_squared(*q)), n + 1)
        });
    (s / n.max(1) as f64).sqrt() as f32
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    // The model the stiffness is fitted on: `Gravity`'s default, or `N`
    // particles (0: the model itself).
    let fit_particles = match args.iter().position(|a| a == "--fit-particles") {
        Some(at) => {
            let n: usize = args[at + 1].parse().unwrap();
            args.drain(at..at + 2);
            Some((n > 0).then_some(n))
        }
        None => None,
    };
    let particles: usize = args.first().map_or(10_000, |a| a.parse().unwrap());
    let e_true: f32 = args.get(1).map_or(1.5, |a| a.parse().unwrap());
    let mut surfaces: Vec<(String, SurfaceMesh)> = args
        .iter()
        .skip(2)
        .map(|p| {
            (
                p.clone(),
                tissue::load_surface(std::path::Path::new(p)).unwrap(),
            )
        })
        .collect();
    if surfaces.is_empty() {
        surfaces.push(("phantom".into(), tissue::phantom::default_breast()));
    }
    let params = DeformParams::default().with(|p| p.force = ForceModel::Elastic);
    for (name, surface) in &surfaces {
        let unloaded = tissue::sample(surface, &SamplingParams::with_particles(particles))
            .unwrap()
            .model;
        let wall = surface
            .vertices
            .iter()
            .map(|v| v.z)
            .fold(f32::INFINITY, f32::min);
        let held: Vec<bool> = surface.vertices.iter().map(|v| v.z - wall < 1e-3).collect();
        let gravity = |g: Vec3| Gravity::millimetres(g, g, Some(e_true));
        // One posture from the unloaded shape: the chest wall held.
        let forward = |g: Vec3| {
            let load = tissue::advanced::model::gravity_load(
                g,
                gravity(g).density_kg_m3,
                e_true,
                params.poisson,
                1e-3,
            )
            .unwrap();
            let mut d = Deformer::new(
                &unloaded,
                params.clone().with(|p| {
                    p.observed = Some(held.clone());
                    p.load = load;
                }),
            )
            .unwrap();
            d.set_surface(&unloaded.surface).unwrap();
            let report = d.solve();
            assert!(report.converged, "{name}: the forward solve under {g}");
            (d.positions().to_vec(), surface_at(&unloaded, &d, &held))
        };
        for (posture, g_rest, g_deformed) in [
            ("prone to supine", Vec3::Z, Vec3::NEG_Z),
            ("supine to lateral", Vec3::NEG_Z, Vec3::X),
        ] {
            let (rest_positions, rest_surface) = forward(g_rest);
            let (deformed_positions, deformed_surface) = forward(g_deformed);
            // The rest scan's model: the same particles where the rest
            // posture put them.
            let model = ParticleModel {
                positions: rest_positions.clone(),
                surface: rest_surface,
                ..unloaded.clone()
            };
            let started = Instant::now();
            let mut solves = Vec::new();
            let found = unload(
                &Device::Cpu,
                &model,
                &deformed_surface,
                &held,
                &Gravity {
                    fit_particles: fit_particles
                        .unwrap_or(Gravity::millimetres(g_rest, g_deformed, None).fit_particles),
                    ..Gravity::millimetres(g_rest, g_deformed, None)
                },
                &params,
                &mut |s| solves.push((s.iterations, s.converged, s.backtracks, s.elastic_retries)),
            );
            let posture_s = started.elapsed().as_secs_f64();
            let found = match found {
                Ok(found) => found,
                Err(e) => {
                    println!("{name}, {posture}: the search failed: {e}");
                    continue;
                }
            };
            // The deformed posture from the shape found, the skin free: where
            // it puts the particles against where the truth did.
            let mut solver = Solver::unloaded(
                Device::Cpu,
                &model,
                &found.shape.positions,
                params.clone().with(|p| {
                    p.observed = Some(held.clone());
                    p.load = found.deformed_load;
                }),
            )
            .unwrap();
            solver.set_surface(&model.surface).unwrap();
            if let Some(guess) = &found.deformed_guess {
                solver.warm_start(guess).unwrap();
            }
            let free = solver.solve().unwrap();
            let skin = |i: usize| model.is_surface(i);
            println!(
                "{name}, {posture} at {particles} particles, {e_true} kPa: fitted {:.3} kPa \
                 ({:+.1} %); {} solves ({} not converged, {} steps back, {} run again) in \
                 {posture_s:.2} s, iterations {:?}; \
                 unloaded shape {:.3} mm RMS from the truth (skin {:.3}), loaded again {:.3} mm \
                 from the rest skin; the deformed posture from it, skin free ({} iterations), \
                 {:.3} mm RMS from the truth's (skin {:.3})",
                found.stiffness_kpa,
                100.0 * (found.stiffness_kpa / e_true - 1.0),
                found.solves,
                solves.iter().filter(|s| !s.1).count(),
                solves.iter().map(|s| s.2).sum::<usize>(),
                solves.iter().map(|s| s.3).sum::<usize>(),
                solves.iter().map(|s| s.0).collect::<Vec<_>>(),
                rms(&found.shape.positions, &unloaded.positions, |_| true),
                rms(&found.shape.positions, &unloaded.positions, skin),
                found.shape.residual,
                free.iterations,
                rms(solver.positions(), &deformed_positions, |_| true),
                rms(solver.positions(), &deformed_positions, skin),
            );
        }
    }
}
