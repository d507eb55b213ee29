//! `tissue-bench`: a headless benchmark of both stages on the bundled phantom
//! or a given closed surface. Stage 1 (sampling) on the CPU; stage 2 (one
//! iteration, convergence from rest, a tracking loop) on each backend asked
//! for; memory per particle, the iteration's traffic floor and effective
//! bandwidth; where the time goes (sampling by its report's stages, one
//! iteration pass by pass, on the GPU by timestamp queries where the adapter
//! offers them). Markdown tables on stdout, every number in `--json`.

mod breakdown;
mod machine;
mod memory;
mod stage2;
mod stats;
mod table;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, ValueEnum};
use glam::{Vec2, Vec3};
use serde::Serialize;
use tissue_core::deform::{Indentation, Rigid, Sag, deform_surface};
use tissue_core::{SamplingParams, StageSeconds, SurfaceMesh};
use tissue_cpu::deformation::{DeformParams, ElasticSolve, ForceModel};

use crate::machine::{Adapter, Machine};
use crate::memory::{CpuModelBytes, IterationFloor};
use crate::stage2::{Cases, Gpu, ProbeCase, Repeats, Stage2};

/// Benchmark sampling and deformation on the CPU and the GPU.
#[derive(Debug, Parser)]
#[command(name = "tissue-bench", version, about, long_about = None)]
struct Args {
    /// Particle counts, comma-separated [default: 1000,10000,100000,1000000;
    /// with --quick 1000,5000].
    #[arg(long, value_delimiter = ',')]
    sizes: Option<Vec<usize>>,
    /// Stage-2 backends, comma-separated. The GPU is the adapter
    /// WGPU_BACKEND / WGPU_ADAPTER_NAME name, or the default one; without
    /// one it is reported as skipped.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cpu,gpu")]
    backends: Vec<BackendName>,
    /// A closed surface to sample instead of the bundled breast phantom
    /// (its sag and indentation are then scaled to its bounding box).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Write every number, and the machine, to this JSON file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Sizes 1000 and 5000 and few repeats: well under a minute.
    #[arg(long)]
    quick: bool,
    /// Time the GPU kernels by the wall clock around a submit and a wait,
    /// even where the adapter offers timestamp queries.
    #[arg(long)]
    no_timestamps: bool,
    /// The two-level solve's cell in mean connection lengths
    /// (`SolverTuning::coarse`, the library's default; on both backends);
    /// 0 measures the solver without it.
    #[arg(long, default_value_t = DeformParams::default().tuning.coarse)]
    coarse: f32,
    /// The stage-2 force model (`DeformParams::force`; the library's
    /// default, elastic).
    #[arg(long, value_enum, default_value_t = ForceName::Elastic)]
    force: ForceName,
    /// How the elastic phase of a solve from rest descends its potential
    /// (`SolverTuning::elastic_solve`; the library's default).
    #[arg(long, value_enum, default_value_t = DescentName::of(DeformParams::default().tuning.elastic_solve))]
    elastic_solve: DescentName,
    /// The elastic force's Poisson ratio (`DeformParams::poisson`).
    #[arg(long, default_value_t = DeformParams::default().poisson)]
    poisson: f32,
    /// Also solve from rest under 16 probes pushed straight down at the
    /// surface's highest vertex, 15, 20, 25 and 30 mm deep and 8, 15, 25 and
    /// 35 mm wide (on the phantom, 55 mm high; scaled to a --mesh's
    /// height): how many iterations and retries each took, how it ended,
    /// and how many particles it left inverted. The deep, narrow ones are
    /// where a solve is least robust.
    #[arg(long)]
    probes: bool,
}

/// The probes' depths and widths on the phantom (mm), scaled by the
/// surface's height over its 55 mm.
const PROBE_DEPTHS_MM: [f32; 4] = [15.0, 20.0, 25.0, 30.0];
const PROBE_WIDTHS_MM: [f32; 4] = [8.0, 15.0, 25.0, 35.0];
const PHANTOM_HEIGHT_MM: f32 = 55.0;

/// A stage-2 force model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ForceName {
    /// The paper's one-sided force.
    Paper,
    /// The symmetric force (rotation-aware energy).
    Symmetric,
    /// The symmetric force plus the volume term (`--poisson`).
    Elastic,
}

/// How an elastic solve's elastic phase descends its potential.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DescentName {
    /// Chebyshev-accelerated two-level iterations, the potential watched.
    Chebyshev,
    /// The conjugate gradient preconditioned by the two-level step.
    ConjugateGradient,
    /// Chebyshev's iterations until the potential first rises or they
    /// stall, then the conjugate gradient.
    ChebyshevThenConjugateGradient,
}

impl DescentName {
    fn of(solve: ElasticSolve) -> Self {
        match solve {
            ElasticSolve::Chebyshev => Self::Chebyshev,
            ElasticSolve::ConjugateGradient => Self::ConjugateGradient,
            ElasticSolve::ChebyshevThenConjugateGradient => Self::ChebyshevThenConjugateGradient,
        }
    }
}

/// A stage-2 backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
enum BackendName {
    /// The CPU path (rayon).
    Cpu,
    /// The GPU path (wgpu).
    Gpu,
}

/// Stage 1's numbers for one size.
#[derive(Debug, Clone, Serialize)]
struct Sampling {
    seconds: f64,
    iterations: usize,
    converged: bool,
    nn_cv: f32,
    connections_median: f32,
    coverage: f32,
    /// Where the time went (the sampling report's own breakdown).
    stage_seconds: StageSeconds,
}

/// One backend's outcome for one size.
#[derive(Debug, Clone, Serialize)]
struct BackendRun {
    backend: BackendName,
    /// `ran`, `skipped` (no adapter) or `failed`.
    status: &'static str,
    reason: Option<String>,
    stage2: Option<Stage2>,
    floor: Option<Floor>,
}

/// The iteration's traffic floor and the bandwidth it implies.
#[derive(Debug, Clone, Serialize)]
struct Floor {
    #[serde(flatten)]
    bytes: IterationFloor,
    /// Floor bytes over the median iteration time, GB/s.
    effective_gb_per_s: f64,
    formula: &'static str,
}

/// Everything for one size.
#[derive(Debug, Clone, Serialize)]
struct SizeRun {
    particles_requested: usize,
    particles: usize,
    sampling: Sampling,
    cpu_model_bytes: CpuModelBytes,
    backends: Vec<BackendRun>,
    /// VmHWM after this size: the peak of the whole process so far.
    peak_resident_bytes: Option<u64>,
}

/// The GPU as found at start.
#[derive(Debug, Clone, Serialize)]
struct GpuFound {
    status: &'static str,
    reason: Option<String>,
    adapter: Option<Adapter>,
    /// Whether the device was opened with timestamp queries (the adapter
    /// offers them and `--no-timestamps` was not given).
    timestamps_used: bool,
}

/// The JSON report.
#[derive(Debug, Clone, Serialize)]
struct Report {
    tool: &'static str,
    quick: bool,
    mesh: String,
    machine: Machine,
    gpu: Option<GpuFound>,
    repeats: Repeats,
    cases: Vec<String>,
    sizes: Vec<SizeRun>,
    total_seconds: f64,
}

const FLOOR_FORMULA: &str = "(1 + k)(2p + r) + 4(k + 1) + 2p bytes per particle: rest and current \
positions and rotations of the particle and its k neighbours read, its connections read, force \
and new position written; p, r = position and rotation size (CPU 12, 36; GPU 16, 48)";

fn main() -> ExitCode {
    // Warnings (a solve that did not converge, a correction that
    // could not be made) go to stderr beside the tables; RUST_LOG=info
    // says more.
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    match run(&Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tissue-bench: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The rest surface, its name, and the stage-2 targets on it (with
/// `probes`, the probe sweep's too).
fn surfaces(mesh: Option<&PathBuf>, probes: bool) -> Result<(String, Cases)> {
    let (name, rest) = match mesh {
        None => (
            "bundled breast phantom".to_owned(),
            tissue_core::phantom::default_breast(),
        ),
        Some(path) => (
            path.display().to_string(),
            tissue_core::io::surface::load_closed_surface(path)
                .with_context(|| format!("loading {}", path.display()))?,
        ),
    };
    let (low, high) = rest.bounds().context("the surface has no vertices")?;
    let centre = 0.5 * (low + high);
    let diagonal = (high - low).length();
    let rotate = Rigid::about_axis(Vec3::X, 30f32.to_radians(), centre, Vec3::ZERO);
    let (sag, indentation) = if mesh.is_none() {
        (Sag::default(), Indentation::default_on(&rest))
    } else {
        // The phantom's 12 mm at 55 mm projection, scaled to this mesh.
        let height = high.z.max(f32::MIN_POSITIVE);
        let sag = Sag {
            magnitude_mm: 12.0 / 55.0 * height,
            projection_mm: height,
            apex_foot: Vec2::new(centre.x, centre.y),
            ..Sag::default()
        };
        let indentation =
            Indentation::on_ray(&rest, centre, Vec3::Z, 0.05 * diagonal, 0.12 * diagonal);
        (sag, indentation)
    };
    let sagged = deform_surface(&rest, &sag);
    let mut targets = vec![
        ("rotate_30".to_owned(), deform_surface(&rest, &rotate)),
        ("sag".to_owned(), sagged.clone()),
    ];
    if let Some(indentation) = indentation {
        targets.push((
            "indentation".to_owned(),
            deform_surface(&rest, &indentation),
        ));
    }
    let probes = if probes {
        let scale = (high.z - low.z) / PHANTOM_HEIGHT_MM;
        let mut cases = Vec::new();
        for depth_mm in PROBE_DEPTHS_MM.map(|d| d * scale) {
            for width_mm in PROBE_WIDTHS_MM.map(|w| w * scale) {
                let probe = Indentation::down_at_top(&rest, depth_mm, width_mm)
                    .context("the surface has no vertices")?;
                cases.push(ProbeCase {
                    depth_mm,
                    width_mm,
                    surface: deform_surface(&rest, &probe),
                });
            }
        }
        cases
    } else {
        Vec::new()
    };
    Ok((
        name,
        Cases {
            rest,
            targets,
            track: sagged,
            probes,
        },
    ))
}

/// The adapter `tissue_gpu::adapter_from_env` chooses, opened with
/// `tissue_gpu::limits_for` it and `TIMESTAMP_QUERY` where the adapter has it and `timestamps`
/// allows (the only optional feature, and only for the per-kernel breakdown).
fn open_gpu(timestamps: bool) -> (GpuFound, Option<Gpu>) {
    let opened = tissue_gpu::adapter_from_env().and_then(|adapter| {
        let features = if timestamps {
            adapter.features() & wgpu::Features::TIMESTAMP_QUERY
        } else {
            wgpu::Features::empty()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("tissue-bench"),
            required_features: features,
            required_limits: tissue_gpu::limits_for(&adapter),
            ..Default::default()
        }))
        .map_err(|e| tissue_gpu::GpuError::RequestDevice(e.to_string()))?;
        Ok((adapter, device, queue, !features.is_empty()))
    });
    match opened {
        Ok((adapter, device, queue, timestamp_query)) => (
            GpuFound {
                status: "available",
                reason: None,
                adapter: Some(Adapter::of(&adapter)),
                timestamps_used: timestamp_query,
            },
            Some(Gpu {
                name: adapter.get_info().name,
                device,
                queue,
                timestamp_query,
            }),
        ),
        Err(e) => (
            GpuFound {
                status: "skipped",
                reason: Some(e.to_string()),
                adapter: None,
                timestamps_used: false,
            },
            None,
        ),
    }
}

fn sample(surface: &SurfaceMesh, particles: usize) -> Result<tissue_cpu::sampling::Sampled> {
    let params = SamplingParams::with_particles(particles);
    tissue_cpu::sample(surface, &params, &mut |_| {})
        .with_context(|| format!("sampling {particles} particles"))
}

fn run(args: &Args) -> Result<()> {
    let started = Instant::now();
    let sizes = match (&args.sizes, args.quick) {
        (Some(sizes), _) => sizes.clone(),
        (None, true) => vec![1_000, 5_000],
        (None, false) => vec![1_000, 10_000, 100_000, 1_000_000],
    };
    anyhow::ensure!(
        sizes.iter().all(|&n| n > 0),
        "--sizes: every size must be positive"
    );
    let repeats = if args.quick {
        Repeats {
            iteration_solves: 3,
            iterations_per_solve: 8,
            frames: 10,
            stage_samples: 5,
        }
    } else {
        Repeats {
            iteration_solves: 7,
            iterations_per_solve: 24,
            frames: 10,
            stage_samples: 15,
        }
    };
    let params = DeformParams::default().with(|p| {
        p.force = match args.force {
            ForceName::Paper => ForceModel::Paper,
            ForceName::Symmetric => ForceModel::Symmetric,
            ForceName::Elastic => ForceModel::Elastic,
        };
        p.poisson = args.poisson;
        p.tuning.coarse = args.coarse;
        p.tuning.elastic_solve = match args.elastic_solve {
            DescentName::Chebyshev => ElasticSolve::Chebyshev,
            DescentName::ConjugateGradient => ElasticSolve::ConjugateGradient,
            DescentName::ChebyshevThenConjugateGradient => {
                ElasticSolve::ChebyshevThenConjugateGradient
            }
        };
    });
    params.validate()?;
    let (mesh, cases) = surfaces(args.mesh.as_ref(), args.probes)?;
    let machine = Machine::detect();
    let (gpu_found, gpu) = if args.backends.contains(&BackendName::Gpu) {
        let (found, gpu) = open_gpu(!args.no_timestamps);
        (Some(found), gpu)
    } else {
        (None, None)
    };

    let mut runs = Vec::new();
    for &n in &sizes {
        eprintln!("tissue-bench: {n} particles");
        let sampled = sample(&cases.rest, n)?;
        let model = &sampled.model;
        eprintln!(
            "tissue-bench:   sampled in {:.1} s ({} iterations)",
            sampled.report.seconds, sampled.report.iterations
        );
        let sampling = Sampling {
            seconds: sampled.report.seconds,
            iterations: sampled.report.iterations,
            converged: sampled.report.converged,
            nn_cv: sampled.report.nn_cv,
            connections_median: sampled.report.connections.median,
            coverage: sampled.report.coverage,
            stage_seconds: sampled.report.stage_seconds,
        };
        let mut backends = Vec::new();
        for &backend in &args.backends {
            let device = match (backend, &gpu) {
                (BackendName::Cpu, _) => None,
                (BackendName::Gpu, Some(gpu)) => Some(gpu),
                (BackendName::Gpu, None) => {
                    let reason = gpu_found.as_ref().and_then(|f| f.reason.clone());
                    backends.push(BackendRun {
                        backend,
                        status: "skipped",
                        reason,
                        stage2: None,
                        floor: None,
                    });
                    continue;
                }
            };
            let (position_bytes, rotation_bytes) = match backend {
                BackendName::Cpu => (12.0, 36.0),
                BackendName::Gpu => (16.0, 48.0),
            };
            backends.push(
                match stage2::measure(device, model, &cases, repeats, &params) {
                    Ok(stage2) => {
                        let bytes = IterationFloor::new(model, position_bytes, rotation_bytes);
                        let seconds = stage2.iteration.per_iteration.median_ms / 1e3;
                        BackendRun {
                            backend,
                            status: "ran",
                            reason: None,
                            floor: Some(Floor {
                                bytes,
                                effective_gb_per_s: bytes.gigabytes_per_second(seconds),
                                formula: FLOOR_FORMULA,
                            }),
                            stage2: Some(stage2),
                        }
                    }
                    Err(e) if backend == BackendName::Gpu => BackendRun {
                        backend,
                        status: "failed",
                        reason: Some(format!("{e:#}")),
                        stage2: None,
                        floor: None,
                    },
                    Err(e) => return Err(e.context(format!("CPU stage 2 at {n} particles"))),
                },
            );
        }
        runs.push(SizeRun {
            particles_requested: n,
            particles: model.len(),
            sampling,
            cpu_model_bytes: CpuModelBytes::of(model),
            backends,
            peak_resident_bytes: machine::peak_resident_bytes(),
        });
    }

    let report = Report {
        tool: "tissue-bench",
        quick: args.quick,
        mesh,
        machine,
        gpu: gpu_found,
        repeats,
        cases: cases.targets.iter().map(|(name, _)| name.clone()).collect(),
        sizes: runs,
        total_seconds: started.elapsed().as_secs_f64(),
    };
    print!("{}", table::markdown(&report));
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
