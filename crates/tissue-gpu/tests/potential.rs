//! The potential the elastic force descends (`E / 2 - sum b . q`), measured
//! on the GPU (`elastic_targets.wgsl::elastic_potential`) against its CPU
//! twin (`Elastic::particle_energy`), at the same positions; with the skin
//! paired with an observation, also under the pairing of the state kept.

#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use glam::Vec3;
use tissue_core::field::SurfaceField;
use tissue_cpu::deformation::{DeformParams, Deformer, ForceModel};
use tissue_gpu::GpuDeformer;
use tissue_solve::SolveDevice;
use tissue_solve::model::held_vertices;
use tissue_solve::stage2::{NO_LIMIT, Pairing, PairingRule, spring_potential};

/// The GPU's potential `gpu` is the CPU's `cpu` within 1e-4 of it (its
/// parts in `f32`).
fn close(gpu: f64, cpu: f64, what: &str) {
    assert!(
        (gpu - cpu).abs() <= 1e-4 * cpu.abs().max(1e-9),
        "{what}: GPU {gpu} against CPU {cpu}"
    );
}

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

/// With the skin paired with an observation (the sag's surface, each free
/// skin particle with its nearest point), the potential is measured twice:
/// paired where the skin is, and held, with every spring as it was paired
/// where the last save kept the state (what the energy watch compares
/// with that state's potential). At the state kept the two are one; at
/// the sag's answer, the skin slid along the sag from where it was paired,
/// they part by `sum_k P_k(x_k; kept) - P_k(x_k; paired at x)`, worked out
/// by hand; the GPU measures both as the CPU does (their difference to the
/// rounding of its `f32` parts).
#[test]
fn a_paired_potential_is_also_measured_under_the_pairing_of_the_state_kept() {
    let Some((device, queue)) = common::gpu("the held potential") else {
        return;
    };
    let model = common::phantom(2_000);
    let sag = tissue_core::deform::sagged_breast();
    let size = {
        let (lo, hi) = model.positions.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        (hi - lo).length()
    };
    let wall = held_vertices(&model.surface, &sag, 1e-3 * size).unwrap();
    let params = DeformParams::default().with(|p| p.observed = Some(wall));
    let mut answer = Deformer::new(model, params.clone()).unwrap();
    answer.set_surface(&sag).unwrap();
    assert!(answer.solve().converged);
    let answer = answer.positions().to_vec();

    let mut cpu = Deformer::new(model, GpuDeformer::cpu_twin(&params)).unwrap();
    let mut gpu = GpuDeformer::new(&device, &queue, model, params).unwrap();
    cpu.set_surface(&model.surface).unwrap();
    gpu.set_surface(&model.surface).unwrap();
    let field = SurfaceField::new(&sag, 4.0, 8.0).unwrap();
    let plan = cpu.plan().clone();
    let pairing = Pairing {
        skin: (0..model.len())
            .filter(|&i| model.attachments[i].is_some() && plan.free[i])
            .map(|i| i as u32)
            .collect(),
        rule: PairingRule {
            weight: plan.lambda_max,
            edge: NO_LIMIT,
            robust: NO_LIMIT,
            cloud: false,
            smooth: 0.0,
        },
    };
    assert!(pairing.skin.len() > 100, "{} paired", pairing.skin.len());
    cpu.set_observation(Some(&field));
    cpu.set_pairing(Some(pairing.clone())).unwrap();
    gpu.set_observation(Some(&field)).unwrap();
    gpu.set_pairing(Some(pairing.clone())).unwrap();

    // Kept at rest: paired there, then saved.
    let at_rest = (
        gpu.solve_device_mut().potential().unwrap().unwrap(),
        cpu.device_mut().potential().unwrap().unwrap(),
    );
    gpu.solve_device_mut().save().unwrap();
    cpu.device_mut().save().unwrap();
    close(at_rest.0.value, at_rest.1.value, "at rest");
    // Measured again where it was kept, under its own pairing.
    for (potential, on) in [
        (gpu.solve_device_mut().potential().unwrap().unwrap(), "GPU"),
        (cpu.device_mut().potential().unwrap().unwrap(), "CPU"),
    ] {
        assert_eq!(potential.held, potential.value, "{on}: {potential:?}");
    }

    let kept_at = cpu.positions().to_vec();
    // At the answer: the skin slid along the sag from where it was
    // paired.
    cpu.warm_start(&answer).unwrap();
    gpu.warm_start(&answer).unwrap();
    let moved = (
        gpu.solve_device_mut().potential().unwrap().unwrap(),
        cpu.device_mut().potential().unwrap().unwrap(),
    );
    close(moved.0.value, moved.1.value, "at the answer");
    close(moved.0.held, moved.1.held, "at the answer, held");
    // Where the warm start put the particles (it moves the held ones onto
    // their targets).
    let now = cpu.positions().to_vec();
    let kept = pairing.springs(&field, &kept_at);
    let paired = pairing.springs(&field, &now);
    let by_hand: f64 = pairing
        .skin
        .iter()
        .map(|&i| {
            let (i, x) = (i as usize, now[i as usize]);
            spring_potential(kept[i], x) - spring_potential(paired[i], x)
        })
        .sum();
    let parted = moved.1.held - moved.1.value;

    eprintln!(
        "at rest {:?}; at the answer {:?} (GPU {:?}); held minus paired {parted}, by hand {by_hand}",
        at_rest.1, moved.1, moved.0
    );
    // The GPU's parts in `f32`, each about 8 here: their rounding.
    let rounding = 3e-8 * moved.0.magnitude;
    assert!(
        by_hand > 10.0 * rounding,
        "the pairing hardly moved: {by_hand}"
    );
    assert!(
        (parted - by_hand).abs() <= 1e-6 * by_hand,
        "held minus paired {parted}, by hand {by_hand}"
    );
    assert!(
        ((moved.0.held - moved.0.value) - by_hand).abs() <= rounding,
        "GPU: held minus paired {}, by hand {by_hand}",
        moved.0.held - moved.0.value
    );
}
