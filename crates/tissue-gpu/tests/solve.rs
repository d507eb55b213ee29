//! `GpuDeformer::solve` against `Deformer::solve` (rotations by SVD, the
//! GPU's method) on the phantom's 12 mm sag: same stopping rule, positions
//! compared particle by particle.

mod common;

use tissue_cpu::deformation::{DeformParams, ElasticSolve, ForceModel, RotationMethod, StopReason};

#[test]
fn the_gpu_solve_of_the_sag_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("whole solve parity") else {
        return;
    };
    let model = common::phantom(2_000);
    for force in [ForceModel::Symmetric, ForceModel::Paper] {
        let params = DeformParams::default().with(|p| {
            p.force = force;
            p.tuning.rotations = RotationMethod::Svd;
        });
        let (cpu, cpu_report, gpu, gpu_report) =
            common::solve_sag_on_both(&device, &queue, model, params);
        eprintln!(
            "{force:?}: CPU {} iterations, {:?}, {:.3} s; GPU {} iterations, {:?}, {:.3} s",
            cpu_report.iterations,
            cpu_report.stopped_by,
            cpu_report.seconds,
            gpu_report.iterations,
            gpu_report.stopped_by,
            gpu_report.seconds
        );
        assert!(
            gpu_report.converged,
            "{force:?}: the GPU solve did not converge: {gpu_report:?}"
        );
        let context = format!("{force:?}");
        let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, &context);
        eprintln!("{force:?}: worst distance {worst:e} of the size");
    }
}

/// The two-level solve (the default `coarse`) on the sag from rest: the
/// GPU corrects with the CPU path's own coarse space (the same aggregates
/// and factor, solved in f32 where the CPU solves in f64), stops within
/// one iteration of the CPU, lands within 1e-5 of the size of its
/// positions, and needs fewer iterations than without the coarse space.
#[test]
fn a_two_level_gpu_solve_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("two-level solve parity") else {
        return;
    };
    // Not a multiple of the workgroup size: the last workgroup is partial.
    let model = common::phantom(3_001);
    for force in [ForceModel::Symmetric, ForceModel::Paper] {
        let params = DeformParams::default().with(|p| {
            p.force = force;
            p.tuning.rotations = RotationMethod::Svd;
        });
        assert_eq!(params.tuning.coarse, 2.0);
        let (cpu, cpu_report, gpu, gpu_report) =
            common::solve_sag_on_both(&device, &queue, model, params.clone());
        let aggregates = cpu.coarse().map(|c| c.count());
        assert!(
            aggregates.is_some_and(|n| n > 10),
            "{force:?}: {aggregates:?}"
        );
        assert_eq!(Some(gpu.state().aggregates()), aggregates, "{force:?}");
        let (_, _, _, plain) = common::solve_sag_on_both(
            &device,
            &queue,
            model,
            params.clone().with(|p| {
                p.tuning.coarse = 0.0;
            }),
        );
        eprintln!(
            "{force:?} two-level: CPU {} iterations, {:?}; GPU {} iterations, {:?}; GPU without {}",
            cpu_report.iterations,
            cpu_report.stopped_by,
            gpu_report.iterations,
            gpu_report.stopped_by,
            plain.iterations
        );
        assert!(cpu_report.converged && gpu_report.converged, "{force:?}");
        assert!(
            cpu_report.iterations.abs_diff(gpu_report.iterations) <= 1,
            "{force:?}: CPU {} iterations, GPU {}",
            cpu_report.iterations,
            gpu_report.iterations
        );
        assert!(
            gpu_report.iterations < plain.iterations,
            "{force:?}: {} two-level, {} without",
            gpu_report.iterations,
            plain.iterations
        );
        common::assert_same_positions(&gpu, &cpu, 1e-5, &format!("{force:?}"));
    }
}

/// Tracking: frames of a growing sag, each starting where `predict` puts it
/// on both paths; the same iterations per frame and the same positions.
#[test]
fn gpu_tracking_predicts_and_follows_frames_as_the_cpu_does() {
    let Some((device, queue)) = common::gpu("tracking parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.tuning.rotations = RotationMethod::Svd;
    });
    let sagged = tissue_core::deform::sagged_breast();
    let mut cpu =
        tissue_cpu::deformation::Deformer::new(model, tissue_gpu::GpuDeformer::cpu_twin(&params))
            .unwrap_or_else(|e| panic!("{e}"));
    let mut gpu = tissue_gpu::GpuDeformer::new(&device, &queue, model, params)
        .unwrap_or_else(|e| panic!("{e}"));
    let tolerance = 1e-5 * cpu.size();
    let mut counts = Vec::new();
    for k in 0..5 {
        let frame =
            tissue_core::deform::interpolate(&model.surface, &sagged, 0.5 + 0.05 * k as f32)
                .unwrap_or_else(|e| panic!("{e}"));
        cpu.set_surface(&frame).unwrap_or_else(|e| panic!("{e}"));
        gpu.set_surface(&frame).unwrap_or_else(|e| panic!("{e}"));
        let on_cpu = cpu.solve();
        let on_gpu = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
        assert!(on_gpu.converged, "frame {k}: {on_gpu:?}");
        // Rounding may tip the stopping rule one iteration either way.
        assert!(
            on_cpu.iterations.abs_diff(on_gpu.iterations) <= 1,
            "frame {k}: CPU {} iterations, GPU {}",
            on_cpu.iterations,
            on_gpu.iterations
        );
        counts.push((on_cpu.iterations, on_gpu.iterations));
        for (i, (g, c)) in gpu.host_positions().iter().zip(cpu.positions()).enumerate() {
            assert!(
                g.distance(*c) <= tolerance,
                "frame {k}, particle {i}: GPU {g} vs CPU {c}, tolerance {tolerance:e}"
            );
        }
    }
    eprintln!("iterations per frame (CPU, GPU): {counts:?}");
}

/// The elastic force (Poisson ratio 0.49) on the sag from rest without the
/// two-level solve: neither path corrects either phase, so both run the same
/// iterations and stop at the same one, within 1e-5 of the size of each
/// other.
#[test]
fn the_gpu_elastic_solve_of_the_sag_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("elastic solve parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.tuning.rotations = RotationMethod::Svd;
        p.tuning.coarse = 0.0;
    });
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params.clone());
    assert!(cpu.coarse().is_none() && gpu.state().aggregates() == 0);
    assert!(gpu.state().elastic());
    eprintln!(
        "Elastic: CPU {} iterations, {:?}, {:.3} s; GPU {} iterations, {:?}, {:.3} s",
        cpu_report.iterations,
        cpu_report.stopped_by,
        cpu_report.seconds,
        gpu_report.iterations,
        gpu_report.stopped_by,
        gpu_report.seconds
    );
    assert!(cpu_report.converged, "{cpu_report:?}");
    assert!(gpu_report.converged, "{gpu_report:?}");
    assert_eq!(
        cpu_report.iterations, gpu_report.iterations,
        "the same iteration and stopping rule on both"
    );
    let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "Elastic");
    let tolerance = 1e-5 * cpu.size();
    // The volume term matters: the symmetric solve lands elsewhere.
    let mut symmetric = tissue_cpu::deformation::Deformer::new(
        model,
        params.clone().with(|p| {
            p.force = ForceModel::Symmetric;
        }),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    symmetric
        .set_surface(&tissue_core::deform::sagged_breast())
        .unwrap_or_else(|e| panic!("{e}"));
    symmetric.solve();
    let apart = symmetric
        .positions()
        .iter()
        .zip(cpu.positions())
        .map(|(s, e)| s.distance(*e))
        .fold(0.0f32, f32::max);
    assert!(
        apart > 100.0 * tolerance,
        "the elastic and symmetric solves differ by {apart:e} only"
    );
    eprintln!(
        "Elastic: worst distance {worst:e} of the size; the symmetric solve lies up to {apart:e} away"
    );
}

/// A deep, narrow indentation (the tip pushed 40 mm down by a probe 15 mm
/// wide) with the elastic force, the tracker's rules written once: without
/// the two-level solve the elastic phase diverges and steps back once to
/// the state it accepted, with half its plain step; two-level, its
/// potential rises in its first iterations and the phase steps back twice
/// to the state it accepted, with half its smoothed step each time. Neither
/// runs again (no retry). Both devices take
/// the same retries and steps back, every accepted state lowering the
/// potential, the same iterations within one per phase run or step back
/// (each ends where a rise or a divergence is seen, on states that differ
/// by rounding), within 1e-5 of the size of each other.
#[test]
fn the_gpu_steps_a_diverged_elastic_phase_back_as_the_cpu_does() {
    let Some((device, queue)) = common::gpu("elastic retry parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, 40.0, 15.0)
        .unwrap_or_else(|| panic!("the phantom has vertices"));
    let poked = tissue_core::deform::deform_surface(&model.surface, &probe);
    for (coarse, retries, backtracks) in [(0.0, 0, 1), (2.0, 0, 2)] {
        let params = DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
            // Chebyshev's steps back and retries, which it holds.
            p.tuning.elastic_solve = ElasticSolve::Chebyshev;
            p.tuning.rotations = RotationMethod::Svd;
            p.tuning.coarse = coarse;
        });
        let solved = common::solve_on_both(&device, &queue, model, params, &poked);
        assert_eq!(
            (solved.1.elastic_retries, solved.1.backtracks),
            (retries, backtracks),
            "{:?}",
            solved.1
        );
        let context = format!("poke, coarse {coarse}");
        common::assert_same_retried_solve(&solved, 1 + retries + backtracks, &context);
    }
}

/// Probes 15 mm wide at the phantom's tip, the elastic force with the
/// defaults, 20 and 30 mm deep: on both devices the corrected elastic
/// phase's potential rises in its first iterations, and the phase steps
/// back once to the state it accepted and goes on with half its smoothed
/// step. The tracker's rules, written once: both converge to the
/// tolerance with no retry, in the same iterations within one, the same
/// positions within 1e-5 of the size.
#[test]
fn the_gpu_steps_a_smoothed_elastic_phase_back_as_the_cpu_does() {
    let Some((device, queue)) = common::gpu("smoothed phase step back parity") else {
        return;
    };
    let model = common::phantom(2_000);
    for depth in [20.0, 30.0] {
        let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, depth, 15.0)
            .unwrap_or_else(|| panic!("the phantom has vertices"));
        let poked = tissue_core::deform::deform_surface(&model.surface, &probe);
        let params = DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
            // Chebyshev's steps back and retries, which it holds.
            p.tuning.elastic_solve = ElasticSolve::Chebyshev;
        });
        let solved = common::solve_on_both(&device, &queue, model, params, &poked);
        for report in [&solved.1, &solved.3] {
            assert_eq!(
                (report.elastic_retries, report.backtracks),
                (0, 1),
                "{depth} mm: {report:?}"
            );
            assert_eq!(
                report.stopped_by,
                StopReason::Tolerance,
                "{depth} mm: {report:?}"
            );
            assert!(report.iterations < 100, "{depth} mm: {report:?}");
        }
        let context = format!("poked {depth} mm");
        common::assert_same_retried_solve(&solved, 1, &context);
    }
}

/// The bench's sixteen probes (`tissue-bench --probes`: 15-30 mm deep,
/// 8-35 mm wide, at the phantom's tip, solved from rest without the
/// prediction's extrapolation) at 2,000 particles: on both devices every
/// elastic descent accepts only states whose potential is at most the one
/// before, none diverges, every probe converges, with the same retries and
/// steps back on both, the same iterations within two and one more per
/// step back or linearisation (the stopping rule's last steps are on
/// states that differ by rounding: 15 x 15 mm takes 76 and 78), the same
/// positions within 1e-5 of the size.
#[test]
fn every_probe_descends_the_potential_on_both_devices() {
    let Some((device, queue)) = common::gpu("probe sweep descent") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.tuning.extrapolate = false;
        // Chebyshev's steps back and retries, which it holds.
        p.tuning.elastic_solve = ElasticSolve::Chebyshev;
    });
    assert_eq!(params.force, ForceModel::Elastic);
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, depth, width)
                .unwrap_or_else(|| panic!("the phantom has vertices"));
            let poked = tissue_core::deform::deform_surface(&model.surface, &probe);
            let solved = common::solve_on_both(&device, &queue, model, params.clone(), &poked);
            let context = format!("probe {depth} x {width} mm");
            for report in [&solved.1, &solved.3] {
                assert_ne!(report.stopped_by, StopReason::Diverged, "{context}");
                assert_eq!(report.potentials.len(), 1, "{context}: {report:?}");
            }
            let (cpu, gpu) = (&solved.1, &solved.3);
            let within = 2 + cpu.backtracks + cpu.elastic_retries;
            common::assert_same_retried_solve(&solved, within, &context);
            assert!(gpu.converged, "{context}");
        }
    }
}

/// A probe 30 mm deep and 35 mm wide solved from rest without the
/// prediction's extrapolation (as the bench solves its probes): the
/// corrected elastic phase's second interval runs away, and on the GPU
/// its state's parts overflow `f32`, an infinite potential. That state is
/// not accepted: both devices step back once to the state before, with no
/// retry, in the same iterations, every accepted potential finite.
#[test]
fn an_infinite_potential_on_the_gpu_is_a_rise() {
    let Some((device, queue)) = common::gpu("infinite potential parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let probe = tissue_core::deform::Indentation::down_at_top(&model.surface, 30.0, 35.0)
        .unwrap_or_else(|| panic!("the phantom has vertices"));
    let poked = tissue_core::deform::deform_surface(&model.surface, &probe);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        // Chebyshev's steps back and retries, which it holds.
        p.tuning.elastic_solve = ElasticSolve::Chebyshev;
        p.tuning.extrapolate = false;
    });
    let solved = common::solve_on_both(&device, &queue, model, params, &poked);
    for report in [&solved.1, &solved.3] {
        assert_eq!(
            (report.elastic_retries, report.backtracks),
            (0, 1),
            "{report:?}"
        );
        assert_eq!(report.stopped_by, StopReason::Tolerance, "{report:?}");
    }
    common::assert_same_retried_solve(&solved, 1, "probe 30 x 35 mm, no extrapolation");
}

/// The elastic force with the defaults: both devices run the two-level
/// solve in the shear phase and the elastic phase's own, made at its start
/// from the same positions (the GPU's read back); the same iterations
/// within one, the same positions within 1e-5 of the size, and fewer
/// iterations on the GPU than without the elastic correction.
#[test]
fn a_corrected_elastic_gpu_solve_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("corrected elastic parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
    });
    assert!(params.tuning.coarse > 0.0 && params.tuning.elastic_coarse_max_aggregates > 0);
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params.clone());
    let (_, _, _, uncorrected) = common::solve_sag_on_both(
        &device,
        &queue,
        model,
        params.clone().with(|p| {
            p.tuning.elastic_coarse_max_aggregates = 0;
        }),
    );
    eprintln!(
        "corrected elastic: CPU {} iterations, {:?}; GPU {} iterations, {:?}; GPU uncorrected {}",
        cpu_report.iterations,
        cpu_report.stopped_by,
        gpu_report.iterations,
        gpu_report.stopped_by,
        uncorrected.iterations
    );
    assert!(cpu_report.converged && gpu_report.converged);
    assert_eq!(
        (cpu_report.elastic_retries, gpu_report.elastic_retries),
        (0, 0)
    );
    assert!(
        cpu_report.iterations.abs_diff(gpu_report.iterations) <= 1,
        "CPU {} iterations, GPU {}",
        cpu_report.iterations,
        gpu_report.iterations
    );
    // (65 against 94 at 2,000 particles; the gain grows with the model.)
    assert!(
        gpu_report.iterations < uncorrected.iterations,
        "{} corrected, {} not",
        gpu_report.iterations,
        uncorrected.iterations
    );
    common::assert_same_positions(&gpu, &cpu, 1e-5, "corrected elastic");
}

/// A coarse space of more aggregates than the GPU's one-workgroup
/// substitution takes (`GPU_COARSE_UNKNOWNS`) is solved by two-grid cycles
/// over groups of them on both devices (`GpuDeformer::cpu_twin` caps the
/// CPU's factor there too): the same iterations from rest, the same
/// positions.
#[test]
fn a_coarse_space_too_large_for_one_factor_is_cycled_on_both_devices() {
    let Some((device, queue)) = common::gpu("coarse space limit") else {
        return;
    };
    let model = common::phantom(10_000);
    // Cells of one spacing: nearly every free particle its own aggregate.
    let params = DeformParams::default().with(|p| {
        p.tuning.coarse = 1.0;
    });
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params);
    let Some(space) = cpu.coarse() else {
        panic!("no coarse space")
    };
    assert!(
        space.count() > tissue_gpu::GPU_COARSE_UNKNOWNS,
        "{} aggregates",
        space.count()
    );
    let groups = space.multilevel().map(|m| m.groups());
    assert!(
        groups.is_some_and(|g| g <= tissue_gpu::GPU_COARSE_UNKNOWNS),
        "{groups:?} groups"
    );
    assert_eq!(gpu.state().aggregates(), space.count());
    assert!(
        cpu_report.converged && gpu_report.converged,
        "{cpu_report:?} {gpu_report:?}"
    );
    assert_eq!(gpu_report.iterations, cpu_report.iterations);
    let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "cycled, 10k");
    eprintln!(
        "10k, cells of 1 spacing: {} aggregates in {groups:?} groups, {} iterations on both, \
         positions within {worst:e} of the size",
        space.count(),
        gpu_report.iterations
    );
}

/// A coarse space solved by two-grid cycles (over
/// `coarse_direct_max_aggregates`, what the CPU does at a million
/// particles) runs its cycles on the GPU too (`shaders/multilevel.wgsl`):
/// the sag from rest stops at the CPU's iteration, at the CPU's
/// positions, and converges faster than without the coarse space.
#[test]
fn a_cycled_coarse_space_runs_on_the_gpu_as_on_the_cpu() {
    let Some((device, queue)) = common::gpu("cycled coarse space") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.tuning.coarse_direct_max_aggregates = 50;
    });
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params.clone());
    let Some(space) = cpu.coarse() else {
        panic!("no coarse space")
    };
    let Some(cycles) = space.multilevel() else {
        panic!("{} aggregates factored", space.count())
    };
    assert!(
        cycles.groups() > 1 && cycles.groups() <= 50,
        "{} groups",
        cycles.groups()
    );
    assert_eq!(gpu.state().aggregates(), space.count());
    assert!(
        cpu_report.converged && gpu_report.converged,
        "{cpu_report:?} {gpu_report:?}"
    );
    assert_eq!(gpu_report.iterations, cpu_report.iterations);
    let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "cycled");
    eprintln!(
        "2k, cycled: {} aggregates in {} groups, {} iterations on both, positions within \
         {worst:e} of the size",
        space.count(),
        cycles.groups(),
        gpu_report.iterations
    );
    // The cycles do correct: without any correction the plain iteration
    // needs several times as many.
    let mut plain = tissue_cpu::deformation::Deformer::new(
        model,
        params.clone().with(|p| {
            p.tuning.coarse = 0.0;
        }),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    plain
        .set_surface(&tissue_core::deform::sagged_breast())
        .unwrap_or_else(|e| panic!("{e}"));
    let plain_report = plain.solve();
    assert!(
        2 * gpu_report.iterations < plain_report.iterations,
        "{} cycled, {} plain",
        gpu_report.iterations,
        plain_report.iterations
    );
}

/// An elastic coarse matrix solved by two-grid cycles (over
/// `elastic_coarse_direct_max_aggregates`, what the CPU does at 100,000
/// particles) runs its cycles on the GPU too
/// (`shaders/block_multilevel.wgsl`): the same groups, the sag from rest
/// within one iteration of the CPU's (the elastic correction's `f32`
/// against `f64`), at the CPU's positions.
#[test]
fn a_cycled_elastic_coarse_matrix_runs_on_the_gpu_as_on_the_cpu() {
    let Some((device, queue)) = common::gpu("cycled elastic coarse matrix") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.tuning.elastic_coarse_direct_max_aggregates = 40;
    });
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params);
    let Some(correction) = cpu.device().elastic_coarse() else {
        panic!("no elastic correction")
    };
    let Some(cycles) = correction.multilevel() else {
        panic!("the elastic correction is factored")
    };
    assert!(
        cycles.groups() > 1 && cycles.groups() <= 40,
        "{}",
        cycles.groups()
    );
    assert!(cycles.len() > 100, "{} aggregates", cycles.len());
    assert_eq!(gpu.state().elastic_groups(), cycles.groups());
    assert!(
        cpu.device().volume_smoother().is_some(),
        "the smoothed iteration is the default one"
    );
    assert!(
        cpu_report.converged && gpu_report.converged,
        "{cpu_report:?} {gpu_report:?}"
    );
    assert_eq!(
        (cpu_report.elastic_retries, gpu_report.elastic_retries),
        (0, 0)
    );
    assert!(
        cpu_report.iterations.abs_diff(gpu_report.iterations) <= 1,
        "CPU {} iterations, GPU {}",
        cpu_report.iterations,
        gpu_report.iterations
    );
    let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "cycled elastic");
    eprintln!(
        "2k elastic, cycled: {} aggregates in {} groups, CPU {} iterations, GPU {}, positions \
         within {worst:e} of the size",
        cycles.len(),
        cycles.groups(),
        cpu_report.iterations,
        gpu_report.iterations
    );
}

/// The elastic coarse matrix at 10,000 particles in cells of one spacing:
/// thousands of aggregates, more than the GPU's one-workgroup factor takes
/// (1,365), in hundreds of groups, so every cycle kernel runs over several
/// workgroups; both devices cycle them and stop together.
#[test]
fn an_elastic_coarse_matrix_too_large_for_one_factor_is_cycled_on_both_devices() {
    let Some((device, queue)) = common::gpu("elastic coarse matrix limit") else {
        return;
    };
    let model = common::phantom(10_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.tuning.coarse = 1.0;
    });
    assert_eq!(
        params.tuning.elastic_coarse_direct_max_aggregates,
        tissue_gpu::GPU_COARSE_UNKNOWNS / 3
    );
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params);
    let Some(cycles) = cpu.device().elastic_coarse().and_then(|c| c.multilevel()) else {
        panic!("the elastic correction is not cycled")
    };
    assert!(cycles.len() > 1_365, "{} aggregates", cycles.len());
    assert!(
        cycles.groups() > 64 && cycles.groups() <= 1_365,
        "{} groups",
        cycles.groups()
    );
    assert_eq!(gpu.state().elastic_groups(), cycles.groups());
    assert!(
        cpu_report.converged && gpu_report.converged,
        "{cpu_report:?} {gpu_report:?}"
    );
    assert!(
        cpu_report.iterations.abs_diff(gpu_report.iterations) <= 1,
        "CPU {} iterations, GPU {}",
        cpu_report.iterations,
        gpu_report.iterations
    );
    let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "cycled elastic, 10k");
    eprintln!(
        "10k elastic, cells of 1 spacing: {} aggregates in {} groups, CPU {} iterations, GPU \
         {}, positions within {worst:e} of the size",
        cycles.len(),
        cycles.groups(),
        cpu_report.iterations,
        gpu_report.iterations
    );
}

/// Half the skin unobserved and a body force: the GPU's free
/// surface particles and loads against the CPU's, with both forces.
#[test]
fn a_partly_observed_loaded_gpu_solve_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("observed and loaded parity") else {
        return;
    };
    let model = common::phantom(2_000);
    let mut heights: Vec<f32> = model.surface.vertices.iter().map(|v| v.z).collect();
    heights.sort_by(f32::total_cmp);
    let median = heights[heights.len() / 2];
    let observed: Vec<bool> = model
        .surface
        .vertices
        .iter()
        .map(|v| v.z <= median)
        .collect();
    for force in [ForceModel::Symmetric, ForceModel::Elastic] {
        let params = DeformParams::default().with(|p| {
            p.force = force;
            p.observed = Some(observed.clone());
            p.load = glam::Vec3::new(0.0, -0.002, 0.0);
        });
        let (cpu, cpu_report, gpu, gpu_report) =
            common::solve_sag_on_both(&device, &queue, model, params);
        eprintln!(
            "observed half, loaded, {force:?}: CPU {} iterations, {:?}; GPU {} iterations, {:?}",
            cpu_report.iterations,
            cpu_report.stopped_by,
            gpu_report.iterations,
            gpu_report.stopped_by
        );
        assert!(cpu_report.converged && gpu_report.converged, "{force:?}");
        // Over a free skin f32 rounding moves the stop by a few iterations
        // (36 / 37 measured with the volume smoother; 148 / 150 with the
        // plain step), within the 10 % allowed.
        let slack = 1.max(cpu_report.iterations / 10);
        assert!(
            cpu_report.iterations.abs_diff(gpu_report.iterations) <= slack,
            "{force:?}: CPU {} iterations, GPU {}",
            cpu_report.iterations,
            gpu_report.iterations
        );
        let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, &format!("{force:?}"));
        eprintln!("{force:?}: positions within {worst:.2e} of the size");
        // The load moved the free particles: the unloaded solve is elsewhere.
        let (unloaded, _, _, _) = common::solve_sag_on_both(
            &device,
            &queue,
            model,
            DeformParams::default().with(|p| {
                p.force = force;
                p.observed = Some(observed.clone());
            }),
        );
        let moved = unloaded
            .positions()
            .iter()
            .zip(cpu.positions())
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(
            moved > 1e-3 * cpu.size(),
            "{force:?}: the load moved nothing ({moved})"
        );
    }
}

/// The check at 10,000 and 100,000 particles, with the default parameters
/// (symmetric force, warm polar rotations, the two-level solve): at 10,000
/// and 100,000 particles the GPU takes the CPU's iterations from rest
/// (within 10 %) to the CPU's positions, and a run of tracking frames, each
/// moving the skin by 2 % of the model's size, takes at most 10 iterations
/// a frame on both.
#[test]
fn the_default_solve_takes_the_cpus_iterations_at_10k_and_100k() {
    let Some((device, queue)) = common::gpu("default solve at 10k and 100k") else {
        return;
    };
    let sagged = tissue_core::deform::sagged_breast();
    for n in [10_000, 100_000] {
        let model = common::phantom(n);
        let params = DeformParams::default();
        let (mut cpu, cpu_report, mut gpu, gpu_report) =
            common::solve_on_both(&device, &queue, model, params, &sagged);
        assert!(
            cpu_report.converged && gpu_report.converged,
            "{n}: {cpu_report:?} {gpu_report:?}"
        );
        let (c, g) = (cpu_report.iterations, gpu_report.iterations);
        assert!(10 * c.abs_diff(g) <= c, "{n}: from rest CPU {c}, GPU {g}");
        let worst = common::assert_same_positions(&gpu, &cpu, 1e-5, "from rest");
        // Frames from the sag back towards rest, each moving the skin by 2 %
        // of the size.
        let largest = model
            .surface
            .vertices
            .iter()
            .zip(&sagged.vertices)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        let step = 0.02 * cpu.size() / largest;
        let mut frames = Vec::new();
        let count = (1.0 / step) as usize;
        assert!(count >= 3, "{n}: the sag is under 6 % of the size");
        for k in 1..=count.min(4) {
            let t = 1.0 - k as f32 * step;
            let frame = tissue_core::deform::interpolate(&model.surface, &sagged, t)
                .unwrap_or_else(|e| panic!("{e}"));
            cpu.set_surface(&frame).unwrap_or_else(|e| panic!("{e}"));
            gpu.set_surface(&frame).unwrap_or_else(|e| panic!("{e}"));
            let on_cpu = cpu.solve();
            let on_gpu = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
            assert!(on_cpu.converged && on_gpu.converged, "{n}, frame {k}");
            assert!(
                on_cpu.iterations <= 10 && on_gpu.iterations <= 10,
                "{n}, frame {k}: CPU {} iterations, GPU {}",
                on_cpu.iterations,
                on_gpu.iterations
            );
            frames.push((on_cpu.iterations, on_gpu.iterations));
        }
        common::assert_same_positions(&gpu, &cpu, 1e-5, "tracked");
        eprintln!(
            "{n}: from rest CPU {c}, GPU {g} iterations, positions within {worst:e} of the size; \
             frames of 2 % of the size (CPU, GPU): {frames:?}"
        );
    }
}

/// The elastic correction's cycles with one group: its vector of three
/// unknowns sits in a buffer of four floats (a buffer holds 16 bytes at
/// least), and the substitutions solve the factor's three, not four. The
/// GPU converges as the CPU does, without a retry.
#[test]
fn elastic_cycles_of_one_group_match_the_cpu() {
    let Some((device, queue)) = common::gpu("elastic cycles of one group") else {
        return;
    };
    let model = common::phantom(2_000);
    for smoother in [true, false] {
        let params = DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
            p.tuning.volume_smoother = smoother;
            p.tuning.elastic_coarse_direct_max_aggregates = 1;
        });
        let (cpu, cpu_report, gpu, gpu_report) =
            common::solve_sag_on_both(&device, &queue, model, params);
        let context = format!("volume smoother {smoother}");
        assert_eq!(gpu.state().elastic_groups(), 1, "{context}");
        assert!(gpu_report.converged, "{context}: {gpu_report:?}");
        assert_eq!(gpu_report.elastic_retries, 0, "{context}");
        assert!(
            gpu_report.iterations.abs_diff(cpu_report.iterations) <= 1,
            "{context}: GPU {} iterations, CPU {}",
            gpu_report.iterations,
            cpu_report.iterations
        );
        common::assert_same_positions(&gpu, &cpu, 1e-4, &context);
    }
}
