//! `--gravity-rest`, `--gravity-deformed` and their options: the
//! organ's unloaded shape and its stiffness from the two postures, made
//! once per run ([`tissue::gravity`]), and what the report says of them.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, anyhow};
use clap::ValueEnum;
use glam::Vec3;
use indicatif::ProgressBar;
use serde::Serialize;
use tissue::backend::{Device, Solver};
use tissue::deformation::{DeformParams, PrepareStage};
use tissue::gravity::{
    FIT_BOUNDS_KPA, FIT_PARTICLES, Gravity, HELD_SPACINGS, SolveProgress, Unloaded, held_vertices,
    unload,
};
use tissue::{ParticleModel, SurfaceMesh};

use crate::progress;
use crate::solve::read_observed;

/// The length unit of the model and its surfaces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Unit {
    /// Millimetres (3D Slicer's, and the bundled phantom's).
    Mm,
    /// Centimetres.
    Cm,
    /// Metres.
    M,
}

impl Unit {
    /// The unit in metres.
    pub fn metres(self) -> f32 {
        match self {
            Unit::Mm => 1e-3,
            Unit::Cm => 1e-2,
            Unit::M => 1.0,
        }
    }
}

/// The posture options shared by `deform` and `track`.
#[derive(Debug, Clone, Default, clap::Args, Serialize)]
pub struct GravityArgs {
    /// Gravity in the rest scan (the model's posture), in units of g and in
    /// the surface file's axes: `0,0,-1` pulls along -z. With
    /// --gravity-deformed, the organ's unloaded shape is found from the
    /// rest scan and its gravity (the held region fixed, the rest of the
    /// skin free), and the deformed posture is solved from it with its own
    /// gravity inside (docs/METHOD.md, "Gravity and the unloaded shape").
    /// Implies `--force elastic`.
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_parser = parse_vector,
        allow_hyphen_values = true,
        requires = "gravity_deformed"
    )]
    pub gravity_rest: Option<Vec3>,
    /// Gravity in the deformed scan, in units of g, in the same axes.
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_parser = parse_vector,
        allow_hyphen_values = true,
        requires = "gravity_rest"
    )]
    pub gravity_deformed: Option<Vec3>,
    /// The tissue's density in kg/m^3 (default 1000, soft tissue).
    #[arg(
        long,
        value_name = "KG_M3",
        allow_negative_numbers = true,
        requires = "gravity_rest"
    )]
    pub density: Option<f32>,
    /// The tissue's Young's modulus in kPa. Without it, it is fitted so
    /// that the deformed posture's gravity, the skin free, best gives the
    /// observed deformed skin (the report gives the fit and its residual).
    #[arg(
        long,
        value_name = "KPA",
        allow_negative_numbers = true,
        requires = "gravity_rest"
    )]
    pub stiffness: Option<f32>,
    /// The surface's held region, which does not move between the scans
    /// (the chest wall), with the posture options or an observation without
    /// correspondence: `auto` (default) takes the vertices that move less
    /// than a thousandth of a particle spacing between the rest and the
    /// deformed surface (for another segmentation's surface, those within
    /// 0.02 spacings of it); or a file, as --observed takes one (a surface
    /// file of the patch, or its vertices as points). A scan (--cloud)
    /// needs the file.
    #[arg(long, value_name = "auto|FILE")]
    pub fixed_region: Option<String>,
    /// The length unit of the model and the surfaces, for gravity's load
    /// (default mm).
    #[arg(long, value_enum, requires = "gravity_rest")]
    pub unit: Option<Unit>,
    /// Fit the stiffness on a model of this many particles sampled on the
    /// same surface (default 4000), then find the model's own unloaded
    /// shape at that stiffness: several times faster than fitting on the
    /// model, the same stiffness within a few per cent (docs/METHOD.md).
    /// 0, or a model with fewer than twice as many: fit on the model
    /// itself.
    #[arg(
        long,
        value_name = "N",
        requires = "gravity_rest",
        conflicts_with = "stiffness"
    )]
    pub fit_particles: Option<usize>,
}

impl GravityArgs {
    /// Whether the gravity options were given.
    pub fn given(&self) -> bool {
        self.gravity_rest.is_some()
    }
}

/// `X,Y,Z`: three numbers.
fn parse_vector(text: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let numbers: Vec<f32> = parts
        .iter()
        .map(|p| p.parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{text}`: expected three numbers X,Y,Z (e.g. 0,0,-1)"))?;
    match numbers[..] {
        [x, y, z] if numbers.iter().all(|v| v.is_finite()) => Ok(Vec3::new(x, y, z)),
        [_, _, _] => Err(format!("`{text}`: the numbers must be finite")),
        _ => Err(format!(
            "`{text}`: expected three numbers X,Y,Z, got {}",
            numbers.len()
        )),
    }
}

/// The held region in the report.
#[derive(Debug, Clone, Serialize)]
pub struct HeldReport {
    /// Held vertices.
    pub vertices: usize,
    /// Vertices of the surface.
    pub of: usize,
    /// `auto`, or the file it was read from.
    pub from: String,
}

/// The two postures in the report.
#[derive(Debug, Clone, Serialize)]
pub struct GravityReport {
    /// The rest scan's gravity, units of g.
    pub rest: [f32; 3],
    /// The deformed scan's.
    pub deformed: [f32; 3],
    /// The change between them, units of g.
    pub change: f32,
    /// The tissue's density, kg/m^3.
    pub density_kg_m3: f32,
    /// The model's length unit.
    pub unit: Unit,
    /// The held region.
    pub held: HeldReport,
}

/// One stiffness the fit tried.
#[derive(Debug, Clone, Serialize)]
pub struct TrialReport {
    /// Young's modulus, kPa.
    pub stiffness_kpa: f32,
    /// The free skin's RMS distance from the observed one (model units;
    /// `null` where a solve did not converge).
    pub residual_mm: Option<f32>,
}

/// What the report says of the postures (top-level fields of
/// `report.json` and of `track.json`'s plan).
#[derive(Debug, Clone, Serialize)]
pub struct PostureReport {
    /// The postures and the held region.
    pub gravity: GravityReport,
    /// Young's modulus the deformed posture was solved with, kPa (`null`:
    /// gravity does not change, and nothing was loaded).
    pub stiffness_kpa: Option<f32>,
    /// Whether it was fitted from the skin (else given by `--stiffness`).
    pub stiffness_fitted: bool,
    /// The fit's residual: the free skin's RMS distance from the observed
    /// one at the fitted stiffness (model units).
    pub fit_residual_mm: Option<f32>,
    /// Every stiffness the fit tried, in order.
    pub fit_trials: Vec<TrialReport>,
    /// The particles of the model the fit ran on (`--fit-particles`, or the
    /// model's own).
    pub fit_particles: Option<usize>,
    /// How far the free skin moved between the scans: the RMS distance of
    /// its (observed) vertices from rest to deformed (model units), the
    /// scale the fit's residual is judged against.
    pub skin_motion_mm: Option<f32>,
    /// The unloaded shape, loaded again with the rest posture's gravity:
    /// its RMS distance from the rest surface particles (model units).
    pub unloaded_residual_mm: Option<f32>,
    /// Whether that is within 0.1 mm with every solve converged.
    pub unloaded_converged: bool,
    /// Stage-2 solves the unloaded shape and the fit made.
    pub solves: usize,
    /// Over those solves, the elastic phases gone on from where they
    /// stopped short (stalled, or out of steps back), in all.
    pub posture_elastic_retries: usize,
    /// Over those solves, the energy watch's steps back, in all.
    pub posture_backtracks: usize,
    /// Seconds the unloaded shape and the fit took, the coarse model's
    /// sampling included (the solve's own are `seconds`).
    pub posture_seconds: f64,
    /// With an observation without correspondence, the error estimate
    /// (a fraction of the model's size) of the match without gravity the
    /// fit read the skin from, where it stopped short of its answer (at
    /// the float floor or stalled); absent where it converged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_match_short: Option<f32>,
}

impl PostureReport {
    /// What makes a fit implausible, one line each (empty when nothing
    /// does): a fitted stiffness on a bound of the search
    /// ([`FIT_BOUNDS_KPA`]: no stiffness in it explains the skin), or a
    /// fit whose free skin misses the observed by more than the skin moved
    /// (the gravity, density or units do not explain the deformation).
    pub fn flags(&self) -> Vec<String> {
        let mut flags = Vec::new();
        let (low, high) = FIT_BOUNDS_KPA;
        if let (true, Some(e)) = (self.stiffness_fitted, self.stiffness_kpa)
            && (e <= low * (1.0 + BOUND_SHARE) || e >= high * (1.0 - BOUND_SHARE))
        {
            flags.push(format!(
                "the stiffness fit ended at its bound ({e:.3} kPa of {low} to {high}): no \
                 stiffness explains the skin with this gravity, density ({} kg/m^3) and unit \
                 ({:?}); check them",
                self.gravity.density_kg_m3, self.gravity.unit
            ));
        }
        if let Some(short) = self.first_match_short {
            flags.push(format!(
                "the match without gravity that the stiffness was fitted from stopped short of \
                 its answer (error estimate {short:.1e} of the size; `first_match_short`), as a \
                 sparse scan's may: the fit, and the answer from it, are not final"
            ));
        }
        if let (true, Some(fit), Some(motion)) = (
            self.stiffness_fitted,
            self.fit_residual_mm,
            self.skin_motion_mm,
        ) && fit > motion
        {
            flags.push(format!(
                "the fit's free skin is {fit:.2} mm RMS from the observed, more than the skin \
                 moved between the scans ({motion:.2} mm RMS): the postures' gravity does not \
                 explain the deformed skin; check --gravity-rest and --gravity-deformed (their \
                 directions, in the surfaces' axes)"
            ));
        }
        flags
    }
}

/// A fitted stiffness within this share of a bound of [`FIT_BOUNDS_KPA`]
/// is on the bound.
const BOUND_SHARE: f32 = 0.01;

/// A `--fixed-region` file's vertices may move this many mean connection
/// lengths between the scans: a held region does not move.
pub const HELD_FILE_SPACINGS: f32 = 0.1;

/// A posture's gravity farther than this from 1 g in length is said to be
/// (a warning): gravity is given in units of g, and a direction written
/// without normalising it (`0,-1,-1` for 45 degrees, 1.41 g) loads the
/// tissue as given.
pub const GRAVITY_G_SLACK: f32 = 0.1;

/// Refuses a held region (`held`, one flag per surface vertex) whose
/// vertices move between `rest` and `deformed` by more than
/// [`HELD_FILE_SPACINGS`] of `spacing`.
fn check_held(
    held: &[bool],
    rest: &SurfaceMesh,
    deformed: &SurfaceMesh,
    spacing: f32,
) -> Result<()> {
    let tolerance = HELD_FILE_SPACINGS * spacing;
    let moved: Vec<f32> = held
        .iter()
        .zip(rest.vertices.iter().zip(&deformed.vertices))
        .filter(|(h, _)| **h)
        .map(|(_, (a, b))| a.distance(*b))
        .filter(|&d| d > tolerance)
        .collect();
    if !moved.is_empty() {
        anyhow::bail!(
            "{} of its vertices move between the rest and the deformed surface, up to {:.2} \
             (more than {tolerance:.3}, a tenth of the particle spacing): a held region does \
             not move; give the surface that stays in place (the chest wall), or auto",
            moved.len(),
            moved.iter().copied().fold(0.0, f32::max)
        );
    }
    Ok(())
}

/// The RMS distance the free skin moved from `rest` to `deformed`: the
/// vertices not `held` and, where `observed` says, observed; `None` when
/// there are none.
fn skin_motion(
    rest: &SurfaceMesh,
    deformed: &SurfaceMesh,
    held: &[bool],
    observed: Option<&[bool]>,
) -> Option<f32> {
    let (sum, count) = rest
        .vertices
        .iter()
        .zip(&deformed.vertices)
        .enumerate()
        .filter(|(v, _)| !held.get(*v).copied().unwrap_or(true))
        .filter(|(v, _)| observed.is_none_or(|o| o.get(*v).copied().unwrap_or(false)))
        .fold((0.0_f64, 0_usize), |(s, n), (_, (a, b))| {
            (s + f64::from(a.distance_squared(*b)), n + 1)
        });
    (count > 0).then(|| (sum / count as f64).sqrt() as f32)
}

/// What the postures give the solve: the unloaded shape, where gravity
/// changes or the stiffness is given, and the report.
#[derive(Debug, Clone)]
pub struct Posture {
    /// The unloaded shape and the deformed posture's load; `None` where
    /// gravity does not change and no stiffness was given (solved as
    /// without gravity).
    pub unloaded: Option<Unloaded>,
    /// What the report says.
    pub report: PostureReport,
}

impl Posture {
    /// The solver of the deformed posture: stress-free in the unloaded
    /// shape with the deformed posture's gravity inside, or, without one,
    /// the model's own (`params` gains the load); `progress` hears each stage
    /// of the preparation.
    pub fn solver(
        &self,
        device: Device,
        model: &ParticleModel,
        params: &mut DeformParams,
        progress: &mut dyn FnMut(PrepareStage),
    ) -> Result<Solver> {
        Ok(match &self.unloaded {
            Some(unloaded) => {
                params.load = unloaded.deformed_load;
                Solver::unloaded_with_progress(
                    device,
                    model,
                    &unloaded.shape.positions,
                    params.clone(),
                    progress,
                )?
            }
            None => Solver::new_with_progress(device, model, params.clone(), progress)?,
        })
    }

    /// Starts `solver`'s next solve from where the fit put the deformed
    /// posture ([`Unloaded::deformed_guess`]), where it has a guess: called
    /// after the posture's own deformed surface is set, before its solve.
    pub fn warm_start(&self, solver: &mut Solver) -> Result<()> {
        if let Some(guess) = self
            .unloaded
            .as_ref()
            .and_then(|u| u.deformed_guess.as_ref())
        {
            solver
                .warm_start(guess)
                .map_err(|e| anyhow!("the deformed posture's start: {e}"))?;
        }
        Ok(())
    }

    /// Lines for the terminal.
    pub fn summary(&self, indent: &str) -> Vec<String> {
        let r = &self.report;
        let mut lines = vec![format!(
            "{indent}gravity {:?} g at rest, {:?} g deformed ({:.2} g change); held region {} of {} \
             surface vertices ({})",
            r.gravity.rest,
            r.gravity.deformed,
            r.gravity.change,
            r.gravity.held.vertices,
            r.gravity.held.of,
            r.gravity.held.from
        )];
        match (r.stiffness_kpa, r.unloaded_residual_mm) {
            (Some(e), Some(residual)) => {
                lines.push(format!(
                    "{indent}stiffness {e:.3} kPa ({}); unloaded shape {} (loaded again, {residual:.3} \
                     mm RMS from the rest surface), {} solves in {:.1} s{}",
                    match r.fit_residual_mm {
                        Some(fit) => format!(
                            "fitted in {} trials on {} particles, free skin {fit:.3} mm from the \
                             observed",
                            r.fit_trials.len(),
                            r.fit_particles.unwrap_or_default()
                        ),
                        None => "given".to_owned(),
                    },
                    if r.unloaded_converged {
                        "found"
                    } else {
                        "NOT found within 0.1 mm"
                    },
                    r.solves,
                    r.posture_seconds,
                    match (r.posture_elastic_retries, r.posture_backtracks) {
                        (0, 0) => String::new(),
                        (0, back) => format!(
                            " (their elastic phases stepped back {back} times: \
                             `posture_backtracks`)"
                        ),
                        (retries, 0) => format!(
                            " (their elastic phases went on from where they stopped short \
                             {retries} times: `posture_elastic_retries`)"
                        ),
                        (retries, back) => format!(
                            " (their elastic phases went on from where they stopped short \
                             {retries} times and stepped back {back} times: \
                             `posture_elastic_retries`, `posture_backtracks`)"
                        ),
                    }
                ));
            }
            _ => lines.push(format!(
                "{indent}gravity does not change between the postures: no load to fit; solved as \
                 without gravity"
            )),
        }
        lines
    }
}

/// The postures `args` gives, for `model` (its positions the rest scan)
/// and the deformed surface `deformed` (the fit's observed skin), on
/// `device`; `None` without the gravity options. `params` is the elastic
/// force's (with `--observed`'s mask where given). A spinner counts the
/// solves on a terminal, unless `quiet`.
pub fn prepare(
    args: &GravityArgs,
    device: &Device,
    model: &ParticleModel,
    deformed: &SurfaceMesh,
    params: &DeformParams,
    quiet: bool,
) -> Result<Option<Posture>> {
    let (Some(rest), Some(deformed_gravity)) = (args.gravity_rest, args.gravity_deformed) else {
        return Ok(None);
    };
    let unit = args.unit.unwrap_or(Unit::Mm);
    let gravity = Gravity {
        rest,
        deformed: deformed_gravity,
        density_kg_m3: args.density.unwrap_or(1000.0),
        stiffness_kpa: args.stiffness,
        metres_per_unit: unit.metres(),
        fit_particles: match args.fit_particles {
            None => Some(FIT_PARTICLES),
            Some(0) => None,
            Some(n) => Some(n),
        },
    };
    gravity
        .validate()
        .map_err(|e| anyhow!("the posture options: {e}"))?;
    for (option, g) in [
        ("--gravity-rest", rest),
        ("--gravity-deformed", deformed_gravity),
    ] {
        let length = g.length();
        if (length - 1.0).abs() > GRAVITY_G_SLACK {
            log::warn!(
                "{option} is {length:.2} g long, where a posture's gravity is 1 g (its \
                 direction as a unit vector: 0,0,-1 along -z, 0,-0.707,-0.707 at 45 degrees); \
                 the tissue is loaded as given"
            );
        }
    }
    let (held, from) = match args.fixed_region.as_deref() {
        None | Some("auto") => {
            let tolerance = HELD_SPACINGS * model.mean_connection_length();
            let held = held_vertices(&model.surface, deformed, tolerance).ok_or_else(|| {
                anyhow!("the deformed surface has other vertices than the model's rest surface")
            })?;
            (held, "auto".to_owned())
        }
        Some(file) => {
            let path = Path::new(file);
            let held = read_observed(path, &model.surface)
                .with_context(|| format!("--fixed-region {file}"))?;
            check_held(
                &held,
                &model.surface,
                deformed,
                model.mean_connection_length(),
            )
            .with_context(|| format!("--fixed-region {file}"))?;
            (held, file.to_owned())
        }
    };
    let held_count = held.iter().filter(|&&h| h).count();
    if held_count == 0 {
        anyhow::bail!(
            "no surface vertex is held between the two scans (--fixed-region auto found none \
             that moved less than {:.2e}): the unloaded shape needs the surface that does not \
             move, e.g. the chest wall; give it with --fixed-region FILE",
            HELD_SPACINGS * model.mean_connection_length()
        );
    }
    let skin_motion_mm = skin_motion(&model.surface, deformed, &held, params.observed.as_deref());
    let gravity_report = GravityReport {
        rest: rest.to_array(),
        deformed: deformed_gravity.to_array(),
        change: (deformed_gravity - rest).length(),
        density_kg_m3: gravity.density_kg_m3,
        unit,
        held: HeldReport {
            vertices: held_count,
            of: held.len(),
            from,
        },
    };
    if !gravity.changes() && gravity.stiffness_kpa.is_none() {
        log::warn!(
            "gravity does not change between the postures ({rest} and {deformed_gravity} g): the \
             skin says nothing about the stiffness, and no load is fitted; solving as without \
             gravity (give --stiffness to solve from the unloaded shape anyway)"
        );
        return Ok(Some(Posture {
            unloaded: None,
            report: PostureReport {
                gravity: gravity_report,
                stiffness_kpa: None,
                stiffness_fitted: false,
                fit_residual_mm: None,
                fit_trials: Vec::new(),
                fit_particles: None,
                skin_motion_mm,
                unloaded_residual_mm: None,
                unloaded_converged: true,
                solves: 0,
                posture_elastic_retries: 0,
                posture_backtracks: 0,
                posture_seconds: 0.0,
                first_match_short: None,
            },
        }));
    }
    let started = Instant::now();
    let mut bar: Option<ProgressBar> = None;
    let mut progress = |p: &SolveProgress| {
        if quiet {
            return;
        }
        let bar = bar.get_or_insert_with(|| {
            progress::bar(
                "{spinner} the unloaded shape and the stiffness: solve {pos} ({elapsed}), {msg}",
                None,
            )
        });
        bar.set_position(p.solve as u64);
        bar.set_message(format!(
            "the last {} iterations{}",
            p.iterations,
            if p.converged { "" } else { ", not converged" }
        ));
    };
    let unloaded = unload(
        device,
        model,
        deformed,
        &held,
        &gravity,
        params,
        &mut progress,
    )
    .map_err(|e| anyhow!("the organ's unloaded shape: {e}"));
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let unloaded = unloaded?;
    let report = PostureReport {
        gravity: gravity_report,
        stiffness_kpa: Some(unloaded.stiffness_kpa),
        stiffness_fitted: unloaded.fit.is_some(),
        fit_residual_mm: unloaded.fit.as_ref().map(|f| f.residual),
        fit_trials: unloaded
            .fit
            .iter()
            .flat_map(|f| &f.trials)
            .map(|t| TrialReport {
                stiffness_kpa: t.stiffness_kpa,
                residual_mm: t.residual.is_finite().then_some(t.residual),
            })
            .collect(),
        fit_particles: unloaded.fit.as_ref().map(|f| f.particles),
        skin_motion_mm,
        unloaded_residual_mm: Some(unloaded.shape.residual),
        unloaded_converged: unloaded.shape.converged,
        solves: unloaded.solves,
        posture_elastic_retries: unloaded.elastic_retries,
        posture_backtracks: unloaded.backtracks,
        posture_seconds: started.elapsed().as_secs_f64(),
        first_match_short: None,
    };
    Ok(Some(Posture {
        unloaded: Some(unloaded),
        report,
    }))
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests")]
mod tests {
    use super::*;

    #[test]
    fn vectors_parse_as_three_finite_numbers() {
        assert_eq!(parse_vector("0,0,-1"), Ok(Vec3::NEG_Z));
        assert_eq!(parse_vector(" 1, 0.5 ,0"), Ok(Vec3::new(1.0, 0.5, 0.0)));
        for bad in ["0,0", "0,0,0,1", "x,0,0", "0,0,inf", ""] {
            let err = parse_vector(bad).unwrap_err();
            assert!(err.contains(bad) || bad.is_empty(), "{bad}: {err}");
        }
    }

    #[test]
    fn units_are_in_metres() {
        assert_eq!(Unit::Mm.metres(), 1e-3);
        assert_eq!(Unit::Cm.metres(), 1e-2);
        assert_eq!(Unit::M.metres(), 1.0);
    }

    /// A fit is flagged when its stiffness lies on a bound of the search,
    /// its free skin misses the observed by more than the skin moved, or
    /// the match without gravity it read the skin from stopped short; a
    /// given stiffness, or a fit inside the bounds that explains the skin,
    /// is not.
    #[test]
    fn a_fit_on_a_bound_or_missing_the_skin_is_flagged() {
        let report = |stiffness: f32, fitted: bool, fit: f32, motion: f32| PostureReport {
            gravity: GravityReport {
                rest: [0.0, 0.0, -1.0],
                deformed: [0.0, -1.0, 0.0],
                change: 2f32.sqrt(),
                density_kg_m3: 1000.0,
                unit: Unit::Mm,
                held: HeldReport {
                    vertices: 10,
                    of: 100,
                    from: "auto".into(),
                },
            },
            stiffness_kpa: Some(stiffness),
            stiffness_fitted: fitted,
            fit_residual_mm: fitted.then_some(fit),
            fit_trials: Vec::new(),
            fit_particles: None,
            skin_motion_mm: Some(motion),
            unloaded_residual_mm: Some(0.01),
            unloaded_converged: true,
            solves: 8,
            posture_elastic_retries: 0,
            posture_backtracks: 0,
            posture_seconds: 1.0,
            first_match_short: None,
        };
        let (low, high) = FIT_BOUNDS_KPA;
        assert!(report(3.0, true, 0.2, 5.0).flags().is_empty());
        assert!(
            report(low, false, 0.0, 5.0).flags().is_empty(),
            "given, not fitted"
        );
        for bound in [low, high] {
            let flags = report(bound, true, 0.2, 5.0).flags();
            assert_eq!(flags.len(), 1, "{flags:?}");
            assert!(flags[0].contains("ended at its bound"), "{flags:?}");
        }
        let flags = report(3.0, true, 6.0, 5.0).flags();
        assert!(
            flags.len() == 1 && flags[0].contains("more than the skin moved"),
            "{flags:?}"
        );
        // Fitted from a match without gravity that stopped short of its
        // answer: flagged, naming its error estimate.
        let mut short = report(3.0, true, 0.2, 5.0);
        short.first_match_short = Some(5e-3);
        let flags = short.flags();
        assert!(
            flags.len() == 1 && flags[0].contains("stopped short") && flags[0].contains("5.0e-3"),
            "{flags:?}"
        );
    }
}
