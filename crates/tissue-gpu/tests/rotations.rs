//! `GpuDeformer::read_rotations`, what the CLI carries structures with,
//! against the CPU: after one iteration it must equal
//! `tissue_cpu::deformation::local_rotations` of the positions that
//! iteration started from, and after a whole solve of the phantom's sag the
//! rotations of `Deformer::rotations` (rotations by SVD, the GPU's method).

mod common;

use glam::Mat3;
use tissue_cpu::deformation::{DeformParams, ForceModel, RotationMethod, local_rotations};
use tissue_gpu::GpuDeformer;

/// Largest entry difference over all particles, with its particle.
fn worst(got: &[Mat3], expected: &[Mat3]) -> (usize, f32) {
    assert_eq!(got.len(), expected.len(), "one rotation per particle");
    got.iter()
        .zip(expected)
        .map(|(g, e)| {
            (*g - *e)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, x| a.max(x.abs()))
        })
        .enumerate()
        .fold((0, 0.0), |w, (i, off)| if off > w.1 { (i, off) } else { w })
}

#[test]
fn read_rotations_after_one_iteration_matches_local_rotations() {
    let Some((device, queue)) = common::gpu("read_rotations, one iteration") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Symmetric;
        p.tuning.rotations = RotationMethod::Svd;
        p.max_iterations = 1;
    });
    let mut gpu =
        GpuDeformer::new(&device, &queue, model, params).unwrap_or_else(|e| panic!("{e}"));
    gpu.set_surface(&tissue_core::deform::sagged_breast())
        .unwrap_or_else(|e| panic!("{e}"));
    let start = gpu.positions().unwrap_or_else(|e| panic!("{e}"));
    let report = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(report.iterations, 1);
    let got = gpu.read_rotations().unwrap_or_else(|e| panic!("{e}"));
    let expected = local_rotations(&model.positions, &start, &model.connections);
    // As in parity.rs: an f32 SVD of a well-conditioned M agrees to ~1e-6.
    let tolerance = 1e-4;
    let (i, off) = worst(&got, &expected);
    assert!(
        off <= tolerance,
        "particle {i}: GPU rotation {} vs CPU {}, max entry difference {off:e} > tolerance {tolerance:e}",
        got[i],
        expected[i]
    );
    eprintln!("one iteration: worst entry difference {off:e} (particle {i})");
}

#[test]
fn read_rotations_after_a_solve_matches_the_cpu_deformer() {
    let Some((device, queue)) = common::gpu("read_rotations, whole solve") else {
        return;
    };
    let model = common::phantom(2_000);
    let params = DeformParams::default().with(|p| {
        p.tuning.rotations = RotationMethod::Svd;
    });
    let (cpu, cpu_report, gpu, gpu_report) =
        common::solve_sag_on_both(&device, &queue, model, params);
    assert_eq!(
        gpu_report.iterations, cpu_report.iterations,
        "the same stopping rule, so the rotations come from the same iteration"
    );
    let got = gpu.read_rotations().unwrap_or_else(|e| panic!("{e}"));
    // The positions agree to 1e-5 of the size (solve.rs); over a neighbour
    // spacing of ~1/20 of the size that turns a rotation by ~2e-4.
    let tolerance = 1e-3;
    let (i, off) = worst(&got, cpu.rotations());
    assert!(
        off <= tolerance,
        "particle {i}: GPU rotation {} vs CPU {}, max entry difference {off:e} > tolerance {tolerance:e}",
        got[i],
        cpu.rotations()[i]
    );
    eprintln!(
        "after {} iterations: worst entry difference {off:e} (particle {i})",
        gpu_report.iterations
    );
}
