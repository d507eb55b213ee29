//! Criterion micro-benchmarks of the hot CPU kernels on the bundled phantom
//! at 10,000 particles: the grid build, the stage-1 force pass, the stage-2
//! rotation pass (SVD and warm polar), the force pass, one whole
//! deformation iteration, and the elastic phase's correction (made at the
//! phase's start, its terms and force, and its smoothed step, the
//! iteration's largest pass). `cargo bench --bench kernels`; in CI
//! `cargo bench --bench kernels -- --test` runs each once (smoke mode).

#![allow(missing_docs, reason = "criterion's macros generate the items")]
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "benchmark set-up")]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Vec3, Vec4};
use tissue::deform::Rigid;
use tissue::field::SurfaceField;
use tissue::{SamplingParams, phantom};
use tissue_cpu::coarse::Aggregates;
use tissue_cpu::coarse::{CorrectionFor, ElasticCoarse};
use tissue_cpu::deformation::{
    Elastic, ForceModel, Plan, RotationMethod, deformation_force, elastic_force, elastic_potential,
    elastic_residual, elastic_terms, integrate, local_rotations, local_rotations_warm,
};
use tissue_cpu::sampling::{SamplingState, imf_force, initial_radius};
use tissue_cpu::stage1::{grid_build, neighbour_rows};

const PARTICLES: usize = 10_000;

fn kernels(c: &mut Criterion) {
    let breast = phantom::default_breast();
    let params = SamplingParams::with_particles(PARTICLES);
    let sampled = tissue::sample(&breast, &params).expect("the phantom samples");
    let model = sampled.model;
    let r0 = initial_radius(breast.signed_volume(), PARTICLES);

    c.bench_function("grid_build 10k", |b| {
        b.iter(|| grid_build(black_box(&model.positions), 2.0 * r0))
    });

    let field = SurfaceField::new(&breast, r0, 0.25 * r0).expect("field");
    let state = SamplingState {
        positions: model.positions.clone(),
        radii: model.radii.clone(),
        contact: vec![Vec4::ZERO; PARTICLES],
    };
    let (offsets, indices) = neighbour_rows(&state.positions, &state.radii, 1.0, 1.2 * r0, false);
    c.bench_function("imf_force 10k", |b| {
        b.iter(|| imf_force(black_box(&state), &offsets, &indices, &field, &params))
    });

    // A state part way through the solve of a 30° rotation.
    let rigid = Rigid::about_axis(
        Vec3::new(1.0, 2.0, 0.5),
        0.5,
        Vec3::new(0.0, 0.0, 25.0),
        Vec3::ZERO,
    );
    let current: Vec<Vec3> = model
        .positions
        .iter()
        .enumerate()
        .map(|(i, &p)| rigid.apply(p) + Vec3::splat(0.01 * (i % 5) as f32))
        .collect();
    let rotations = local_rotations(&model.positions, &current, &model.connections);
    c.bench_function("local_rotations (SVD) 10k", |b| {
        b.iter(|| local_rotations(black_box(&model.positions), &current, &model.connections))
    });
    c.bench_function("local_rotations_warm 10k", |b| {
        b.iter(|| {
            local_rotations_warm(
                black_box(&model.positions),
                &current,
                &model.connections,
                &rotations,
            )
        })
    });
    c.bench_function("deformation_force (symmetric) 10k", |b| {
        b.iter(|| {
            deformation_force(
                black_box(&model.positions),
                &current,
                &rotations,
                &model.connections,
                ForceModel::Symmetric,
            )
        })
    });

    let free: Vec<bool> = model.attachments.iter().map(Option::is_none).collect();
    c.bench_function("deformation iteration (warm polar) 10k", |b| {
        b.iter(|| {
            let r = local_rotations_warm(
                &model.positions,
                black_box(&current),
                &model.connections,
                &rotations,
            );
            let f = deformation_force(
                &model.positions,
                &current,
                &r,
                &model.connections,
                ForceModel::Symmetric,
            );
            integrate(&current, &f, &[], &[], &free, 0.05)
        })
    });

    // The elastic phase's correction as the solve makes it at the phase's
    // start, over the default aggregates, with the volume smoother.
    let (rest, connections) = (&model.positions, &model.connections);
    let plan = Plan::new(&model).expect("plan");
    let elastic = Elastic::new(rest, connections, 0.49, &free);
    let cell = 2.0 * model.mean_connection_length();
    let aggregates = Aggregates::new(rest, connections, &free, cell, 1_000).expect("aggregates");
    let made_for = CorrectionFor {
        contraction: 0.01,
        smoothing: Some(tissue_solve::coarse::Smoothing {
            delta: tissue_solve::coarse::SHEAR_STEP * f64::from(plan.lambda_max),
            sweeps: tissue_solve::coarse::SMOOTHER_SWEEPS,
        }),
        rho: Some(0.9),
        direct_max_aggregates: 10_000,
        envelope: false,
    };
    // After the first, whose factor lends its order and symbolic analysis,
    // as at every phase start of a solver but its first.
    let made = |previous: Option<&ElasticCoarse>| {
        ElasticCoarse::at_phase_start(
            &aggregates,
            rest,
            &current,
            connections,
            &elastic,
            made_for,
            &[],
            previous,
        )
        .expect("the correction is made")
    };
    let coarse = made(None);
    c.bench_function("elastic correction made 10k", |b| {
        b.iter(|| made(Some(&coarse)))
    });
    let (terms, _) = elastic_terms(
        rest,
        &current,
        connections,
        &rotations,
        &elastic,
        RotationMethod::WarmPolar,
    );
    c.bench_function("elastic_terms (warm polar) 10k", |b| {
        b.iter(|| {
            elastic_terms(
                rest,
                black_box(&current),
                connections,
                &rotations,
                &elastic,
                RotationMethod::WarmPolar,
            )
        })
    });
    c.bench_function("elastic_force 10k", |b| {
        b.iter(|| elastic_force(rest, black_box(&current), connections, &terms, &elastic))
    });
    // The energy watch's measure, made every 8 elastic iterations.
    c.bench_function("elastic_potential 10k", |b| {
        b.iter(|| {
            elastic_potential(
                rest,
                black_box(&current),
                connections,
                &elastic,
                &[],
                &[],
                &[],
                &free,
                &rotations,
            )
        })
    });
    let force = elastic_force(rest, &current, connections, &terms, &elastic);
    let residual = elastic_residual(&force, &current, &[], &[], &aggregates.aggregate);
    c.bench_function("elastic smoothed step 10k", |b| {
        b.iter(|| coarse.smoothed_step(&aggregates, connections, black_box(&residual)))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = kernels
}
criterion_main!(benches);
