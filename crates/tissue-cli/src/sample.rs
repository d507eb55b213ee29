//! `tissue sample` (stage 1) and `tissue phantom`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use indicatif::ProgressBar;
use tissue::{Sampled, SamplingParams, SamplingReport, SurfaceMesh, deform, phantom};

use crate::backend::{self, Backend, Device};
use crate::progress;

/// Parameter presets.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Preset {
    /// The measured best settings (docs/METHOD.md).
    Default,
    /// The paper read literally (random start, constant surface force, threshold 0.6).
    Paper,
}

/// Options of `tissue sample`.
#[derive(Debug, clap::Args)]
pub struct SampleArgs {
    /// Closed surface: .stl, .obj, .ply, legacy .vtk or VTK XML .vtp (3D Slicer, ParaView).
    surface: PathBuf,
    /// Number of particles.
    #[arg(long, short = 'n')]
    particles: usize,
    /// Seed of the initial placement.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to write the model: .vtp (the full model), or .csv / .ply (positions alone).
    #[arg(long, short = 'o')]
    output: PathBuf,
    /// Write the quality report as JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Start from a preset.
    #[arg(long, value_enum, default_value_t = Preset::Default)]
    preset: Preset,
    /// Read parameters from a JSON file (fields of `SamplingParams`; missing ones keep the preset's).
    #[arg(long)]
    params: Option<PathBuf>,
    /// Connect particles closer than this times `r_i + r_j` (eq. 9).
    #[arg(long)]
    connection_ratio: Option<f32>,
    /// Pair forces act below this times `r_i + r_j`.
    #[arg(long)]
    force_cutoff: Option<f32>,
    /// Iteration cap.
    #[arg(long)]
    max_iterations: Option<usize>,
    /// When the surface has several closed shells, sample only the largest
    /// (by volume) and drop the rest with a warning.
    #[arg(long)]
    largest_shell: bool,
    /// Where the sampling iterations run: `gpu` through wgpu (honours
    /// WGPU_BACKEND and WGPU_ADAPTER_NAME), `cpu`, or `auto` (a hardware GPU
    /// when there is one, else the CPU). The field, the initial placement and
    /// the surface placement stay on the CPU either way.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// Print nothing but errors.
    #[arg(long, short)]
    pub quiet: bool,
}

fn params_of(args: &SampleArgs) -> Result<SamplingParams> {
    let mut params = match args.preset {
        Preset::Default => SamplingParams::default(),
        Preset::Paper => SamplingParams::paper(args.particles),
    };
    if let Some(path) = &args.params {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading parameters from {}", path.display()))?;
        let mut value: serde_json::Value = serde_json::to_value(&params)?;
        let overrides: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{}: not valid JSON", path.display()))?;
        let (Some(base), Some(over)) = (value.as_object_mut(), overrides.as_object()) else {
            bail!("{}: expected a JSON object of parameters", path.display());
        };
        for (key, v) in over {
            if !base.contains_key(key) {
                bail!("{}: unknown parameter `{key}`", path.display());
            }
            base.insert(key.clone(), v.clone());
        }
        params = serde_json::from_value(value)
            .with_context(|| format!("{}: a parameter has the wrong type", path.display()))?;
    }
    params.particles = args.particles;
    params.seed = args.seed;
    if let Some(v) = args.connection_ratio {
        params.connection_ratio = v;
    }
    if let Some(v) = args.force_cutoff {
        params.force_cutoff = v;
    }
    if let Some(v) = args.max_iterations {
        params.max_iterations = v;
    }
    params.validate()?;
    Ok(params)
}

/// `tissue sample`: loads, validates and samples a surface, writes the model.
pub fn sample(args: &SampleArgs) -> Result<()> {
    let params = params_of(args)?;
    check_output(&args.output, &["vtp", "csv", "ply"])?;
    let mut outputs = vec![args.output.clone()];
    outputs.extend(args.report.clone());
    crate::output::refuse_overwriting(&outputs, &[("surface", args.surface.as_path())])?;
    crate::output::prepare_outputs(&outputs)?;
    let options = tissue::io::surface::LoadOptions::keeping_largest_shell(args.largest_shell);
    let (surface, validation, dropped) =
        tissue::io::surface::load_closed_surface_with(&args.surface, &options)?;
    // The library logs a flipped surface and dropped shells as warnings.
    let _ = (validation, dropped);
    let device = backend::pick(args.backend, args.quiet)?;
    let sampled = sample_on(&device, &surface, &params, args.quiet)?;
    tissue::export_model(&sampled.model, &args.output)?;
    if let Some(path) = &args.report {
        crate::output::write_json(path, &sampled.report)?;
    }
    if !args.quiet {
        print_report(&sampled.report);
        println!("  wrote {}", args.output.display());
    }
    Ok(())
}

/// Stage 1 on a validated surface on `device`, with a progress bar once it
/// has taken [`progress::SHOW_AFTER`] (none when `quiet`).
pub fn sample_on(
    device: &Device,
    surface: &SurfaceMesh,
    params: &SamplingParams,
    quiet: bool,
) -> Result<Sampled> {
    let started = Instant::now();
    let mut bar: Option<ProgressBar> = None;
    let mut progress = |p: &tissue::Progress| {
        if quiet || started.elapsed() < progress::SHOW_AFTER {
            return;
        }
        let bar = bar.get_or_insert_with(|| {
            progress::bar(
                "{spinner} sampling {pos} iterations ({elapsed}) {msg}",
                Some(p.max_iterations as u64),
            )
        });
        bar.set_position(p.iteration as u64);
        bar.set_message(format!("step {:.1e} r0", p.step_rms));
    };
    let sampled = tissue::backend::sample_on(device, surface, params, &mut progress)?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    Ok(sampled)
}

/// The quality report in three lines.
pub fn print_report(r: &SamplingReport) {
    println!(
        "sampled {} particles in {:.3} s ({} iterations, {})",
        r.particles,
        r.seconds,
        r.iterations,
        if r.converged {
            "converged"
        } else {
            "NOT converged: raise --max-iterations"
        }
    );
    println!(
        "  nn_cv {:.4}  connections median {} (p5 {}, p95 {})  surface particles {}",
        r.nn_cv, r.connections.median, r.connections.p5, r.connections.p95, r.surface_particles
    );
    println!(
        "  coverage {:.2} spacings  max_outside {:.1e} spacings  mean spacing {:.4}",
        r.coverage, r.max_outside, r.mean_spacing
    );
}

/// Refuses an output extension we cannot write before any work is done.
fn check_output(path: &Path, allowed: &[&str]) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if !allowed.contains(&ext.as_str()) {
        bail!(
            "{}: cannot write this file type (expected .{})",
            path.display(),
            allowed.join(", .")
        );
    }
    Ok(())
}

/// The bundled phantom files and what makes each.
pub fn phantom_files() -> [(&'static str, SurfaceMesh); 4] {
    [
        ("phantom-breast.obj", phantom::default_breast()),
        ("phantom-tumour.obj", phantom::default_tumour()),
        ("phantom-sag.obj", deform::sagged_breast()),
        ("phantom-indentation.obj", deform::indented_breast()),
    ]
}

/// `tissue phantom`: writes the bundled phantom files into `dir`.
pub fn write_phantom(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut written = Vec::new();
    for (name, mesh) in phantom_files() {
        let path = dir.join(name);
        tissue::save_surface(&mesh, &path)?;
        written.push(path.display().to_string());
    }
    println!("wrote {}", written.join(", "));
    Ok(())
}
