//! `tissue demo`: the whole pipeline on the bundled phantom. Sample the
//! breast, then deform it to two skins (sagging, indented), each from rest,
//! carrying the tumour as a deformable and as a rigid structure.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;
use tissue::backend::with_cpu_fallback;
use tissue::deformation::DeformParams;
use tissue::{SamplingParams, SamplingReport, SurfaceMesh, deform, phantom};

use crate::backend::{self, BackendArgs, Solver};
use crate::carry::{Carried, Kind, Structure, StructureReport};
use crate::output::{Destination, Solved, write_json, write_solution};
use crate::progress::{self, SolveBar};
use crate::sample::{print_report, sample_on};
use crate::solve::PREPARING;

/// The demo's summary.
pub const DEMO_FILE: &str = "demo.json";
/// The demo's picture: the sagging breast (`crate::picture`).
pub const DEMO_PICTURE: &str = "demo.png";

/// Options of `tissue demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Folder for everything the demo writes (created if missing).
    #[arg(long, short = 'o', default_value = "tissue-demo")]
    pub output_dir: PathBuf,
    /// Particles to fill the phantom with.
    #[arg(long, short = 'n', default_value_t = 10_000)]
    pub particles: usize,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Print nothing but errors.
    #[arg(long, short)]
    pub quiet: bool,
}

/// One deformation of the demo in `demo.json`.
#[derive(Debug, Serialize)]
struct CaseReport {
    /// Also the name of its folder.
    name: &'static str,
    description: &'static str,
    /// The deformed skin (OBJ).
    skin: String,
    folder: String,
    /// Its picture.
    picture: String,
    iterations: usize,
    seconds: f64,
    converged: bool,
    residual: f32,
    max_displacement_mm: f32,
    structures: Vec<StructureReport>,
}

/// `demo.json`.
#[derive(Debug, Serialize)]
struct DemoReport {
    particles: usize,
    /// Where the stages ran: `cpu`, or the GPU adapter's name and graphics
    /// backend (both stages ran there).
    backend: String,
    sampling: SamplingReport,
    cases: Vec<CaseReport>,
    /// The whole demo, writing included.
    seconds: f64,
}

/// One deformation of the phantom.
struct Case {
    name: &'static str,
    description: &'static str,
    skin_file: &'static str,
    skin: SurfaceMesh,
    /// Its picture.
    picture: &'static str,
}

/// `tissue demo`.
pub fn demo(args: &DemoArgs) -> Result<()> {
    let started = Instant::now();
    let quiet = args.quiet;
    let say = |line: String| {
        if !quiet {
            println!("{line}");
        }
    };
    let params = SamplingParams::with_particles(args.particles);
    params.validate()?;
    let out = &args.output_dir;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;

    let mut breast = phantom::default_breast();
    let tumour = phantom::default_tumour();
    let spec = phantom::TumourPhantom::default();
    let (size, centre) = (2.0 * spec.radii, spec.centre);
    say(format!(
        "tissue demo: the bundled breast phantom (mm; chest wall at z = 0, +z forward, +y towards the head)\n\
         with a tumour of {:.0} x {:.0} x {:.0} mm centred at ({}, {}, {}): where does it go when the skin moves?",
        size.x, size.y, size.z, centre.x, centre.y, centre.z,
    ));
    // The bundled phantom faces outward already; validation only checks it.
    let _checked = tissue::validate(&mut breast).map_err(|source| tissue::Error::Mesh {
        path: "the bundled phantom".into(),
        source,
    })?;
    // Before sampling, so that a missing GPU fails at once.
    let device = backend::pick(args.backend.backend, quiet)?;
    let sampled = sample_on(&device, &breast, &params, quiet)?;
    if !quiet {
        print_report(&sampled.report);
    }
    let model = sampled.model;
    let model_path = out.join("model.vtp");
    tissue::save_model(&model, &model_path)?;
    tissue::save_surface(&breast, &out.join("breast.obj"))?;
    tissue::save_surface(&tumour, &out.join("tumour.obj"))?;

    let deform_params = DeformParams::default();
    // `auto` prepares stage 2 on the CPU where the GPU it picked has no room.
    let (mut solver, fell_back) = progress::busy(quiet, PREPARING, |busy| {
        with_cpu_fallback(
            args.backend.backend.into(),
            device,
            tissue::Error::is_gpu_capacity,
            |device| {
                Solver::new_with_progress(device, &model, deform_params.clone(), &mut |stage| {
                    busy.say(stage)
                })
            },
        )
    })?;
    if let (Some(why), false) = (fell_back, quiet) {
        println!("backend: cpu ({why})");
    }
    let carried = Carried {
        points: None,
        structures: [Kind::Deformable, Kind::Rigid]
            .into_iter()
            .map(|kind| {
                let name = match kind {
                    Kind::Deformable => "tumour.obj",
                    Kind::Rigid => "tumour-rigid.obj",
                };
                let source = out.join("tumour.obj").display().to_string();
                Structure::bind(name.into(), source, kind, tumour.clone(), &solver)
            })
            .collect::<Result<_>>()?,
        space: tissue::io::space::Space::Lps,
    };

    let cases = [
        Case {
            name: "sag",
            description: "the breast hangs 12 mm towards the feet at the apex (a patient who lay down sits up)",
            skin_file: "breast-sag.obj",
            skin: deform::sagged_breast(),
            picture: DEMO_PICTURE,
        },
        Case {
            name: "indentation",
            description: "a probe pushes the skin 8 mm in, straight above the tumour",
            skin_file: "breast-indentation.obj",
            skin: deform::indented_breast(),
            picture: "demo-indentation.png",
        },
    ];
    let model_name = model_path.display().to_string();
    let mut reports = Vec::new();
    for case in cases {
        let skin_path = out.join(case.skin_file);
        tissue::save_surface(&case.skin, &skin_path)?;
        solver.reset()?;
        solver.set_surface(&case.skin)?;
        let mut bar = SolveBar::new(case.name, quiet);
        let solve = solver.solve_with_progress(&mut |step| bar.step(step));
        bar.finish();
        let solve = solve?;
        let dir = out.join(case.name);
        let skin = skin_path.display().to_string();
        let picture = out.join(case.picture);
        let destination = Destination {
            dir: &dir,
            report: None,
            model: &model_name,
            surface: &skin,
            field: None,
            picture: Some(&picture),
        };
        let report = write_solution(
            destination,
            &model,
            &solver,
            &case.skin,
            &carried,
            Solved {
                params: &deform_params,
                solve,
                posture: None,
                observation: None,
                uncertainty: None,
            },
        )?;
        say(format!("{}: {}", case.name, case.description));
        for line in report.summary("  ") {
            say(line);
        }
        reports.push(CaseReport {
            name: case.name,
            description: case.description,
            skin,
            folder: dir.display().to_string(),
            picture: picture.display().to_string(),
            iterations: report.iterations,
            seconds: report.seconds,
            converged: report.converged,
            residual: report.residual,
            max_displacement_mm: report.max_displacement_mm,
            structures: report.structures,
        });
    }

    let summary = DemoReport {
        particles: model.len(),
        backend: solver.backend(),
        sampling: sampled.report,
        cases: reports,
        seconds: started.elapsed().as_secs_f64(),
    };
    write_json(&out.join(DEMO_FILE), &summary)?;
    say(format!(
        "wrote {}: model.vtp, breast.obj, tumour.obj, breast-sag.obj, breast-indentation.obj,\n  \
         sag/ and indentation/ (particles.vtp, tumour.obj, tumour-rigid.obj, tumour-rigid.tfm, report.json),\n  \
         {DEMO_FILE}, {DEMO_PICTURE} and demo-indentation.png (a cut coloured by displacement, the tumour at rest and moved)",
        folder(out)
    ));
    say(format!(
        "  to look: {picture}; or open {sag}particles.vtp in ParaView and colour by \
         displacement, with {rest} (rest) beside {sag}tumour.obj (moved)",
        picture = out.join(DEMO_PICTURE).display(),
        sag = folder(&out.join("sag")),
        rest = out.join("tumour.obj").display(),
    ));
    say(format!("done in {:.2} s", summary.seconds));
    Ok(())
}

/// `dir/` as the user typed it.
fn folder(dir: &Path) -> String {
    format!("{}/", dir.display())
}
