//! `--uncertainty`: how sure the answer is. The solve is repeated from the
//! answer over what the program does not know (`tissue::uncertainty`);
//! each particle, landmark and structure centroid gets a 95 % region.

use std::collections::BTreeMap;

use anyhow::{Context, Result};
use glam::Vec3;
use serde::Serialize;
use tissue::SurfaceMesh;
use tissue::observation::HeldObservation;
use tissue::uncertainty::{
    Answered, Explorer, GRAVITY_DEGREES, HeldBy, LOAD_SPREAD, POSTURE_G, Priors, Refresh, Region,
    SURFACE_CORRELATION_MM, SURFACE_NOISE_MM, Spread, Unknown, exact_vertices,
};
use tissue::{ParticleModel, gravity::Unloaded};

use crate::backend::Solver;
use crate::carry::{Carried, Carriers};
use crate::progress;

/// The particle array and the points' column the radius is written under.
pub const RADIUS_NAME: &str = "uncertainty_95";

/// Options of the uncertainty, shared by the commands that solve.
#[derive(Debug, Clone, clap::Args)]
pub struct UncertaintyArgs {
    /// Also say how sure the answer is: the solve repeated from the answer
    /// over the Poisson ratio's range, the observed surface's error
    /// (SAMPLES samples, default 16) and, with the posture options, the
    /// load's scale and each posture's gravity direction
    /// (docs/METHOD.md, "Uncertainty"). Each landmark and structure
    /// centroid gets a 95 % region in the report, points.csv a column
    /// `uncertainty_95` (the region's radius) and particles.vtp an array
    /// of it.
    #[arg(long, value_name = "SAMPLES", num_args = 0..=1,
          default_missing_value = "16")]
    pub uncertainty: Option<usize>,
    /// With --uncertainty: the observed surface's error along its normals,
    /// standard deviation in the model's units (0: exact).
    #[arg(long, value_name = "MM", default_value_t = SURFACE_NOISE_MM, requires = "uncertainty")]
    pub surface_noise: f32,
    /// With --uncertainty: the surface error's correlation length, in the
    /// model's units.
    #[arg(long, value_name = "MM", default_value_t = SURFACE_CORRELATION_MM,
          requires = "uncertainty")]
    pub surface_correlation: f32,
    /// With --uncertainty: the Poisson ratio's range (uniform), LO,HI.
    #[arg(long, value_name = "LO,HI", value_parser = parse_range,
          default_value = "0.45,0.495", requires = "uncertainty")]
    pub poisson_range: (f32, f32),
    /// With --uncertainty and the posture options: the load's relative
    /// standard deviation (density and stiffness).
    #[arg(long, value_name = "FRACTION", default_value_t = LOAD_SPREAD,
          requires = "uncertainty")]
    pub load_spread: f32,
    /// With --uncertainty and the posture options: each posture's gravity
    /// direction's standard deviation about each axis across it, degrees.
    #[arg(long, value_name = "DEGREES", default_value_t = GRAVITY_DEGREES,
          requires = "uncertainty")]
    pub gravity_spread: f32,
    /// With --uncertainty and without the posture options: the RMS change
    /// of gravity between the scans that the solve did not model, in g,
    /// acting on tissue of the library's stiffness (2 kPa), over the
    /// Poisson ratio's range; default sqrt(2) (either scan's gravity in
    /// any direction); 0 where the posture did not change.
    #[arg(long, value_name = "G", default_value_t = POSTURE_G, requires = "uncertainty")]
    pub posture_spread: f32,
}

/// The CLI's models are in millimetres.
const MILLIMETRE: f32 = 1e-3;

/// `LO,HI`: two numbers.
fn parse_range(text: &str) -> Result<(f32, f32), String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    match parts[..] {
        [lo, hi] => match (lo.parse(), hi.parse()) {
            (Ok(lo), Ok(hi)) => Ok((lo, hi)),
            _ => Err(format!("`{text}`: two numbers LO,HI")),
        },
        _ => Err(format!("`{text}`: two numbers LO,HI")),
    }
}

impl UncertaintyArgs {
    /// The priors asked for, checked; `None` without `--uncertainty`.
    pub fn priors(&self) -> Result<Option<Priors>> {
        let Some(samples) = self.uncertainty else {
            return Ok(None);
        };
        let priors = Priors::default().with(|p| {
            p.samples = samples;
            p.surface_noise = self.surface_noise;
            p.surface_correlation = self.surface_correlation;
            p.poisson = self.poisson_range;
            p.load_spread = self.load_spread;
            p.gravity_degrees = self.gravity_spread;
            p.posture_g = self.posture_spread;
        });
        priors.validate().context("--uncertainty")?;
        Ok(Some(priors))
    }
}

/// A solve's answer, for its spread.
#[derive(Clone, Copy)]
pub struct Answer<'a> {
    /// Whether the solve converged (no spread is made of one that did not).
    pub converged: bool,
    /// The deformed surface it followed: the rest surface with moved
    /// vertices.
    pub deformed: &'a SurfaceMesh,
    /// With the posture options, the unloaded shape and the loads.
    pub unloaded: Option<&'a Unloaded>,
    /// For an observation without correspondence, the observation as
    /// the skin was paired with it at the answer.
    pub held_by: Option<&'a HeldObservation>,
}

/// With an explorer (`--uncertainty`), the spread of the converged answer
/// `solver` holds; `None` without one or where the solve did not
/// converge. The solver is left at its answer.
pub fn spread_after(
    explorer: Option<&mut Explorer>,
    answer: Answer<'_>,
    solver: &mut Solver,
    model: &ParticleModel,
    quiet: bool,
) -> Result<Option<Spread>> {
    let Some(explorer) = explorer.filter(|_| answer.converged) else {
        return Ok(None);
    };
    let exact = exact_vertices(&model.surface, answer.deformed);
    let answered = Answered {
        surface: answer.deformed,
        exact: &exact,
        rest_load: answer.unloaded.map(|u| u.rest_load),
        metres_per_unit: MILLIMETRE,
        held_by: answer.held_by.map(|h| h as &dyn HeldBy),
    };
    progress::busy(quiet, "the uncertainty's solves", |_| {
        explorer.explore(solver, model, answered)
    })
    .context("the uncertainty's solves")
    .map(Some)
}

/// [`spread_after`], and the regions of its particles and of `carried`'s
/// targets.
pub fn regions_after(
    mut explorer: Option<&mut Explorer>,
    answer: Answer<'_>,
    (solver, model): (&mut Solver, &ParticleModel),
    carried: &Carried,
    quiet: bool,
) -> Result<Option<Uncertainty>> {
    let spread = spread_after(explorer.as_deref_mut(), answer, solver, model, quiet)?;
    Ok(spread
        .zip(explorer)
        .map(|(spread, explorer)| Uncertainty::of(&spread, explorer.priors(), carried)))
}

/// One target's region as the report holds it (model units).
#[derive(Debug, Clone, Serialize)]
pub struct TargetRegion {
    /// Within this distance of the answer with probability 0.95.
    pub radius_mm: f32,
    /// The 95 % ellipsoid's semi-axes, largest first.
    pub semi_axes_mm: [f32; 3],
    /// Their directions.
    pub axes: [[f32; 3]; 3],
    /// The covariance: xx, yy, zz, xy, xz, yz.
    pub covariance_mm2: [f64; 6],
    /// The unknown the spread owes most to (`null`: no spread).
    pub dominant: Option<Unknown>,
    /// Each unknown's share of the variance.
    pub shares: BTreeMap<&'static str, f32>,
}

impl From<&Region> for TargetRegion {
    fn from(region: &Region) -> Self {
        Self {
            radius_mm: region.radius,
            semi_axes_mm: region.semi_axes,
            axes: region.axes.map(|a| a.to_array()),
            covariance_mm2: region.covariance,
            dominant: region.dominant,
            shares: Unknown::ALL
                .iter()
                .map(|u| (u.name(), region.shares[u.index()]))
                .collect(),
        }
    }
}

/// A structure's centroid's region.
#[derive(Debug, Clone, Serialize)]
pub struct StructureRegion {
    /// The structure's output file name.
    pub name: String,
    /// Its centroid's region.
    pub centroid: TargetRegion,
}

/// The particles' regions in brief.
#[derive(Debug, Clone, Serialize)]
pub struct ParticleSpread {
    /// The median radius.
    pub median_radius_mm: f32,
    /// The largest radius.
    pub max_radius_mm: f32,
    /// How many particles each unknown dominates.
    pub dominant: BTreeMap<&'static str, usize>,
}

/// The report's `uncertainty`.
#[derive(Debug, Clone, Serialize)]
pub struct UncertaintyReport {
    /// The priors the solves drew from.
    pub priors: Priors,
    /// Stage-2 solves made.
    pub solves: usize,
    /// Re-solves carried from an earlier frame instead (`track
    /// --uncertainty-refresh`).
    #[serde(skip_serializing_if = "is_zero")]
    pub carried: usize,
    /// Their iterations.
    pub iterations: usize,
    /// Whether every one converged.
    pub converged: bool,
    /// Wall-clock seconds, the other Poisson ratios' preparation included.
    pub seconds: f64,
    /// The particles' regions in brief.
    pub particles: ParticleSpread,
    /// Each landmark point's region, in input order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub points: Vec<TargetRegion>,
    /// Each structure's centroid's region.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub structures: Vec<StructureRegion>,
}

/// What the outputs take from a spread: every particle's radius, the
/// points' radii, the report.
#[derive(Debug, Clone)]
pub struct Uncertainty {
    /// Each particle's 95 % radius.
    pub particle_radii: Vec<f32>,
    /// Each landmark point's 95 % radius.
    pub point_radii: Option<Vec<f32>>,
    /// Each structure's centroid in the answer, its covariance and a line
    /// that says it, for the picture.
    pub centroids: Vec<(Vec3, [f64; 6], String)>,
    /// The report's section.
    pub report: UncertaintyReport,
}

impl Uncertainty {
    /// The regions of `spread`'s particles and of `carried`'s targets.
    pub fn of(spread: &Spread, priors: &Priors, carried: &Carried) -> Self {
        let particles = spread.particle_regions();
        let particle_radii: Vec<f32> = particles.iter().map(|r| r.radius).collect();
        let mut sorted = particle_radii.clone();
        sorted.sort_by(f32::total_cmp);
        let mut dominant = BTreeMap::new();
        for region in &particles {
            if let Some(u) = region.dominant {
                *dominant.entry(u.name()).or_insert(0) += 1;
            }
        }
        let (points, structures) = carried.target_carriers();
        let carried_by = |carriers: &[Carriers]| {
            spread.regions(&|positions: &[Vec3]| {
                carriers
                    .iter()
                    .map(|c| c.iter().map(|&(j, w)| w * positions[j as usize]).sum())
                    .collect()
            })
        };
        let point_regions = points.as_deref().map(carried_by);
        let centre = |carriers: &Carriers| -> Vec3 {
            carriers
                .iter()
                .map(|&(j, w)| w * spread.answer[j as usize])
                .sum()
        };
        let mut centroids = Vec::new();
        let structure_regions = structures
            .iter()
            .map(|(name, carriers)| {
                let region = carried_by(std::slice::from_ref(carriers))
                    .pop()
                    .unwrap_or_else(|| Region::of([]));
                centroids.push((
                    centre(carriers),
                    region.covariance,
                    format!(
                        "{name}\nwithin {} (95 %), mostly {}",
                        crate::picture::number(region.radius),
                        region.dominant.map_or("nothing", Unknown::name)
                    ),
                ));
                StructureRegion {
                    name: name.clone(),
                    centroid: TargetRegion::from(&region),
                }
            })
            .collect();
        Self {
            particle_radii,
            point_radii: point_regions
                .as_ref()
                .map(|r| r.iter().map(|r| r.radius).collect()),
            centroids,
            report: UncertaintyReport {
                priors: priors.clone(),
                solves: spread.solves,
                carried: spread.carried,
                iterations: spread.iterations,
                converged: spread.converged,
                seconds: spread.seconds,
                particles: ParticleSpread {
                    median_radius_mm: sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
                    max_radius_mm: sorted.last().copied().unwrap_or(0.0),
                    dominant,
                },
                points: point_regions
                    .iter()
                    .flatten()
                    .map(TargetRegion::from)
                    .collect(),
                structures: structure_regions,
            },
        }
    }
}

impl UncertaintyReport {
    /// What is wrong with the estimate, if anything.
    pub fn flags(&self) -> Vec<String> {
        if self.converged {
            Vec::new()
        } else {
            vec![
                "not every solve of the uncertainty converged (`uncertainty.converged` in the \
                 report): its regions are not to be trusted"
                    .into(),
            ]
        }
    }

    /// The lines the command prints.
    pub fn summary(&self, indent: &str) -> Vec<String> {
        let mut lines = vec![format!(
            "{indent}uncertainty: {} solves in {:.2} s; particles' 95 % radius median {:.3}, \
             largest {:.3}",
            self.solves,
            self.seconds,
            self.particles.median_radius_mm,
            self.particles.max_radius_mm
        )];
        for s in &self.structures {
            lines.push(format!(
                "{indent}  {} centroid: within {:.3} (95 %), mostly {}",
                s.name,
                s.centroid.radius_mm,
                s.centroid.dominant.map_or("nothing", Unknown::name)
            ));
        }
        lines
    }
}

/// `--uncertainty-refresh`: `all`, or a count of at least one.
pub fn parse_refresh(text: &str) -> Result<Refresh, String> {
    match text.trim() {
        "all" => Ok(Refresh::all()),
        count => match count.parse::<usize>() {
            Ok(count) if count >= 1 => Ok(Refresh::every(count)),
            _ => Err(format!(
                "`{text}`: a count of re-solves of at least 1, or `all`"
            )),
        },
    }
}

/// Whether a count is zero (left out of the report).
fn is_zero(count: &usize) -> bool {
    *count == 0
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use tissue::uncertainty::{POISSON_RANGE, SURFACE_SAMPLES};

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        uncertainty: UncertaintyArgs,
    }

    /// `--uncertainty` alone takes the library's priors, samples
    /// included; without it there are none; the priors' options need it
    /// and a range out of order is refused by name.
    #[test]
    fn the_flag_takes_the_library_priors() {
        let parse = |args: &[&str]| Cli::try_parse_from([&["tissue"], args].concat());
        let priors = parse(&["--uncertainty"])
            .ok()
            .and_then(|c| c.uncertainty.priors().ok().flatten());
        assert_eq!(priors, Some(Priors::default()));
        assert_eq!(Priors::default().samples, SURFACE_SAMPLES);
        assert_eq!(Priors::default().poisson, POISSON_RANGE);
        let none = parse(&[]).ok().and_then(|c| c.uncertainty.priors().ok());
        assert_eq!(none, Some(None));
        let more = parse(&["--uncertainty", "32"])
            .ok()
            .and_then(|c| c.uncertainty.priors().ok().flatten());
        assert_eq!(more.map(|p| p.samples), Some(32));
        assert!(parse(&["--surface-noise", "1"]).is_err());
        let reversed = parse(&["--uncertainty", "--poisson-range", "0.49,0.45"])
            .map_err(|e| e.to_string())
            .and_then(|c| c.uncertainty.priors().map_err(|e| format!("{e:#}")));
        assert!(
            reversed.as_ref().is_err_and(|e| e.contains("poisson")),
            "{reversed:?}"
        );
    }

    /// `--uncertainty-refresh` takes a count of at least one, or `all`;
    /// nothing else.
    #[test]
    fn the_refresh_is_a_count_or_all() {
        assert_eq!(parse_refresh("2"), Ok(Refresh::every(2)));
        assert_eq!(parse_refresh(" all "), Ok(Refresh::all()));
        for bad in ["0", "-1", "two", ""] {
            assert!(
                parse_refresh(bad).is_err_and(|e| e.contains("at least 1")),
                "{bad}"
            );
        }
    }
}
