//! Both devices run the same pass list, from the one rule in
//! `tissue_solve::stage2::passes`, for every combination of the iteration's
//! choices a solve reaches: the force, the rotations, and the correction
//! (none, the two-level solve factored or cycled, the elastic
//! one factored or cycled, with the volume smoother, a whole skin's or a
//! free skin's, or without), and for the elastic force the skin paired
//! with an observation or not.

mod common;

use std::collections::HashSet;

use tissue_core::ParticleModel;
use tissue_core::field::SurfaceField;
use tissue_cpu::deformation::{DeformParams, ForceModel, Pass, RotationMethod};
use tissue_gpu::Kernel;
use tissue_solve::stage2::{Choices, NO_LIMIT, Pairing, PairingRule};

/// A named change to the default parameters (given the model).
type Setting = (&'static str, fn(&mut DeformParams, &ParticleModel));

#[test]
fn both_devices_run_the_same_passes_for_every_combination() {
    let Some((device, queue)) = common::gpu("pass lists") else {
        return;
    };
    let model = common::phantom(2_000);
    let corrections: [Setting; 9] = [
        ("two-level", |_, _| {}),
        ("two-level cycled", |p, _| {
            p.tuning.coarse_direct_max_aggregates = 1
        }),
        ("uncorrected", |p, _| p.tuning.coarse = 0.0),
        ("elastic smoothed", |_, _| {}),
        // The front half of the skin observed: a free skin's sweeps.
        ("elastic smoothed, free skin", |p, model| {
            p.observed = Some(model.surface.vertices.iter().map(|v| v.y >= 0.0).collect());
        }),
        ("elastic cycled, free skin", |p, model| {
            p.observed = Some(model.surface.vertices.iter().map(|v| v.y >= 0.0).collect());
            p.tuning.elastic_coarse_direct_max_aggregates = 16;
        }),
        ("elastic plain step", |p, _| {
            p.tuning.volume_smoother = false
        }),
        ("elastic cycled", |p, _| {
            p.tuning.elastic_coarse_direct_max_aggregates = 16
        }),
        ("elastic plain step cycled", |p, _| {
            p.tuning.volume_smoother = false;
            p.tuning.elastic_coarse_direct_max_aggregates = 16;
        }),
    ];
    let mut seen = HashSet::new();
    for force in [
        ForceModel::Symmetric,
        ForceModel::Paper,
        ForceModel::Elastic,
    ] {
        for rotations in [RotationMethod::Svd, RotationMethod::WarmPolar] {
            for (name, set) in &corrections {
                let elastic_case = name.starts_with("elastic");
                if elastic_case != (force == ForceModel::Elastic) && !name.ends_with("uncorrected")
                {
                    continue;
                }
                let params = DeformParams::default().with(|p| {
                    p.force = force;
                    p.tuning.rotations = rotations;
                    p.max_iterations = 200;
                    set(p, model);
                });
                let context = format!("{force:?}, {rotations:?}, {name}");
                let (cpu, cpu_report, gpu, gpu_report) =
                    common::solve_sag_on_both(&device, &queue, model, params);
                eprintln!(
                    "{context}: CPU {:?} {} it, GPU {:?} {} it, retries {:?} {:?}",
                    cpu_report.stopped_by,
                    cpu_report.iterations,
                    gpu_report.stopped_by,
                    gpu_report.iterations,
                    cpu_report.elastic_retries,
                    gpu_report.elastic_retries
                );
                let passes = cpu.passes();
                assert!(!passes.is_empty(), "{context}: no passes");
                assert_eq!(gpu.passes(), passes, "{context}");
                assert_eq!(
                    gpu.state().iteration(),
                    Kernel::of_passes(&passes),
                    "{context}"
                );
                seen.insert(passes);
                if force == ForceModel::Elastic {
                    // The skin paired with an observation: the pairing
                    // comes first in the same iterations.
                    let field = SurfaceField::new(&model.surface, 4.0, 8.0)
                        .unwrap_or_else(|e| panic!("{e}"));
                    let plan = cpu.plan().clone();
                    let skin: Vec<u32> = (0..model.len())
                        .filter(|&i| model.attachments[i].is_some() && plan.free[i])
                        .map(|i| i as u32)
                        .collect();
                    let pairing = Pairing {
                        skin,
                        rule: PairingRule {
                            weight: plan.lambda_max,
                            edge: NO_LIMIT,
                            robust: NO_LIMIT,
                            cloud: false,
                            smooth: 0.0,
                        },
                    };
                    let (mut cpu, mut gpu) = (cpu, gpu);
                    cpu.set_observation(Some(&field));
                    cpu.set_pairing(Some(pairing.clone()))
                        .unwrap_or_else(|e| panic!("{e}"));
                    gpu.set_observation(Some(&field))
                        .unwrap_or_else(|e| panic!("{e}"));
                    gpu.set_pairing(Some(pairing))
                        .unwrap_or_else(|e| panic!("{e}"));
                    let paired = cpu.passes();
                    assert_eq!(paired.first(), Some(&Pass::Pair), "{context}, paired");
                    assert_eq!(gpu.passes(), paired, "{context}, paired");
                    assert_eq!(
                        gpu.state().iteration(),
                        Kernel::of_passes(&paired),
                        "{context}, paired"
                    );
                    seen.insert(paired);
                }
            }
        }
    }
    // Every combination is reached.
    let expected: HashSet<Vec<Pass>> = Choices::all().iter().map(Choices::passes).collect();
    let missing: Vec<_> = expected.difference(&seen).collect();
    assert!(missing.is_empty(), "combinations not reached: {missing:?}");
    assert_eq!(seen, expected);
}
