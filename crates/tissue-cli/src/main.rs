//! The `tissue` command-line tool.

mod backend;
mod carry;
mod demo;
mod folder;
mod frames;
mod observe;
mod output;
mod picture;
mod posture;
mod progress;
mod sample;
mod solve;
mod track;
mod uncertain;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Track where the inside of a soft organ goes when its surface moves.
#[derive(Debug, Parser)]
#[command(name = "tissue", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The whole pipeline on the bundled phantom in a few seconds: sample it,
    /// sag it and indent it, and report where the tumour went.
    Demo(demo::DemoArgs),
    /// Fill a closed surface with uniformly spread particles (stage 1).
    Sample(sample::SampleArgs),
    /// Move a sampled model's interior to follow one deformed surface (stage 2).
    Deform(solve::DeformArgs),
    /// Follow a sequence of deformed surfaces, each solve starting from the last.
    Track(track::TrackArgs),
    /// Write the bundled breast phantom, its tumour and two deformed skins (millimetres).
    Phantom {
        /// Folder to write `phantom-breast.obj`, `phantom-tumour.obj`,
        /// `phantom-sag.obj` and `phantom-indentation.obj` into.
        #[arg(long, default_value = "assets")]
        output_dir: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let quiet = match &cli.command {
        Command::Sample(args) => args.quiet,
        Command::Deform(args) => args.quiet,
        Command::Track(args) => args.quiet,
        Command::Demo(args) => args.quiet,
        Command::Phantom { .. } => false,
    };
    let level = if quiet { "error" } else { "warn" };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level))
        .format_timestamp_millis()
        .init();
    let outcome = match cli.command {
        Command::Demo(args) => demo::demo(&args),
        Command::Sample(args) => sample::sample(&args),
        Command::Deform(args) => solve::deform(&args),
        Command::Track(args) => track::track(&args),
        Command::Phantom { output_dir } => sample::write_phantom(&output_dir),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            if let Some(unfinished) = err.downcast_ref::<output::Unfinished>() {
                eprintln!("warning: {}", unfinished.message);
                return ExitCode::from(unfinished.status.exit_code());
            }
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
