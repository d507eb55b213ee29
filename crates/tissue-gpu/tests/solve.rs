//! `GpuDeformer::solve` against `Deformer::solve` (rotations by SVD, the
//! GPU's method) on the phantom's 12 mm sag: same stopping rule, positions
//! compared particle by particle.

mod common;

use tissue_cpu::deformation::{DeformParams, ForceModel, RotationMethod};

#[test]
fn the_gpu_solve_of_the_sag_matches_the_cpu_solve() {
    let Some((device, queue)) = common::gpu("whole solve parity") else {
        return;
    };
    let model = common::phantom(2_000);
    for force in [ForceModel::Symmetric, ForceModel::Paper] {
        let params = DeformParams {
            force,
            rotations: RotationMethod::Svd,
            ..DeformParams::default()
        };
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
        let got = gpu
            .positions(&device, &queue)
            .unwrap_or_else(|e| panic!("{e}"));
        let tolerance = 1e-5 * cpu.size();
        let mut worst = 0.0f32;
        for (i, (g, e)) in got.iter().zip(cpu.positions()).enumerate() {
            let off = g.distance(*e);
            worst = worst.max(off);
            assert!(
                off <= tolerance,
                "{force:?}, particle {i}: GPU {g} vs CPU {e}, distance {off:e} > tolerance {tolerance:e} (1e-5 of the size)"
            );
        }
        eprintln!(
            "{force:?}: worst distance {worst:e} = {:e} of the size",
            worst / cpu.size()
        );
    }
}
