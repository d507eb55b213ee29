//! The warm-started polar rotations (`RotationMethod::WarmPolar`, the
//! default) on the GPU against the CPU path: the kernel against
//! `local_rotations_warm` from the same positions and start rotations
//! (settled updates and SVD fallbacks both), the frame boundary's turn, and
//! whole solves (the phantom's sag from rest, tracking frames).

mod common;

use glam::{Mat3, Vec3};
use tissue_core::ParticleModel;
use tissue_cpu::deformation::{
    DeformParams, ElasticSolve, ForceModel, POLAR_ITERATIONS, POLAR_MOST_ITERATIONS,
    RotationMethod, local_rotations_warm, polar_update,
};
use tissue_gpu::{DeformState, Kernel, Pipelines};
use tissue_solve::model::{offsets_product, rotation_of};

/// Largest entry difference of two matrices.
fn entry_difference(a: Mat3, b: Mat3) -> f32 {
    (a - b)
        .to_cols_array()
        .iter()
        .fold(0.0f32, |w, x| w.max(x.abs()))
}

/// The rest shape twisted about z, sheared and rippled: rotations that vary
/// from particle to particle, and `M_i` far from a rotation.
fn deformed(model: &ParticleModel) -> Vec<Vec3> {
    let (lo, hi) = model.positions.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let size = (hi - lo).length();
    let centre = 0.5 * (lo + hi);
    model
        .positions
        .iter()
        .map(|&p| {
            let r = p - centre;
            let twist = Mat3::from_rotation_z(1.2 * r.z / size) * Mat3::from_rotation_x(0.3);
            let shear = Vec3::new(0.05 * r.y, 0.0, -0.03 * r.x);
            let ripple = Vec3::new((9.0 * r.y / size).sin(), 0.0, (8.0 * r.x / size).cos());
            centre + twist * r + shear + 0.005 * size * ripple
        })
        .collect()
}

/// Start rotations of four kinds, particle by particle: the SVD's rotation
/// of `M_i` itself, it turned by 0.01 rad, the identity, and it turned by
/// 2.8 rad (which the updates, at most `POLAR_MOST_ITERATIONS`, seldom bring
/// back, so the SVD is taken).
fn starts(model: &ParticleModel, current: &[Vec3]) -> Vec<Mat3> {
    (0..model.len())
        .map(|i| {
            let exact = rotation_of(offsets_product(
                &model.positions,
                current,
                &model.connections,
                i,
            ));
            let axis = Vec3::new(1.0, (i % 7) as f32 - 3.0, 2.0).normalize();
            match i % 4 {
                0 => exact,
                1 => Mat3::from_axis_angle(axis, 0.01) * exact,
                2 => Mat3::IDENTITY,
                _ => Mat3::from_axis_angle(axis, 2.8) * exact,
            }
        })
        .collect()
}

fn run(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipelines: &Pipelines,
    state: &DeformState,
    kernel: Kernel,
) {
    let mut encoder = device.create_command_encoder(&Default::default());
    pipelines.dispatch(&mut encoder, state, kernel, 0);
    queue.submit([encoder.finish()]);
}

/// From the same positions and start rotations, the WGSL warm rotations
/// equal `local_rotations_warm`'s. Tolerance 1e-4 on entries of size 1,
/// as for the SVD kernel: both paths run the same f32 operations in the
/// same order (glam's quaternion formulas written out), so they differ by
/// rounding, a few ulps per operation over three updates; and where one
/// path settles and the other falls back (a last turn within rounding of
/// the 1e-3 rad threshold), the settled rotation is within far less than
/// that of the SVD's.
#[test]
fn local_rotations_warm_matches_the_cpu_twin_settled_or_not() {
    let Some((device, queue)) = common::gpu("local_rotations_warm parity") else {
        return;
    };
    for n in [2_000, 3_001] {
        let model = common::phantom(n);
        let current = deformed(model);
        let start = starts(model, &current);
        let expected = local_rotations_warm(&model.positions, &current, &model.connections, &start);
        let settled: Vec<bool> = (0..model.len())
            .map(|i| {
                let m = offsets_product(&model.positions, &current, &model.connections, i);
                polar_update(m, start[i], POLAR_ITERATIONS, POLAR_MOST_ITERATIONS).1
            })
            .collect();
        let mut fallbacks = [0usize; 4];
        for (i, _) in settled.iter().enumerate().filter(|(_, s)| !**s) {
            fallbacks[i % 4] += 1;
        }
        let pipelines = Pipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
        let free = vec![true; model.len()];
        let state = DeformState::new(&device, &queue, &pipelines, model, &free)
            .unwrap_or_else(|e| panic!("{e}"));
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state
            .write_rotations(&queue, &start)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(&queue, 0, state.params(ForceModel::Symmetric, 0.0, 1.0, 0));
        run(
            &device,
            &queue,
            &pipelines,
            &state,
            Kernel::LocalRotationsWarm,
        );
        let got = state
            .read_rotations(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        let tolerance = 1e-4;
        let mut worst = 0.0f32;
        // Settled updates that turned their start by more than a rounding.
        let mut moved = 0;
        for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
            let off = entry_difference(*g, *e);
            worst = worst.max(off);
            assert!(
                off <= tolerance,
                "n = {n}, particle {i} (start kind {}): GPU {g} vs CPU {e}, max entry difference {off:e} > tolerance {tolerance:e}",
                i % 4
            );
            if settled[i] && entry_difference(*e, start[i]) > 1e-3 {
                moved += 1;
            }
        }
        eprintln!(
            "local_rotations_warm, n = {n}: worst entry difference {worst:e}; fell back to the SVD by start kind {fallbacks:?} of {}; {moved} settled away from their start",
            model.len()
        );
        // Every kind is exercised: the exact starts settle where they
        // are, most of the nearby ones settle after turning, the identity
        // (far from this twist) and nearly all the 2.8 rad turns fall
        // back to the SVD.
        let quarter = n / 4;
        assert_eq!(fallbacks[0], 0, "{fallbacks:?}");
        assert!(fallbacks[1] < quarter / 4, "{fallbacks:?}");
        assert!(fallbacks[3] > quarter * 9 / 10, "{fallbacks:?}");
        assert!(moved > quarter / 2, "{moved} settled away from their start");
    }
}

/// The frame boundary's turn premultiplies every stored rotation, as the
/// CPU device's `write_positions` does (one matrix product in f32: 1e-6).
#[test]
fn turn_rotations_premultiplies_every_rotation() {
    let Some((device, queue)) = common::gpu("turn_rotations") else {
        return;
    };
    let model = common::phantom(2_000);
    let current = deformed(model);
    let start = starts(model, &current);
    let pipelines = Pipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let free = vec![true; model.len()];
    let state = DeformState::new(&device, &queue, &pipelines, model, &free)
        .unwrap_or_else(|e| panic!("{e}"));
    state
        .write_rotations(&queue, &start)
        .unwrap_or_else(|e| panic!("{e}"));
    let turn = Mat3::from_axis_angle(Vec3::new(0.3, -1.0, 0.5).normalize(), 0.7);
    state
        .write_turn(&queue, turn)
        .unwrap_or_else(|e| panic!("{e}"));
    state.write_params(&queue, 0, state.params(ForceModel::Symmetric, 0.0, 1.0, 0));
    run(&device, &queue, &pipelines, &state, Kernel::TurnRotations);
    let got = state
        .read_rotations(&device, &queue)
        .unwrap_or_else(|e| panic!("{e}"));
    for (i, (g, r)) in got.iter().zip(&start).enumerate() {
        let off = entry_difference(*g, turn * *r);
        assert!(
            off <= 1e-6,
            "particle {i}: {g} vs {}, off {off:e}",
            turn * *r
        );
    }
}

/// The sag from rest at 2,000 particles with warm rotations on both paths,
/// two-level (both forces) and not: the same iterations (one either way, if
/// the reductions' rounding tips the rule) and positions within 1e-5 of the
/// size, the SVD test's tolerance.
#[test]
fn the_warm_gpu_solve_of_the_sag_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("warm whole solve parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let two_level = DeformParams::default().tuning.coarse;
    assert!(two_level > 0.0);
    for (force, coarse) in [
        (ForceModel::Symmetric, two_level),
        (ForceModel::Paper, two_level),
        (ForceModel::Symmetric, 0.0),
    ] {
        let params = DeformParams::default().with(|p| {
            p.force = force;
            p.tuning.coarse = coarse;
            p.tuning.rotations = RotationMethod::WarmPolar;
        });
        let (cpu, cpu_report, gpu, gpu_report) =
            common::solve_sag_on_both(&device, &queue, model, params);
        eprintln!(
            "{force:?}, coarse {coarse}, warm: CPU {} iterations, {:?}; GPU {} iterations, {:?}",
            cpu_report.iterations,
            cpu_report.stopped_by,
            gpu_report.iterations,
            gpu_report.stopped_by,
        );
        assert!(gpu_report.converged, "{force:?}: {gpu_report:?}");
        assert!(
            cpu_report.iterations.abs_diff(gpu_report.iterations) <= 1,
            "{force:?}: CPU {} iterations, GPU {}",
            cpu_report.iterations,
            gpu_report.iterations
        );
        let context = format!("{force:?}, coarse {coarse}, warm");
        let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, &context);
        let rotations = gpu.read_rotations().unwrap_or_else(|e| panic!("{e}"));
        let worst_rotation = rotations
            .iter()
            .zip(cpu.rotations())
            .map(|(g, c)| entry_difference(*g, *c))
            .fold(0.0f32, f32::max);
        eprintln!(
            "{force:?}, coarse {coarse}, warm: worst distance {worst:e} of the size; worst rotation entry {worst_rotation:e}"
        );
    }
}

/// Tracking frames of a growing sag with warm rotations: each frame's
/// prediction turns the stored rotations (the turn kernel), and the warm
/// updates start from them; the same iterations per frame (one either
/// way) and the same positions as the CPU path.
#[test]
fn warm_gpu_tracking_follows_frames_as_the_cpu_does() {
    let Some((device, queue)) = common::gpu("warm tracking parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.tuning.rotations = RotationMethod::WarmPolar;
    });
    assert!(
        params.tuning.extrapolate,
        "the frames are predicted, and turned"
    );
    let sagged = tissue_core::deform::sagged_breast();
    let mut cpu =
        tissue_cpu::deformation::Deformer::new(model, tissue_gpu::GpuDeformer::cpu_twin(&params))
            .unwrap_or_else(|e| panic!("{e}"));
    let mut gpu = tissue_gpu::GpuDeformer::new(&device, &queue, model, params)
        .unwrap_or_else(|e| panic!("{e}"));
    let tolerance = 1e-5 * cpu.size();
    let mut counts = Vec::new();
    let mut worst = 0.0f32;
    let mut frames: Vec<tissue_core::SurfaceMesh> = (0..5)
        .map(|k| {
            tissue_core::deform::interpolate(&model.surface, &sagged, 0.5 + 0.05 * k as f32)
                .unwrap_or_else(|e| panic!("{e}"))
        })
        .collect();
    // Then the last frame turned rigidly about its centre, twice: turns the
    // prediction carries the stored rotations through.
    let last = frames[4].clone();
    let centre = last.vertices.iter().copied().sum::<Vec3>() / last.vertices.len() as f32;
    for angle in [0.15f32, 0.3] {
        let turn = Mat3::from_axis_angle(Vec3::new(0.2, 1.0, 0.4).normalize(), angle);
        let mut turned = last.clone();
        for v in &mut turned.vertices {
            *v = centre + turn * (*v - centre);
        }
        frames.push(turned);
    }
    let mut turned_by = Vec::new();
    for (k, frame) in frames.iter().enumerate() {
        let before = cpu.rotations().to_vec();
        cpu.set_surface(frame).unwrap_or_else(|e| panic!("{e}"));
        gpu.set_surface(frame).unwrap_or_else(|e| panic!("{e}"));
        // The rotations the next solve starts from: turned alike.
        let (mut off, mut turned) = (0.0f32, 0.0f32);
        let on_gpu = gpu.read_rotations().unwrap_or_else(|e| panic!("{e}"));
        for ((g, c), b) in on_gpu.iter().zip(cpu.rotations()).zip(&before) {
            off = off.max(entry_difference(*g, *c));
            turned = turned.max(entry_difference(*c, *b));
        }
        assert!(off <= 1e-4, "frame {k}: start rotations differ by {off:e}");
        turned_by.push(turned);
        let on_cpu = cpu.solve();
        let on_gpu = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
        assert!(on_gpu.converged, "frame {k}: {on_gpu:?}");
        assert!(
            on_cpu.iterations.abs_diff(on_gpu.iterations) <= 1,
            "frame {k}: CPU {} iterations, GPU {}",
            on_cpu.iterations,
            on_gpu.iterations
        );
        counts.push((on_cpu.iterations, on_gpu.iterations));
        for (i, (g, c)) in gpu.host_positions().iter().zip(cpu.positions()).enumerate() {
            worst = worst.max(g.distance(*c));
            assert!(
                g.distance(*c) <= tolerance,
                "frame {k}, particle {i}: GPU {g} vs CPU {c}, tolerance {tolerance:e}"
            );
        }
    }
    eprintln!(
        "warm tracking: iterations per frame (CPU, GPU): {counts:?}; worst distance {:e} of the size; the turn moved the stored rotations by {turned_by:?}",
        worst / cpu.size()
    );
    // The rigid turns moved the stored rotations by about their angle.
    assert!(turned_by[5] > 0.1 && turned_by[6] > 0.1, "{turned_by:?}");
}

/// The elastic force with warm rotations: the sag from rest (the plain
/// shear phase, then the elastic phase) and a deep, narrow poke whose
/// elastic phase diverges and runs again from the end of the shear phase
/// with the rotations it left. The same iterations and retries on both
/// paths, positions within 1e-5 of the size.
#[test]
fn warm_gpu_elastic_solves_and_retries_match_the_cpu() {
    let Some((device, queue)) = common::gpu("warm elastic parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        // Chebyshev's steps back and retries, which it holds.
        p.tuning.elastic_solve = ElasticSolve::Chebyshev;
        p.tuning.rotations = RotationMethod::WarmPolar;
        p.tuning.coarse = 0.0;
    });
    let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, 40.0, 15.0)
        .unwrap_or_else(|| panic!("the phantom has vertices"));
    let poked = tissue_core::deform::deform_surface(&model.surface, &probe);
    for (name, surface) in [
        ("sag", tissue_core::deform::sagged_breast()),
        ("poke", poked),
    ] {
        let solved = common::solve_on_both(&device, &queue, model, params.clone(), &surface);
        let context = format!("warm elastic {name}");
        common::assert_same_retried_solve(&solved, 1, &context);
    }
}
