//! What a stage-2 solve knows about a model before it starts, the same on
//! every device: which particles move, the spectrum, the size, the floor.

use std::sync::Arc;

use glam::Vec3;
use tissue_core::{Connections, DeformError, Error, ParamError, ParticleModel};

use crate::model::elastic::Elastic;
use crate::stage2::pairing::Pairing;
use crate::stage2::params::{DeformParams, ForceModel};
use crate::stage2::report::PrepareStage;
use crate::stage2::spectrum::laplacian_extremes;
use crate::stage2::springs::{Spring, springs_stiffness};

/// The largest `|load|` times the model's size [`Plan::for_params`]
/// accepts (a load moves a model by about `2 |load| size^2`): gravity on
/// tissue of shear modulus 0.1 kPa, softer than any organ, over a 20 cm
/// model is 9.8 (`rho g / (2 mu)` = 0.049 / mm); past that a load is a
/// unit mistake.
pub const MAX_LOAD_SIZE: f32 = 10.0;

/// Per particle, whether it is a control point under the observed-vertex
/// mask `observed` (one flag per surface vertex; `None`: all observed): a
/// surface particle whose triangle's three vertices are all observed. A
/// mask shorter than the surface reads as unobserved past its end.
pub fn control_points(model: &ParticleModel, observed: Option<&[bool]>) -> Vec<bool> {
    let seen = |v: u32| observed.is_none_or(|mask| mask.get(v as usize).copied().unwrap_or(false));
    model
        .attachments
        .iter()
        .map(|a| {
            a.is_some_and(|a| {
                model.surface.triangles[a.triangle as usize]
                    .iter()
                    .all(|&v| seen(v))
            })
        })
        .collect()
}

/// What a stage-2 solve needs to know about a model before it starts, the
/// same for the CPU and the GPU path: which particles move, the spectrum
/// that sets the step and the Chebyshev rate, the model's size and the
/// finest step `f32` resolves at its coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Per particle: moved by the solve (not a control point, and connected
    /// to one through some path of connections).
    pub free: Vec<bool>,
    /// Per particle: a control point, placed on the deformed surface (a
    /// surface particle whose triangle's vertices are all observed,
    /// [`DeformParams::observed`]).
    pub controls: Vec<bool>,
    /// Per particle its body force `a_i` times [`DeformParams::load`]
    /// (empty without a load).
    pub loads: Vec<Vec3>,
    /// Per particle its spring towards the observation
    /// ([`crate::stage2::springs`]: a point and a stiffness; zero where
    /// none), which the elastic force's iterations apply at the free
    /// particles (empty without an observation's springs:
    /// [`Plan::set_springs`]).
    pub springs: Vec<Spring>,
    /// How each elastic iteration pairs the skin with the observation the
    /// device holds and sets its springs anew (`None`: the springs stay as
    /// set; [`Plan::set_pairing`]).
    pub pairing: Option<Pairing>,
    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub lambda_min: f32,
    /// Largest one, with a 2 % margin.
    pub lambda_max: f32,
    /// [`laplacian_key`] of the connections and `free`: which solvers'
    /// Laplacian preparation this one may share (`SharedLaplacian`).
    pub laplacian_key: u64,
    /// The model's bounding-box diagonal at rest.
    pub size: f32,
    /// An RMS step below this is `f32` rounding at the model's coordinates.
    pub floor: f32,
    /// The elastic model's rest data, for a solve with the elastic force.
    pub elastic: Option<Arc<Elastic>>,
    /// The largest eigenvalue the elastic force's step is set for
    /// ([`Elastic::lambda_max`], in the Laplacian's units), with it.
    pub elastic_lambda_max: Option<f32>,
    /// [`elastic_key`] of the rest shape and the particles the elastic
    /// model holds its integration constraint at, with it: which solvers'
    /// elastic model this one may share (`SharedLaplacian`).
    pub elastic_key: Option<u64>,
}

impl Plan {
    /// Checks `model` ([`ParticleModel::validate`], and that it has surface
    /// particles for the surface to move) and works out its plan.
    ///
    /// # Errors
    ///
    /// [`Error::InvalidModel`] for a model [`ParticleModel::validate`]
    /// refuses; [`Error::Deformation`] for one without surface particles.
    pub fn new(model: &ParticleModel) -> Result<Self, Error> {
        Self::observed(model, None)
    }

    /// [`Plan::new`] with only the surface particles whose triangles'
    /// vertices are all `observed` (one flag per surface vertex) as control
    /// points; the others are free.
    ///
    /// # Errors
    ///
    /// As [`Plan::new`]; [`DeformError::ObservedLength`] for a mask that is
    /// not one flag per surface vertex, [`DeformError::NothingObserved`]
    /// where no surface particle is observed.
    pub fn observed(model: &ParticleModel, observed: Option<&[bool]>) -> Result<Self, Error> {
        Self::observed_shared(model, observed, None)
    }

    /// [`Plan::observed`], the Laplacian's extreme eigenvalues taken from
    /// `shared` where it was made for the same connections and free
    /// particles.
    fn observed_shared(
        model: &ParticleModel,
        observed: Option<&[bool]>,
        shared: Option<&SharedSpectrum>,
    ) -> Result<Self, Error> {
        model.validate()?;
        if model.attachments.iter().all(Option::is_none) {
            return Err(DeformError::NoControlPoints.into());
        }
        let vertices = model.surface.vertices.len();
        if let Some(mask) = observed
            && mask.len() != vertices
        {
            return Err(DeformError::ObservedLength {
                got: mask.len(),
                vertices,
            }
            .into());
        }
        let controls = control_points(model, observed);
        if !controls.contains(&true) {
            return Err(DeformError::NothingObserved {
                observed: observed.map_or(vertices, |m| m.iter().filter(|&&o| o).count()),
                vertices,
            }
            .into());
        }
        let mut free: Vec<bool> = controls.iter().map(|c| !c).collect();
        // A free particle with no path of connections to a control point has
        // nothing to follow: it would stay put anyway, and its zero Laplacian
        // eigenvalue would stall the acceleration for everyone. Hold it.
        let anchored = anchored(&model.connections, &free);
        let floating = free
            .iter()
            .zip(&anchored)
            .filter(|(f, a)| **f && !**a)
            .count();
        if floating > 0 {
            log::warn!(
                "{floating} particles are not connected to the surface through any path of connections; \
                 they stay where they are"
            );
        }
        for (f, a) in free.iter_mut().zip(&anchored) {
            *f = *f && *a;
        }
        let laplacian_key = laplacian_key(&model.connections, &free);
        let (lambda_min, lambda_max) = shared
            .and_then(|shared| shared.for_key(laplacian_key))
            .unwrap_or_else(|| laplacian_extremes(&model.connections, &free));
        let (lo, hi) = model.positions.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        // f32 resolves about EPSILON * |x|: at single precision most particles
        // no longer move and a few flip by an ulp, so the RMS step (unlike the
        // largest, which grows with the particle count) settles below one ulp.
        let largest = model
            .positions
            .iter()
            .map(|q| q.abs().max_element())
            .fold(0.0, f32::max);
        Ok(Self {
            free,
            controls,
            loads: Vec::new(),
            springs: Vec::new(),
            pairing: None,
            lambda_min,
            lambda_max,
            laplacian_key,
            size: (hi - lo).length(),
            floor: FLOOR_ULPS * f32::EPSILON * largest,
            elastic: None,
            elastic_lambda_max: None,
            elastic_key: None,
        })
    }

    /// [`Plan::new`] for a solve under `params`: with the elastic force,
    /// also the elastic model's rest data and the largest eigenvalue of its
    /// operator ([`Elastic::lambda_max`], in the Laplacian's units), which
    /// sets its step.
    pub fn for_params(model: &ParticleModel, params: &DeformParams) -> Result<Self, Error> {
        Self::for_params_observed(model, params, &mut |_| {})
    }

    /// [`Plan::for_params`], telling `observe` as each of its stages starts
    /// ([`PrepareStage::Plan`], then with the elastic force
    /// [`PrepareStage::ElasticModel`]).
    pub fn for_params_observed(
        model: &ParticleModel,
        params: &DeformParams,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        Self::for_params_shared(model, params, None, None, observe)
    }

    /// [`Plan::for_params_observed`], the Laplacian's extreme eigenvalues
    /// taken from `shared` where it was made for the same connections and
    /// free particles ([`SharedSpectrum`]), and the elastic model where it
    /// was made in the same rest shape with the constraint held at the
    /// same particles (for another Poisson ratio only its weights made
    /// again, [`Elastic::with_poisson`]).
    pub fn for_params_shared(
        model: &ParticleModel,
        params: &DeformParams,
        shared: Option<&SharedSpectrum>,
        shared_elastic: Option<&SharedElastic>,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        observe(PrepareStage::Plan);
        let mut plan = Self::observed_shared(model, params.observed.as_deref(), shared)?;
        plan.set_load(&model.positions, &model.connections, params.load)?;
        if params.force == ForceModel::Elastic {
            observe(PrepareStage::ElasticModel);
            // The integration constraint holds inside; a surface particle's
            // gradient vectors integrate to its share of the boundary, free
            // (unobserved) or not.
            let inside: Vec<bool> = model
                .attachments
                .iter()
                .zip(&plan.free)
                .map(|(a, &free)| a.is_none() && free)
                .collect();
            let key = elastic_key(&model.positions, &inside, plan.laplacian_key);
            let known = shared_elastic.and_then(|shared| {
                shared.for_ratio(key, params.poisson, &model.positions, &model.connections)
            });
            let (elastic, lambda_max) = match known {
                Some(known) => known,
                None => (
                    Arc::new(Elastic::new(
                        &model.positions,
                        &model.connections,
                        params.poisson,
                        &inside,
                    )),
                    None,
                ),
            };
            let lambda_max = lambda_max.unwrap_or_else(|| {
                let stiff = elastic.lambda_max(&model.positions, &model.connections, &plan.free);
                stiff.max(plan.lambda_max)
            });
            plan.elastic_lambda_max = Some(lambda_max);
            plan.elastic = Some(elastic);
            plan.elastic_key = Some(key);
        }
        Ok(plan)
    }

    /// Sets every particle's body force for `load` ([`DeformParams::load`]):
    /// `load` times its stiffness weight `a_i = tr(A_i) / 3` at `positions`
    /// (the rest shape the solve is prepared in), none for a zero load.
    ///
    /// # Errors
    ///
    /// [`ParamError`] for a load longer than [`MAX_LOAD_SIZE`] over the
    /// model's size.
    pub fn set_load(
        &mut self,
        positions: &[Vec3],
        connections: &Connections,
        load: Vec3,
    ) -> Result<(), Error> {
        if load == Vec3::ZERO {
            self.loads.clear();
            return Ok(());
        }
        ParamError::check(
            load.is_finite() && load.length() * self.size <= MAX_LOAD_SIZE,
            "load",
            load,
            format!(
                "at most {MAX_LOAD_SIZE} over the model's size ({}) in length",
                self.size
            ),
        )?;
        self.loads = (0..positions.len())
            .map(|i| {
                let trace: f32 = connections
                    .of(i)
                    .iter()
                    .map(|&j| (positions[j as usize] - positions[i]).length_squared())
                    .sum();
                load * (trace / 3.0)
            })
            .collect();
        Ok(())
    }

    /// The largest eigenvalue the step of `force` is set for: the
    /// Laplacian's, or for the elastic force its operator's.
    /// With springs, the elastic operator's is raised by the most one adds
    /// (the largest eigenvalue of `P / 2`, a bound: each spring is a particle's own block),
    /// with a pairing by the most its springs add (half their weight).
    pub fn lambda_max_for(&self, force: ForceModel) -> f32 {
        match (force, self.elastic_lambda_max) {
            (ForceModel::Elastic, Some(stiff)) => {
                let paired = self.pairing.as_ref().map_or(0.0, |p| 0.5 * p.rule.weight);
                stiff + springs_stiffness(&self.springs).max(paired)
            }
            _ => self.lambda_max,
        }
    }

    /// Sets how each of the elastic force's iterations pairs the skin with
    /// the observation and sets its springs ([`crate::stage2::pairing`]),
    /// or (`None`) stops pairing: the springs then stay as the last
    /// iteration set them.
    ///
    /// # Errors
    ///
    /// [`Error::Deformation`] for a pairing on a plan without the elastic
    /// model, of a particle that is not free or not in the model, or with a
    /// weight that is not a positive number or limits that are not positive
    /// lengths.
    pub fn set_pairing(&mut self, pairing: Option<Pairing>) -> Result<(), Error> {
        if let Some(pairing) = &pairing {
            let refuse = |why: String| Err(DeformError::Springs(why).into());
            if self.elastic.is_none() {
                return refuse(
                    "only the elastic force pulls towards an observation; this solve was \
                     prepared for another force"
                        .into(),
                );
            }
            let n = self.free.len();
            if let Some(&i) = pairing
                .skin
                .iter()
                .find(|&&i| !self.free.get(i as usize).copied().unwrap_or(false))
            {
                return refuse(format!(
                    "particle {i} is paired with the observation but is not a free particle of \
                     the model's {n}"
                ));
            }
            let rule = &pairing.rule;
            if !(rule.weight.is_finite() && rule.weight > 0.0) {
                return refuse(format!(
                    "the pairing's weight {} is not a positive number",
                    rule.weight
                ));
            }
            for (what, limit) in [("edge", rule.edge), ("robust scale", rule.robust)] {
                if !(limit.is_finite() && limit > 0.0) {
                    return refuse(format!(
                        "the pairing's {what} {limit} is not a positive length"
                    ));
                }
            }
            if !(rule.smooth.is_finite() && rule.smooth >= 0.0) {
                return refuse(format!(
                    "the pairing's smoothing radius {} is not a length of at least zero",
                    rule.smooth
                ));
            }
        }
        self.pairing = pairing;
        Ok(())
    }

    /// Sets every particle's spring towards the observation
    /// ([`crate::stage2::springs::spring`]), one per particle (zero where
    /// none; a control point's is never applied); an empty list takes them
    /// away. Only the elastic force applies them.
    ///
    /// # Errors
    ///
    /// [`Error::Deformation`] for a list that is not one per particle, one
    /// with a value that is not finite, or springs on a plan without the
    /// elastic model.
    pub fn set_springs(&mut self, springs: Vec<Spring>) -> Result<(), Error> {
        if !springs.is_empty() {
            if springs.len() != self.free.len() {
                return Err(DeformError::Springs(format!(
                    "{} springs for {} particles (one per particle)",
                    springs.len(),
                    self.free.len()
                ))
                .into());
            }
            if let Some(i) = springs.iter().position(|s| !s.is_finite()) {
                return Err(DeformError::Springs(format!(
                    "particle {i}'s spring is not finite ({:?})",
                    springs[i]
                ))
                .into());
            }
            if let Some(i) = springs.iter().position(|s| !s.is_positive()) {
                return Err(DeformError::Springs(format!(
                    "particle {i}'s spring pushes away ({:?}): its stiffness `a I + b u u^T` \
                     needs a >= 0 and a + b |u|^2 >= 0",
                    springs[i]
                ))
                .into());
            }
            if self.elastic.is_none() {
                return Err(DeformError::Springs(
                    "only the elastic force pulls towards an observation; this solve was \
                     prepared for another force"
                        .into(),
                )
                .into());
            }
        }
        self.springs = springs;
        Ok(())
    }

    /// The step `alpha = sigma / m`: `step_fraction` of the largest stable
    /// step, `2 / lambda_max` for the paper's force, `1 / lambda_max` for the
    /// symmetric one.
    pub fn alpha(&self, params: &DeformParams) -> f32 {
        let limit = match params.force {
            ForceModel::Paper => 2.0,
            ForceModel::Symmetric | ForceModel::Elastic => 1.0,
        };
        params.tuning.step_fraction * limit
            / self.lambda_max_for(params.force).max(f32::MIN_POSITIVE)
    }

    /// `c alpha`: the plain step is `-c alpha L e` for the error `e` while the
    /// rotations are fixed (`c = 2` for the symmetric force, 1 for the paper's).
    pub fn contraction(&self, params: &DeformParams) -> f32 {
        let c = match params.force {
            ForceModel::Paper => 1.0,
            ForceModel::Symmetric | ForceModel::Elastic => 2.0,
        };
        c * self.alpha(params)
    }

    /// The plain iteration `q <- (I - c alpha L) q + b` (`c = 2` symmetric, 1
    /// paper) contracts at `1 - 2 step_fraction lambda_min / lambda_max` for both.
    /// With the elastic force, whose smallest eigenvalue is at least the
    /// Laplacian's, `lambda_max` is its operator's.
    pub fn rho(&self, params: &DeformParams) -> f32 {
        let lambda_max = self.lambda_max_for(params.force);
        (1.0 - 2.0 * params.tuning.step_fraction * self.lambda_min / lambda_max).clamp(0.0, 0.9999)
    }

    /// The contraction a solve's Chebyshev weights and stopping rule use:
    /// [`Plan::rho`]; with a coarse space, the two-level iteration's
    /// (`coarse_rho`, measured by the device that built it). The elastic
    /// force runs without it (it is made for the Laplacian): [`Plan::rho`].
    pub fn solve_rho(&self, params: &DeformParams, coarse_rho: Option<f32>) -> f32 {
        match coarse_rho {
            Some(rho) if params.force != ForceModel::Elastic => rho,
            _ => self.rho(params),
        }
    }
}

/// A fingerprint of `connections` and `free`: two solvers whose keys agree
/// have the same connection Laplacian (a 64-bit hash; a model differing
/// in either is another key but for a chance of about 1 in 10^19).
pub fn laplacian_key(connections: &Connections, free: &[bool]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    connections.offsets.hash(&mut hasher);
    connections.indices.hash(&mut hasher);
    free.hash(&mut hasher);
    hasher.finish()
}

/// Which elastic models a solver may share: a hash of the rest positions
/// (their bits), the particles the integration constraint holds at
/// (`inside`) and the [`laplacian_key`] of the connections and free
/// particles.
pub fn elastic_key(positions: &[Vec3], inside: &[bool], laplacian_key: u64) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    laplacian_key.hash(&mut hasher);
    for p in positions {
        p.to_array().map(f32::to_bits).hash(&mut hasher);
    }
    inside.hash(&mut hasher);
    hasher.finish()
}

/// The elastic model another solver's plan made, its [`elastic_key`] and
/// the plan's largest eigenvalue with it ([`Plan::elastic_lambda_max`]):
/// a plan for the same key takes it (`SharedLaplacian` carries it).
#[derive(Debug, Clone)]
pub struct SharedElastic {
    key: u64,
    model: Arc<Elastic>,
    lambda_max: f32,
}

impl SharedElastic {
    /// The elastic model `plan` made, if any.
    pub fn of(plan: &Plan) -> Option<Self> {
        Some(Self {
            key: plan.elastic_key?,
            model: Arc::clone(plan.elastic.as_ref()?),
            lambda_max: plan.elastic_lambda_max?,
        })
    }

    /// The elastic model for Poisson ratio `poisson`, where it was made for
    /// `key` ([`elastic_key`]; `rest` and `connections` its rest shape and
    /// connections): the same one with the plan's largest eigenvalue for
    /// the same ratio, otherwise its weights made again for `poisson`
    /// ([`Elastic::with_poisson`]; the eigenvalue is then the caller's to
    /// estimate). The consistent gradients, most of the model's making, do
    /// not depend on the ratio.
    pub fn for_ratio(
        &self,
        key: u64,
        poisson: f32,
        rest: &[Vec3],
        connections: &Connections,
    ) -> Option<(Arc<Elastic>, Option<f32>)> {
        if self.key != key {
            return None;
        }
        if self.model.poisson == poisson {
            return Some((Arc::clone(&self.model), Some(self.lambda_max)));
        }
        Some((
            Arc::new(self.model.with_poisson(rest, connections, poisson)),
            None,
        ))
    }
}

/// The connection Laplacian's extreme eigenvalues that another solver
/// estimated, and the [`laplacian_key`] of the connections and free
/// particles it estimated them for: a plan for the same key takes them
/// instead of estimating them again.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SharedSpectrum {
    /// [`laplacian_key`] of the connections and free particles.
    pub key: u64,
    /// The smallest eigenvalue.
    pub lambda_min: f32,
    /// The largest eigenvalue.
    pub lambda_max: f32,
}

impl SharedSpectrum {
    /// The eigenvalues, where `key` is the one they were estimated for.
    pub fn for_key(&self, key: u64) -> Option<(f32, f32)> {
        (self.key == key).then_some((self.lambda_min, self.lambda_max))
    }
}

/// The RMS step, in ulps of the largest coordinate, below which a solve has
/// reached single precision.
const FLOOR_ULPS: f32 = 2.0;

/// Per particle: reachable from a control point through connections.
fn anchored(connections: &Connections, free: &[bool]) -> Vec<bool> {
    let mut reached: Vec<bool> = free.iter().map(|f| !f).collect();
    let mut stack: Vec<usize> = (0..free.len()).filter(|&i| reached[i]).collect();
    while let Some(i) = stack.pop() {
        for &j in connections.of(i) {
            if !reached[j as usize] {
                reached[j as usize] = true;
                stack.push(j as usize);
            }
        }
    }
    reached
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use tissue_core::{Attachment, SurfaceMesh};

    use super::*;

    /// A tetrahedron with one interior particle connected to two attached ones.
    fn small_model() -> ParticleModel {
        let on = |triangle| {
            Some(Attachment {
                triangle,
                barycentric: [0.5, 0.25, 0.25],
            })
        };
        ParticleModel {
            positions: vec![
                Vec3::splat(0.2),
                Vec3::new(0.25, 0.25, 0.0),
                Vec3::new(0.3, 0.0, 0.3),
            ],
            radii: vec![0.1, 0.05, 0.05],
            attachments: vec![None, on(0), on(1)],
            connections: Connections::from_pairs(3, [(0, 1), (0, 2)]),
            surface: SurfaceMesh::new(
                vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
                vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            ),
        }
    }

    #[test]
    fn only_interior_particles_move() {
        assert_eq!(
            Plan::new(&small_model()).unwrap().free,
            [true, false, false]
        );
    }

    #[test]
    fn invalid_model_is_refused_by_its_validation() {
        let mut model = small_model();
        model.attachments[2] = Some(Attachment {
            triangle: 4,
            barycentric: [1.0, 0.0, 0.0],
        });
        assert!(matches!(Plan::new(&model), Err(Error::InvalidModel(_))));
        let mut model = small_model();
        model.connections.offsets.pop();
        assert!(matches!(Plan::new(&model), Err(Error::InvalidModel(_))));
    }

    #[test]
    fn model_without_surface_particles_is_refused() {
        let mut model = small_model();
        model.attachments = vec![None; 3];
        let err = Plan::new(&model).unwrap_err();
        assert!(err.to_string().contains("no surface particles"), "{err}");
    }
}
