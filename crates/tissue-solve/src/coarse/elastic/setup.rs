//! What the elastic phase's two-level solve is made with, once per model:
//! its aggregates, and whether it smooths with the volume term (the
//! volume smoother's step and its contraction at rest).

use glam::Vec3;
use tissue_core::{Connections, ParticleModel};

use super::{CorrectionFor, ElasticCoarse, Making, REST_RATE_STEPS};
use crate::coarse::laplacian::Aggregates;
use crate::coarse::volume_smoother::{MAX_SMOOTHER_SWEEPS, SMOOTHER_SWEEPS, Smoothing};
use crate::model::elastic::Elastic;
use crate::stage2::params::DeformParams;
use crate::stage2::plan::Plan;

/// The contraction of the elastic phase's two-level iteration with the
/// volume smoother made as `smoothing` says, estimated once per model: the operator
/// linearised at rest, [`REST_RATE_STEPS`] Lanczos steps. Where the elastic
/// phase starts, every neighbourhood is near its rest volume and turned by
/// its rotation, and the estimate there agrees with this one to 0.004 on
/// both breast phantoms; the estimate costs as much as 40 iterations, too
/// much for every solve. With it, from the same Lanczos steps, the
/// iteration's most negative eigenvalue at rest ([`SMOOTHER_MIN_LOWEST`]).
/// `None` (with a warning) where the coarse matrix cannot be made.
pub fn rest_rate(
    aggregates: &Aggregates,
    rest: &[Vec3],
    connections: &Connections,
    elastic: &Elastic,
    smoothing: Smoothing,
    direct_max_aggregates: usize,
) -> Option<(f32, f32)> {
    let made_for = CorrectionFor {
        contraction: 0.0,
        smoothing: Some(smoothing),
        rho: None,
        direct_max_aggregates,
        envelope: false,
    };
    ElasticCoarse::made(
        aggregates,
        rest,
        rest,
        connections,
        elastic,
        made_for,
        Making {
            rate_steps: REST_RATE_STEPS,
            ..Making::default()
        },
    )
    .inspect_err(|e| log::warn!("the volume smoother's contraction could not be estimated: {e}"))
    .ok()
    .map(|coarse| (coarse.rho, coarse.lowest))
}

/// The largest cells (in mean connection lengths) the elastic aggregates
/// may have for the volume smoother. Two Jacobi sweeps never over-correct
/// the volume term, but they under-correct its medium-frequency modes,
/// which aggregates of at most 2 spacings carry and coarser ones do not:
/// on breast_c at 10,000 particles, cells of 2.5, 3 and 4 spacings put the
/// iteration's most negative eigenvalue at -1.14, -1.27 and -1.44 (it
/// diverges), and cells of 4.9 spacings (1,000 aggregates at 100,000
/// particles) at -3.3 (docs/METHOD.md, "The volume smoother").
pub const SMOOTHER_MAX_CELL: f32 = 2.0;

/// The Jacobi sweeps a model with part of its skin free starts with: its
/// one-sided neighbourhoods under the skin take more than a whole skin's.
/// With two (stopped by the accelerated rule) the posture searches of
/// breast_c and breast_d at 10,000 particles ran their elastic phases
/// again 3 and 4 times (stepping back 6 and 21 times), with four 0 and 3
/// times (0 and 19); both contract at rest at 0.92-0.95.
pub const FREE_SKIN_SWEEPS: usize = 4;

/// A measured contraction at or above this leaves the plain step in place
/// of the volume smoother: the smoother's iteration would not converge, or
/// hardly faster than the plain step's.
pub const SMOOTHER_MAX_RATE: f32 = 0.97;

/// The most negative eigenvalue the smoother's two-level iteration may
/// have at rest; below it the sweeps are doubled. Too few sweeps
/// under-correct the volume term's medium-frequency modes, which puts
/// the iteration's negative end towards -1, and where an elastic phase
/// starts (its operator linearised at a turned, stretched state) that end
/// lies lower than at rest: at a Poisson ratio of 0.495 with two sweeps
/// the shared breast cases' negative end at rest is -0.71 to -0.76, and
/// breast_c's and breast_e's elastic phases diverged after 5-8
/// iterations (each rescued by the conjugate gradient: 44 and 49
/// iterations, against 31 and 36 with four sweeps, whose end is -0.15 to
/// -0.17); at 0.49 it is -0.17 to -0.19 with two. The contraction itself,
/// `max(|lowest|, largest)`, is 0.91-0.92 in every one of these: it does
/// not tell them apart.
pub const SMOOTHER_MIN_LOWEST: f32 = -0.5;

/// How the volume smoother is made ([`Smoothing`]: `delta`,
/// [`crate::coarse::volume_smoother::SHEAR_STEP`] times the plan's largest
/// Laplacian eigenvalue, and its Jacobi sweeps) and its two-level
/// iteration's contraction at rest ([`rest_rate`]), where the elastic phase
/// has its two-level solve (`aggregates`), `params` asks for the smoother,
/// the aggregates' cells are at most [`SMOOTHER_MAX_CELL`] spacings and the
/// contraction is below [`SMOOTHER_MAX_RATE`] with at most
/// [`MAX_SMOOTHER_SWEEPS`] sweeps: [`SMOOTHER_SWEEPS`] first
/// ([`FREE_SKIN_SWEEPS`] where part of the skin is free), doubled while the
/// contraction is not below it or the most negative eigenvalue is below
/// [`SMOOTHER_MIN_LOWEST`] (a stiffer volume term needs more); `None`
/// otherwise, the plain step smoothing (said in the log where the
/// smoother was asked for). `known`, a solver's of the same connections and
/// parameters ([`crate::coarse::laplacian::SharedLaplacian::smoother_for`]),
/// stands in for the estimate.
pub fn volume_smoother(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
    aggregates: Option<&Aggregates>,
    direct_max_aggregates: usize,
    known: Option<(Smoothing, f32)>,
) -> Option<(Smoothing, f32)> {
    let (aggregates, elastic) = (aggregates?, plan.elastic.as_deref()?);
    if !params.tuning.volume_smoother {
        return None;
    }
    let free_skin = model
        .attachments
        .iter()
        .zip(&plan.controls)
        .any(|(a, &control)| a.is_some() && !control);
    let spacing = model.mean_connection_length();
    if aggregates.cell > SMOOTHER_MAX_CELL * spacing * 1.001 {
        log::info!(
            "the elastic phase smooths with the plain step: its aggregates' cells are {:.1} \
             spacings (at most {} for the volume smoother; a multilevel coarse space would keep \
             them small at this size)",
            aggregates.cell / spacing,
            SMOOTHER_MAX_CELL
        );
        return None;
    }
    if let Some((smoothing, rho)) = known {
        log::debug!(
            "the volume smoother: {} Jacobi sweeps, contraction {rho:.3} at rest (a solver's of \
             the same connections)",
            smoothing.sweeps
        );
        return Some((smoothing, rho));
    }
    let mut smoothing = Smoothing {
        delta: crate::coarse::volume_smoother::SHEAR_STEP * f64::from(plan.lambda_max),
        sweeps: if free_skin {
            FREE_SKIN_SWEEPS
        } else {
            SMOOTHER_SWEEPS
        },
    };
    loop {
        let (rho, lowest) = rest_rate(
            aggregates,
            &model.positions,
            &model.connections,
            elastic,
            smoothing,
            direct_max_aggregates,
        )?;
        if rho < SMOOTHER_MAX_RATE && lowest >= SMOOTHER_MIN_LOWEST {
            log::info!(
                "the volume smoother: {} Jacobi sweeps, contraction {rho:.3} at rest (its most \
                 negative eigenvalue {lowest:.2})",
                smoothing.sweeps
            );
            return Some((smoothing, rho));
        }
        if rho < SMOOTHER_MAX_RATE && smoothing.sweeps * 2 > MAX_SMOOTHER_SWEEPS {
            log::info!(
                "the volume smoother: {} Jacobi sweeps, contraction {rho:.3} at rest (its most \
                 negative eigenvalue {lowest:.2}, below {SMOOTHER_MIN_LOWEST}, at the most \
                 sweeps)",
                smoothing.sweeps
            );
            return Some((smoothing, rho));
        }
        if smoothing.sweeps * 2 > MAX_SMOOTHER_SWEEPS {
            log::warn!(
                "the elastic phase smooths with the plain step: the volume smoother's iteration \
                 contracts at {rho:.3} on this model with {} Jacobi sweeps (below \
                 {SMOOTHER_MAX_RATE} to use it)",
                smoothing.sweeps
            );
            return None;
        }
        log::debug!(
            "the volume smoother contracts at {rho:.3} (most negative eigenvalue {lowest:.2}) \
             with {} Jacobi sweeps; trying {}",
            smoothing.sweeps,
            smoothing.sweeps * 2
        );
        smoothing.sweeps *= 2;
    }
}

/// The aggregates of the elastic phase's two-level solve under `params`:
/// with the elastic force and the two-level solve on, the cells of
/// `coarse` grown until there are at most `elastic_coarse_max_aggregates`;
/// none otherwise, or (with a warning) where they cannot be made.
pub fn elastic_aggregates(
    model: &ParticleModel,
    plan: &Plan,
    params: &DeformParams,
) -> Option<Aggregates> {
    if plan.elastic.is_none()
        || params.tuning.coarse == 0.0
        || params.tuning.elastic_coarse_max_aggregates == 0
    {
        return None;
    }
    Aggregates::new(
        &model.positions,
        &model.connections,
        &plan.free,
        params.tuning.coarse * model.mean_connection_length(),
        params.tuning.elastic_coarse_max_aggregates,
    )
    .inspect_err(|e| log::warn!("the elastic phase runs without its two-level solve: {e}"))
    .ok()
}
