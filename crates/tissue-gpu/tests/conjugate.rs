//! The conjugate-gradient elastic phase (`ElasticSolve::ConjugateGradient`,
//! and after Chebyshev's, `ElasticSolve::ChebyshevThenConjugateGradient`)
//! on both devices: its kernels (`shaders/descent.wgsl`) against their CPU
//! twins through whole solves, with the tracker's phase written once.

#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use glam::Vec3;
use tissue_cpu::deformation::{DeformParams, DeformReport, ForceModel, StopReason};
use tissue_solve::model::gravity_load;
use tissue_solve::stage2::{DESCENT_RELINEARISE, ElasticSolve};

/// Every state the conjugate-gradient phase accepted has a finite
/// potential below the one before: by Armijo's margin, or, where the
/// decrease is below what the potential tells apart, within its rounding.
fn every_step_lowered(report: &DeformReport) -> bool {
    report.potentials.len() == 1 && report.potentials_fell()
}

/// Asserts what both devices' solves of one case share: converged, every
/// accepted step lowering the potential, no divergence; the same
/// iterations within a fifth, two and one more per new linearisation
/// (every [`DESCENT_RELINEARISE`] steps: the devices' `beta`s differ by
/// rounding, so their paths part, and near the tolerance the error falls
/// by a few tenths an iteration, so the last iteration moves by a few: 37
/// and 41 under the 30 x 35 mm probe), the same
/// positions within the tolerance (3e-5 of the size: the devices' `beta`s
/// differ by rounding, so their paths part, and each answer is within
/// about the tolerance of the converged one).
fn assert_same_descent(
    solved: &(
        tissue_cpu::deformation::Deformer,
        DeformReport,
        tissue_gpu::GpuDeformer,
        DeformReport,
    ),
    context: &str,
) {
    let (cpu, cpu_report, gpu, gpu_report) = solved;
    eprintln!(
        "{context}: CPU {} iterations, {} retries, {} halvings, {:?}; GPU {} iterations, {} \
         retries, {} halvings, {:?}",
        cpu_report.iterations,
        cpu_report.elastic_retries,
        cpu_report.backtracks,
        cpu_report.stopped_by,
        gpu_report.iterations,
        gpu_report.elastic_retries,
        gpu_report.backtracks,
        gpu_report.stopped_by
    );
    for (device, report) in [("CPU", cpu_report), ("GPU", gpu_report)] {
        assert!(report.converged, "{context} on the {device}: {report:?}");
        assert_ne!(report.stopped_by, StopReason::Diverged, "{context}");
        assert!(
            every_step_lowered(report),
            "{context} on the {device}: {:?}",
            report.potentials
        );
    }
    let within = 2 + cpu_report.iterations / DESCENT_RELINEARISE + cpu_report.iterations / 5;
    assert!(
        cpu_report.iterations.abs_diff(gpu_report.iterations) <= within,
        "{context}: CPU {} iterations, GPU {}",
        cpu_report.iterations,
        gpu_report.iterations
    );
    // Each answer is within the tolerance of the converged one, so the two
    // are within two tolerances of each other.
    common::assert_same_positions(gpu, cpu, 2.0 * DeformParams::default().tolerance, context);
}

/// The default elastic parameters descending by `solve`.
fn descending(solve: ElasticSolve) -> DeformParams {
    DeformParams::default().with(|p| {
        p.tuning.extrapolate = false;
        p.tuning.elastic_solve = solve;
    })
}

/// The conjugate-gradient phase by default's elastic parameters.
fn conjugate() -> DeformParams {
    descending(ElasticSolve::ConjugateGradient)
}

/// The bench's sixteen probes (15-30 mm deep, 8-35 mm wide, at the
/// phantom's tip, from rest) and its sag at 2,000 particles: on both
/// devices every step the phase accepted lowered the potential, every
/// solve converged with no divergence, in the same iterations within a
/// fifth and two (one more per new linearisation), the same positions
/// within the tolerance.
#[test]
fn every_conjugate_step_descends_on_both_devices_under_the_probes() {
    let Some((device, queue)) = common::gpu("conjugate-gradient probes") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = conjugate();
    assert_eq!(params.force, ForceModel::Elastic);
    let sag = tissue_core::deform::sagged_breast();
    let solved = common::solve_on_both(&device, &queue, model, params.clone(), &sag);
    assert_same_descent(&solved, "sag");
    for (depth, width, poked) in probes(model) {
        let solved = common::solve_on_both(&device, &queue, model, params.clone(), &poked);
        assert_same_descent(&solved, &format!("probe {depth} x {width} mm"));
    }
}

/// The bench's sixteen probes on the phantom's surface, depth and width
/// in mm.
fn probes(model: &tissue_core::ParticleModel) -> Vec<(f32, f32, tissue_core::SurfaceMesh)> {
    let mut probes = Vec::new();
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, depth, width)
                .unwrap_or_else(|| panic!("the phantom has vertices"));
            probes.push((
                depth,
                width,
                tissue_core::deform::deform_surface(&model.surface, &probe),
            ));
        }
    }
    probes
}

/// Chebyshev's phase, then the conjugate gradient's from where its
/// potential first rose (`ElasticSolve::ChebyshevThenConjugateGradient`),
/// under the sixteen probes at 2,000 particles: as the conjugate gradient
/// alone, every accepted state below the one before, every solve
/// converged with no retry, on both devices alike; and the conjugate
/// gradient took over under at least one probe on each device (a step
/// back is the turn).
#[test]
fn chebyshev_then_the_conjugate_gradient_descends_on_both_devices_under_the_probes() {
    let Some((device, queue)) = common::gpu("Chebyshev then the conjugate gradient") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = descending(ElasticSolve::ChebyshevThenConjugateGradient);
    let mut turned = [0, 0];
    for (depth, width, poked) in probes(model) {
        let solved = common::solve_on_both(&device, &queue, model, params.clone(), &poked);
        let context = format!("probe {depth} x {width} mm");
        assert_same_descent(&solved, &context);
        for (k, report) in [&solved.1, &solved.3].into_iter().enumerate() {
            assert_eq!(report.elastic_retries, 0, "{context}: {report:?}");
            turned[k] += usize::from(report.backtracks > 0);
        }
    }
    assert!(
        turned[0] > 0 && turned[1] > 0,
        "turned on the CPU and the GPU: {turned:?}"
    );
}

/// `base` for the phantom `model` with its skin free and its chest wall
/// held (the rest vertices on z = 0), hanging under its weight (2 kPa,
/// 1,000 kg/m^3) towards `gravity`.
fn hanging(model: &tissue_core::ParticleModel, base: DeformParams, gravity: Vec3) -> DeformParams {
    let held: Vec<bool> = model
        .surface
        .vertices
        .iter()
        .map(|v| v.z.abs() < 1e-3)
        .collect();
    let load = gravity_load(gravity, 1000.0, 2.0, base.poisson, 1e-3).unwrap();
    base.with(|p| {
        p.observed = Some(held);
        p.load = load;
    })
}

/// The phantom's skin free, its chest wall held (the rest vertices on
/// z = 0), hanging under its weight (2 kPa, 1,000 kg/m^3) towards its
/// feet, its back and its side, at 2,000 particles: the same on both
/// devices, every accepted step lowering the potential.
#[test]
fn every_conjugate_step_descends_on_both_devices_under_gravity() {
    let Some((device, queue)) = common::gpu("conjugate-gradient gravity") else {
        return;
    };
    let model = common::phantom(2_000);
    for (towards, gravity) in [
        ("the feet", Vec3::NEG_Y),
        ("the back", Vec3::NEG_Z),
        ("the side", Vec3::X),
    ] {
        let params = hanging(model, conjugate(), gravity);
        let solved = common::solve_on_both(&device, &queue, model, params, &model.surface);
        assert_same_descent(&solved, &format!("hanging towards {towards}"));
    }
}

/// A solve warm-started from a guess far from its answer (the phantom at
/// 2,000 particles, its chest wall held, hanging one way and started from
/// where it hangs another; the posture searches' solves start so): its
/// watched Chebyshev phase turns to the conjugate gradient where its
/// potential first rises, as a phase from rest does, on both devices
/// alike: converged with no retry and no step back but the turn, every
/// accepted state below the one before (each of the three turns,
/// measured).
#[test]
fn a_warm_start_far_from_its_answer_turns_to_the_conjugate_gradient_on_both_devices() {
    let Some((device, queue)) = common::gpu("a warm start turning to the conjugate gradient")
    else {
        return;
    };
    let model = common::phantom(2_000);
    for (from, to) in [
        (Vec3::NEG_Y, Vec3::NEG_Z),
        (Vec3::NEG_Z, Vec3::X),
        (Vec3::X, Vec3::NEG_X),
    ] {
        let mut start = tissue_cpu::deformation::Deformer::new(
            model,
            hanging(model, DeformParams::default(), from),
        )
        .unwrap();
        start.set_surface(&model.surface).unwrap();
        assert!(start.solve().converged);
        let guess = start.positions().to_vec();
        let params = hanging(model, DeformParams::default(), to);
        let mut cpu = tissue_cpu::deformation::Deformer::new(
            model,
            tissue_gpu::GpuDeformer::cpu_twin(&params),
        )
        .unwrap();
        cpu.set_surface(&model.surface).unwrap();
        cpu.warm_start(&guess).unwrap();
        let cpu_report = cpu.solve();
        let mut gpu = tissue_gpu::GpuDeformer::new(&device, &queue, model, params).unwrap();
        gpu.set_surface(&model.surface).unwrap();
        gpu.warm_start(&guess).unwrap();
        let gpu_report = gpu.solve().unwrap();
        let context = format!("hanging towards {to}, started from towards {from}");
        let solved = (cpu, cpu_report, gpu, gpu_report);
        assert_same_descent(&solved, &context);
        for report in [&solved.1, &solved.3] {
            assert_eq!(
                (report.backtracks, report.elastic_retries),
                (1, 0),
                "{context}: {report:?}"
            );
        }
    }
}
