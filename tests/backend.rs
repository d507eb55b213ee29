//! The library's backend choice: both stages through `tissue::backend` on the
//! GPU and on the CPU give the same model and the same moved tumour. Without
//! an adapter the test prints "SKIPPED: no GPU adapter", and fails under
//! `CI=true`.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use common::gpu;

use tissue::backend::{Device, Solver, sample_on};
use tissue::deformation::{DeformParams, ForceModel, PrepareStage};
use tissue::{SamplingParams, Vec3, deform, phantom};

#[test]
fn both_stages_on_the_gpu_match_the_cpu_through_the_library() {
    let Some(gpu) = gpu() else { return };
    let skin = phantom::default_breast();
    // Not a multiple of the workgroup size.
    let params = SamplingParams::with_particles(1_001);
    let on_cpu = sample_on(&Device::Cpu, &skin, &params, &mut |_| {}).unwrap();
    let mut batches = 0;
    let on_gpu = sample_on(&gpu, &skin, &params, &mut |_| batches += 1).unwrap();
    assert!(batches > 0, "progress was never called");
    let (c, g) = (&on_cpu.report, &on_gpu.report);
    assert!(c.converged && g.converged, "{c:?}\n{g:?}");
    assert!(
        c.iterations.abs_diff(g.iterations) <= c.iterations / 10,
        "iterations: CPU {} GPU {}",
        c.iterations,
        g.iterations
    );
    assert!(
        (c.nn_cv - g.nn_cv).abs() <= 0.005,
        "nn_cv: CPU {} GPU {}",
        c.nn_cv,
        g.nn_cv
    );

    // Stage 2 of the same (CPU-sampled) model on both devices.
    let model = &on_cpu.model;
    let size = skin.bounds().map(|(lo, hi)| (hi - lo).length()).unwrap();
    let tumour = phantom::default_tumour().vertices;
    let sag = deform::sagged_breast();
    let mut moved = Vec::new();
    for device in [Device::Cpu, gpu] {
        let name = device.name().to_owned();
        let mut solver = Solver::new(device, model, DeformParams::default()).unwrap();
        let carrier = solver.bind(&tumour).unwrap();
        solver.set_surface(&sag).unwrap();
        let report = solver.solve().unwrap();
        assert!(report.converged, "{name}: {report:?}");
        assert_eq!(solver.positions().len(), model.len());
        moved.push(solver.carry(&carrier).unwrap());
    }
    let centroid = |p: &[Vec3]| p.iter().copied().sum::<Vec3>() / p.len() as f32;
    let rest = centroid(&tumour);
    let (c, g) = (centroid(&moved[0]), centroid(&moved[1]));
    eprintln!("tumour centroid: rest {rest}, CPU {c}, GPU {g}");
    assert!(
        c.distance(rest) > 1.0 && g.distance(rest) > 1.0,
        "the sag moves the tumour: {rest} -> CPU {c}, GPU {g}"
    );
    let tolerance = 1e-3 * size;
    for (i, (c, g)) in moved[0].iter().zip(&moved[1]).enumerate() {
        assert!(
            c.distance(*g) <= tolerance,
            "tumour vertex {i}: CPU {c} GPU {g}, {} mm apart > {tolerance} mm",
            c.distance(*g)
        );
    }
}

#[test]
fn points_bound_on_one_device_are_refused_by_another() {
    let Some(gpu) = gpu() else { return };
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(500),
    )
    .unwrap()
    .model;
    let on_gpu = Solver::new(gpu, &model, DeformParams::default()).unwrap();
    let on_cpu = Solver::new(Device::Cpu, &model, DeformParams::default()).unwrap();
    let carrier = on_gpu.bind(&[Vec3::new(10.0, 0.0, 20.0)]).unwrap();
    let err = on_cpu.carry(&carrier).unwrap_err().to_string();
    assert!(err.contains("bound on one backend"), "{err}");
}

/// The phantom's size (its bounding-box diagonal).
fn phantom_size() -> f32 {
    phantom::default_breast()
        .bounds()
        .map(|(lo, hi)| (hi - lo).length())
        .unwrap()
}

/// The largest distance between corresponding points.
fn apart(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0f32, f32::max)
}

/// The bundled sag solved from rest on `device` under `params`, converged:
/// its iterations and positions.
fn solve_sag(
    model: &tissue::ParticleModel,
    device: Device,
    params: &DeformParams,
) -> (usize, Vec<Vec3>) {
    let name = device.name().to_owned();
    let mut solver = Solver::new(device, model, params.clone()).unwrap();
    solver.set_surface(&deform::sagged_breast()).unwrap();
    let report = solver.solve().unwrap();
    assert!(report.converged, "{name}: {report:?}");
    (report.iterations, solver.positions().to_vec())
}

/// The defaults on both backends: both solve two-level (in fewer
/// iterations than without it, in the same number on both); the answers
/// agree within their tolerances.
#[test]
fn the_default_two_level_cpu_solve_agrees_with_the_gpu() {
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(2_000),
    )
    .unwrap()
    .model;
    let defaults = DeformParams::default();
    assert!(defaults.tuning.coarse > 0.0);
    let solve = |device: Device, params: &DeformParams| solve_sag(&model, device, params);
    let size = phantom_size();
    let tolerance = 3.0 * 3e-5 * size;
    let two_level = solve(Device::Cpu, &defaults);
    let plain = solve(
        Device::Cpu,
        &defaults.clone().with(|p| {
            p.tuning.coarse = 0.0;
        }),
    );
    eprintln!(
        "CPU, sag from rest: {} iterations two-level, {} without",
        two_level.0, plain.0
    );
    assert!(two_level.0 < plain.0, "{} vs {}", two_level.0, plain.0);
    let worst = apart(&two_level.1, &plain.1);
    assert!(worst <= tolerance, "CPU: {:e} of the size", worst / size);

    let Some(device) = gpu() else { return };
    let on_gpu = solve(device, &defaults);
    assert!(
        on_gpu.0.abs_diff(two_level.0) <= 1,
        "GPU {} iterations, CPU {}",
        on_gpu.0,
        two_level.0
    );
    let worst = apart(&on_gpu.1, &two_level.1);
    assert!(
        worst <= tolerance,
        "default, GPU against CPU: {:e} of the size",
        worst / size
    );
}

/// The preparation's progress callback hears each stage once, in order,
/// on both devices. The solve's comes once per iteration, numbered from 1
/// across the elastic force's phases, each with the error estimate the
/// report's history records; the GPU, which runs iterations in batches,
/// tells none it replays past the stop.
#[test]
fn progress_comes_in_order_on_both_devices() {
    let Some(gpu) = gpu() else { return };
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(2_000),
    )
    .unwrap()
    .model;
    let sag = deform::sagged_breast();
    for force in [ForceModel::Symmetric, ForceModel::Elastic] {
        let mut iterations = Vec::new();
        for device in [Device::Cpu, gpu.clone()] {
            let name = device.name().to_owned();
            let params = DeformParams::default().with(|p| {
                p.force = force;
            });
            let on_gpu = matches!(device, Device::Gpu { .. });
            let mut stages = Vec::new();
            let mut solver =
                Solver::new_with_progress(device, &model, params, &mut |stage| stages.push(stage))
                    .unwrap();
            // The preparation's stages in order, each once; the GPU's
            // upload after the plan's.
            let mut expected = vec![PrepareStage::Plan];
            if force == ForceModel::Elastic {
                expected.push(PrepareStage::ElasticModel);
            }
            if on_gpu {
                expected.push(PrepareStage::Upload);
            }
            expected.push(PrepareStage::CoarseSpace);
            if force == ForceModel::Elastic {
                expected.push(PrepareStage::ElasticCoarse);
            }
            assert_eq!(stages, expected, "{name} {force:?}");
            solver.set_surface(&sag).unwrap();
            let mut steps = Vec::new();
            let report = solver
                .solve_with_progress(&mut |step| steps.push(*step))
                .unwrap();
            assert!(report.converged, "{name} {force:?}: {report:?}");
            assert_eq!(steps.len(), report.iterations, "{name} {force:?}");
            for (k, step) in steps.iter().enumerate() {
                assert_eq!(step.iteration, k + 1, "{name} {force:?}");
                assert_eq!(step.max_iterations, DeformParams::default().max_iterations);
                assert_eq!(
                    step.residual.to_bits(),
                    report.residual_history[k].to_bits(),
                    "{name} {force:?}: iteration {}",
                    k + 1
                );
            }
            iterations.push(report.iterations);
        }
        assert_eq!(iterations[0], iterations[1], "{force:?}: CPU, GPU");
    }
    // Without the Laplacian's coarse space the symmetric force prepares
    // nothing after the plan, the elastic force its model and its own
    // correction.
    for (force, expected) in [
        (ForceModel::Symmetric, vec![PrepareStage::Plan]),
        (
            ForceModel::Elastic,
            vec![
                PrepareStage::Plan,
                PrepareStage::ElasticModel,
                PrepareStage::ElasticCoarse,
            ],
        ),
    ] {
        let mut stages = Vec::new();
        let no_coarse = DeformParams::default().with(|p| {
            p.force = force;
            p.tuning.coarse = 0.0;
        });
        Solver::new_with_progress(Device::Cpu, &model, no_coarse, &mut |stage| {
            stages.push(stage)
        })
        .unwrap();
        assert_eq!(stages, expected, "cpu, no coarse space, {force:?}");
    }
}

/// A solve warm-started where a converged solve of the same surface ended
/// runs its elastic phase alone and stops within a few iterations where it
/// started, on both devices in the same iterations; a start of the wrong
/// length or with a non-finite position is refused, naming it.
#[test]
fn a_warm_start_at_the_answer_stays_there_on_both_devices() {
    let Some(gpu) = gpu() else { return };
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(2_000),
    )
    .unwrap()
    .model;
    let sag = deform::sagged_breast();
    let params = DeformParams::default().with(|p| p.force = ForceModel::Elastic);
    let size = phantom::default_breast()
        .bounds()
        .map(|(lo, hi)| (hi - lo).length())
        .unwrap();
    let mut iterations = Vec::new();
    for device in [Device::Cpu, gpu] {
        let name = device.name().to_owned();
        let mut cold = Solver::new(device.clone(), &model, params.clone()).unwrap();
        cold.set_surface(&sag).unwrap();
        let first = cold.solve().unwrap();
        assert!(first.converged, "{name}: {first:?}");
        let answer = cold.positions().to_vec();
        let mut warm = Solver::new(device, &model, params.clone()).unwrap();
        warm.set_surface(&sag).unwrap();
        warm.warm_start(&answer).unwrap();
        let again = warm.solve().unwrap();
        assert!(again.converged, "{name}: {again:?}");
        assert!(
            again.iterations <= 3 && again.iterations < first.iterations,
            "{name}: {} iterations warm, {} cold",
            again.iterations,
            first.iterations
        );
        let moved = warm
            .positions()
            .iter()
            .zip(&answer)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(moved <= 1e-3 * size, "{name}: moved {moved}");
        iterations.push(again.iterations);
        let short = warm.warm_start(&answer[1..]).unwrap_err().to_string();
        assert!(short.contains("warm start"), "{short}");
        let mut bad = answer.clone();
        bad[7] = Vec3::NAN;
        let nan = warm.warm_start(&bad).unwrap_err().to_string();
        assert!(nan.contains("warm start"), "{nan}");
    }
    assert_eq!(iterations[0], iterations[1], "CPU, GPU");
}
