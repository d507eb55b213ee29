//! What solvers of one model share: the connection Laplacian's spectrum and
//! two-level coarse space depend only on the connections and the free
//! particles, not on the positions (docs/METHOD.md, "Gravity and the
//! unloaded shape", *The Laplacian's preparation shared*); the volume
//! smoother's contraction at rest hardly depends on them. The elastic
//! model does, and is shared only within one rest shape.

use std::sync::Arc;

use tissue_core::ParticleModel;

use super::{CoarseSpace, coarse_space};
use crate::coarse::volume_smoother::Smoothing;
use crate::stage2::params::DeformParams;
pub use crate::stage2::plan::laplacian_key;
use crate::stage2::plan::{Plan, SharedElastic, SharedSpectrum};

/// What preparing a solver costs that depends only on a model's
/// connections and which of its particles are free, not on where they are:
/// the connection Laplacian's extreme eigenvalues and its two-level coarse
/// space (the Laplacian has one weight per connection). Solvers of one
/// model in other rest shapes with the same region held (the unloaded
/// shape's rounds, the stiffness search's trials) take it from the last
/// one instead of making it again ([`SharedLaplacian::spectrum_for`],
/// [`coarse_space_shared`]); anything else makes its own. It may also
/// carry the elastic model, for solvers in the same rest shape at any
/// Poisson ratio ([`SharedLaplacian::elastic`]: the uncertainty's other
/// ratios).
#[derive(Debug, Clone)]
pub struct SharedLaplacian {
    /// The Laplacian's extreme eigenvalues, and the [`laplacian_key`] of
    /// the connections and free particles they were made for.
    spectrum: SharedSpectrum,
    coarse: Option<(CoarseFor, Arc<CoarseSpace>)>,
    /// The volume smoother's making and its contraction at rest, and the
    /// parameters they were made under.
    smoother: Option<(SmootherFor, (Smoothing, f32))>,
    /// The elastic model a solver's plan made, for the same rest shape.
    elastic: Option<SharedElastic>,
}

/// What a volume smoother's contraction at rest was estimated for besides
/// the connections and the free particles.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SmootherFor {
    poisson: f32,
    max_aggregates: usize,
    direct_max: usize,
}

impl SmootherFor {
    fn of(params: &DeformParams) -> Self {
        Self {
            poisson: params.poisson,
            max_aggregates: params.tuning.elastic_coarse_max_aggregates,
            direct_max: params.tuning.elastic_coarse_direct_max_aggregates,
        }
    }
}

/// What a coarse space was made for besides the connections and the free
/// particles.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CoarseFor {
    /// The cell in mean connection lengths, [`crate::stage2::params::SolverTuning::coarse`].
    coarse: f32,
    max_aggregates: usize,
    direct_max: usize,
    /// The plain step's contraction its rate was estimated for.
    contraction: f32,
}

impl CoarseFor {
    fn of(plan: &Plan, params: &DeformParams) -> Self {
        Self {
            coarse: params.tuning.coarse,
            max_aggregates: params.tuning.coarse_max_aggregates,
            direct_max: params.tuning.coarse_direct_max_aggregates,
            contraction: plan.contraction(&params.shear()),
        }
    }
}

impl SharedLaplacian {
    /// What a solver prepared for the Laplacian of `key`
    /// ([`laplacian_key`]): its extreme eigenvalues, the coarse space it
    /// made for `params` under `plan`, if any, and its volume smoother's
    /// making and contraction at rest, if any.
    pub fn new(
        key: u64,
        plan: &Plan,
        params: &DeformParams,
        coarse: Option<Arc<CoarseSpace>>,
        smoother: Option<(Smoothing, f32)>,
    ) -> Self {
        Self {
            spectrum: SharedSpectrum {
                key,
                lambda_min: plan.lambda_min,
                lambda_max: plan.lambda_max,
            },
            coarse: coarse.map(|space| (CoarseFor::of(plan, params), space)),
            smoother: smoother.map(|made| (SmootherFor::of(params), made)),
            elastic: None,
        }
    }

    /// With the elastic model `plan` made (if any), for solvers of the same
    /// rest shape ([`SharedLaplacian::elastic`]).
    pub fn with_elastic(mut self, plan: &Plan) -> Self {
        self.elastic = SharedElastic::of(plan);
        self
    }

    /// The elastic model it holds, if any ([`SharedElastic::for_ratio`]
    /// gives it to a plan of the same rest shape at any Poisson ratio).
    pub fn elastic(&self) -> Option<&SharedElastic> {
        self.elastic.as_ref()
    }

    /// The volume smoother's making and contraction at rest, where `key`
    /// and the parameters they were made under match `params`, the Poisson
    /// ratio at most theirs. Another rest shape of the same connections
    /// moves the contraction little (breast_c's posture search at 10,000
    /// particles: 0.925-0.930 over its shapes), and estimating it costs as
    /// much as 40 iterations. A lower ratio's volume term is softer: its
    /// smoother needs no more sweeps and contracts at least as fast
    /// (breast_c at 10,000 particles: 0.889 at 0.45, 0.900 at 0.49, 0.912
    /// at 0.495), so the contraction made for a higher ratio bounds it (the
    /// acceleration then takes the slower rate, safely); a higher ratio
    /// estimates its own.
    pub fn smoother_for(&self, key: u64, params: &DeformParams) -> Option<(Smoothing, f32)> {
        let asked = SmootherFor::of(params);
        match self.smoother {
            Some((made_for, made))
                if self.spectrum.key == key
                    && made_for.max_aggregates == asked.max_aggregates
                    && made_for.direct_max == asked.direct_max
                    && asked.poisson <= made_for.poisson =>
            {
                Some(made)
            }
            _ => None,
        }
    }

    /// The Laplacian's extreme eigenvalues, where `key` is the one they
    /// were estimated for.
    pub fn spectrum_for(&self, key: u64) -> Option<(f32, f32)> {
        self.spectrum.for_key(key)
    }

    /// The Laplacian's extreme eigenvalues with their key, for a plan.
    pub fn spectrum(&self) -> &SharedSpectrum {
        &self.spectrum
    }

    /// [`laplacian_key`] of the connections and free particles it was made for.
    pub fn key(&self) -> u64 {
        self.spectrum.key
    }

    /// The coarse space it holds, if any.
    pub fn coarse(&self) -> Option<&Arc<CoarseSpace>> {
        self.coarse.as_ref().map(|(_, space)| space)
    }

    /// The coarse space, where `key` and what it is asked for match.
    fn coarse_for(&self, key: u64, made_for: CoarseFor) -> Option<Arc<CoarseSpace>> {
        match &self.coarse {
            Some((made, space)) if self.spectrum.key == key && *made == made_for => {
                Some(Arc::clone(space))
            }
            _ => None,
        }
    }
}

/// [`coarse_space`], taken from `shared` where it was made for the same
/// Laplacian (`key`) and parameters.
pub fn coarse_space_shared(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
    shared: Option<(&SharedLaplacian, u64)>,
) -> Option<Arc<CoarseSpace>> {
    if params.tuning.coarse == 0.0 {
        return None;
    }
    let made_for = CoarseFor::of(plan, params);
    if let Some(space) = shared.and_then(|(shared, key)| shared.coarse_for(key, made_for)) {
        log::debug!(
            "two-level solve: the {} aggregates of a solver of the same connections",
            space.count()
        );
        return Some(space);
    }
    coarse_space(model, plan, params).map(Arc::new)
}
