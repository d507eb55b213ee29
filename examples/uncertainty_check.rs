//! The uncertainty's linearised load columns against a Monte Carlo
//! ensemble (docs/METHOD.md, "Uncertainty"): on a shared case with its
//! posture options, the load's scale and both postures' gravity
//! directions sampled jointly (each sample a re-solve from the answer),
//! against the five linearised columns `tissue::uncertainty::explore`
//! makes for them. Prints the probes' 95 % radii of both and their ratio.
//!
//! `cargo run --release --example uncertainty_check -- CASE_DIR [SAMPLES] [PARTICLES]`
//!
//! CASE_DIR is one of `../shared/cases/breast_*` (its `truth.json` gives
//! the probes and the postures).
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "an example")]

use std::path::PathBuf;

use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use tissue::backend::{Device, Solver};
use tissue::deformation::DeformParams;
use tissue::gravity::{Gravity, held_vertices, unload};
use tissue::structures::Embedding;
use tissue::uncertainty::{Answered, Priors, Region, Unknown, exact_vertices, explore};
use tissue::{SamplingParams, load_surface};

fn vec3(v: &serde_json::Value) -> Vec3 {
    Vec3::new(
        v[0].as_f64().unwrap() as f32,
        v[1].as_f64().unwrap() as f32,
        v[2].as_f64().unwrap() as f32,
    )
}

/// A standard normal number (Box and Muller).
fn normal(random: &mut Pcg64) -> f32 {
    let u: f32 = 1.0 - random.random::<f32>();
    let v: f32 = random.random();
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let case = PathBuf::from(args.first().expect("CASE_DIR"));
    let samples: usize = args.get(1).map_or(32, |s| s.parse().unwrap());
    let particles: usize = args.get(2).map_or(10_000, |s| s.parse().unwrap());
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(case.join("truth.json")).unwrap()).unwrap();
    let rest = load_surface(&case.join("rest.obj")).unwrap();
    let deformed = load_surface(&case.join("deformed.obj")).unwrap();
    let model = tissue::sample(&rest, &SamplingParams::with_particles(particles))
        .unwrap()
        .model;
    let postures = &truth["program_may_use"];
    let gravity = Gravity::millimetres(
        vec3(&postures["gravity_rest"]),
        vec3(&postures["gravity_deformed"]),
        None,
    );
    let params = DeformParams::default();
    let held = held_vertices(&model.surface, &deformed, 1e-3).unwrap();
    let unloaded = unload(
        &Device::Cpu,
        &model,
        &deformed,
        &held,
        &gravity,
        &params,
        &mut |_| {},
    )
    .unwrap();
    let load = unloaded.deformed_load;
    let mut solver = Solver::unloaded(
        Device::Cpu,
        &model,
        &unloaded.shape.positions,
        params.clone().with(|p| p.load = load),
    )
    .unwrap();
    solver.set_surface(&deformed).unwrap();
    if let Some(guess) = &unloaded.deformed_guess {
        solver.warm_start(guess).unwrap();
    }
    assert!(solver.solve().unwrap().converged);
    let answer = solver.positions().to_vec();

    // The probes, carried by their particles' offsets.
    let probes: Vec<Vec3> = truth["probes_rest"]
        .as_array()
        .unwrap()
        .iter()
        .map(vec3)
        .collect();
    let carriers = Embedding::new(&model.positions, &probes).carriers;
    let at = |positions: &[Vec3]| -> Vec<Vec3> {
        carriers
            .iter()
            .map(|c| c.iter().map(|&(j, w)| w * positions[j as usize]).sum())
            .collect()
    };

    // The linearised columns of the load alone.
    let priors = Priors::default().with(|p| {
        p.poisson = (params.poisson, params.poisson);
        p.surface_noise = 0.0;
    });
    let exact = exact_vertices(&model.surface, &deformed);
    let answered = Answered {
        surface: &deformed,
        exact: &exact,
        rest_load: Some(unloaded.rest_load),
        metres_per_unit: 1e-3,
        held_by: None,
    };
    let started = std::time::Instant::now();
    let linear = explore(&mut solver, &model, answered, &priors).unwrap();
    let linear_seconds = started.elapsed().as_secs_f64();
    let linear_regions = linear.regions(&at);

    // The ensemble: every unknown drawn at once, each sample a re-solve.
    let started = std::time::Instant::now();
    let mut random = Pcg64::seed_from_u64(7);
    let change = load - unloaded.rest_load;
    let angle = priors.gravity_degrees.to_radians();
    let tilt = |posture: Vec3, random: &mut Pcg64| -> Vec3 {
        let (a, b) = posture.normalize_or_zero().any_orthonormal_pair();
        let turn = Quat::from_axis_angle(a, angle * normal(random))
            * Quat::from_axis_angle(b, angle * normal(random));
        turn * posture - posture
    };
    let (answer_probes, mut moved) = (at(&answer), Vec::new());
    let mut iterations = 0;
    for _ in 0..samples {
        let scale = priors.load_spread * normal(&mut random);
        let sample =
            load + scale * change + tilt(load, &mut random) - tilt(unloaded.rest_load, &mut random);
        solver.set_load(sample).unwrap();
        solver.set_surface(&deformed).unwrap();
        solver.warm_start(&answer).unwrap();
        let report = solver.solve().unwrap();
        iterations += report.iterations;
        moved.push(at(solver.positions()));
    }
    let ensemble_seconds = started.elapsed().as_secs_f64();
    let weight = 1.0 / samples as f64;
    let ensemble: Vec<Region> = (0..probes.len())
        .map(|k| {
            Region::of(
                moved
                    .iter()
                    .map(|m| (Unknown::Load, weight, m[k] - answer_probes[k])),
            )
        })
        .collect();
    let mut ratios: Vec<f32> = linear_regions
        .iter()
        .zip(&ensemble)
        .filter(|(l, _)| l.radius > 0.0)
        .map(|(l, e)| e.radius / l.radius)
        .collect();
    ratios.sort_by(f32::total_cmp);
    let median = |v: &[f32]| v[v.len() / 2];
    let mut lr: Vec<f32> = linear_regions.iter().map(|r| r.radius).collect();
    let mut er: Vec<f32> = ensemble.iter().map(|r| r.radius).collect();
    lr.sort_by(f32::total_cmp);
    er.sort_by(f32::total_cmp);
    println!(
        "{}: linearised {} solves {:.2} s, median radius {:.3} mm; ensemble of {samples} ({iterations} iterations) {:.2} s, median radius {:.3} mm; ensemble / linearised per probe: p5 {:.2}, median {:.2}, p95 {:.2}",
        case.display(),
        linear.solves,
        linear_seconds,
        median(&lr),
        ensemble_seconds,
        median(&er),
        ratios[ratios.len() / 20],
        median(&ratios),
        ratios[ratios.len() * 19 / 20],
    );
}
