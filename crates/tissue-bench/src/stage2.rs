//! Stage-2 measurements, the same on both backends: one iteration, solves to
//! convergence from rest, and a tracking loop.

use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;
use tissue::backend::{Device, Solver, SolverDevice};
use tissue::deformation::inversions;
use tissue_core::deform::interpolate;
use tissue_core::{ParticleModel, SurfaceMesh, Vec3};
use tissue_cpu::deformation::{DeformParams, ForceModel, PrepareStage, RotationMethod};

use crate::breakdown::{self, Breakdown};
use crate::memory::GpuStateBytes;
use crate::stats::Summary;

/// An opened GPU device and its queue.
#[derive(Debug)]
pub struct Gpu {
    /// The adapter's name.
    pub name: String,
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Whether the device was opened with `wgpu::Features::TIMESTAMP_QUERY`.
    pub timestamp_query: bool,
}

/// Stage 2 on the CPU (`gpu` `None`) or on the opened GPU, through the
/// library's solver; `progress` hears each stage of its preparation.
fn solver_on(
    gpu: Option<&Gpu>,
    model: &ParticleModel,
    params: DeformParams,
    progress: &mut dyn FnMut(PrepareStage),
) -> Result<Solver> {
    let device = match gpu {
        None => Device::Cpu,
        Some(gpu) => Device::Gpu {
            name: gpu.name.clone(),
            device: gpu.device.clone(),
            queue: gpu.queue.clone(),
        },
    };
    Ok(Solver::new_with_progress(device, model, params, progress)?)
}

/// How many times to measure.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Repeats {
    /// Timed solves of `iterations_per_solve` fixed iterations.
    pub iteration_solves: usize,
    /// Iterations in each of those solves.
    pub iterations_per_solve: usize,
    /// Tracking frames.
    pub frames: usize,
    /// Samples of each pass in the per-stage breakdown.
    pub stage_samples: usize,
}

/// The surfaces stage 2 is measured on, all the rest surface with moved vertices.
#[derive(Debug)]
pub struct Cases {
    /// The rest surface.
    pub rest: SurfaceMesh,
    /// Named targets solved to convergence from rest.
    pub targets: Vec<(String, SurfaceMesh)>,
    /// The target the iteration timing and the tracking loop follow (the sag).
    pub track: SurfaceMesh,
    /// Probes solved from rest one by one (`--probes`; empty without).
    pub probes: Vec<ProbeCase>,
}

/// A probe pushed straight down at the surface's highest vertex.
#[derive(Debug)]
pub struct ProbeCase {
    /// How deep, mm.
    pub depth_mm: f32,
    /// How wide (the Gaussian's radius), mm.
    pub width_mm: f32,
    /// The rest surface so poked.
    pub surface: SurfaceMesh,
}

/// A solve from rest under one probe.
#[derive(Debug, Clone, Serialize)]
pub struct ProbeSolve {
    /// How deep, mm.
    pub depth_mm: f32,
    /// How wide, mm.
    pub width_mm: f32,
    /// Iterations, every retry's included.
    pub iterations: usize,
    /// Wall-clock seconds of the solve.
    pub seconds: f64,
    /// Whether the stopping rule held before the cap.
    pub converged: bool,
    /// Which rule ended it.
    pub stopped_by: String,
    /// How many times the elastic phase went on from where it stopped short
    /// (`DeformReport::elastic_retries`).
    pub retries: usize,
    /// How many times an elastic phase stepped back (`DeformReport::backtracks`).
    pub backtracks: usize,
    /// Particles left turned inside out (`tissue::deformation::inversions`).
    pub inverted: usize,
}

/// One iteration's wall time.
#[derive(Debug, Clone, Serialize)]
pub struct IterationTiming {
    /// Per-iteration wall time over the timed solves (solve time / iterations).
    pub per_iteration: Summary,
    /// Iterations each timed solve ran (the stopping rule is disabled, so
    /// all of `iterations_per_solve` unless the state stopped changing).
    pub iterations_run: Vec<usize>,
}

/// A solve to convergence from rest.
#[derive(Debug, Clone, Serialize)]
pub struct Converge {
    /// Which target.
    pub case: String,
    /// Iterations.
    pub iterations: usize,
    /// Wall-clock seconds of the solve (from rest, surface set).
    pub seconds: f64,
    /// Whether the stopping rule held before the cap.
    pub converged: bool,
    /// Which rule ended it.
    pub stopped_by: String,
}

/// Frames of a sequence, each starting from the last solution.
#[derive(Debug, Clone, Serialize)]
pub struct Tracking {
    /// The sequence.
    pub description: String,
    /// Per-frame latency: set_surface (upload), solve, positions readback.
    pub latency: Summary,
    /// Iterations of each frame.
    pub iterations: Vec<usize>,
}

/// Everything measured on one backend for one model.
#[derive(Debug, Clone, Serialize)]
pub struct Stage2 {
    /// How rotations are found on this backend.
    pub rotations: String,
    /// Aggregates of the two-level solve's coarse space (CPU; 0: none).
    pub coarse_aggregates: usize,
    /// Seconds to prepare stage 2 for the model (the spectrum, the coarse
    /// space, and on the GPU the kernels and buffers).
    pub prepare_seconds: f64,
    /// One iteration.
    pub iteration: IterationTiming,
    /// One iteration, pass by pass.
    pub stages: Breakdown,
    /// Solves to convergence from rest.
    pub converge: Vec<Converge>,
    /// Solves from rest under the probes (`--probes`).
    pub probes: Vec<ProbeSolve>,
    /// The tracking loop.
    pub tracking: Tracking,
    /// The GPU buffers (GPU only).
    pub gpu_state_bytes: Option<GpuStateBytes>,
}

/// Measures stage 2 for `model` on the CPU (`gpu` `None`) or the GPU.
pub fn measure(
    gpu: Option<&Gpu>,
    model: &ParticleModel,
    cases: &Cases,
    repeats: Repeats,
    defaults: &DeformParams,
) -> Result<Stage2> {
    // Where a long run is, on stderr (the report goes to stdout).
    let begun = Instant::now();
    let device = if gpu.is_some() { "gpu" } else { "cpu" };
    let phase = |what: &str| {
        eprintln!(
            "tissue-bench:   {device}: {what} ({:.1} s into stage 2)",
            begun.elapsed().as_secs_f64()
        );
    };
    phase("timing fixed iterations and the per-stage breakdown");
    let (iteration, stages) = {
        // The stopping rule off: the smallest positive tolerance never holds
        // while the sag is still being followed.
        let fixed = defaults.clone().with(|p| {
            p.tolerance = f32::MIN_POSITIVE;
            p.max_iterations = repeats.iterations_per_solve;
            p.tuning.extrapolate = false;
        });
        let mut solver = solver_on(gpu, model, fixed.clone(), &mut |_| {})
            .context("stage 2, fixed iterations")?;
        // The elastic force's iterations are its elastic phase's: each
        // timed solve starts warm (the elastic phase alone) halfway from
        // rest to the sag's answer, where it neither diverges nor settles
        // within the iterations timed. From rest the shear phase would take
        // them all, its tolerance never holding either.
        let halfway = if fixed.force == ForceModel::Elastic {
            solver.set_params(defaults.clone().with(|p| p.tuning.extrapolate = false))?;
            solver.set_surface(&cases.track)?;
            let answer = solver.solve()?;
            anyhow::ensure!(answer.converged, "the sag did not converge: {answer:?}");
            let halfway: Vec<Vec3> = model
                .positions
                .iter()
                .zip(solver.positions())
                .map(|(rest, solved)| rest.lerp(*solved, 0.5))
                .collect();
            solver.set_params(fixed.clone())?;
            Some(halfway)
        } else {
            None
        };
        let mut per_iteration = Vec::new();
        let mut iterations_run = Vec::new();
        // One untimed solve first: shader compilation, first-touch of memory.
        for run in 0..=repeats.iteration_solves {
            solver.reset()?;
            solver.set_surface(&cases.track)?;
            if let Some(halfway) = &halfway {
                solver.warm_start(halfway)?;
            }
            let started = Instant::now();
            let report = solver.solve()?;
            let seconds = started.elapsed().as_secs_f64();
            if run > 0 && report.iterations > 0 {
                per_iteration.push(seconds / report.iterations as f64);
                iterations_run.push(report.iterations);
            }
        }
        let stages = match (solver.device(), gpu) {
            (SolverDevice::Cpu(cpu), _) => breakdown::cpu(
                solver.plan(),
                cpu,
                &fixed,
                repeats.iterations_per_solve,
                repeats.stage_samples,
            ),
            (SolverDevice::Gpu(on_gpu), Some(gpu)) => {
                breakdown::gpu(gpu, on_gpu.solve(), repeats.stage_samples)
            }
            (SolverDevice::Gpu(_), None) => anyhow::bail!("a GPU solver without a GPU"),
        }
        .context("per-stage breakdown")?;
        let timing = IterationTiming {
            per_iteration: Summary::of_seconds(&per_iteration)
                .context("no timed iteration solve ran")?,
            iterations_run,
        };
        (timing, stages)
    };

    phase("preparing the solver");
    let started = Instant::now();
    // The timed preparation says where it is: at 1M particles it takes a
    // minute with the elastic force.
    let mut solver = solver_on(gpu, model, defaults.clone(), &mut |stage| {
        phase(&format!("preparing: {stage}"));
    })
    .context("stage 2")?;
    let prepare_seconds = started.elapsed().as_secs_f64();
    // What the solve runs: the coarse space's aggregates on both devices.
    let coarse_aggregates = match solver.device() {
        SolverDevice::Cpu(cpu) => cpu.coarse().map_or(0, |c| c.count()),
        SolverDevice::Gpu(on_gpu) => on_gpu.solve().state().aggregates(),
    };
    let gpu_state_bytes = match solver.device() {
        SolverDevice::Cpu(_) => None,
        SolverDevice::Gpu(on_gpu) => Some(GpuStateBytes::of(on_gpu.solve(), model.len())),
    };
    // From rest, the solver alone: the tracking prediction would carry a
    // rigid rotation there exactly, and hide the solver's convergence.
    let mut from_rest = solver_on(
        gpu,
        model,
        defaults.clone().with(|p| {
            p.tuning.extrapolate = false;
        }),
        &mut |_| {},
    )
    .context("stage 2, from rest")?;
    let mut converge = Vec::new();
    for (case, target) in &cases.targets {
        phase(&format!("solving {case} from rest"));
        from_rest.reset()?;
        from_rest.set_surface(target)?;
        let started = Instant::now();
        let report = from_rest.solve()?;
        converge.push(Converge {
            case: case.clone(),
            iterations: report.iterations,
            seconds: started.elapsed().as_secs_f64(),
            converged: report.converged,
            stopped_by: format!("{:?}", report.stopped_by),
        });
    }

    let mut probes = Vec::new();
    for probe in &cases.probes {
        phase(&format!(
            "solving a probe {:.0} mm deep and {:.0} mm wide from rest",
            probe.depth_mm, probe.width_mm
        ));
        from_rest.reset()?;
        from_rest.set_surface(&probe.surface)?;
        let started = Instant::now();
        let report = from_rest.solve()?;
        let seconds = started.elapsed().as_secs_f64();
        let judged = inversions(&model.positions, from_rest.positions(), &model.connections);
        probes.push(ProbeSolve {
            depth_mm: probe.depth_mm,
            width_mm: probe.width_mm,
            iterations: report.iterations,
            seconds,
            converged: report.converged,
            stopped_by: format!("{:?}", report.stopped_by),
            retries: report.elastic_retries,
            backtracks: report.backtracks,
            inverted: judged.count,
        });
    }

    // Tracking: reach half the sag, then frames of 2 % of it each.
    phase("tracking frames");
    solver.reset()?;
    let half = interpolate(&cases.rest, &cases.track, 0.5).map_err(anyhow::Error::msg)?;
    solver.set_surface(&half)?;
    solver.solve()?;
    let frames: Vec<SurfaceMesh> = (1..=repeats.frames)
        .map(|k| interpolate(&cases.rest, &cases.track, 0.5 + 0.02 * k as f32))
        .collect::<Result<_, _>>()
        .map_err(anyhow::Error::msg)?;
    let mut latency = Vec::new();
    let mut iterations = Vec::new();
    for frame in &frames {
        let started = Instant::now();
        solver.set_surface(frame)?;
        let report = solver.solve()?;
        let positions = solver.positions();
        latency.push(started.elapsed().as_secs_f64());
        iterations.push(report.iterations);
        anyhow::ensure!(
            positions.len() == model.len(),
            "read back {} positions for {} particles",
            positions.len(),
            model.len()
        );
    }
    // Both devices find the rotations as the parameters say.
    let rotations = match defaults.tuning.rotations {
        RotationMethod::Svd => "svd",
        RotationMethod::WarmPolar => "warm_polar",
    };
    Ok(Stage2 {
        rotations: rotations.to_owned(),
        coarse_aggregates,
        prepare_seconds,
        iteration,
        stages,
        converge,
        probes,
        tracking: Tracking {
            description: format!(
                "{} frames from 50 % of the sag in steps of 2 % of it",
                repeats.frames
            ),
            latency: Summary::of_seconds(&latency).context("no tracking frame ran")?,
            iterations,
        },
        gpu_state_bytes,
    })
}
