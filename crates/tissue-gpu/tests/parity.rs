//! Each stage-2 kernel against its CPU twin in `tissue_cpu::deformation`, on
//! identical inputs: the phantom sampled to 2,000 particles and to 3,001
//! (not a multiple of the workgroup size), deformed by a smooth twist plus
//! ripples. Tolerances are explicit; a failure names the particle, both
//! values and the tolerance.

mod common;

use glam::{Mat3, Vec3};
use tissue_core::ParticleModel;
use tissue_cpu::coarse::Aggregates;
use tissue_cpu::coarse::{CorrectionFor, ElasticCoarse};
use tissue_cpu::deformation::{
    Elastic, ForceModel, Pass, Plan, RotationMethod, deformation_force, elastic_force,
    elastic_residual, elastic_terms, integrate, local_rotations,
};
use tissue_gpu::{DeformState, Kernel, Pipelines};
use tissue_solve::stage2::{Spring, spring};

const SIZES: [usize; 2] = [2_000, 3_001];

/// An elastic iteration without a correction, kernel by kernel.
const ELASTIC_ITERATION: [Kernel; 5] = [
    Kernel::ElasticTargets,
    Kernel::ElasticForce,
    Kernel::Integrate,
    Kernel::StepNorms,
    Kernel::Chebyshev,
];

/// An iteration of the rotations' force without a correction, kernel by kernel.
const SYMMETRIC_ITERATION: [Kernel; 5] = [
    Kernel::LocalRotations,
    Kernel::DeformationForce,
    Kernel::Integrate,
    Kernel::StepNorms,
    Kernel::Chebyshev,
];

/// A smooth non-rigid deformation of the rest shape: a twist about z and ripples.
/// The CPU path's symmetric force at `current`, with its own rotations.
fn symmetric_force(model: &ParticleModel, current: &[Vec3]) -> Vec<Vec3> {
    let rotations = local_rotations(&model.positions, current, &model.connections);
    deformation_force(
        &model.positions,
        current,
        &rotations,
        &model.connections,
        ForceModel::Symmetric,
    )
}

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
            let twist = Mat3::from_rotation_z(0.4 * r.z / size);
            let ripple = Vec3::new(
                (6.0 * r.y / size).sin(),
                (5.0 * r.z / size).cos(),
                (7.0 * r.x / size).sin(),
            );
            centre + twist * r + 0.01 * size * ripple
        })
        .collect()
}

fn setup(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    model: &ParticleModel,
) -> (Pipelines, DeformState) {
    let pipelines = Pipelines::new(device).unwrap_or_else(|e| panic!("{e}"));
    let state = DeformState::new(device, queue, &pipelines, model, &free_of(model))
        .unwrap_or_else(|e| panic!("{e}"));
    (pipelines, state)
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

#[test]
fn local_rotations_matches_the_cpu_twin() {
    let Some((device, queue)) = common::gpu("local_rotations parity") else {
        return;
    };
    for n in SIZES {
        let model = common::phantom(n);
        let current = deformed(model);
        let expected = local_rotations(&model.positions, &current, &model.connections);
        let (pipelines, state) = setup(&device, &queue, model);
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(&queue, 0, state.params(ForceModel::Symmetric, 0.0, 1.0, 0));
        run(&device, &queue, &pipelines, &state, Kernel::LocalRotations);
        let got = state
            .read_rotations(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        // Rotation entries are O(1); an f32 SVD of a well-conditioned M agrees to ~1e-6.
        let tolerance = 1e-4;
        let mut worst = 0.0f32;
        for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
            let off = (*g - *e)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()));
            worst = worst.max(off);
            assert!(
                off <= tolerance,
                "n = {n}, particle {i}: GPU rotation {g} vs CPU {e}, max entry difference {off:e} > tolerance {tolerance:e}"
            );
        }
        eprintln!("local_rotations, n = {n}: worst entry difference {worst:e}");
    }
}

#[test]
fn deformation_force_matches_the_cpu_twin_for_both_models() {
    let Some((device, queue)) = common::gpu("deformation_force parity") else {
        return;
    };
    for n in SIZES {
        let model = common::phantom(n);
        let current = deformed(model);
        let rotations = local_rotations(&model.positions, &current, &model.connections);
        let (pipelines, state) = setup(&device, &queue, model);
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state
            .write_rotations(&queue, &rotations)
            .unwrap_or_else(|e| panic!("{e}"));
        // Each of ~12 terms is an offset of about one spacing; rounding is a
        // few ulp of that per term.
        let tolerance = 4e-6 * model.mean_connection_length();
        for force_model in [ForceModel::Paper, ForceModel::Symmetric] {
            let expected = deformation_force(
                &model.positions,
                &current,
                &rotations,
                &model.connections,
                force_model,
            );
            state.write_params(&queue, 0, state.params(force_model, 0.0, 1.0, 0));
            run(
                &device,
                &queue,
                &pipelines,
                &state,
                Kernel::DeformationForce,
            );
            let got = state
                .read_force(&device, &queue)
                .unwrap_or_else(|e| panic!("{e}"));
            let mut worst = 0.0f32;
            for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                let off = (*g - *e).abs().max_element();
                worst = worst.max(off);
                assert!(
                    off <= tolerance,
                    "n = {n}, {force_model:?}, particle {i}: GPU force {g} vs CPU {e}, difference {off:e} > tolerance {tolerance:e}"
                );
            }
            eprintln!(
                "deformation_force {force_model:?}, n = {n}: worst {worst:e} (tolerance {tolerance:e})"
            );
        }
    }
}

/// Largest entry of `a - b`.
fn entry_difference(a: Mat3, b: Mat3) -> f32 {
    (a - b)
        .to_cols_array()
        .iter()
        .fold(0.0f32, |m, x| m.max(x.abs()))
}

/// The elastic model of `model` at Poisson ratio 0.49 (the default), with
/// every seventh particle made flat (no stress weight, no volume weight),
/// so that the kernel's flat branch (`T_i = R_i`) runs beside the rest.
fn elastic_of(model: &ParticleModel) -> Elastic {
    let free = free_of(model);
    let mut elastic = Elastic::new(&model.positions, &model.connections, 0.49, &free);
    for i in (0..model.len()).step_by(7) {
        elastic.weights[i] = 0.0;
        elastic.consistency.scales[i] = 0.0;
    }
    elastic
}

/// Largest absolute entry of `m`.
fn largest_entry(m: Mat3) -> f32 {
    m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()))
}

#[test]
fn elastic_targets_matches_the_cpu_twin() {
    let Some((device, queue)) = common::gpu("elastic_targets parity") else {
        return;
    };
    for n in SIZES {
        let model = common::phantom(n);
        let current = deformed(model);
        let rotations = local_rotations(&model.positions, &current, &model.connections);
        let elastic = elastic_of(model);
        let (pipelines, mut state) = setup(&device, &queue, model);
        assert!(
            state
                .read_terms(&device, &queue)
                .is_ok_and(|t| t.is_empty()),
            "n = {n}: a state without the elastic model has no terms"
        );
        state
            .set_elastic(&device, &pipelines, &elastic)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(state.iteration(), ELASTIC_ITERATION);
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(&queue, 0, state.params(ForceModel::Elastic, 0.0, 1.0, 0));
        // Each kernel starts from the rotations in the buffer and leaves its
        // own there: the SVD's from the rotations of M_i, the warm one's
        // from the SVD's, as the CPU's from those it is given.
        let mut starts = rotations.clone();
        state
            .write_rotations(&queue, &rotations)
            .unwrap_or_else(|e| panic!("{e}"));
        for (method, kernel) in [
            (RotationMethod::Svd, Kernel::ElasticTargets),
            (RotationMethod::WarmPolar, Kernel::ElasticTargetsWarm),
        ] {
            let (expected, left) = elastic_terms(
                &model.positions,
                &current,
                &model.connections,
                &starts,
                &elastic,
                method,
            );
            run(&device, &queue, &pipelines, &state, kernel);
            let got = state
                .read_terms(&device, &queue)
                .unwrap_or_else(|e| panic!("{e}"));
            let got_rotations = state
                .read_rotations(&device, &queue)
                .unwrap_or_else(|e| panic!("{e}"));
            let worst_rotation = got_rotations
                .iter()
                .zip(&left)
                .map(|(g, e)| entry_difference(*g, *e))
                .fold(0.0f32, f32::max);
            assert!(
                worst_rotation <= 1e-4,
                "n = {n}, {method:?}: rotations off by {worst_rotation:e}"
            );
            starts = left;
            // The volume term's W_i (J_i - 1) cof(F_i): J_i - 1 comes out of
            // sums of ~12 offset products to a few ulp of |F|^3 (~1), and
            // W_i is 24.5 a_i at Poisson ratio 0.49, which multiplies that
            // rounding: entries of T = ... - Q_i B_i (B_i about A_i^-1, of
            // size 1 / (3 a_i)) agree to 2e-4, as before the consistent
            // vectors; U = a_i Q_i carries a_i twice (W_i is 24.5 a_i), so
            // its entries agree to 2e-4 a_i^2.
            let (mut worst_target, mut worst_stress, mut largest_stress) = (0.0f32, 0.0f32, 0.0f32);
            for (i, ((target, stress), e)) in got.iter().zip(&expected).enumerate() {
                if elastic.is_flat(i) {
                    assert_eq!(
                        *stress,
                        Mat3::ZERO,
                        "n = {n}, particle {i}: flat, no stress"
                    );
                    assert!(
                        entry_difference(*target, rotations[i]) <= 1e-4,
                        "n = {n}, particle {i}: flat, so the target is the rotation of M_i"
                    );
                    continue;
                }
                let a = elastic.consistency.scales[i];
                let (off_target, off_stress) = (
                    entry_difference(*target, Mat3::from(e.target)),
                    entry_difference(*stress, Mat3::from(e.stress)) / (a * a),
                );
                worst_target = worst_target.max(off_target);
                worst_stress = worst_stress.max(off_stress);
                largest_stress = largest_stress.max(largest_entry(Mat3::from(e.stress)) / (a * a));
                assert!(
                    off_target <= 2e-4 && off_stress <= 2e-4,
                    "n = {n}, {method:?}, particle {i}: GPU target {target} vs CPU {}, \
                     stress {stress} vs {} (a_i = {a}): differences {off_target:e}, \
                     {off_stress:e} a_i^2 > 2e-4",
                    e.target,
                    e.stress
                );
            }
            assert!(
                largest_stress > 0.01,
                "n = {n}: the deformation barely stresses the model ({largest_stress:e} a_i^2)"
            );
            eprintln!(
                "elastic_targets {method:?}, n = {n}: worst differences {worst_target:e} (T), \
                 {worst_stress:e} a_i^2 (U); largest |U| entry {largest_stress:e} a_i^2"
            );
        }
    }
}

/// The elastic phase's kernels in turn (rotations, terms, force) against
/// the CPU's elastic force at the same positions; the shear phase of the
/// same state gathers the symmetric force.
#[test]
fn an_elastic_state_gathers_the_force_over_the_terms() {
    let Some((device, queue)) = common::gpu("elastic force parity") else {
        return;
    };
    for n in SIZES {
        let model = common::phantom(n);
        let current = deformed(model);
        let free = free_of(model);
        let elastic = Elastic::new(&model.positions, &model.connections, 0.49, &free);
        let rotations = local_rotations(&model.positions, &current, &model.connections);
        let (terms, _) = elastic_terms(
            &model.positions,
            &current,
            &model.connections,
            &rotations,
            &elastic,
            RotationMethod::Svd,
        );
        let expected = elastic_force(
            &model.positions,
            &current,
            &model.connections,
            &terms,
            &elastic,
        );
        let symmetric = deformation_force(
            &model.positions,
            &current,
            &rotations,
            &model.connections,
            ForceModel::Symmetric,
        );
        let (pipelines, mut state) = setup(&device, &queue, model);
        state
            .set_elastic(&device, &pipelines, &elastic)
            .unwrap_or_else(|e| panic!("{e}"));
        // The shear phase runs the symmetric force's kernels, the elastic
        // phase the elastic ones.
        assert_eq!(state.iteration(), ELASTIC_ITERATION);
        state.set_phase(ForceModel::Symmetric, true);
        assert_eq!(state.iteration(), SYMMETRIC_ITERATION);
        state.set_phase(ForceModel::Elastic, false);
        assert_eq!(state.iteration(), ELASTIC_ITERATION);
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(&queue, 0, state.params(ForceModel::Elastic, 0.0, 1.0, 0));
        for kernel in &ELASTIC_ITERATION[..2] {
            run(&device, &queue, &pipelines, &state, *kernel);
        }
        let got = state
            .read_force(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        // About a dozen terms (T_i + T_j) d and (U_i + U_j)(mu_j - mu_i):
        // the terms' difference (up to elastic_targets' tolerance, the
        // rotations' SVD adding ~1e-6) times a spacing each.
        let spacing = model.mean_connection_length();
        let tolerance = 12.0 * 2e-4 * spacing;
        let mut worst = 0.0f32;
        let mut volume_force = 0.0f32;
        for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
            let off = (*g - *e).abs().max_element();
            worst = worst.max(off);
            volume_force = volume_force.max((*e - symmetric[i]).abs().max_element());
            assert!(
                off <= tolerance,
                "n = {n}, particle {i}: GPU elastic force {g} vs CPU {e}, difference {off:e} > tolerance {tolerance:e}"
            );
        }
        assert!(
            volume_force > 10.0 * tolerance,
            "n = {n}: the volume term ({volume_force:e}) is lost in the tolerance {tolerance:e}"
        );
        eprintln!(
            "elastic_force, n = {n}: worst {worst:e} = {:e} spacings \
             (tolerance {tolerance:e}); the volume term moves it by up to {volume_force:e}",
            worst / spacing
        );
        // The shear phase: the same state finds the rotations of the M_i
        // again (the elastic phase left its gradients' there) and gathers
        // the symmetric force over them.
        state.set_phase(ForceModel::Symmetric, true);
        state.write_params(&queue, 0, state.params(ForceModel::Symmetric, 0.0, 1.0, 0));
        for kernel in [Kernel::LocalRotations, Kernel::DeformationForce] {
            run(&device, &queue, &pipelines, &state, kernel);
        }
        let got = state
            .read_force(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        for (i, (g, e)) in got.iter().zip(&symmetric).enumerate() {
            let off = (*g - *e).abs().max_element();
            assert!(
                off <= tolerance,
                "n = {n}, particle {i}: shear phase GPU force {g} vs CPU symmetric {e}"
            );
        }
    }
}

/// The elastic phase's step with the volume smoother and its two-level
/// correction (`volume_smoother.wgsl`, then `coarse_elastic.wgsl`'s
/// correction) against the CPU's `ElasticCoarse::smoothed_step` at the same
/// positions, from the same linearisation: the rotations, terms and force,
/// the residual, the pressures' sweeps, the step, `K s - r`, the coarse
/// solve and its prolongation, every kernel of a smoothed iteration before
/// the combine. The GPU runs in `f32`, the CPU's smoother and correction in
/// `f64`.
#[test]
fn the_smoothed_elastic_step_matches_the_cpu_twin() {
    let Some((device, queue)) = common::gpu("volume smoother parity") else {
        return;
    };
    // The default Poisson ratio with the first sweeps, and a nearly
    // incompressible one with the sweeps it takes.
    // And the default with springs towards planes (the smoother and the
    // correction take them in).
    let first = tissue_solve::coarse::SMOOTHER_SWEEPS;
    let settings = [(0.49, first, false), (0.499, 8, false), (0.49, first, true)];
    for (n, (poisson, sweeps, pulled)) in SIZES.into_iter().flat_map(|n| settings.map(|s| (n, s))) {
        let model = common::phantom(n);
        let (rest, connections) = (&model.positions, &model.connections);
        let current = deformed(model);
        let free = free_of(model);
        let plan = Plan::new(model).unwrap_or_else(|e| panic!("{e}"));
        let elastic = Elastic::new(rest, connections, poisson, &free);
        let cell = 2.0 * model.mean_connection_length();
        let aggregates = Aggregates::new(rest, connections, &free, cell, 1_000)
            .unwrap_or_else(|e| panic!("{e}"));
        let delta = tissue_solve::coarse::SHEAR_STEP * f64::from(plan.lambda_max);
        let made_for = CorrectionFor {
            contraction: 0.01,
            smoothing: Some(tissue_solve::coarse::Smoothing { delta, sweeps }),
            rho: Some(0.9),
            direct_max_aggregates: usize::MAX,
            envelope: true,
        };
        // Springs a little off every third free particle, as stiff as the
        // default, in turn towards a plane, a line and a point, tilted from
        // axis to axis.
        let springs: Vec<Spring> = if pulled {
            (0..model.len())
                .map(|i| match free[i] {
                    true if i % 3 == 0 => {
                        let normal = Vec3::new(1.0, (i % 7) as f32 - 3.0, 0.5).normalize();
                        let weight = tissue_solve::stage2::SPRING_WEIGHT * plan.lambda_max;
                        let point =
                            current[i] + 0.3 * normal.any_orthonormal_vector() - 0.2 * normal;
                        match i % 9 {
                            0 => spring(point, normal, weight),
                            3 => Spring::line(point, normal, weight),
                            _ => Spring::point(point, weight),
                        }
                    }
                    _ => Spring::ZERO,
                })
                .collect()
        } else {
            Vec::new()
        };
        let coarse = if pulled {
            ElasticCoarse::at_phase_start(
                &aggregates,
                rest,
                &current,
                connections,
                &elastic,
                made_for,
                &springs,
                None,
            )
            .unwrap_or_else(|| panic!("the correction is made"))
        } else {
            ElasticCoarse::new(&aggregates, rest, &current, connections, &elastic, made_for)
                .unwrap_or_else(|e| panic!("{e}"))
        };
        let rotations = local_rotations(rest, &current, connections);
        let (terms, _) = elastic_terms(
            rest,
            &current,
            connections,
            &rotations,
            &elastic,
            RotationMethod::Svd,
        );
        let force = elastic_force(rest, &current, connections, &terms, &elastic);
        let residual = elastic_residual(&force, &current, &[], &springs, &aggregates.aggregate);
        let expected = coarse
            .smoothed_step(&aggregates, connections, &residual)
            .unwrap_or_else(|| panic!("the correction has its smoother"));

        let (pipelines, mut state) = setup(&device, &queue, model);
        state
            .set_elastic(&device, &pipelines, &elastic)
            .unwrap_or_else(|e| panic!("{e}"));
        state
            .set_elastic_aggregates(&device, &pipelines, &aggregates)
            .unwrap_or_else(|e| panic!("{e}"));
        if pulled {
            state
                .set_loads(&device, &pipelines, &[], &springs)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        state
            .linearise_elastic(&device, &pipelines, &coarse)
            .unwrap_or_else(|e| panic!("{e}"));
        state.set_phase(ForceModel::Elastic, true);
        assert_eq!(
            state.passes(),
            [
                Pass::ElasticTerms(RotationMethod::Svd),
                Pass::ElasticForce,
                Pass::SmoothedStep {
                    cycled: false,
                    sweeps
                },
                Pass::Combine,
                Pass::UpdateNorms,
            ]
        );
        let iteration = state.iteration();
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(&queue, 0, state.params(ForceModel::Elastic, 0.0, 1.0, 0));
        let before_combine = iteration
            .iter()
            .position(|&k| k == Kernel::Chebyshev)
            .unwrap_or_else(|| panic!("the iteration combines"));
        for kernel in &iteration[..before_combine] {
            run(&device, &queue, &pipelines, &state, *kernel);
        }
        let plain = state
            .read_plain(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        let largest = expected.iter().map(|s| s.length()).fold(0.0f64, f64::max);
        // Without the volume term's part of the smoother the step is the
        // residual over delta: the volume term must show.
        let unsmoothed = residual
            .iter()
            .zip(&expected)
            .map(|(r, s)| (*r / delta - *s).length())
            .fold(0.0f64, f64::max);
        let tolerance = 5e-4 * largest;
        let mut worst = 0.0f64;
        for (i, ((p, q), e)) in plain.iter().zip(&current).zip(&expected).enumerate() {
            let got = (*p - *q).as_dvec3();
            let off = (got - *e).length();
            worst = worst.max(off);
            assert!(
                off <= tolerance,
                "n = {n}, poisson {poisson}, springs {pulled}, particle {i}: GPU step {got} vs CPU {e}, difference {off:e} > tolerance {tolerance:e}"
            );
        }
        assert!(
            unsmoothed > 10.0 * tolerance,
            "n = {n}: the smoother's volume part ({unsmoothed:e}) is lost in the tolerance {tolerance:e}"
        );
        eprintln!(
            "smoothed elastic step, n = {n}, poisson {poisson}, {sweeps} sweeps, springs {pulled}: worst {worst:.2e} of the largest step {largest:.2e} \
             ({:.2e} of it; tolerance 5e-4), the volume part {unsmoothed:.2e}",
            worst / largest
        );
    }
}

#[test]
fn integrate_and_step_norms_match_the_cpu_twins() {
    let Some((device, queue)) = common::gpu("integrate parity") else {
        return;
    };
    for n in SIZES {
        let model = common::phantom(n);
        let current = deformed(model);
        let force = symmetric_force(model, &current);
        let free = free_of(model);
        let alpha = 0.07;
        let expected = integrate(&current, &force, &[], &[], &free, alpha);
        let (pipelines, state) = setup(&device, &queue, model);
        state
            .write_current(&queue, &current)
            .unwrap_or_else(|e| panic!("{e}"));
        state
            .write_force(&queue, &force)
            .unwrap_or_else(|e| panic!("{e}"));
        state.write_params(
            &queue,
            0,
            state.params(ForceModel::Symmetric, alpha, 1.0, 0),
        );
        run(&device, &queue, &pipelines, &state, Kernel::Integrate);
        let got = state
            .read_plain(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        // q + alpha F: a fused multiply-add may differ by an ulp or two of |q|.
        assert_within_ulps(&got, &expected, &current, 4.0, &format!("n = {n}"));
        for (i, g) in got.iter().enumerate() {
            if !free[i] {
                assert_eq!(*g, current[i], "n = {n}, control point {i} moved");
            }
        }
        // The reduction: max and RMS of |q̂ - q| over all particles.
        run(&device, &queue, &pipelines, &state, Kernel::StepNorms);
        let rows = state
            .read_partials(&device, &queue, 1)
            .unwrap_or_else(|e| panic!("{e}"));
        let gpu_max = rows[0].iter().map(|x| x[0]).fold(0.0f32, f32::max).sqrt();
        let gpu_rms = (rows[0].iter().map(|x| f64::from(x[1])).sum::<f64>() / n as f64).sqrt();
        let squares: Vec<f32> = current
            .iter()
            .zip(&got)
            .map(|(a, b)| (*b - *a).length_squared())
            .collect();
        let cpu_max = squares.iter().copied().fold(0.0, f32::max).sqrt();
        let cpu_rms = (squares.iter().map(|&x| f64::from(x)).sum::<f64>() / n as f64).sqrt();
        assert!(
            (gpu_max - cpu_max).abs() <= 1e-6 * cpu_max,
            "n = {n}: max step GPU {gpu_max:e} vs CPU {cpu_max:e}, tolerance 1e-6 relative"
        );
        assert!(
            (gpu_rms - cpu_rms).abs() <= 1e-5 * cpu_rms,
            "n = {n}: RMS step GPU {gpu_rms:e} vs CPU {cpu_rms:e}, tolerance 1e-5 relative"
        );
    }
}

#[test]
fn chebyshev_matches_the_cpu_combine() {
    let Some((device, queue)) = common::gpu("chebyshev parity") else {
        return;
    };
    let n = 3_001;
    let model = common::phantom(n);
    let old = model.positions.clone();
    let current = deformed(model);
    let force = symmetric_force(model, &current);
    let free: Vec<bool> = model.attachments.iter().map(Option::is_none).collect();
    let alpha = 0.07;
    let plain = integrate(&current, &force, &[], &[], &free, alpha);
    let omega = 1.83f32;
    let expected: Vec<Vec3> = plain
        .iter()
        .zip(&old)
        .map(|(&q_hat, &q_old)| omega * (q_hat - q_old) + q_old)
        .collect();
    // State starts with previous = rest = `old`.
    let (pipelines, state) = setup(&device, &queue, model);
    state
        .write_current(&queue, &current)
        .unwrap_or_else(|e| panic!("{e}"));
    state
        .write_force(&queue, &force)
        .unwrap_or_else(|e| panic!("{e}"));
    state.write_params(
        &queue,
        0,
        state.params(ForceModel::Symmetric, alpha, omega, 0),
    );
    run(&device, &queue, &pipelines, &state, Kernel::Integrate);
    run(&device, &queue, &pipelines, &state, Kernel::Chebyshev);
    let got = state
        .read_positions(&device, &queue)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_within_ulps(&got, &expected, &current, 8.0, "integrate + chebyshev");
}

/// Every `got` within `ulps` ulps of the largest coordinate of `scale` of
/// `expected`, naming the particle, both values and the tolerance.
fn assert_within_ulps(got: &[Vec3], expected: &[Vec3], scale: &[Vec3], ulps: f32, what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}: lengths");
    let largest = scale
        .iter()
        .map(|q| q.abs().max_element())
        .fold(0.0, f32::max);
    let tolerance = ulps * f32::EPSILON * largest;
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        let off = (*g - *e).abs().max_element();
        assert!(
            off <= tolerance,
            "{what}, particle {i}: GPU {g} vs CPU {e}, difference {off:e} > tolerance {tolerance:e}"
        );
    }
}

/// The particles the solve moves, as both paths take them.
fn free_of(model: &ParticleModel) -> Vec<bool> {
    tissue_cpu::deformation::Plan::new(model)
        .unwrap_or_else(|e| panic!("{e}"))
        .free
}
