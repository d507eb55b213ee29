//! The `tissue` command-line tool.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use tissue::{SamplingParams, SamplingReport, phantom};

/// Track where the inside of a soft organ goes when its surface moves.
#[derive(Debug, Parser)]
#[command(name = "tissue", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fill a closed surface with uniformly spread particles (stage 1).
    Sample(SampleArgs),
    /// Write the bundled breast phantom and its tumour (millimetres).
    Phantom {
        /// Folder to write `phantom-breast.obj` and `phantom-tumour.obj` into.
        #[arg(long, default_value = "assets")]
        output_dir: PathBuf,
    },
}

/// Parameter presets.
#[derive(Debug, Clone, Copy, ValueEnum)]
enum Preset {
    /// The measured best settings (docs/METHOD.md).
    Default,
    /// The paper read literally (random start, constant surface force, threshold 0.6).
    Paper,
}

#[derive(Debug, clap::Args)]
struct SampleArgs {
    /// Closed surface: .stl, .obj, .ply or legacy .vtk.
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
    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let quiet = matches!(&cli.command, Command::Sample(args) if args.quiet);
    let level = if quiet { "error" } else { "warn" };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level)).init();
    let outcome = match cli.command {
        Command::Sample(args) => sample(&args),
        Command::Phantom { output_dir } => write_phantom(&output_dir),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", message(&err));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes, each once: our errors already print their cause.
fn message(err: &anyhow::Error) -> String {
    let mut text = err.to_string();
    for cause in err.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text = format!("{text}: {cause}");
        }
    }
    text
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

fn sample(args: &SampleArgs) -> Result<()> {
    let params = params_of(args)?;
    check_output(&args.output, &["vtp", "csv", "ply"])?;
    let options = tissue::io::surface::LoadOptions {
        largest_shell: args.largest_shell,
    };
    let (surface, validation, dropped) =
        tissue::io::surface::load_closed_surface_with(&args.surface, &options)?;
    // The library logs a flipped surface and dropped shells as warnings.
    let _ = (validation, dropped);
    let started = Instant::now();
    let mut bar: Option<ProgressBar> = None;
    let sampled = tissue_cpu::sample(&surface, &params, &mut |p| {
        if args.quiet || started.elapsed() < Duration::from_secs(1) {
            return;
        }
        let bar = bar.get_or_insert_with(|| {
            let bar = ProgressBar::new(p.max_iterations as u64);
            bar.set_style(
                ProgressStyle::with_template(
                    "{spinner} sampling {pos} iterations ({elapsed}) {msg}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            bar
        });
        bar.set_position(p.iteration as u64);
        bar.set_message(format!("step {:.1e} r0", p.step_rms));
    })?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    tissue::export_model(&sampled.model, &args.output)?;
    if let Some(path) = &args.report {
        let json = serde_json::to_string_pretty(&sampled.report)?;
        std::fs::write(path, json + "\n").with_context(|| format!("writing {}", path.display()))?;
    }
    if !args.quiet {
        print_report(&sampled.report, &args.output);
    }
    Ok(())
}

fn print_report(r: &SamplingReport, output: &Path) {
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
    println!("  wrote {}", output.display());
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

fn write_phantom(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let breast = dir.join("phantom-breast.obj");
    let tumour = dir.join("phantom-tumour.obj");
    tissue::save_surface(&phantom::default_breast(), &breast)?;
    tissue::save_surface(&phantom::default_tumour(), &tumour)?;
    println!("wrote {} and {}", breast.display(), tumour.display());
    Ok(())
}
