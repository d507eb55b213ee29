//! Posture-aware stage 2 on any device: the organ's unloaded
//! shape from the rest scan and its posture's gravity, the stiffness
//! fitted from the deformed skin where it is not given, and what a
//! [`Solver`] needs to solve the deformed posture stress-free in that
//! shape with its own gravity inside (docs/METHOD.md, "Gravity and the
//! unloaded shape"). The search is `tissue_solve::stage2::posture`'s, run here
//! on a [`Device`].
//!
//! ```
//! use glam::Vec3;
//! use tissue::backend::{Device, Solver};
//! use tissue::deformation::{DeformParams, ForceModel};
//! use tissue::gravity::{Gravity, held_vertices, unload};
//! use tissue::{SamplingParams, phantom};
//!
//! let model = tissue::sample(&phantom::default_breast(), &SamplingParams::with_particles(1_000))?
//!     .model;
//! let deformed = tissue::deform::sagged_breast();
//! let params = DeformParams::default().with(|p| p.force = ForceModel::Elastic);
//! // Lying on the back (+z forward), then sitting up (gravity towards the
//! // feet, -y), tissue of 3 kPa; without a stiffness it is fitted.
//! let gravity = Gravity::millimetres(Vec3::NEG_Z, Vec3::NEG_Y, Some(3.0));
//! // The chest wall: what does not move between the scans.
//! let held = held_vertices(&model.surface, &deformed, 1e-3).unwrap_or_default();
//! let unloaded = unload(&Device::Cpu, &model, &deformed, &held, &gravity, &params, &mut |_| {})?;
//! assert!(unloaded.shape.converged);
//! let params = params.with(|p| p.load = unloaded.deformed_load);
//! let mut solver = Solver::unloaded(Device::Cpu, &model, &unloaded.shape.positions, params)?;
//! solver.set_surface(&deformed)?;
//! // Where a fit put the deformed posture, its solve starts there.
//! if let Some(guess) = &unloaded.deformed_guess {
//!     solver.warm_start(guess)?;
//! }
//! assert!(solver.solve()?.converged);
//! # Ok::<(), tissue::Error>(())
//! ```

use tissue_core::{Error, ParticleModel, SamplingParams, SurfaceMesh};
use tissue_cpu::deformation::{DeformParams, SharedLaplacian};
use tissue_solve::Tracker;
use tissue_solve::stage2::PostureDevice;

use crate::backend::{Device, Solver, SolverDevice};
use crate::observation::{MatchParams, MatchReport, Observation, match_observation};

pub use tissue_solve::model::{STANDARD_GRAVITY, held_vertices};
pub use tissue_solve::stage2::{
    DENSITY_KG_M3, FIT_BOUNDS_KPA, FIT_PARTICLES, FIT_START_KPA, Fit, Gravity, HELD_SPACINGS,
    MAX_GRAVITY_G, MIN_FIT_PARTICLES, NO_CHANGE, ORGAN_SIZE_M, SolveProgress, UNLOADED_TOLERANCE_M,
    Unloaded,
};

/// The unloaded shape of `model` (its positions the rest scan) under
/// `gravity`, on `device`: `tissue_solve::stage2::unload`, each solve a
/// [`Solver`] on `device`, the stiffness fit's coarse model sampled on
/// the host. `held` is one flag per surface vertex: the surface that does
/// not move between the scans (the chest wall), observed in every solve,
/// the rest of the skin free; with no stiffness given it is fitted so that
/// the deformed posture's gravity, the skin free, best gives the skin of
/// `deformed` (the observed part where `params.observed` says). `params`
/// must be the elastic force's. `progress` is told of every solve as it
/// ends (a fit makes 3-8 of them, and the model's own rounds after a
/// coarse fit 1-3 more).
///
/// # Errors
///
/// [`tissue_core::ParamError`] for gravity values out of range, another
/// force, a gravity that does not change while the stiffness is to be
/// fitted, a held mask of the wrong length, or none or every vertex held;
/// what the solves refuse; no stiffness whose solves converge.
pub fn unload(
    device: &Device,
    model: &ParticleModel,
    deformed: &SurfaceMesh,
    held: &[bool],
    gravity: &Gravity,
    params: &DeformParams,
    progress: &mut dyn FnMut(&SolveProgress),
) -> Result<Unloaded, Error> {
    tissue_solve::stage2::unload(
        &mut OnDevice(device),
        model,
        deformed,
        held,
        gravity,
        params,
        progress,
    )
}

/// Where an observation without correspondence puts the skin before
/// gravity is known: the stiffness fit's frame.
#[derive(Debug, Clone)]
pub struct ObservedFrame {
    /// The rest surface carried by the match without gravity, its held
    /// region where it is: a frame of the rest surface, the `deformed`
    /// that [`unload`] fits the stiffness to.
    pub frame: SurfaceMesh,
    /// Per vertex of `frame`, whether the observation saw it
    /// ([`Observation::sees`]): the skin the fit may use, given to
    /// [`unload`] as its `params.observed`.
    pub seen: Vec<bool>,
    /// The match's report.
    pub report: MatchReport,
}

/// The skin of `model` matched to `observation` without gravity on
/// `device` (`params.observed` the held region, the rest of the skin free;
/// `matching` as for [`match_observation`]), the first step of a posture
/// with an observation without correspondence: the stiffness is then
/// fitted to the frame this gives over the skin the observation saw
/// (`unload(device, model, &observed.frame, held, gravity,
/// &params.with(|p| p.observed = Some(observed.seen.clone())), ..)`), and
/// the deformed posture matched again with its gravity inside, from the
/// fit's guess (docs/METHOD.md, "Observations without correspondence").
/// The caller judges `report.converged`.
///
/// # Errors
///
/// What [`Solver::new`] and [`match_observation`] refuse.
pub fn observed_frame(
    device: &Device,
    model: &ParticleModel,
    observation: &Observation,
    params: &DeformParams,
    matching: &MatchParams,
) -> Result<ObservedFrame, Error> {
    let mut solver = Solver::new(device.clone(), model, params.clone())?;
    solver.set_surface(&model.surface)?;
    let report = match_observation(&mut solver, model, observation, matching)?;
    Ok(ObservedFrame {
        frame: report.surface.clone(),
        seen: observation.sees(&report.surface.vertices),
        report,
    })
}

/// The posture search's solves on a [`Device`].
struct OnDevice<'a>(&'a Device);

impl PostureDevice for OnDevice<'_> {
    type Device = SolverDevice;

    fn tracker(
        &mut self,
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
    ) -> Result<Tracker<SolverDevice>, Error> {
        Solver::new_shared(self.0.clone(), model, params, shared, &mut |_| {})
            .map(Solver::into_tracker)
    }

    fn sample(&mut self, surface: &SurfaceMesh, particles: usize) -> Result<ParticleModel, Error> {
        crate::sample(surface, &SamplingParams::with_particles(particles)).map(|s| s.model)
    }
}
