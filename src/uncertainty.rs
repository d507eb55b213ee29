//! How sure an answer is, on any device: the solve repeated over what the
//! program does not know (the Poisson ratio, the observed surface's
//! error, a posture's load and gravity directions), each repeat started
//! from the answer; every particle, carried point and structure gets a
//! covariance, a 95 % region and the unknown it owes most to
//! (docs/METHOD.md, "Uncertainty"). The mathematics is
//! `tissue_solve::stage2::uncertainty`'s, run here on a [`Solver`].
//!
//! ```
//! use tissue::backend::{Device, Solver};
//! use tissue::deformation::DeformParams;
//! use tissue::uncertainty::{Answered, Priors, explore, exact_vertices};
//! use tissue::{SamplingParams, phantom};
//!
//! let model = tissue::sample(&phantom::default_breast(), &SamplingParams::with_particles(1_000))?
//!     .model;
//! let deformed = tissue::deform::sagged_breast();
//! let mut solver = Solver::new(Device::Cpu, &model, DeformParams::default())?;
//! solver.set_surface(&deformed)?;
//! assert!(solver.solve()?.converged);
//! // The chest wall does not move: no surface error there.
//! let exact = exact_vertices(&model.surface, &deformed);
//! let answered = Answered { surface: &deformed, exact: &exact, rest_load: None, metres_per_unit: 0.001, held_by: None };
//! let priors = Priors::default().with(|p| p.samples = 4);
//! let spread = explore(&mut solver, &model, answered, &priors)?;
//! assert!(spread.converged);
//! let regions = spread.particle_regions();
//! assert!(regions.iter().any(|r| r.radius > 0.0));
//! # Ok::<(), tissue::Error>(())
//! ```

use tissue_core::{Error, ParticleModel, SurfaceMesh};

use crate::backend::{Device, Solver, SolverDevice};
use crate::deformation::SharedLaplacian;

pub use tissue_solve::stage2::uncertainty::{
    Answered, CHI2_3_95, COLUMN_TOLERANCE, Column, FLAT_FLOOR, GRAVITY_DEGREES, HeldBy,
    LOAD_SPREAD, POISSON_RANGE, POSTURE_G, POSTURE_KPA, Priors, Refresh, Region, SEED,
    SURFACE_CORRELATION_MM, SURFACE_NOISE_MM, SURFACE_SAMPLES, Spread, SurfaceNoise, Unknown,
    radius_95,
};

/// The tolerance, in model units, within which a deformed vertex that
/// stayed at rest counts as held ([`exact_vertices`]).
pub const EXACT_TOLERANCE: f32 = 1e-3;

/// Per vertex of `deformed` (the rest surface with moved vertices),
/// whether it stayed where it was at rest within [`EXACT_TOLERANCE`]: the
/// held region (a chest wall), taken as exact. All false where the two
/// surfaces differ in vertex count.
pub fn exact_vertices(rest: &SurfaceMesh, deformed: &SurfaceMesh) -> Vec<bool> {
    tissue_solve::model::held_vertices(rest, deformed, EXACT_TOLERANCE)
        .unwrap_or_else(|| vec![false; deformed.vertices.len()])
}

/// The spread of the answer `solver` holds (its last solve's, converged,
/// of `model` on `answered.surface`) under `priors`:
/// `tissue_solve::stage2::uncertainty::explore`, the other Poisson
/// ratios' solvers prepared on the solver's device in its rest shape,
/// taking what it prepared that they share. The solver is left at the
/// answer.
///
/// # Errors
///
/// [`tissue_core::ParamError`] for priors out of range or a mask of the
/// wrong length; what the solves refuse.
pub fn explore(
    solver: &mut Solver,
    model: &ParticleModel,
    answered: Answered<'_>,
    priors: &Priors,
) -> Result<Spread, Error> {
    Explorer::new(priors.clone()).explore(solver, model, answered)
}

/// [`explore`] over a sequence of answers of one solver (a tracking run's
/// frames; the solver and model of its first answer): the other Poisson
/// ratios' solvers prepared once, each re-solve
/// started from where the same re-solve of the last answer ended, moved
/// with the answer.
pub struct Explorer {
    inner: tissue_solve::stage2::uncertainty::Explorer<SolverDevice>,
    /// What the other Poisson ratios' solvers are prepared from (the
    /// model in the solver's rest shape, what the solver prepared that
    /// they share, its device), made at the first answer.
    setup: Option<(ParticleModel, SharedLaplacian, Device)>,
}

impl Explorer {
    /// An explorer of `priors` with nothing prepared.
    pub fn new(priors: Priors) -> Self {
        Self {
            inner: tissue_solve::stage2::uncertainty::Explorer::new(priors),
            setup: None,
        }
    }

    /// The explorer refreshing its re-solves as `refresh` says: all of
    /// them at every answer ([`Refresh::all`], the default), or after the
    /// first answer a few in turn, the others carried from the answer that
    /// made them last ([`Refresh::every`]).
    pub fn refreshing(self, refresh: Refresh) -> Self {
        Self {
            inner: self.inner.refreshing(refresh),
            ..self
        }
    }

    /// The priors it samples.
    pub fn priors(&self) -> &Priors {
        self.inner.priors()
    }

    /// How it refreshes its re-solves.
    pub fn refresh(&self) -> Refresh {
        self.inner.refresh()
    }

    /// The spread of the answer `solver` holds, as [`explore`] makes it,
    /// from what this explorer kept of the last answer.
    ///
    /// # Errors
    ///
    /// As [`explore`].
    pub fn explore(
        &mut self,
        solver: &mut Solver,
        model: &ParticleModel,
        answered: Answered<'_>,
    ) -> Result<Spread, Error> {
        let (stress_free, shared, device) = self.setup.get_or_insert_with(|| {
            let stress_free = ParticleModel {
                positions: solver.rest().to_vec(),
                ..model.clone()
            };
            (stress_free, solver.shared_laplacian(), solver.on_device())
        });
        let mut other = |params| {
            Solver::new_shared(
                device.clone(),
                stress_free,
                params,
                Some(shared),
                &mut |_| {},
            )
            .map(Solver::into_tracker)
        };
        self.inner
            .explore(solver.tracker_mut(), answered, &mut other)
    }
}
