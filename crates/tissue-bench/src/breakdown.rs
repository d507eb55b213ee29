//! Where the time of one deformation iteration goes: each pass timed on its
//! own, on the state a solve left behind, beside the passes back to back.

use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;
use tissue_cpu::deformation::{
    Chebyshev, CpuSolve, DeformParams, Iteration, Pass, Plan, SolveDevice,
};
use tissue_gpu::GpuSolve;
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

/// The CPU iteration of `Deformer::solve`, pass by pass: the solve's own
/// iteration (`CpuSolve::iterate_timed`) on a copy of `solve`'s state (`plan` its solver's)
/// (after `iterations` iterations of `params`), run on for `samples`
/// iterations, each pass timed where it runs.
pub fn cpu(
    plan: &Plan,
    solve: &CpuSolve,
    params: &DeformParams,
    iterations: usize,
    samples: usize,
) -> Result<Breakdown> {
    let mut chebyshev = Chebyshev::new(plan, params);
    let omega = (1..=iterations + 1)
        .map(|k| chebyshev.omega(k))
        .last()
        .unwrap_or(1.0);
    let it = Iteration {
        force: params.force,
        rotations: params.tuning.rotations,
        alpha: plan.alpha(params),
        contraction: plan.contraction(params),
        correct: true,
        relinearise: true,
        damping: 1.0,
    };
    let mut solve = solve.clone();
    let Ok(()) = solve.begin(it);

    // Each pass of the iteration, in order, with its seconds per sample.
    let mut passes: Vec<(Pass, Vec<f64>)> = solve
        .passes()
        .into_iter()
        .map(|p| (p, Vec::new()))
        .collect();
    let mut whole = Vec::new();
    // One untimed round first: first touch of the output allocations.
    for sample in 0..=samples {
        let mut laps = vec![0.0f64; passes.len()];
        let (t_whole, norms) = timed(|| {
            solve.iterate_timed(it, omega, &mut |pass, seconds| {
                if let Some(k) = passes.iter().position(|(p, _)| *p == pass) {
                    laps[k] += seconds;
                }
            })
        });
        std::hint::black_box(norms);
        if sample > 0 {
            for ((_, list), t) in passes.iter_mut().zip(laps) {
                list.push(t);
            }
            whole.push(t_whole);
        }
    }
    let passes = passes
        .into_iter()
        .map(|(pass, times)| (pass.name().to_owned(), times))
        .collect();
    Breakdown::new(
        "wall_clock",
        format!(
            "each pass of the CPU iteration timed where it runs, over {samples} iterations \
             from the state after {iterations} iterations of the sag"
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

/// The GPU iteration kernel by kernel on `solve`'s current state (each
/// timed run moves it on by an iteration), `samples` times each: by
/// timestamp queries where the device has them, by the wall clock around a
/// submit and a wait otherwise.
pub fn gpu(gpu: &Gpu, solve: &GpuSolve, samples: usize) -> Result<Breakdown> {
    let (pipelines, state) = (solve.pipelines(), solve.state());
    let iteration = state.iteration();
    let names: Vec<&str> = iteration.iter().map(|k| k.name()).collect();
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
            by_kernel(&names, &times),
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
        by_kernel(&names, &times),
        &whole,
    )
}

/// The passes of one iteration by kernel: a kernel dispatched more than
/// once an iteration (the coarse cycles' sweeps, restrictions and
/// substitutions) is one row, `name ×count`, its dispatches' times summed
/// sample by sample; rows in the order of each kernel's first dispatch.
fn by_kernel(names: &[&str], times: &[Vec<f64>]) -> Vec<(String, Vec<f64>)> {
    let mut rows: Vec<(&str, usize, Vec<f64>)> = Vec::new();
    for (&name, samples) in names.iter().zip(times) {
        match rows.iter_mut().find(|(n, _, _)| *n == name) {
            Some((_, count, sums)) => {
                *count += 1;
                for (sum, t) in sums.iter_mut().zip(samples) {
                    *sum += t;
                }
            }
            None => rows.push((name, 1, samples.clone())),
        }
    }
    rows.into_iter()
        .map(|(name, count, sums)| match count {
            1 => (name.to_owned(), sums),
            _ => (format!("{name} ×{count}"), sums),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::by_kernel;

    #[test]
    fn a_kernel_dispatched_several_times_an_iteration_is_one_row() {
        let names = ["force", "sweep", "restrict", "sweep", "apply", "sweep"];
        let times: Vec<Vec<f64>> = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
            .iter()
            .map(|&t| vec![t, 10.0 * t])
            .collect();
        let rows = by_kernel(&names, &times);
        let expected = [
            ("force", [1.0, 10.0]),
            ("sweep ×3", [12.0, 120.0]),
            ("restrict", [3.0, 30.0]),
            ("apply", [5.0, 50.0]),
        ];
        assert_eq!(rows.len(), expected.len());
        for ((name, sums), (want, want_sums)) in rows.iter().zip(expected) {
            assert_eq!(name, want);
            assert_eq!(&sums[..], &want_sums[..]);
        }
    }
}
