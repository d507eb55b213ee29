//! Criterion micro-benchmarks of the GPU stage-2 kernels on the bundled
//! phantom at 10,000 particles: rotations by the 3x3 SVD, the force, the
//! plain step, and one whole iteration (all five kernels in one pass); the
//! elastic force's targets and its iteration (six kernels), on the
//! adapter `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` name or the default one.
//!
//! Every sample records the dispatch, submits it and waits for the queue, so
//! a time is the kernel plus one submit and one wait (on lavapipe, a CPU,
//! that overhead is small beside the kernel; on a real GPU it can dominate:
//! `tissue-bench`'s per-kernel breakdown uses timestamp queries where the
//! adapter has them). `cargo bench --bench gpu_kernels`; in CI
//! `cargo bench --bench gpu_kernels -- --test` runs each once (smoke mode).
//! Without an adapter the bench says it skipped, and fails under `CI=true`.

#![allow(missing_docs, reason = "criterion's macros generate the items")]
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "benchmark set-up")]

use criterion::{Criterion, criterion_group, criterion_main};
use tissue::deform::{Sag, deform_surface};
use tissue::{SamplingParams, phantom};
use tissue_cpu::deformation::{DeformParams, ForceModel};
use tissue_gpu::{GpuDeformer, Kernel};

const PARTICLES: usize = 10_000;

fn gpu_kernels(c: &mut Criterion) {
    let (adapter, device, queue) = match tissue_gpu::device_from_env() {
        Ok(opened) => opened,
        Err(e) => {
            // A GPU check never passes silently without a GPU in CI.
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "gpu_kernels: no GPU adapter under CI=true: {e}"
            );
            eprintln!("gpu_kernels: skipped, no GPU adapter: {e}");
            return;
        }
    };
    eprintln!("gpu_kernels: adapter {}", adapter.get_info().name);

    let breast = phantom::default_breast();
    let sampled = tissue::sample(&breast, &SamplingParams::with_particles(PARTICLES))
        .expect("the phantom samples");
    // A state part way through the solve of the 12 mm sag.
    let params = DeformParams::default().with(|p| {
        p.tolerance = f32::MIN_POSITIVE;
        p.max_iterations = 24;
    });
    let sagged = deform_surface(&breast, &Sag::default());
    let part_way = |params: DeformParams| {
        let mut deformer =
            GpuDeformer::new(&device, &queue, &sampled.model, params).expect("the GPU deformer");
        deformer.set_surface(&sagged).expect("the sagged surface");
        deformer.solve().expect("24 iterations");
        deformer
    };
    let symmetric = part_way(params.clone());
    let elastic = part_way(params.clone().with(|p| {
        p.force = ForceModel::Elastic;
    }));
    let wait = || {
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .expect("the queue finishes");
    };

    for (deformer, kernel, name) in [
        (
            &symmetric,
            Kernel::LocalRotations,
            "gpu local_rotations (SVD) 10k",
        ),
        (
            &symmetric,
            Kernel::DeformationForce,
            "gpu deformation_force (symmetric) 10k",
        ),
        (&symmetric, Kernel::Integrate, "gpu integrate 10k"),
        (&elastic, Kernel::ElasticTargets, "gpu elastic_targets 10k"),
        (&elastic, Kernel::ElasticForce, "gpu elastic_force 10k"),
    ] {
        let (pipelines, state) = (deformer.pipelines(), deformer.state());
        c.bench_function(name, |b| {
            b.iter(|| {
                let mut encoder = device.create_command_encoder(&Default::default());
                pipelines.dispatch(&mut encoder, state, kernel, 0);
                queue.submit([encoder.finish()]);
                wait();
            })
        });
    }
    for (deformer, name) in [
        (
            &symmetric,
            "gpu deformation iteration (all five kernels) 10k",
        ),
        (
            &elastic,
            "gpu elastic deformation iteration (all six kernels) 10k",
        ),
    ] {
        let (pipelines, state) = (deformer.pipelines(), deformer.state());
        c.bench_function(name, |b| {
            b.iter(|| {
                let mut encoder = device.create_command_encoder(&Default::default());
                pipelines.record_iterations(&mut encoder, state, 1);
                queue.submit([encoder.finish()]);
                wait();
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = gpu_kernels
}
criterion_main!(benches);
