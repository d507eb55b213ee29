//! The potential the elastic force descends (`E / 2 - sum b . q`), measured
//! on the GPU (`elastic_targets.wgsl::elastic_potential`) against its CPU
//! twin (`Elastic::particle_energy`), at the same positions.

#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use glam::Vec3;
use tissue_cpu::deformation::{DeformParams, Deformer, ForceModel};
use tissue_gpu::GpuDeformer;

/// At rest the potential is nothing; at the sag's start (the control
/// points moved, the rest at rest) and at its answer the GPU's is the
/// CPU's within 1e-4 (its parts in `f32`), and the solve lowered it on
/// both; under a load the loads' work enters on both alike. The symmetric
/// force has none.
#[test]
fn the_gpu_measures_the_potential_as_the_cpu_does() {
    let Some((device, queue)) = common::gpu("the potential") else {
        return;
    };
    let model = common::phantom(2_000);
    let sag = tissue_core::deform::sagged_breast();
    let close = |gpu: f64, cpu: f64, what: &str| {
        assert!(
            (gpu - cpu).abs() <= 1e-4 * cpu.abs().max(1e-9),
            "{what}: GPU {gpu} against CPU {cpu}"
        );
    };
    for load in [Vec3::ZERO, Vec3::new(0.0, -2e-3, 0.0)] {
        let params = DeformParams::default().with(|p| p.load = load);
        let mut cpu = Deformer::new(model, GpuDeformer::cpu_twin(&params)).unwrap();
        let mut gpu = GpuDeformer::new(&device, &queue, model, params).unwrap();
        let at_rest = (gpu.potential().unwrap().unwrap(), cpu.potential().unwrap());
        if load == Vec3::ZERO {
            assert!(at_rest.1.abs() < 1e-6, "{at_rest:?}");
            assert!(at_rest.0.abs() < 1e-3, "{at_rest:?}");
        } else {
            close(at_rest.0, at_rest.1, "at rest, loaded");
        }
        cpu.set_surface(&sag).unwrap();
        gpu.set_surface(&sag).unwrap();
        let start = (gpu.potential().unwrap().unwrap(), cpu.potential().unwrap());
        close(start.0, start.1, "the sag's start");
        assert!(cpu.solve().converged);
        assert!(gpu.solve().unwrap().converged);
        let solved_cpu = cpu.potential().unwrap();
        assert!(solved_cpu < start.1, "{solved_cpu} from {}", start.1);
        let solved_gpu = gpu.potential().unwrap().unwrap();
        assert!(solved_gpu < start.0, "{solved_gpu} from {}", start.0);
        // At the CPU's answer exactly.
        gpu.warm_start(cpu.positions()).unwrap();
        close(
            gpu.potential().unwrap().unwrap(),
            solved_cpu,
            "the sag's answer",
        );
        eprintln!(
            "load {load}: at rest {at_rest:?}, start {start:?}, solved CPU {solved_cpu} GPU {solved_gpu}"
        );
    }
    let symmetric = DeformParams::default().with(|p| p.force = ForceModel::Symmetric);
    let mut gpu = GpuDeformer::new(&device, &queue, model, symmetric.clone()).unwrap();
    assert_eq!(gpu.potential().unwrap(), None);
    assert_eq!(Deformer::new(model, symmetric).unwrap().potential(), None);
}
