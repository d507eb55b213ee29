//! `tissue deform` with an observation without correspondence: a surface
//! of another triangulation, or a point cloud (`--cloud`), matched by the
//! skin inside the elastic solve (`tissue::observation::match_observation`).

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use serde::Serialize;
use tissue::deformation::StopReason;
use tissue::observation::{
    CleanedScan, Cloud, FiducialFit, HELD_TOLERANCE, MatchParams, MatchReport, Observation,
    SURFACE_NOISE, fiducial_fit, load_cloud,
};
use tissue::{ParticleModel, SurfaceMesh};

/// A residual RMS above this many noise scales flags the result: the
/// model does not reach the observation.
pub const RESIDUAL_FLAG: f32 = 3.0;

/// A change of the organ's volume by more than this share flags the
/// result: soft tissue keeps its volume.
pub const VOLUME_FLAG: f32 = tissue::observation::MAX_VOLUME_CHANGE;

/// What the deformed surface file is to the model.
pub enum Surface {
    /// The rest surface with moved vertices: the correspondence.
    Frame(SurfaceMesh),
    /// Another closed surface of the organ.
    Other(SurfaceMesh),
}

/// Reads `path` as the rest surface's frame where its vertices and
/// triangles are the rest surface's (checked as `read_deformed` does), or
/// else as another closed surface of the organ.
pub fn read_surface(path: &Path, rest: &SurfaceMesh) -> Result<Surface> {
    let written = tissue::load_surface_as_written(path)?;
    let stl = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("stl"));
    let (vertices, triangles) = (written.vertices.len(), written.triangles.len());
    let frame = written.as_frame_of(rest, stl);
    if frame.vertices.len() == rest.vertices.len() && frame.triangles == rest.triangles {
        return Ok(Surface::Frame(crate::solve::read_deformed(path, rest)?));
    }
    let other = tissue::load_closed_surface(path).map_err(|e| {
        anyhow::anyhow!(
            "{}: not the same mesh with moved vertices as the model's rest surface ({} vertices \
             and {} triangles, against {} and {}), and not a closed surface of the organ to match \
             without correspondence: {e}",
            path.display(),
            vertices,
            triangles,
            rest.vertices.len(),
            rest.triangles.len()
        )
    })?;
    Ok(Surface::Other(other))
}

/// The observation of `--cloud`: its points read, checked against the
/// organ's size and place (another unit or frame is refused), its
/// outliers set aside and its noise averaged out (`noise`, or the
/// default), its normals fitted and turned away from the model's inside;
/// first moved by `motion` (`--fiducials`) where given.
pub fn read_cloud(
    path: &Path,
    model: &ParticleModel,
    noise: Option<f32>,
    motion: Option<&FiducialFit>,
) -> Result<Observation> {
    let scan = clean_cloud(path, model, noise, motion)?;
    Observation::of_cleaned(&scan).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// A scan read, checked and cleaned as [`read_cloud`] reads it, without
/// its grid.
pub fn clean_cloud(
    path: &Path,
    model: &ParticleModel,
    noise: Option<f32>,
    motion: Option<&FiducialFit>,
) -> Result<CleanedScan> {
    let cloud = checked_cloud(path, model, motion)?;
    let centre = model.positions.iter().copied().sum::<glam::Vec3>() / model.len() as f32;
    Observation::clean_cloud(&cloud, noise, centre)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The points of `--cloud` read and checked against the organ's size and
/// place (another unit or frame is refused), not yet cleaned; first moved
/// by `motion` where given.
pub fn checked_cloud(
    path: &Path,
    model: &ParticleModel,
    motion: Option<&FiducialFit>,
) -> Result<Cloud> {
    let mut points = load_cloud(path, Default::default())?;
    if let Some(motion) = motion {
        for p in &mut points {
            *p = motion.apply(*p);
        }
    }
    let cloud = Cloud::new(points).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let (lo, hi) = model.positions.iter().fold(
        (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    cloud
        .check_against(lo, hi)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(cloud)
}

/// A match's parameters from `--noise` and `--surface-smoothing`, where
/// given.
pub fn matching(noise: Option<f32>, surface_smoothing: Option<f32>) -> MatchParams {
    let defaults = MatchParams::default();
    MatchParams {
        noise,
        surface_smoothing: surface_smoothing.unwrap_or(defaults.surface_smoothing),
        ..defaults
    }
}

/// Refuses a `--surface-smoothing` the match cannot take: a radius of 0 to
/// 8 of the surface's mean edges.
pub fn check_smoothing(smoothing: Option<f32>) -> Result<()> {
    if let Some(edges) = smoothing
        && !(edges.is_finite() && (0.0..=8.0).contains(&edges))
    {
        bail!("--surface-smoothing is {edges}: 0 to 8 of the surface's mean edges are needed");
    }
    Ok(())
}

/// The match without gravity that the posture options start from: `model`
/// under `params` (its held region observed, no load) matched to
/// `observation` on `device` with `matching`; the rest surface carried by it (a frame of
/// the rest surface), which of its vertices the observation saw, and its
/// error estimate where it stopped short of its answer (at the float
/// floor or stalled, as a sparse scan's may: the stiffness is then fitted
/// to the skin it left, and the run flagged). A match stopped by the
/// iteration cap or diverged is refused.
pub fn first_match(
    device: crate::backend::Device,
    model: &ParticleModel,
    params: &tissue::deformation::DeformParams,
    observation: &Observation,
    matching: &MatchParams,
    quiet: bool,
) -> Result<(SurfaceMesh, Vec<bool>, Option<f32>)> {
    let observed = crate::progress::busy(quiet, "matching the skin without gravity first", |_| {
        tissue::gravity::observed_frame(&device, model, observation, params, matching)
    })?;
    let last = &observed.report.last;
    let short = match last.stopped_by {
        _ if observed.report.converged => None,
        StopReason::FloatPrecision | StopReason::Stalled => Some(last.residual),
        StopReason::Tolerance | StopReason::IterationCap | StopReason::Diverged => bail!(
            "it did not converge ({} iterations, stopped by {:?})",
            observed.report.iterations,
            last.stopped_by
        ),
    };
    Ok((observed.frame, observed.seen, short))
}

/// The rest surface's vertices that lie on `observed` (within
/// [`HELD_TOLERANCE`] mean connection lengths): the region that did not
/// move, held where the user gives no `--fixed-region`.
pub fn held_on(observed: &SurfaceMesh, model: &ParticleModel) -> Result<Vec<bool>> {
    let tolerance = HELD_TOLERANCE * model.mean_connection_length();
    tissue::observation::held_on(observed, &model.surface, tolerance)
        .map_err(|e| anyhow::anyhow!("{e} as --fixed-region"))
}

/// The observation in the report.
#[derive(Debug, Clone, Serialize)]
pub struct ObservationReport {
    /// `surface` (another triangulation) or `cloud`.
    pub kind: &'static str,
    /// Observed points kept (the surface's vertices, or the cloud's points
    /// but its outliers).
    pub points: usize,
    /// A cloud's points set aside as outliers.
    pub outliers: usize,
    /// A cloud's: whether its points were kept as scanned, not moved onto
    /// their neighbours' planes (a scan sparse for the skin's curvature,
    /// whose planes lie under the skin); absent for a surface.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kept_as_scanned: Option<bool>,
    /// A cloud's points on lines of points (a stylus's strips), whose
    /// normals are the model's skin's where the match starts; absent for a
    /// surface.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub on_lines: Option<usize>,
    /// The noise scale, in the model's units.
    pub noise_mm: f32,
    /// The last stage's robust scale (a cloud's; pairs farther off are
    /// pulled with a bounded force), in the model's units; absent for a
    /// surface, whose pairs all pull in proportion to their distance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robust_mm: Option<f32>,
    /// Free skin particles.
    pub skin: usize,
    /// Of them, those pulled towards the observation at the end.
    pub pulled: usize,
    /// Of them, those not pulled (past a cloud's edge).
    pub set_aside: usize,
    /// Of those pulled, the ones farther from the observation than the
    /// robust scale at the end (pulled with a bounded force).
    pub beyond_robust: usize,
    /// `pulled / skin`.
    pub observed_fraction: f32,
    /// The observed points' distances to the deformed model's surface.
    pub residual_rms_mm: f32,
    /// Their 95th percentile.
    pub residual_p95_mm: f32,
    /// Their largest.
    pub residual_max_mm: f32,
    /// Solves over which the springs' weight grew.
    pub stages: usize,
    /// The deformed organ's volume over the rest one's, less one.
    pub volume_change: f32,
    /// With `--fiducials`: the rigid motion that put the observation in
    /// the model's frame first.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment: Option<Alignment>,
}

/// The rigid motion fitted to `--fiducials` ([`tissue::observation::fiducial_fit`]).
#[derive(Debug, Clone, Serialize)]
pub struct Alignment {
    /// The fiducials paired.
    pub fiducials: usize,
    /// The rotation (rows): an observed point `p` goes to `rotation p +
    /// translation`.
    pub rotation: [[f32; 3]; 3],
    /// The translation, in the model's units.
    pub translation: [f32; 3],
    /// The rotation's angle, degrees.
    pub angle_degrees: f32,
    /// The fiducials' distances after the motion: RMS and largest (the
    /// fiducial registration error).
    pub residual_rms_mm: f32,
    /// See `residual_rms_mm`.
    pub residual_max_mm: f32,
}

impl Alignment {
    /// The report of `fit`.
    pub fn of(fit: &FiducialFit) -> Self {
        let r = fit.rotation.transpose();
        Self {
            fiducials: fit.count,
            rotation: [r.x_axis.into(), r.y_axis.into(), r.z_axis.into()],
            translation: fit.translation.into(),
            angle_degrees: fit.angle_degrees,
            residual_rms_mm: fit.rms,
            residual_max_mm: fit.max,
        }
    }

    /// One line for the screen.
    pub fn line(&self) -> String {
        let [x, y, z] = self.translation;
        format!(
            "put in the model's frame by {} fiducials: turned {:.2} degrees and moved \
             ({x:.3}, {y:.3}, {z:.3}); the fiducials {:.3} apart after it (RMS; largest {:.3})",
            self.fiducials, self.angle_degrees, self.residual_rms_mm, self.residual_max_mm
        )
    }
}

/// The rigid motion that puts `--fiducials`' observed points (the second
/// file) onto the model's (the first), read in the model's space.
pub fn read_fiducials(files: &[PathBuf]) -> Result<FiducialFit> {
    let [model_points, observed_points] = files else {
        bail!("--fiducials takes two files: the model's points, then the observation's");
    };
    let read = |path: &Path| {
        tissue::load_points(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    };
    let (to, from) = (read(model_points)?, read(observed_points)?);
    fiducial_fit(&from, &to).map_err(|e| {
        anyhow::anyhow!(
            "--fiducials {} {}: {e}",
            model_points.display(),
            observed_points.display()
        )
    })
}

impl ObservationReport {
    /// What `match_observation` reported of `observation` with `noise`
    /// (`None`: the default scale).
    pub fn of(
        observation: &Observation,
        report: &MatchReport,
        noise: Option<f32>,
        model: &ParticleModel,
    ) -> Self {
        let noise_mm = noise.unwrap_or_else(|| {
            observation
                .cloud_noise()
                .unwrap_or(SURFACE_NOISE * model.mean_connection_length())
        });
        Self {
            kind: if observation.is_cloud() {
                "cloud"
            } else {
                "surface"
            },
            points: observation.points().len(),
            outliers: observation.outliers(),
            kept_as_scanned: observation
                .is_cloud()
                .then(|| observation.kept_as_scanned()),
            on_lines: observation.is_cloud().then(|| observation.on_lines()),
            noise_mm,
            robust_mm: report.robust,
            skin: report.skin,
            pulled: report.pulled,
            set_aside: report.set_aside,
            beyond_robust: report.beyond_robust,
            observed_fraction: report.observed_fraction(),
            residual_rms_mm: report.residual.rms,
            residual_p95_mm: report.residual.p95,
            residual_max_mm: report.residual.max,
            stages: report.stages,
            volume_change: report.volume_change,
            alignment: None,
        }
    }

    /// What flags the result: a residual far above the noise.
    pub fn flags(&self) -> Vec<String> {
        let mut flags = Vec::new();
        if self.residual_rms_mm > RESIDUAL_FLAG * self.noise_mm {
            flags.push(format!(
                "the model does not reach the observation: its points lie {:.3} from the \
                 deformed skin (RMS), more than {RESIDUAL_FLAG} times the noise ({:.3}); it may \
                 show another organ, lie in another frame, or ask more than the mechanics allows",
                self.residual_rms_mm, self.noise_mm
            ));
        }
        if self.volume_change.abs() > VOLUME_FLAG {
            flags.push(format!(
                "the organ's volume changed by {:+.1} % to meet the observation (soft tissue \
                 keeps its volume): the observation is likely in another unit, or in a frame \
                 shifted from the held region",
                100.0 * self.volume_change
            ));
        }
        flags
    }

    /// A line for the screen.
    pub fn line(&self) -> String {
        format!(
            "matched without correspondence to a {} of {} points ({} set aside as outliers{}{}): {} \
             of {} free skin particles pulled ({} past the observation's edge, {} farther off than \
             the robust scale at the end); the observed points {:.3} from the deformed skin (RMS; \
             95th percentile {:.3}, largest {:.3})",
            self.kind,
            self.points,
            self.outliers,
            if self.kept_as_scanned == Some(true) {
                "; kept as scanned, sparse for the skin's curvature"
            } else {
                ""
            },
            match self.on_lines {
                Some(lines) if lines > 0 => {
                    format!("; {lines} on lines of points, their normals the skin's")
                }
                _ => String::new(),
            },
            self.pulled,
            self.skin,
            self.set_aside,
            self.beyond_robust,
            self.residual_rms_mm,
            self.residual_p95_mm,
            self.residual_max_mm
        )
    }
}
