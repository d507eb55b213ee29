//! A change of posture on any device: the organ's unloaded shape from the
//! rest scan and its posture's gravity ([`crate::model::gravity`]'s fixed point),
//! with the stiffness fitted from the deformed skin where it is not given
//! ([`crate::model::stiffness`]), on a coarse model of the same surface where the
//! model is large enough, the model's own unloaded shape then found at the
//! fitted stiffness. Every solve is a [`Tracker`] the caller's
//! [`PostureDevice`] prepares, so the search is written once for every
//! device (docs/METHOD.md, "Gravity and the unloaded shape").

use glam::{Mat3, Vec3};
use tissue_core::{Error, ParamError, ParticleModel, SurfaceMesh};

use crate::coarse::laplacian::SharedLaplacian;
use crate::model::gravity::{
    Accuracy, ROUND_TOLERANCE, UnloadedShape, Unloading, gravity_load, unloaded_shape_near,
};
use crate::model::stiffness::{Postures, StiffnessFit, Trial, fit_stiffness, free_skin_targets};
use crate::model::structures::Embedding;
use crate::stage2::device::SolveDevice;
use crate::stage2::params::{DeformParams, ForceModel};
use crate::stage2::plan::control_points;
use crate::stage2::report::DeformReport;
use crate::stage2::tracker::Tracker;

/// What the posture search asks of a device: a stage-2 tracker for a
/// model, and a coarse model sampled on a surface (stage 1).
pub trait PostureDevice {
    /// The device the trackers solve on.
    type Device: SolveDevice<Error = Error>;

    /// A tracker for `model`, stress-free in its positions, with `params`,
    /// taking what `shared` prepared where it matches
    /// ([`Tracker::shared_laplacian`] of another tracker of the model).
    ///
    /// # Errors
    ///
    /// What preparing stage 2 refuses.
    fn tracker(
        &mut self,
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
    ) -> Result<Tracker<Self::Device>, Error>;

    /// `particles` particles sampled in `surface` by stage 1 with its
    /// default settings, for the stiffness fit's coarse model.
    ///
    /// # Errors
    ///
    /// What sampling refuses.
    fn sample(&mut self, surface: &SurfaceMesh, particles: usize) -> Result<ParticleModel, Error>;
}

/// The held region found automatically (`--fixed-region auto`, Python's
/// `held=None`): the surface vertices that move less than this many mean
/// connection lengths between the rest and the deformed surface.
pub const HELD_SPACINGS: f32 = 1e-3;

/// A change of gravity between the postures smaller than this, in units of
/// `g`, is none: the skin then says nothing about the stiffness, and the
/// deformed posture is solved as without gravity.
pub const NO_CHANGE: f32 = 1e-3;

/// The stiffness the fit starts from, kPa (soft tissue is 0.5 to 50), and
/// the bounds it searches within.
pub const FIT_START_KPA: f32 = 3.0;

/// The particles of the model the stiffness is fitted on
/// ([`Gravity::fit_particles`]): the shared breast cases fit the same
/// stiffness on 4,000 particles as on 10,000 within 1 %, each solve in
/// about two fifths of the time; on 2,000, within 3 %, and the
/// forward-made breast_c prone to supine 10 % high (docs/METHOD.md).
pub const FIT_PARTICLES: usize = 4_000;

/// The fewest particles [`Gravity::fit_particles`] may ask: fewer leave a
/// breast a few particles across, too coarse to bend as it does.
pub const MIN_FIT_PARTICLES: usize = 500;

/// The fit's bounds, kPa.
pub const FIT_BOUNDS_KPA: (f32, f32) = (0.1, 100.0);

/// The longest gravity a posture may have, in g: a posture's gravity is
/// 1 g, and anything longer than this is a unit mistake (m/s^2) rather
/// than a load.
pub const MAX_GRAVITY_G: f32 = 2.0;

/// The densities a posture may have, kg/m^3: fat is about 900, muscle and
/// gland about 1050, cortical bone about 1900. Outside it the density is
/// almost surely in other units (1 for g/cm^3).
pub const DENSITY_KG_M3: std::ops::RangeInclusive<f32> = 100.0..=5000.0;

/// The sizes an organ may have, in metres across at its widest, with the
/// posture options: outside it the model's unit is almost surely wrong.
pub const ORGAN_SIZE_M: std::ops::RangeInclusive<f32> = 0.005..=1.0;

/// The unloaded shape, loaded again, must give the rest surface within
/// this (RMS over the surface particles), in metres: 0.1 mm.
pub const UNLOADED_TOLERANCE_M: f32 = 1e-4;

/// What a navigation system knows of the two scans besides the surfaces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gravity {
    /// The rest scan's gravity (the model's posture), in units of `g`, in
    /// the model's axes.
    pub rest: Vec3,
    /// The deformed scan's.
    pub deformed: Vec3,
    /// The tissue's density, kg/m^3.
    pub density_kg_m3: f32,
    /// Young's modulus in kPa where it is known; `None`: fitted from the
    /// deformed skin.
    pub stiffness_kpa: Option<f32>,
    /// The model's length unit in metres (`1e-3` for millimetres).
    pub metres_per_unit: f32,
    /// Where the stiffness is fitted: on a model of this many particles
    /// sampled on the same surface, where the model has at least twice
    /// as many ([`FIT_PARTICLES`]; docs/METHOD.md), the model's own
    /// unloaded shape then found at the fitted stiffness; `None`: on the
    /// model itself.
    pub fit_particles: Option<usize>,
}

impl Gravity {
    /// Gravity in two postures of a model in millimetres, tissue of 1000
    /// kg/m^3.
    pub fn millimetres(rest: Vec3, deformed: Vec3, stiffness_kpa: Option<f32>) -> Self {
        Self {
            rest,
            deformed,
            density_kg_m3: 1000.0,
            stiffness_kpa,
            metres_per_unit: 1e-3,
            fit_particles: Some(FIT_PARTICLES),
        }
    }

    /// Refuses a model whose size, in metres by
    /// [`Gravity::metres_per_unit`], is no organ's: from 5 mm to 1 m
    /// ([`ORGAN_SIZE_M`]) across at its widest. Outside that the unit is
    /// almost surely wrong (`--unit cm` on a model in millimetres makes a
    /// breast 1.5 m across), and gravity's load would be wrong by the same
    /// factor.
    ///
    /// # Errors
    ///
    /// [`ParamError`] on `unit`, naming the size in metres.
    pub fn check_size(&self, surface: &SurfaceMesh) -> Result<(), ParamError> {
        let across = surface
            .bounds()
            .map_or(0.0, |(lo, hi)| (hi - lo).max_element());
        let metres = across * self.metres_per_unit;
        ParamError::check(
            ORGAN_SIZE_M.contains(&metres),
            "unit",
            format!(
                "{} m per unit, making the model {metres:.3} m across",
                self.metres_per_unit
            ),
            format!(
                "the model's length unit, giving an organ {} to {} m across (a model in \
                 millimetres needs --unit mm, the default)",
                ORGAN_SIZE_M.start(),
                ORGAN_SIZE_M.end()
            ),
        )
    }

    /// Whether gravity changes between the postures (by [`NO_CHANGE`] or more).
    pub fn changes(&self) -> bool {
        (self.deformed - self.rest).length() >= NO_CHANGE
    }

    /// Checks every field, naming the first that is out of range.
    ///
    /// # Errors
    ///
    /// [`ParamError`] for a gravity that is not finite or longer than 10
    /// g, a density, stiffness or unit that is not positive and finite.
    pub fn validate(&self) -> Result<(), ParamError> {
        for (name, g) in [
            ("gravity_rest", self.rest),
            ("gravity_deformed", self.deformed),
        ] {
            let length = g.length();
            // 9.81 is gravity in m/s^2; 981 in cm/s^2.
            let likely = if (8.0..12.0).contains(&length) {
                format!(" ({length:.2} long: m/s^2? give 0,0,-1 for 1 g along -z)")
            } else if (800.0..1200.0).contains(&length) {
                format!(" ({length:.0} long: cm/s^2? give 0,0,-1 for 1 g along -z)")
            } else {
                String::new()
            };
            ParamError::check(
                g.is_finite() && length <= MAX_GRAVITY_G,
                name,
                g,
                format!(
                    "a finite vector in units of g, at most {MAX_GRAVITY_G} g long: a \
                     posture's gravity is 1 g (0,0,-1: along -z){likely}"
                ),
            )?;
        }
        ParamError::check(
            DENSITY_KG_M3.contains(&self.density_kg_m3),
            "density_kg_m3",
            self.density_kg_m3,
            format!(
                "a density in kg/m^3 from {} to {} (soft tissue: about 1000; 1 g/cm^3 is \
                 1000 kg/m^3)",
                DENSITY_KG_M3.start(),
                DENSITY_KG_M3.end()
            ),
        )?;
        if let Some(e) = self.stiffness_kpa {
            ParamError::check(
                e.is_finite() && e > 0.0,
                "stiffness_kpa",
                e,
                "a positive Young's modulus in kPa (soft tissue: 0.5 to 50)",
            )?;
        }
        if let Some(n) = self.fit_particles {
            ParamError::check(
                n >= MIN_FIT_PARTICLES,
                "fit_particles",
                n,
                format!(
                    "at least {MIN_FIT_PARTICLES} particles to fit the stiffness on (or none: fit \
                     on the model itself)"
                ),
            )?;
        }
        // The density and the unit: as the load checks them.
        gravity_load(
            Vec3::ZERO,
            self.density_kg_m3,
            1.0,
            0.3,
            self.metres_per_unit,
        )?;
        Ok(())
    }
}

/// The stiffness's fit.
#[derive(Debug, Clone)]
pub struct Fit {
    /// The free skin's RMS distance from the observed one at the fitted
    /// stiffness, in model units.
    pub residual: f32,
    /// Every trial, in order.
    pub trials: Vec<Trial>,
    /// The particles of the model the fit ran on: [`Gravity::fit_particles`],
    /// or the model's own where it is not at least twice that.
    pub particles: usize,
}

/// One stage-2 solve of [`unload`]'s search, told to its progress callback.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveProgress {
    /// Solves made so far, this one included.
    pub solve: usize,
    /// Its iterations.
    pub iterations: usize,
    /// Whether it converged.
    pub converged: bool,
    /// Its elastic phases run again ([`DeformReport::elastic_retries`]).
    pub elastic_retries: usize,
    /// Its energy watch's steps back ([`DeformReport::backtracks`]).
    pub backtracks: usize,
    /// Whether every state its watched phases accepted lowered the
    /// potential ([`DeformReport::potentials_fell`]).
    pub potentials_fell: bool,
}

/// The organ's unloaded shape and what the deformed posture is solved with.
#[derive(Debug, Clone)]
pub struct Unloaded {
    /// The unloaded shape, and how well it gives the rest shape back.
    pub shape: UnloadedShape,
    /// Young's modulus, kPa: given, or fitted.
    pub stiffness_kpa: f32,
    /// The fit, where the stiffness was fitted.
    pub fit: Option<Fit>,
    /// The deformed posture's gravity as [`DeformParams::load`].
    pub deformed_load: Vec3,
    /// The rest posture's gravity as [`DeformParams::load`] (what the
    /// unloaded shape was found under).
    pub rest_load: Vec3,
    /// Where the deformed posture puts the particles, about: the fit's
    /// winning trial (its unloaded shape loaded, the skin free), carried to
    /// the model from a coarse one; `None` where the stiffness was given.
    /// A warm start for the deformed posture's first solve
    /// ([`Tracker::warm_start`], after the observed skin is set): its
    /// elastic phase starts near the answer, linearised there.
    pub deformed_guess: Option<Vec<Vec3>>,
    /// Every stage-2 solve the search made.
    pub solves: usize,
    /// Over those solves, the elastic phases run again
    /// ([`DeformReport::elastic_retries`]).
    pub elastic_retries: usize,
    /// Over those solves, the energy watch's steps back
    /// ([`DeformReport::backtracks`]).
    pub backtracks: usize,
}

/// The unloaded shape of `model` (its positions the rest scan) under
/// `gravity`, on `device` ([`PostureDevice`]): `held` (one flag per surface vertex) is the
/// surface that does not move between the scans (the chest wall), observed
/// in every solve, the rest of the skin free; with no stiffness given it
/// is fitted so that the deformed posture's gravity, the skin free, best
/// gives the skin of `deformed` (the observed part where
/// `params.observed` says), on a coarse model of the same surface where
/// `gravity.fit_particles` asks one ([`Gravity::fit_particles`]), the
/// model's own unloaded shape then found at the fitted stiffness.
/// `params` must be the elastic force's. `progress` is told of every
/// solve as it ends (a fit makes 3-8 of them, each of a few hundred
/// iterations over the free skin, and the model's own rounds after a
/// coarse fit 1-3 more).
///
/// # Errors
///
/// [`ParamError`] for gravity values out of range, another force, a
/// gravity that does not change while the stiffness is to be fitted, a
/// held mask of the wrong length, or none or every vertex held; what the
/// solves refuse; no stiffness whose solves converge.
pub fn unload<P: PostureDevice>(
    device: &mut P,
    model: &ParticleModel,
    deformed: &SurfaceMesh,
    held: &[bool],
    gravity: &Gravity,
    params: &DeformParams,
    progress: &mut dyn FnMut(&SolveProgress),
) -> Result<Unloaded, Error> {
    gravity.validate()?;
    gravity.check_size(&model.surface)?;
    ParamError::check(
        params.force == ForceModel::Elastic,
        "force",
        format!("{:?}", params.force),
        "the elastic force (gravity's unloaded shape is that of an elastic body)",
    )?;
    let vertices = model.surface.vertices.len();
    ParamError::check(
        held.len() == vertices,
        "held region",
        format!("{} flags", held.len()),
        format!("one per surface vertex ({vertices})"),
    )?;
    let held_count = held.iter().filter(|&&h| h).count();
    ParamError::check(
        held_count > 0,
        "held region",
        "no vertex",
        "the surface that does not move between the scans (the chest wall): at least one vertex",
    )?;
    ParamError::check(
        gravity.stiffness_kpa.is_some() || held_count < vertices,
        "held region",
        "every vertex",
        "some free skin to fit the stiffness from (or the stiffness given)",
    )?;
    ParamError::check(
        gravity.stiffness_kpa.is_some() || gravity.changes(),
        "gravity",
        format!(
            "the same in both postures ({} and {})",
            gravity.rest, gravity.deformed
        ),
        "a change of posture to fit the stiffness from (or the stiffness given)",
    )?;
    let per_kpa = |g: Vec3| {
        gravity_load(
            g,
            gravity.density_kg_m3,
            1.0,
            params.poisson,
            gravity.metres_per_unit,
        )
    };
    let (rest_per_kpa, deformed_per_kpa) = (per_kpa(gravity.rest)?, per_kpa(gravity.deformed)?);
    let unloading = Unloading {
        tolerance: UNLOADED_TOLERANCE_M / gravity.metres_per_unit,
        ..Unloading::MILLIMETRES
    };
    let mut solves = Solves {
        device,
        params,
        held,
        progress,
        count: 0,
        elastic_retries: 0,
        backtracks: 0,
        last_round: None,
        laplacian: None,
    };
    let (stiffness_kpa, shape, fit, deformed_guess) = match gravity.stiffness_kpa {
        Some(e) => {
            let shape = solves.unloaded(model, None, rest_per_kpa / e, unloading)?;
            (e, shape, None, None)
        }
        None => {
            let started = std::time::Instant::now();
            let coarse = gravity
                .fit_particles
                .filter(|&n| model.len() >= 2 * n)
                .and_then(|n| coarse_model(solves.device, model, n));
            if let Some(coarse) = &coarse {
                log::info!(
                    "the stiffness is fitted on {} particles of the same surface (sampled in \
                     {:.2} s)",
                    coarse.len(),
                    started.elapsed().as_secs_f64()
                );
            }
            let fitted = match &coarse {
                Some(coarse) => {
                    let fitted =
                        solves.fit(coarse, deformed, rest_per_kpa, deformed_per_kpa, unloading);
                    if let Err(e) = &fitted {
                        log::warn!(
                            "the stiffness fit on a model of {} particles failed ({e}); fitting on \
                             the model itself",
                            coarse.len()
                        );
                    }
                    fitted.ok().map(|f| (coarse, f))
                }
                None => None,
            };
            match fitted {
                // The model's own unloaded shape at the stiffness fitted on
                // the coarse one, from the coarse shape's displacement.
                Some((coarse, f)) => {
                    log::info!(
                        "fitted {:.3} kPa on {} particles in {:.2} s; the model's own unloaded \
                         shape at it",
                        f.stiffness_kpa,
                        coarse.len(),
                        started.elapsed().as_secs_f64()
                    );
                    let start = carried(&coarse.positions, &f.unloaded.positions, &model.positions);
                    let shape = solves.unloaded(
                        model,
                        Some((&start, None)),
                        rest_per_kpa / f.stiffness_kpa,
                        unloading,
                    )?;
                    let guess = carried(&coarse.positions, &f.deformed, &model.positions);
                    let fit = Fit {
                        residual: f.residual,
                        trials: f.trials,
                        particles: coarse.len(),
                    };
                    (f.stiffness_kpa, shape, Some(fit), Some(guess))
                }
                // The fit's shape, measured loosely, measured again in full.
                None => {
                    let f =
                        solves.fit(model, deformed, rest_per_kpa, deformed_per_kpa, unloading)?;
                    let shape = solves.unloaded(
                        model,
                        Some((&f.unloaded.positions, Some(f.unloaded.residual))),
                        rest_per_kpa / f.stiffness_kpa,
                        unloading,
                    )?;
                    let fit = Fit {
                        residual: f.residual,
                        trials: f.trials,
                        particles: model.len(),
                    };
                    (f.stiffness_kpa, shape, Some(fit), Some(f.deformed))
                }
            }
        }
    };
    Ok(Unloaded {
        shape,
        stiffness_kpa,
        fit,
        deformed_load: deformed_per_kpa / stiffness_kpa,
        rest_load: rest_per_kpa / stiffness_kpa,
        deformed_guess,
        solves: solves.count,
        elastic_retries: solves.elastic_retries,
        backtracks: solves.backtracks,
    })
}

/// The stage-2 solves of [`unload`]'s search on one device, counted and
/// told to its progress callback.
struct Solves<'a, P: PostureDevice> {
    device: &'a mut P,
    params: &'a DeformParams,
    /// The held region, a flag per surface vertex (the same surface for
    /// every model the search solves).
    held: &'a [bool],
    progress: &'a mut dyn FnMut(&SolveProgress),
    count: usize,
    /// The solves' elastic phases run again and steps back, in all.
    elastic_retries: usize,
    backtracks: usize,
    /// The last round's solver, which the round's confirmation
    /// ([`Accuracy::Full`] for the same guess and load) solves on from
    /// where it stopped instead of preparing the model again.
    last_round: Option<Round<P::Device>>,
    /// What the last solver prepared that the next one of the same model
    /// takes (every solve holds the same region, so the same particles
    /// are free): the Laplacian's spectrum and coarse space.
    laplacian: Option<SharedLaplacian>,
}

/// A round's solve, kept for its confirmation (its guess is the solver's
/// rest shape).
struct Round<D> {
    load: Vec3,
    solver: Tracker<D>,
}

impl<P: PostureDevice> Solves<'_, P> {
    /// Loads `model` stress-free in `guess` with `load`: the held region
    /// observed where the rest surface puts it, the rest of the skin free;
    /// from `warm` where the search knows about where the loaded positions
    /// are; as closely as `accuracy` asks. A confirmation of the last
    /// round (the same guess and load, in full) tightens that round's
    /// solver and solves on from its state.
    fn solve(
        &mut self,
        model: &ParticleModel,
        guess: &[Vec3],
        load: Vec3,
        warm: Option<&[Vec3]>,
        accuracy: Accuracy,
    ) -> Result<(Vec<Vec3>, DeformReport), Error> {
        self.count += 1;
        let held_params = self.params.clone().with(|p| {
            p.observed = Some(self.held.to_vec());
            p.load = load;
        });
        let last = self.last_round.take();
        let mut solver = match last {
            Some(round)
                if accuracy == Accuracy::Full
                    && round.load == load
                    && round.solver.rest() == guess =>
            {
                log::debug!("the round measured again at the full tolerance, on its own solver");
                let mut solver = round.solver;
                solver.set_params(held_params)?;
                solver
            }
            _ => {
                let stress_free = ParticleModel {
                    positions: guess.to_vec(),
                    ..model.clone()
                };
                let params = match accuracy {
                    Accuracy::Round => held_params.with(|p| p.tolerance *= ROUND_TOLERANCE),
                    Accuracy::Full => held_params,
                };
                let mut solver =
                    self.device
                        .tracker(&stress_free, params, self.laplacian.as_ref())?;
                self.laplacian = Some(solver.shared_laplacian());
                solver.set_surface::<Error>(&model.surface)?;
                if let Some(warm) = warm {
                    solver.warm_start::<Error>(warm)?;
                }
                solver
            }
        };
        let report = solver.solve()?;
        self.elastic_retries += report.elastic_retries;
        self.backtracks += report.backtracks;
        (self.progress)(&SolveProgress {
            solve: self.count,
            iterations: report.iterations,
            converged: report.converged,
            elastic_retries: report.elastic_retries,
            backtracks: report.backtracks,
            potentials_fell: report.potentials_fell(),
        });
        let loaded = solver.positions().to_vec();
        if accuracy == Accuracy::Round {
            self.last_round = Some(Round { load, solver });
        }
        Ok((loaded, report))
    }

    /// `model`'s unloaded shape under the rest posture's `load`, from the
    /// guess `start` and its loose miss where known (the rest shape where
    /// there is none).
    fn unloaded(
        &mut self,
        model: &ParticleModel,
        start: Option<(&[Vec3], Option<f32>)>,
        load: Vec3,
        unloading: Unloading,
    ) -> Result<UnloadedShape, Error> {
        let surface: Vec<bool> = (0..model.len()).map(|i| model.is_surface(i)).collect();
        let rest = &model.positions;
        let (start, miss) = start.unwrap_or((rest, None));
        unloaded_shape_near(
            rest,
            start,
            miss,
            &surface,
            unloading,
            |x, warm, accuracy| self.solve(model, x, load, warm, accuracy),
        )
    }

    /// The stiffness fitted on `model` (module docs; [`fit_stiffness`]).
    fn fit(
        &mut self,
        model: &ParticleModel,
        deformed: &SurfaceMesh,
        rest_per_kpa: Vec3,
        deformed_per_kpa: Vec3,
        unloading: Unloading,
    ) -> Result<StiffnessFit, Error> {
        // Where the observed deformed skin puts each free skin particle.
        let observed = self
            .params
            .observed
            .as_deref()
            .map(|mask| control_points(model, Some(mask)));
        let targets: Vec<Option<Vec3>> = free_skin_targets(model, deformed, self.held)
            .into_iter()
            .enumerate()
            .map(|(i, t)| t.filter(|_| observed.as_ref().is_none_or(|o| o[i])))
            .collect();
        ParamError::check(
            targets.iter().any(Option::is_some),
            "observed",
            "no free skin particle observed",
            "some observed skin outside the held region to fit the stiffness from",
        )?;
        let surface: Vec<bool> = (0..model.len()).map(|i| model.is_surface(i)).collect();
        let postures = Postures {
            rest: &model.positions,
            surface: &surface,
            targets: &targets,
            rest_load_per_kpa: rest_per_kpa,
            deformed_load_per_kpa: deformed_per_kpa,
        };
        fit_stiffness(
            &postures,
            FIT_START_KPA,
            FIT_BOUNDS_KPA,
            unloading,
            |x, load, warm, accuracy| self.solve(model, x, load, warm, accuracy),
        )
    }
}

/// A model of `particles` on `model`'s surface for the stiffness's fit
/// (stage 1 on the host, the default settings); `None`, with a warning,
/// where sampling it fails.
fn coarse_model(
    device: &mut impl PostureDevice,
    model: &ParticleModel,
    particles: usize,
) -> Option<ParticleModel> {
    match device.sample(&model.surface, particles) {
        Ok(coarse) if coarse.surface.vertices.len() == model.surface.vertices.len() => Some(coarse),
        Ok(_) => {
            log::warn!(
                "the coarse model's surface is not the model's; fitting on the model itself"
            );
            None
        }
        Err(e) => {
            log::warn!(
                "sampling {particles} particles to fit the stiffness on failed ({e}); fitting on \
                 the model itself"
            );
            None
        }
    }
}

/// `points` moved as the particles at `rest` moved to `moved`: each by the
/// weighted displacement of the particles that carry it
/// ([`crate::model::structures::carriers_of`]).
fn carried(rest: &[Vec3], moved: &[Vec3], points: &[Vec3]) -> Vec<Vec3> {
    let embedding = Embedding::new(rest, points);
    let still = vec![Mat3::IDENTITY; rest.len()];
    embedding.moved(rest, moved, &still)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;

    /// The fit's coarse model is 4,000 particles by default, and fewer
    /// than [`MIN_FIT_PARTICLES`] are refused, naming the field.
    #[test]
    fn the_coarse_fit_default_is_pinned_and_too_few_refused() {
        let g = Gravity::millimetres(Vec3::NEG_Z, Vec3::NEG_Y, None);
        assert_eq!(g.fit_particles, Some(4_000));
        assert_eq!(FIT_PARTICLES, 4_000);
        assert!(g.validate().is_ok());
        let none = Gravity {
            fit_particles: None,
            ..g
        };
        assert!(none.validate().is_ok());
        let few = Gravity {
            fit_particles: Some(MIN_FIT_PARTICLES - 1),
            ..g
        };
        let said = few.validate().unwrap_err().to_string();
        assert!(said.contains("fit_particles"), "{said}");
    }

    /// Gravity in m/s^2 or 10 g, a density in g/cm^3 and a model in the
    /// wrong unit are refused up front, each naming the likely mistake.
    #[test]
    fn units_that_are_surely_wrong_are_refused_naming_the_likely_cause() {
        let g = Gravity::millimetres(Vec3::NEG_Z, Vec3::NEG_Y, None);
        for (bad, expected) in [
            (
                Gravity {
                    deformed: Vec3::new(0.0, 0.0, -9.81),
                    ..g
                },
                "m/s^2?",
            ),
            (
                Gravity {
                    rest: Vec3::new(0.0, -981.0, 0.0),
                    ..g
                },
                "cm/s^2?",
            ),
            (
                Gravity {
                    rest: Vec3::new(0.0, 0.0, -10.0),
                    ..g
                },
                "at most 2 g long",
            ),
            (
                Gravity {
                    density_kg_m3: 1.0,
                    ..g
                },
                "1 g/cm^3 is 1000 kg/m^3",
            ),
        ] {
            let said = bad.validate().unwrap_err().to_string();
            assert!(said.contains(expected), "{said}");
        }
        assert!(
            Gravity {
                rest: Vec3::new(0.0, 0.0, -2.0),
                density_kg_m3: 900.0,
                ..g
            }
            .validate()
            .is_ok()
        );
        let breast = tissue_core::phantom::breast(&tissue_core::phantom::BreastPhantom::default());
        assert!(g.check_size(&breast).is_ok());
        let in_cm = Gravity {
            metres_per_unit: 1e-2,
            ..g
        };
        let said = in_cm.check_size(&breast).unwrap_err().to_string();
        assert!(
            said.contains("unit") && said.contains("--unit mm"),
            "{said}"
        );
    }

    /// Points follow the carrying particles' displacement: a translation
    /// exactly, nothing where nothing moved, and a stretch within what
    /// the carriers' spread allows.
    #[test]
    fn points_are_carried_by_the_particles_displacement() {
        let grid: Vec<Vec3> = (0..6 * 6 * 6)
            .map(|i| Vec3::new((i % 6) as f32, (i / 6 % 6) as f32, (i / 36) as f32))
            .collect();
        let points = [Vec3::splat(2.5), Vec3::new(1.2, 3.7, 0.4), Vec3::splat(4.0)];
        let shift = Vec3::new(0.3, -0.2, 0.1);
        let moved: Vec<Vec3> = grid.iter().map(|p| *p + shift).collect();
        for (c, p) in carried(&grid, &moved, &points).iter().zip(&points) {
            assert!(c.distance(*p + shift) < 1e-5, "{c} from {p}");
        }
        for (c, p) in carried(&grid, &grid, &points).iter().zip(&points) {
            assert!(c.distance(*p) < 1e-6, "{c} from {p}");
        }
        let stretched: Vec<Vec3> = grid.iter().map(|p| *p * Vec3::new(1.1, 1.0, 1.0)).collect();
        let centre = carried(&grid, &stretched, &[Vec3::splat(2.5)])[0];
        assert!((centre.x - 2.75).abs() < 0.05, "{centre}");
    }
}
