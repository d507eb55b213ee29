//! Where the time of one deformation iteration goes: each pass timed on its
//! own, on the state a solve left behind, beside the passes back to back.

use std::time::Instant;

use anyhow::{Context, Result};
use glam::Vec3;
use serde::Serialize;
use tissue_cpu::deformation::{
    Chebyshev, DeformParams, Deformer, RotationMethod, chebyshev_combine, deformation_force,
    integrate, local_rotations, local_rotations_warm, steps,
};
use tissue_gpu::GpuDeformer;
use tissue_gpu::timing::KernelTimer;

use crate::stage2::Gpu;
use crate::stats::Summary;

/// One pass of an iteration.
#[derive(Debug, Clone, Serialize)]
pub struct StageTime {
    /// The pass: the CPU function or the GPU kernel (WGSL entry point).
    pub stage: String,
    /// Its time over the samples.
    pub time: Summary,
}

/// One iteration, pass by pass.
#[derive(Debug, Clone, Serialize)]
pub struct Breakdown {
    /// `wall_clock` (CPU), `timestamp_queries` or `wall_clock_submit_wait` (GPU).
    pub method: &'static str,
    /// What the numbers include.
    pub note: String,
    /// Each pass, in the order of an iteration.
    pub stages: Vec<StageTime>,
    /// Sum of the stages' medians, ms.
    pub sum_of_medians_ms: f64,
    /// The passes back to back as one iteration (on the GPU with timestamps:
    /// first kernel's start to last kernel's end).
    pub iteration: Summary,
}

impl Breakdown {
    fn new(
        method: &'static str,
        note: String,
        stages: Vec<(String, Vec<f64>)>,
        iteration: &[f64],
    ) -> Result<Self> {
        let stages = stages
            .into_iter()
            .map(|(stage, seconds)| {
                Ok(StageTime {
                    time: Summary::of_seconds(&seconds)
                        .with_context(|| format!("no sample of {stage}"))?,
                    stage,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            method,
            note,
            sum_of_medians_ms: stages.iter().map(|s| s.time.median_ms).sum(),
            stages,
            iteration: Summary::of_seconds(iteration).context("no iteration sample")?,
        })
    }
}

/// Seconds `f` takes, and its result (kept alive so the work is not elided).
fn timed<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let started = Instant::now();
    let out = f();
    (started.elapsed().as_secs_f64(), out)
}

/// The CPU iteration of `Deformer::solve`, pass by pass, through the public
/// `tissue_cpu::deformation` functions on `deformer`'s current state (after
/// `iterations` iterations of `params`), `samples` times each.
pub fn cpu(
    deformer: &Deformer,
    connections: &tissue_core::Connections,
    params: &DeformParams,
    iterations: usize,
    samples: usize,
) -> Result<Breakdown> {
    let rest = deformer.rest();
    let current = deformer.positions();
    let warm = deformer.rotations();
    let plan = deformer.plan();
    let alpha = plan.alpha(params);
    let mut chebyshev = Chebyshev::new(plan, params);
    let omega = (1..=iterations + 1)
        .map(|k| chebyshev.omega(k))
        .last()
        .unwrap_or(1.0);
    // The Chebyshev combine's cost does not depend on which positions it
    // mixes; the rest shape stands in for the previous iterate.
    let previous = rest;
    let rotations_of = |current: &[Vec3]| match params.rotations {
        RotationMethod::Svd => local_rotations(rest, current, connections),
        RotationMethod::WarmPolar => local_rotations_warm(rest, current, connections, warm),
    };
    let rotation_name = match params.rotations {
        RotationMethod::Svd => "local_rotations (svd)",
        RotationMethod::WarmPolar => "local_rotations_warm (warm polar)",
    };

    // With a coarse space or deflation, the plain step is corrected before
    // the Chebyshev combine (`Deformer::solve`'s order).
    let modes = deformer.modes().filter(|m| m.count() > 0);
    let coarse = deformer.coarse();
    let contraction = plan.contraction(params);
    let correct = |plain: &mut Vec<Vec3>| {
        if let Some(modes) = modes {
            tissue_cpu::deformation::deflate(modes, current, plain, contraction);
        }
        if let Some(coarse) = coarse {
            coarse.correct(current, plain, connections, contraction);
        }
    };

    let mut times: [Vec<f64>; 5] = Default::default();
    let mut whole = Vec::new();
    // One untimed round first: first touch of the output allocations.
    for sample in 0..=samples {
        let (t_rot, rotations) = timed(|| rotations_of(current));
        let (t_force, force) =
            timed(|| deformation_force(rest, current, &rotations, connections, params.force));
        let (t_int, (plain, next)) = timed(|| {
            let plain = integrate(current, &force, &plan.free, alpha);
            let next = chebyshev_combine(&plain, previous, omega);
            (plain, next)
        });
        let mut corrected = plain.clone();
        let (t_correct, ()) = timed(|| correct(&mut corrected));
        let (t_steps, norms) = timed(|| steps(current, &plain));
        std::hint::black_box((&next, &corrected, norms));
        let (t_whole, out) = timed(|| {
            let rotations = rotations_of(current);
            let force = deformation_force(rest, current, &rotations, connections, params.force);
            let mut plain = integrate(current, &force, &plan.free, alpha);
            correct(&mut plain);
            let norms = steps(current, &plain);
            (chebyshev_combine(&plain, previous, omega), norms)
        });
        std::hint::black_box(out);
        if sample > 0 {
            for (list, t) in times
                .iter_mut()
                .zip([t_rot, t_force, t_int, t_correct, t_steps])
            {
                list.push(t);
            }
            whole.push(t_whole);
        }
    }
    let [rot, force, int, correction, steps] = times;
    let mut passes = vec![
        (rotation_name.to_owned(), rot),
        ("deformation_force".to_owned(), force),
        ("integrate + chebyshev_combine".to_owned(), int),
    ];
    if let Some(modes) = modes {
        passes.push((format!("deflate ({} modes)", modes.count()), correction));
    } else if coarse.is_some() {
        passes.push(("coarse correction (two-level)".to_owned(), correction));
    }
    passes.push(("step norms".to_owned(), steps));
    Breakdown::new(
        "wall_clock",
        format!(
            "each public tissue-cpu pass timed alone on the state after {iterations} \
             iterations of the sag"
        ),
        passes,
        &whole,
    )
}

fn wait(gpu: &Gpu) -> Result<()> {
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .context("waiting for the GPU")
}

/// The GPU iteration kernel by kernel on `deformer`'s current state (each
/// timed run moves it on by an iteration), `samples` times each: by
/// timestamp queries where the device has them, by the wall clock around a
/// submit and a wait otherwise.
pub fn gpu(gpu: &Gpu, deformer: &GpuDeformer, samples: usize) -> Result<Breakdown> {
    let (pipelines, state) = (deformer.pipelines(), deformer.state());
    let iteration = state.iteration();
    let names = || iteration.iter().map(|k| k.name().to_owned());
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); iteration.len()];
    let mut whole = Vec::new();
    if gpu.timestamp_query {
        let timer = KernelTimer::new(&gpu.device, &gpu.queue)?;
        for sample in 0..=samples {
            let t = timer.time_iteration(&gpu.device, &gpu.queue, pipelines, state, 0)?;
            if sample > 0 {
                for (list, (_, ms)) in times.iter_mut().zip(&t.kernels) {
                    list.push(ms / 1e3);
                }
                whole.push(t.iteration_ms / 1e3);
            }
        }
        return Breakdown::new(
            "timestamp_queries",
            "GPU time of each kernel in a compute pass of its own (timestamps at its start \
             and end); the iteration from the first start to the last end"
                .to_owned(),
            names().zip(times).collect(),
            &whole,
        );
    }
    for sample in 0..=samples {
        for (k, &kernel) in iteration.iter().enumerate() {
            let started = Instant::now();
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("kernel"),
                });
            pipelines.dispatch(&mut encoder, state, kernel, 0);
            gpu.queue.submit([encoder.finish()]);
            wait(gpu)?;
            if sample > 0 {
                times[k].push(started.elapsed().as_secs_f64());
            }
        }
        let started = Instant::now();
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("iteration"),
            });
        pipelines.record_iterations(&mut encoder, state, 1);
        gpu.queue.submit([encoder.finish()]);
        wait(gpu)?;
        if sample > 0 {
            whole.push(started.elapsed().as_secs_f64());
        }
    }
    Breakdown::new(
        "wall_clock_submit_wait",
        "no timestamp queries (the adapter lacks them, or --no-timestamps): wall clock \
         around recording, submitting and waiting for each kernel alone, and for one \
         iteration in one pass"
            .to_owned(),
        names().zip(times).collect(),
        &whole,
    )
}
