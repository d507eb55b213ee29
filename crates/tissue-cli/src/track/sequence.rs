//! What a `tissue track` sequence is (frames of the rest surface, or
//! observations without correspondence) and how each of its frames is
//! solved.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use tissue::deformation::DeformReport;
use tissue::observation::{
    CleanedScan, FiducialFit, HeldObservation, HeldRegion, MatchParams, Observation,
    match_observation_held,
};
use tissue::{ParticleModel, SurfaceMesh};

use super::TrackArgs;
use crate::observe::{self, ObservationReport};
use crate::progress::{self, SolveBar};
use crate::solve::{read_frame, read_observed, set_deformed};

/// The most points the cleaned scans of `track --clouds` keep from their
/// check before the first frame to their own frame (about 70 bytes a
/// point: 140 MB); a longer sequence reads and cleans each scan again when
/// its frame comes.
pub(super) const KEPT_SCAN_POINTS: usize = 2_000_000;

/// What the frames are.
pub(super) enum Sequence {
    /// Frames of the model's rest surface: the skin follows each vertex by
    /// vertex.
    Frames,
    /// Observations without correspondence (closed surfaces of any
    /// triangulation, or scans), with the held region's rest vertices.
    /// A scan is `None`: read, checked and cleaned before the first solve
    /// (its grid not made), and gridded when its frame comes, so that a
    /// long sequence does not hold every scan's grid at once; the cleaned
    /// scans are kept in `scans` up to [`KEPT_SCAN_POINTS`] in all, and
    /// beyond it read and cleaned again.
    Matched {
        observations: Vec<Option<Observation>>,
        /// Per scan, the scan cleaned where it is kept (empty for
        /// surfaces).
        scans: Vec<Option<CleanedScan>>,
        held: Vec<bool>,
        /// The motion `--fiducials` fitted, which puts every observation
        /// in the model's frame first.
        motion: Option<FiducialFit>,
    },
}

impl Sequence {
    /// Every one of `frames` read and checked against `model`: all frames of
    /// the rest surface, or all observations without correspondence.
    pub(super) fn read(
        args: &TrackArgs,
        frames: &[PathBuf],
        model: &ParticleModel,
    ) -> Result<Self> {
        let rest = &model.surface;
        let held_file = fixed_region_file(args);
        let motion = match &args.fiducials {
            Some(files) => Some(observe::read_fiducials(files)?),
            None => None,
        };
        observe::check_smoothing(args.surface_smoothing)?;
        if args.clouds.is_some() {
            if args.surface_smoothing.is_some() {
                bail!(
                    "--surface-smoothing is for surfaces of another triangulation; a scan's \
                     plane is smoothed over its own spacing"
                );
            }
            let Some(region) = held_file else {
                bail!(
                    "--clouds: scans of part of the skin need the region held at rest (the chest \
                     wall) as --fixed-region FILE"
                );
            };
            let held = read_observed(region, rest)?;
            // Every scan read and cleaned on every thread; the first bad
            // one in the sequence's order is the one named.
            let cleaned: Vec<Result<CleanedScan>> = frames
                .par_iter()
                .map(|path| observe::clean_cloud(path, model, args.noise, motion.as_ref()))
                .collect();
            let cleaned = cleaned.into_iter().collect::<Result<Vec<_>>>()?;
            let scans = kept(cleaned, KEPT_SCAN_POINTS);
            return Self::matched(args, vec![None; frames.len()], scans, held, motion);
        }
        let mut others = Vec::new();
        let mut framed = Vec::new();
        for path in frames {
            match observe::read_surface(path, rest)? {
                observe::Surface::Frame(_) => framed.push(path),
                observe::Surface::Other(mut mesh) => {
                    // In the model's frame first, where fiducials say how.
                    if let Some(motion) = &motion {
                        for v in &mut mesh.vertices {
                            *v = motion.apply(*v);
                        }
                    }
                    others.push((path, mesh));
                }
            }
        }
        if others.is_empty() {
            if motion.is_some() {
                bail!(
                    "--frames are the model's rest surface with moved vertices, in the model's \
                     frame; --fiducials are for observations without correspondence"
                );
            }
            if args.noise.is_some()
                || args.surface_smoothing.is_some()
                || (args.solve.gravity.fixed_region.is_some() && !args.solve.gravity.given())
            {
                bail!(
                    "--frames are the model's rest surface with moved vertices, which the skin \
                     follows vertex by vertex; --noise, --surface-smoothing, and \
                     --fixed-region without the posture options (--gravity-rest, \
                     --gravity-deformed), are for observations without correspondence"
                );
            }
            return Ok(Self::Frames);
        }
        if let (Some(frame), Some((other, _))) = (framed.first(), others.first()) {
            bail!(
                "--frames mixes the model's rest surface with moved vertices ({}) and other \
                 surfaces ({}): a sequence is either all frames of the rest surface or all \
                 observations without correspondence",
                frame.display(),
                other.display()
            );
        }
        // Without the file: the rest vertices that lie on every frame
        // (what did not move in any).
        let held = match held_file {
            Some(region) => read_observed(region, rest)?,
            None => {
                let mut held = vec![true; rest.vertices.len()];
                for (path, mesh) in &others {
                    let on = observe::held_on(mesh, model)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
                    held.iter_mut().zip(on).for_each(|(h, on)| *h &= on);
                }
                if !held.contains(&true) {
                    bail!(
                        "--frames: no rest vertex lies on every frame, so nothing is known to be \
                         held; give the held region (the chest wall) as --fixed-region"
                    );
                }
                held
            }
        };
        let observations = others
            .iter()
            .map(|(_, mesh)| Observation::surface(mesh).map(Some))
            .collect::<Result<Vec<_>, _>>()?;
        Self::matched(args, observations, Vec::new(), held, motion)
    }

    /// Observations without correspondence, once the options are checked.
    fn matched(
        args: &TrackArgs,
        observations: Vec<Option<Observation>>,
        scans: Vec<Option<CleanedScan>>,
        held: Vec<bool>,
        motion: Option<FiducialFit>,
    ) -> Result<Self> {
        if args.solve.observed.is_some() {
            bail!(
                "--observed names the seen vertices of frames with the rest surface's vertices; \
                 observations without correspondence are matched where they are seen (give the \
                 held region as --fixed-region)"
            );
        }
        if args.noise.is_some_and(|n| !(n.is_finite() && n >= 0.0)) {
            bail!(
                "--noise is {}: a distance of at least zero is needed",
                args.noise.unwrap_or_default()
            );
        }
        Ok(Self::Matched {
            observations,
            scans,
            held,
            motion,
        })
    }

    /// Frame `k`'s observation (`path`): a surface's as read, a scan's
    /// gridded from the scan kept cleaned or else read again; `None` for a
    /// frame of the rest surface.
    pub(super) fn observation(
        &self,
        k: usize,
        path: &Path,
        model: &ParticleModel,
        noise: Option<f32>,
    ) -> Result<Option<std::borrow::Cow<'_, Observation>>> {
        use std::borrow::Cow;
        match self {
            Self::Frames => Ok(None),
            Self::Matched {
                observations,
                scans,
                motion,
                ..
            } => Ok(Some(match (&observations[k], scans.get(k)) {
                (Some(observation), _) => Cow::Borrowed(observation),
                (None, Some(Some(scan))) => Cow::Owned(
                    Observation::of_cleaned(scan)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
                ),
                (None, _) => Cow::Owned(observe::read_cloud(path, model, noise, motion.as_ref())?),
            })),
        }
    }
}

/// The cleaned scans, each kept where they hold at most `budget` points
/// in all, none otherwise (each is then read and cleaned again when its
/// frame comes).
fn kept(cleaned: Vec<CleanedScan>, budget: usize) -> Vec<Option<CleanedScan>> {
    let points: usize = cleaned.iter().map(CleanedScan::len).sum();
    if points <= budget {
        cleaned.into_iter().map(Some).collect()
    } else {
        vec![None; cleaned.len()]
    }
}

/// The `--fixed-region` file, if one is given (not `auto`).
pub(super) fn fixed_region_file(args: &TrackArgs) -> Option<&Path> {
    match args.solve.gravity.fixed_region.as_deref() {
        None | Some("auto") => None,
        Some(file) => Some(Path::new(file)),
    }
}

/// How each frame is solved.
pub(super) struct Framing<'a> {
    pub(super) model: &'a ParticleModel,
    pub(super) frames: &'a [PathBuf],
    pub(super) sequence: &'a Sequence,
    /// With the posture options, the first frame the posture was made
    /// from (for observations: their first match without gravity).
    pub(super) first_frame: Option<&'a SurfaceMesh>,
    pub(super) posture: Option<&'a crate::posture::Posture>,
    pub(super) noise: Option<f32>,
    /// `--surface-smoothing`, where given.
    pub(super) surface_smoothing: Option<f32>,
    /// The held region the matches pair around, made at the first match
    /// and kept for the next frames (the solver and its plan stay).
    pub(super) held: std::cell::RefCell<Option<HeldRegion>>,
}

/// A frame solved.
pub(super) struct Framed {
    pub(super) solve: DeformReport,
    /// The deformed surface: the frame, or the model's surface matched.
    pub(super) deformed: SurfaceMesh,
    pub(super) observation: Option<ObservationReport>,
    /// For an observation without correspondence, the observation as
    /// the skin was paired with it (the uncertainty's re-solves pair it
    /// again).
    pub(super) held: Option<HeldObservation>,
}

impl Framing<'_> {
    /// Solves frame `k` from where the frames before left `solver` (the
    /// first with the posture, from where its fit put it); `quiet` shows no
    /// progress.
    pub(super) fn solve(
        &self,
        k: usize,
        solver: &mut crate::backend::Solver,
        quiet: bool,
    ) -> Result<Framed> {
        let path = &self.frames[k];
        let posture_frame = self
            .first_frame
            .filter(|_| k == 0 && self.posture.is_some());
        let placed = match self.sequence {
            // Checked whole before the first solve: read again, not
            // re-checked.
            Sequence::Frames => read_frame(path, &self.model.surface)?,
            // The held region where it is (or the first match's frame).
            Sequence::Matched { .. } => posture_frame.unwrap_or(&self.model.surface).clone(),
        };
        set_deformed(path, solver, &placed)?;
        // The first frame is the posture's deformed scan: solved from where
        // the fit put it.
        if let (0, Some(posture)) = (k, self.posture) {
            posture.warm_start(solver)?;
        }
        let label = format!("frame {}/{}", k + 1, self.frames.len());
        match self.sequence {
            Sequence::Frames => {
                let mut bar = SolveBar::new(label, quiet);
                let solve = solver.solve_with_progress(&mut |step| bar.step(step));
                bar.finish();
                Ok(Framed {
                    solve: solve?,
                    deformed: placed,
                    observation: None,
                    held: None,
                })
            }
            Sequence::Matched { motion, .. } => {
                let observation = self
                    .sequence
                    .observation(k, path, self.model, self.noise)?
                    .ok_or_else(|| anyhow::anyhow!("{}: no observation", path.display()))?;
                let started = Instant::now();
                // A frame after the first starts from the last one's
                // answer.
                let first = observe::matching(self.noise, self.surface_smoothing);
                // Each frame keeps its elastic correction for the next.
                let matching = if k == 0 {
                    MatchParams {
                        keep_correction: true,
                        ..first
                    }
                } else {
                    MatchParams {
                        surface_smoothing: first.surface_smoothing,
                        keep_correction: true,
                        ..MatchParams::next_frame(self.noise)
                    }
                };
                let report = progress::busy(quiet, &format!("{label}: matching"), |_| {
                    let mut held = self.held.borrow_mut();
                    if held.is_none() {
                        *held = Some(HeldRegion::of(solver, self.model)?);
                    }
                    match_observation_held(
                        solver,
                        self.model,
                        &observation,
                        &matching,
                        held.as_ref(),
                    )
                })
                .with_context(|| format!("{}", path.display()))?;
                let mut solve = report.last.clone();
                solve.iterations = report.iterations;
                solve.seconds = started.elapsed().as_secs_f64();
                let mut described =
                    ObservationReport::of(&observation, &report, self.noise, self.model);
                described.alignment = motion.as_ref().map(observe::Alignment::of);
                Ok(Framed {
                    solve,
                    deformed: report.surface,
                    observation: Some(described),
                    held: Some(report.held),
                })
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use glam::Vec3;
    use tissue::observation::Cloud;

    use super::*;

    /// A scan of a flat patch, 12 x 12 points 1 mm apart, seen from below.
    fn patch() -> CleanedScan {
        let points = (0..144)
            .map(|k| Vec3::new((k % 12) as f32, (k / 12) as f32, 0.0))
            .collect();
        let cloud = Cloud::new(points).unwrap();
        Observation::clean_cloud(&cloud, None, Vec3::new(5.5, 5.5, -10.0)).unwrap()
    }

    #[test]
    fn scans_are_kept_within_the_budget_and_read_again_beyond_it() {
        let scans = vec![patch(), patch(), patch()];
        let points: usize = scans.iter().map(CleanedScan::len).sum();
        assert!(points > 0);
        let within = kept(scans.clone(), points);
        assert!(within.iter().all(Option::is_some));
        // Each kept scan grids into the scan's observation.
        let observation = Observation::of_cleaned(within[0].as_ref().unwrap()).unwrap();
        assert_eq!(observation.points().len(), scans[0].len());
        let beyond = kept(scans, points - 1);
        assert_eq!(beyond.len(), 3);
        assert!(beyond.iter().all(Option::is_none));
    }
}
