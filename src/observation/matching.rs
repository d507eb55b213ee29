//! The model's skin pulled onto an observation without correspondence
//! inside the elastic solve ([`match_observation`]).

use std::borrow::Cow;

use rayon::prelude::*;
use tissue_core::ParamError;
use tissue_solve::stage2::{
    CLOUD_SMOOTHING, ENERGY_ROUNDING, ElasticSolve, NO_LIMIT, Pairing, PairingRule, RIGID_TRIM,
    SPRING_WEIGHT, pair_plane, paired_point, paired_spring, predict_paired,
};

use super::ObservationError;
use super::held::HeldObservation;
use super::observed::{Kind, Observation};
use super::region::{HeldRegion, held_field};
use crate::backend::Solver;
use crate::deformation::DeformReport;
use crate::field::{SurfaceField, signed_distances};
use crate::{Error, ParticleModel, SurfaceMesh, Vec3};

/// A tracking frame's predicted start ([`predict_paired`]) pairs the skin
/// this many times: at the last answer, then at each prediction.
pub const PREDICTION_ROUNDS: usize = 3;

/// The springs' weight grows over this many solves, each from where the
/// last one ended, by [`STAGE_GROWTH`] each to [`MatchParams::weight`]:
/// a weak pull first moves the skin most of the way without the large
/// steps that overshoot while the pairs change quickly, then a stiff one
/// holds it on the observation. On the shared cases' remeshed surfaces at
/// 10,000 particles, paired with the plane smoothed over their vertices,
/// 1 to 4 stages land the same millimetres (within 0.0005 mm) in 435 /
/// 394 / 486 iterations with one stage and 129 / 122 / 100 with four, the
/// fewest in all, every stage by Chebyshev's steps (86 / 82 / 82 with
/// the first by the conjugate gradient, [`SURFACE_FIRST_STAGE`];
/// docs/METHOD.md, "Observations without correspondence").
pub const MATCH_STAGES: usize = 4;

/// Solves of a tracking frame matched from the last frame's answer
/// ([`MatchParams::next_frame`]): the skin starts near the observation, so
/// no weak pull is needed first. On the phantom's sag in three steps of
/// 4 mm (another triangulation, and scans of its upper skin) at 2,000
/// particles, the second and third frames took 88 and 90 iterations with
/// one stage against 161 and 156 with four (scans: 308 and 296 against
/// 861 and 999).
pub const FRAME_STAGES: usize = 1;

/// A surface's stages before the last one solve to this many times the
/// solver's tolerance ([`MatchParams::early_tolerance`]). On the shared
/// cases' remeshed surfaces at 10,000 particles: 320 / 513 / 412
/// iterations at 1, 250 / 340 / 349 at 30, 221 / 287 / 301 at 100, the
/// millimetres the same to 0.001 mm; at 1,000, 148 / 283 / 264 and up to
/// 0.003 mm off. (The shared clouds at 1,000 with a loose stage before
/// each, the skin a stage left behind ended 10-16 mm off.)
pub const EARLY_TOLERANCE: f32 = 100.0;

/// The factor between one stage's weight and the next's.
pub const STAGE_GROWTH: f32 = 4.0;

/// A particle farther than this many cloud spacings along the cloud's
/// plane from its nearest point is past the cloud's edge (or over a hole
/// in it): nothing is seen there, and it is not pulled.
pub const CLOUD_EDGE_SPACINGS: f32 = 2.0;

/// A surface's triangles within this many mean connection lengths of the
/// model's held region at every corner show that region: no free skin
/// particle is paired on them.
pub const HELD_REACH: f32 = 0.5;

/// A surface of another triangulation is paired as the plane smoothed over
/// its vertices ([`MatchParams::surface_smoothing`]), radius `h` this many
/// of its mean edges. The distance to a triangle mesh bends where the
/// nearest point crosses from a face to an edge or a vertex, or jumps to
/// another face: a particle on such a place is pulled one way and then the
/// other, the last stage steps back, and it ends at the float floor. The
/// smoothed plane moves with the particle. On the shared cases' remeshed
/// surfaces at 10,000 particles (the first stage by Chebyshev's steps):
/// 129 / 122 / 100 iterations, every stage
/// to the tolerance, against 184 / 268 / 271 paired with the nearest
/// point (the last stages at the float floor), the probes and tumour
/// centres within 0.03 mm of theirs on breast_d and breast_e and closer on
/// breast_c (docs/METHOD.md, "Observations without correspondence"); at
/// 0.75 and 1.5 edges 133-152 and 100-138 iterations.
pub const SURFACE_SMOOTHING: f32 = 1.0;

/// A surface's first stage from rest descends by the conjugate gradient
/// where the solve's own choice is the default (Chebyshev's steps, then
/// the conjugate gradient where the potential first rises, which a
/// pairing does not take): the skin starts far from the surface, and
/// Chebyshev's first steps overshoot, its potential rising after 6-7
/// iterations on every shared case, then settle at half their length. On
/// the shared cases' remeshed surfaces at 10,000 particles the first
/// stage took 21 / 22 / 22 iterations against 65 / 64 / 41, the match 86
/// / 82 / 82 against 129 / 122 / 100 and 5-14 % less time (medians of
/// eight runs alternating: 0.54 / 0.56 / 0.58 s against 0.62 / 0.65 /
/// 0.61 s on two cores), the same millimetres. The later stages start
/// near their answer, where a Chebyshev iteration costs half of one of
/// the conjugate gradient's (its line search measures the potential); a
/// cloud's first stage gained nothing (its pairs' robust scale and rim),
/// nor does a surface paired with the nearest point, whose potential
/// jumps as the nearest point moves.
pub const SURFACE_FIRST_STAGE: ElasticSolve = ElasticSolve::ConjugateGradient;

/// The noise scale where none is given, for a surface in mean connection
/// lengths of the model (another segmentation's corners and facets).
pub const SURFACE_NOISE: f32 = 0.1;

/// [`SURFACE_NOISE`]'s twin for a point cloud, in the cloud's spacings
/// (the shared cases' scans: 0.5 mm of noise on points 2.6 mm apart).
pub const CLOUD_NOISE: f32 = 0.2;

/// The skin's median distance from the observation at a stage's start may
/// be at most this share of the model's size (its bounding-box diagonal):
/// beyond it the observation cannot be of this organ in this frame and
/// unit, and it is refused.
pub const MAX_REACH: f32 = 0.25;

/// The largest change of the organ's volume an observation may ask
/// for: soft tissue keeps its volume, so beyond it the observation is in
/// another frame or unit ([`Observation::implied_volume_change`]; refused
/// before the solve), or the match asked the impossible (flagged after it).
/// The shared cases' observations imply -3 % to +1 %; their clouds shifted
/// 20 mm away from the chest wall +15 % to +33 %.
pub const MAX_VOLUME_CHANGE: f32 = 0.1;

/// A rest vertex within this many mean connection lengths of an observed
/// closed surface lies on it ([`super::held_on`]): held where no held region is
/// given.
pub const HELD_TOLERANCE: f32 = 0.02;

/// The held region's rest vertices may lie this many mean connection
/// lengths from an observed closed surface (their median) at most: it does
/// not move, so farther off the surface is in another frame.
pub const HELD_OFF: f32 = 0.5;

/// The observation's field is exact within this many of its own spacings
/// of the observation (a surface's mean edge, a cloud's spacing): a
/// particle farther off is answered by a search over every triangle or
/// point.
pub const FIELD_MARGIN: f32 = 4.0;

/// A surface's field has cells of this many of its mean edges, or of the
/// model's mean connection length where that is longer: finer cells
/// multiply the band's cells and the candidates each gathers while the
/// pairing's queries, a connection length apart, gain little. The
/// phantom's sag cut into 22,440 triangles (2 mm edges) took 1.07 s to
/// grid at 10,000 particles in cells of one edge, 0.27 s in two and 0.13 s
/// in four, the match's iterations as fast; against the shared cases'
/// remeshed surfaces (6 mm edges) cells of four edges made each iteration
/// 4-11 % slower than cells of two. The query is exact whatever the cell.
pub const FIELD_CELL_EDGES: f32 = 2.0;

/// How [`match_observation`] pulls the skin.
#[derive(Debug, Clone, PartialEq)]
pub struct MatchParams {
    /// The springs' last weight in units of the Laplacian's largest
    /// eigenvalue ([`SPRING_WEIGHT`]).
    pub weight: f32,
    /// The observation's noise scale (model units): a cloud's pairs
    /// farther than [`RIGID_TRIM`] times the larger of it and the pairs'
    /// robust deviation at a stage's start (the robust scale,
    /// [`PairingRule::robust`]) are pulled with the force they would have
    /// there (Huber's; a surface's pull in proportion to the distance:
    /// every part of the skin is on it somewhere). `None`:
    /// [`SURFACE_NOISE`] mean connection lengths for a surface, the
    /// cloud's own for a cloud (the larger of [`CLOUD_NOISE`] spacings and
    /// its points' scatter, [`Observation::cloud_noise`]).
    pub noise: Option<f32>,
    /// Solves over which the weight grows ([`MATCH_STAGES`]).
    pub stages: usize,
    /// For a surface, the stages before the last solve to this many times
    /// the solver's tolerance ([`EARLY_TOLERANCE`]): only the last stage's
    /// answer is the match, the ones before bring the skin near it. A
    /// cloud's stages all solve to the solver's tolerance: each stage's
    /// robust scale is set from where the one before left the skin.
    pub early_tolerance: f32,
    /// Whether the first solve starts from the solver's positions as from
    /// a converged solve ([`Solver::warm_start`]: a tracking frame from the
    /// last frame's answer) rather than as a solve from its start.
    pub warm: bool,
    /// How a surface is paired, in its mean edges
    /// ([`SURFACE_SMOOTHING`]): above zero, with the plane of its
    /// vertices smoothed over this radius (a cloud's plane,
    /// [`CLOUD_SMOOTHING`], with the surface's own normals, each vertex
    /// lifted so that the smoothed plane passes through it); zero, with
    /// its nearest point and the curvature of the distance there (a
    /// face's plane, an edge's line, a vertex's point). A cloud's
    /// smoothing is its own.
    pub surface_smoothing: f32,
    /// For a `warm` match (a tracking frame), whether it starts where the
    /// last frames' changes put the skin on the observation
    /// ([`predict_paired`]), where that lowers the potential, rather than
    /// at the last answer.
    pub predict: bool,
    /// For a match in a tracking sequence: whether the elastic correction
    /// the match ends with is kept for the next frame, and a `warm` match
    /// starts with the one in hand rather than making it again
    /// ([`Solver::set_springs_keeping_correction`]). Made at an earlier
    /// frame's start with that frame's springs, it is a preconditioner for
    /// springs that change little, as a correspondence's tracking frames
    /// keep theirs; a frame that circles far from it is solved again from
    /// a shear phase, the correction made anew.
    pub keep_correction: bool,
}

impl MatchParams {
    /// A tracking frame's match, from the last frame's answer: warm, in
    /// [`FRAME_STAGES`] solves, with the noise scale `noise`.
    pub fn next_frame(noise: Option<f32>) -> Self {
        Self {
            noise,
            stages: FRAME_STAGES,
            warm: true,
            predict: true,
            ..Self::default()
        }
    }
}

impl Default for MatchParams {
    fn default() -> Self {
        Self {
            weight: SPRING_WEIGHT,
            noise: None,
            stages: MATCH_STAGES,
            early_tolerance: EARLY_TOLERANCE,
            warm: false,
            surface_smoothing: SURFACE_SMOOTHING,
            predict: true,
            keep_correction: false,
        }
    }
}

/// Distances from the observed points to the deformed model's surface.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Residual {
    /// Root mean square.
    pub rms: f32,
    /// 95th percentile.
    pub p95: f32,
    /// Largest.
    pub max: f32,
}

/// How a [`match_observation`] went.
#[derive(Debug, Clone)]
pub struct MatchReport {
    /// Solves run (one a stage).
    pub stages: usize,
    /// Whether the last stage's solve converged.
    pub converged: bool,
    /// Iterations over all stages.
    pub iterations: usize,
    /// Free skin particles (surface particles the solve moves).
    pub skin: usize,
    /// Of them, those pulled towards the observation at the end.
    pub pulled: usize,
    /// Of them, those not pulled at the end: for a cloud, past its edge
    /// (nothing is seen there).
    pub set_aside: usize,
    /// Of those pulled, the ones farther from the observation than the
    /// robust scale at the end: pulled with a bounded force (a pair with
    /// an outlier, or skin the solve could not bring to the observation).
    pub beyond_robust: usize,
    /// The last stage's robust scale (model units; [`PairingRule::robust`]):
    /// a cloud's; `None` for a surface, whose pairs all pull in proportion
    /// to their distance.
    pub robust: Option<f32>,
    /// Distances from the observed points to the deformed model's surface.
    pub residual: Residual,
    /// The deformed model surface's volume over the rest surface's, less
    /// one: soft tissue keeps its volume, so a large change says the
    /// observation asked the impossible (another unit, or a frame shifted
    /// away from the held region).
    pub volume_change: f32,
    /// The model's surface carried by the solve, its held region where it
    /// is (a frame of the rest surface).
    pub surface: SurfaceMesh,
    /// The last stage's solve.
    pub last: DeformReport,
    /// The observation as the last stage paired the skin with it: what
    /// the uncertainty's re-solves pair it with again
    /// ([`crate::uncertainty::HeldBy`]).
    pub held: HeldObservation,
}

impl MatchReport {
    /// The share of the free skin pulled towards the observation.
    pub fn observed_fraction(&self) -> f32 {
        self.pulled as f32 / self.skin.max(1) as f32
    }
}

/// Deforms the model held by `solver` (its control points placed: the
/// held region, the chest wall, by [`Solver::set_surface`]) so that its
/// free skin lies on `observation`, which has no correspondence with it.
///
/// Every elastic iteration pairs each free skin particle with its nearest
/// observed point and pulls it there with a spring of the distance's
/// curvature (a face's or the cloud's fitted plane, an edge's line, a
/// vertex's point; [`Solver::set_pairing`], on the solver's device): along
/// a plane the skin slides where the mechanics sends it. The springs' weight grows over [`MatchParams::stages`]
/// solves; for a cloud, those past its edge are not pulled, and those
/// farther off than the robust scale (set at each stage's start) are
/// pulled with the force they would have there (Huber's). Needs the
/// elastic force. The solver is left without springs or pairing.
///
/// # Errors
///
/// [`Error::Param`] for absurd parameters; [`Error::Deformation`] without
/// the elastic force; [`Error::Observation`] where the observation cannot
/// be of the model in its frame and unit ([`Observation::check_against`])
/// or no free skin particle can be paired; the solver's errors.
pub fn match_observation(
    solver: &mut Solver,
    model: &ParticleModel,
    observation: &Observation,
    params: &MatchParams,
) -> Result<MatchReport, Error> {
    match_observation_held(solver, model, observation, params, None)
}

/// [`match_observation`] with the model's held region made beforehand
/// ([`HeldRegion::of`], for a sequence of matches of one solver); made
/// again where `held` is `None` or was made for other control points.
///
/// # Errors
///
/// As [`match_observation`].
pub fn match_observation_held(
    solver: &mut Solver,
    model: &ParticleModel,
    observation: &Observation,
    params: &MatchParams,
    held: Option<&HeldRegion>,
) -> Result<MatchReport, Error> {
    ParamError::check(
        params.weight.is_finite() && params.weight > 0.0,
        "weight",
        params.weight,
        "a positive number",
    )?;
    // Only a given noise can be refused: shown as the number it is.
    let noise = params.noise.map_or_else(String::new, |n| n.to_string());
    ParamError::check(
        params.noise.is_none_or(|n| n.is_finite() && n >= 0.0),
        "noise",
        &noise,
        "a distance of at least zero",
    )?;
    ParamError::check(
        (1..=8).contains(&params.stages),
        "stages",
        params.stages,
        "1 to 8",
    )?;
    ParamError::check(
        params.early_tolerance.is_finite() && params.early_tolerance >= 1.0,
        "early_tolerance",
        params.early_tolerance,
        "a factor of at least 1",
    )?;
    ParamError::check(
        params.surface_smoothing.is_finite() && (0.0..=8.0).contains(&params.surface_smoothing),
        "surface_smoothing",
        params.surface_smoothing,
        "0 to 8 mean edges of the surface",
    )?;
    let plan = solver.plan().clone();
    // A noise beyond the farthest the skin may lie from the observation
    // leaves the robust scale and the residual's flag nothing to tell.
    ParamError::check(
        params.noise.is_none_or(|n| n <= MAX_REACH * plan.size),
        "noise",
        &noise,
        format!(
            "at most a quarter of the organ's size ({:.3}): no scan is that noisy (is it in \
             another unit?)",
            MAX_REACH * plan.size
        ),
    )?;
    let solve_params = solver.params().clone();
    let spacing = model.mean_connection_length();
    let skin: Vec<u32> = (0..model.len())
        .filter(|&i| model.attachments[i].is_some() && plan.free[i])
        .map(|i| i as u32)
        .collect();
    observation.check_against(&model.surface, solver.params().observed.as_deref(), spacing)?;
    let made;
    let region = held.filter(|region| region.made_for(solver));
    let held = match region {
        Some(region) => region.field.as_ref(),
        None => {
            made = held_field(model, &plan.controls)?;
            made.as_ref()
        }
    };
    // The model's surface bound to the particles: the skin the match
    // starts from, and the answer's surface.
    let bound = match region.map(|region| region.surface.clone()) {
        Some(embedding) => solver.bind_embedded(embedding)?,
        None => solver.bind(&model.surface.vertices)?,
    };
    let mut field = observation.pairing_field(
        held,
        HELD_REACH * spacing,
        spacing,
        params.surface_smoothing,
    )?;
    // A cloud's points on lines of points (a stylus's strips) take the
    // normal of the skin the match starts from.
    if observation.on_lines() > 0 {
        let start = SurfaceMesh {
            vertices: solver.carry(&bound)?,
            ..model.surface.clone()
        };
        if let Some(turned) = observation.turned_on(&start)? {
            field.field = Cow::Owned(turned);
        }
    }
    // A cloud's pairs have a robust scale at each stage and all its stages
    // solve to the tolerance; a surface's, smoothed or not, pull in
    // proportion to their distance.
    let scan = observation.is_cloud();
    let (cloud, edge, noise, smooth) = match (&observation.kind, field.smoothed_edge) {
        (
            Kind::Cloud {
                spacing: cloud,
                noise: scale,
                ..
            },
            _,
        ) => (
            true,
            CLOUD_EDGE_SPACINGS * cloud,
            params.noise.unwrap_or(*scale),
            CLOUD_SMOOTHING * cloud,
        ),
        (Kind::Surface(_), Some(edge)) => (
            true,
            CLOUD_EDGE_SPACINGS * edge,
            params.noise.unwrap_or(SURFACE_NOISE * spacing),
            params.surface_smoothing * edge,
        ),
        (Kind::Surface(_), None) => (
            false,
            NO_LIMIT,
            params.noise.unwrap_or(SURFACE_NOISE * spacing),
            0.0,
        ),
    };
    let paired_on = field;
    let field = &paired_on.field;
    // A surface paired with its smoothed plane ([`SURFACE_FIRST_STAGE`]).
    let smoothed_surface = !scan && paired_on.smoothed_edge.is_some();
    solver.set_observation(Some(field))?;
    let mut iterations = 0;
    let mut last = None;
    let begun = solver.positions().to_vec();
    let mut rule = PairingRule {
        weight: 0.0,
        edge,
        robust: NO_LIMIT,
        cloud,
        smooth,
    };
    for stage in 0..params.stages {
        let start = solver.positions().to_vec();
        rule.weight = stage_weight(params.weight, params.stages, stage) * plan.lambda_max;
        let median = median_distance(field, &skin, &start, &rule);
        let most = MAX_REACH * plan.size;
        if median.is_some_and(|median| median > most) {
            clear(solver)?;
            let median = median.unwrap_or_default();
            return Err(ObservationError::Unreachable { median, most }.into());
        }
        rule.robust = match median {
            Some(median) if scan => RIGID_TRIM as f32 * (1.4826_f32 * median).max(noise),
            _ => NO_LIMIT,
        };
        let pairing = Pairing {
            skin: skin.clone(),
            rule,
        };
        let (springs, iterated) = pairing.for_solve_from(field, &start);
        if !springs.iter().any(|s| !s.is_zero()) {
            clear(solver)?;
            return Err(ObservationError::Unpaired { skin: skin.len() }.into());
        }
        let predicted = if stage == 0 && params.warm && params.predict {
            let noise = solve_params.tolerance * plan.size;
            predict_paired(
                &start,
                solver.history(),
                field,
                &pairing,
                PREDICTION_ROUNDS,
                noise,
            )
        } else {
            None
        };
        if stage == 0 && params.warm && params.keep_correction {
            solver.set_springs_keeping_correction(springs)?;
        } else {
            solver.set_springs(springs)?;
        }
        solver.set_pairing(Some(iterated))?;
        let last_stage = stage + 1 == params.stages;
        solver.set_params(solve_params.clone().with(|p| {
            if !last_stage && !scan {
                p.tolerance *= params.early_tolerance;
            }
            if stage == 0
                && !params.warm
                && smoothed_surface
                && p.tuning.elastic_solve == ElasticSolve::ChebyshevThenConjugateGradient
            {
                p.tuning.elastic_solve = SURFACE_FIRST_STAGE;
            }
        }))?;
        if stage > 0 || params.warm {
            solver.warm_start(&start)?;
        }
        if let Some(predicted) = predicted {
            predict_if_lower(solver, &start, &predicted)?;
        }
        let report = solver.solve()?;
        log::debug!(
            "match stage {stage}: weight {:.3e}, robust scale {}, {} iterations, stopped by {:?} \
             (error estimate {:.1e})",
            rule.weight,
            if rule.robust < NO_LIMIT {
                format!("{:.3}", rule.robust)
            } else {
                "none".to_owned()
            },
            report.iterations,
            report.stopped_by,
            report.residual
        );
        iterations += report.iterations;
        last = Some(report);
    }
    if !params.warm {
        // The stages' answers are no frames: the next frame's prediction
        // takes the match's whole change.
        solver.restart_history(&begun);
    }
    let end = solver.positions().to_vec();
    // What holds the skin at the answer: the uncertainty's re-solves pair
    // it again as the last stage did.
    let pairing = Pairing { skin, rule };
    // Each free skin particle paired once at the answer: whether it is
    // pulled, and whether from farther off than the robust scale.
    let rule = pairing.rule;
    let (pulled, beyond_robust) = pairing
        .skin
        .par_iter()
        .map(|&i| {
            let x = end[i as usize];
            let paired = paired_point(field, x, &rule);
            if paired_spring(x, &paired, &rule).is_zero() {
                return (0, 0);
            }
            let far = pair_plane(x, paired.point, paired.normal, &rule)
                .is_some_and(|(_, d)| d > rule.robust);
            (1, usize::from(far))
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let skin = pairing.skin.len();
    let held = paired_on.held(pairing);
    clear_keeping(solver, params.keep_correction)?;
    let mut surface = SurfaceMesh {
        vertices: solver.carry(&bound)?,
        ..model.surface.clone()
    };
    // The held region stays where it is: its vertices exactly, not as the
    // particles around them carry them.
    if let Some(held) = &solver.params().observed {
        for (v, _) in held.iter().enumerate().filter(|(_, h)| **h) {
            surface.vertices[v] = model.surface.vertices[v];
        }
    }
    let residual = residual(observation.points(), &surface)?;
    let volume_change = surface.signed_volume() / model.surface.signed_volume() - 1.0;
    let last = last.ok_or_else(|| Error::from(ObservationError::Unpaired { skin }))?;
    Ok(MatchReport {
        stages: params.stages,
        converged: last.converged,
        iterations,
        skin,
        pulled,
        set_aside: skin - pulled,
        beyond_robust,
        robust: (rule.robust < NO_LIMIT).then_some(rule.robust),
        residual,
        volume_change: volume_change as f32,
        surface,
        last,
        held,
    })
}

/// Starts the solve from `predicted` where the potential there (the skin
/// paired there) is below the one at `start` by more than its rounding
/// ([`ENERGY_ROUNDING`] of its parts' magnitude, so that every device
/// decides alike); otherwise from `start`, where the solver starts now.
fn predict_if_lower(solver: &mut Solver, start: &[Vec3], predicted: &[Vec3]) -> Result<(), Error> {
    if !predicted.iter().all(|p| p.is_finite()) {
        return Ok(());
    }
    let Some(at_start) = solver.potential_parts()? else {
        return Ok(());
    };
    solver.warm_start(predicted)?;
    let lower = solver.potential_parts()?.is_some_and(|at| {
        let rounding = ENERGY_ROUNDING * at.magnitude.max(at_start.magnitude);
        at.value.is_finite() && at.value < at_start.value - rounding
    });
    log::debug!(
        "the predicted start {}",
        if lower {
            "lowers the potential"
        } else {
            "does not lower the potential: set aside"
        }
    );
    if !lower {
        solver.warm_start(start)?;
    }
    Ok(())
}

/// The springs' weight of stage `stage` of `stages` (in the Laplacian's
/// largest eigenvalue): `weight` at the last, [`STAGE_GROWTH`] times less
/// at each one before.
fn stage_weight(weight: f32, stages: usize, stage: usize) -> f32 {
    let before_last = stages.saturating_sub(stage + 1);
    weight / STAGE_GROWTH.powi(before_last as i32)
}

/// Takes the springs, the pairing and the observation away.
fn clear(solver: &mut Solver) -> Result<(), Error> {
    clear_keeping(solver, false)
}

/// [`clear`], the elastic correction kept where `keep_correction` says
/// ([`MatchParams::keep_correction`]).
fn clear_keeping(solver: &mut Solver, keep_correction: bool) -> Result<(), Error> {
    solver.set_pairing(None)?;
    if keep_correction {
        solver.set_springs_keeping_correction(Vec::new())?;
    } else {
        solver.set_springs(Vec::new())?;
    }
    solver.set_observation(None)
}

/// The median of the skin's distances from the observation at
/// `positions`, those past a cloud's edge left out (`None`: all are). The
/// robust scale is [`RIGID_TRIM`] times the larger of the noise and the
/// robust deviation, 1.4826 times the median.
fn median_distance(
    field: &SurfaceField,
    skin: &[u32],
    positions: &[Vec3],
    rule: &PairingRule,
) -> Option<f32> {
    let mut distances: Vec<f32> = skin
        .par_iter()
        .filter_map(|&i| {
            let x = positions[i as usize];
            let paired = paired_point(field, x, rule);
            pair_plane(x, paired.point, paired.normal, rule).map(|(_, d)| d)
        })
        .collect();
    if distances.is_empty() {
        return None;
    }
    let middle = distances.len() / 2;
    Some(*distances.select_nth_unstable_by(middle, f32::total_cmp).1)
}

/// The distances from `points` to `surface`: RMS, 95th percentile, largest.
fn residual(points: &[Vec3], surface: &SurfaceMesh) -> Result<Residual, Error> {
    let mut distances: Vec<f32> = signed_distances(surface, points)
        .map_err(ObservationError::from)?
        .into_iter()
        .map(f32::abs)
        .collect();
    if distances.is_empty() {
        return Ok(Residual {
            rms: 0.0,
            p95: 0.0,
            max: 0.0,
        });
    }
    distances.sort_unstable_by(f32::total_cmp);
    let rms = (distances.iter().map(|d| d * d).sum::<f32>() / distances.len() as f32).sqrt();
    let p95 = distances[((distances.len() - 1) as f32 * 0.95).round() as usize];
    Ok(Residual {
        rms,
        p95,
        max: distances[distances.len() - 1],
    })
}

/// A surface's mean edge length: the cell of its nearest points' grid.
pub fn mean_edge(surface: &SurfaceMesh) -> f32 {
    let edges: f64 = (0..surface.triangles.len())
        .map(|t| {
            let [a, b, c] = surface.corners(t);
            f64::from((b - a).length() + (c - b).length() + (a - c).length())
        })
        .sum();
    (edges / (3.0 * surface.triangles.len().max(1) as f64)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The defaults: the springs' weight of the solve, four stages, the
    /// noise from the observation, a surface's early stages to a hundred
    /// times the tolerance, from the solve's start (a tracking frame: one
    /// stage, warm); the weight grows by four a stage to the last one's; a
    /// surface's field in cells of two mean edges, exact within four; a
    /// surface paired by its plane smoothed over one mean edge, its first
    /// stage by the conjugate gradient; a tracking frame's start
    /// predicted, its skin paired three times.
    #[test]
    fn the_weight_grows_by_four_a_stage_to_the_springs_weight() {
        let params = MatchParams::default();
        assert_eq!(params.weight, SPRING_WEIGHT);
        assert_eq!(params.stages, 4);
        assert_eq!(params.noise, None);
        assert_eq!(params.early_tolerance, 100.0);
        assert!(!params.warm);
        assert_eq!(params.surface_smoothing, 1.0);
        assert_eq!(SURFACE_SMOOTHING, 1.0);
        assert_eq!(SURFACE_FIRST_STAGE, ElasticSolve::ConjugateGradient);
        assert_eq!(FIELD_CELL_EDGES, 2.0);
        assert_eq!(FIELD_MARGIN, 4.0);
        let frame = MatchParams::next_frame(Some(0.5));
        assert_eq!(
            (
                frame.stages,
                frame.warm,
                frame.noise,
                frame.surface_smoothing,
                frame.predict
            ),
            (1, true, Some(0.5), SURFACE_SMOOTHING, true)
        );
        assert!(params.predict);
        assert_eq!(PREDICTION_ROUNDS, 3);
        let weights: Vec<f32> = (0..4).map(|k| stage_weight(16.0, 4, k)).collect();
        assert_eq!(weights, [0.25, 1.0, 4.0, 16.0]);
        assert_eq!(stage_weight(16.0, 1, 0), 16.0);
    }
}
