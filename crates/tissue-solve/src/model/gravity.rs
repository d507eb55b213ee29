//! Gravity and the organ's unloaded shape: the body
//! force a posture's gravity puts on the particles, the held region of
//! the surface, and the unloaded positions from which gravity, with the
//! held region fixed and the rest of the skin free, gives the rest shape.
//!
//! The unloaded shape comes from the backward-displacement fixed point
//! (Sellier 2011, "An iterative method for the inverse elasto-static
//! problem"; Rajagopal et al. 2008 use it for the breast): load a guess
//! `X` with the rest posture's gravity, and move the guess by what the
//! loaded shape misses, `X <- X + (X_rest - forward(X))`. Each round is one
//! stage-2 solve with the guess as the model's positions; the loop is
//! written once here and takes the solve as a closure, so that any device
//! runs it (`crate::stage2::posture` gives it a tracker's solves). Measured on the shared breast
//! phantoms (docs/METHOD.md, "Gravity and the unloaded shape"), each round
//! cuts the miss by a factor of 5 to 8.

use glam::Vec3;
use tissue_core::{Error, ParamError, SurfaceMesh};

use crate::stage2::report::DeformReport;

/// Standard gravity, m/s^2.
pub const STANDARD_GRAVITY: f32 = 9.806_65;

/// The body force of gravity in the form [`crate::DeformParams::load`]
/// takes, `rho g / (2 mu)` in reciprocal model units: `gravity` in units
/// of `g` (its direction in the model's axes), the tissue's density in
/// kg/m^3, its Young's modulus in kPa and Poisson ratio (`mu = E / (2 (1 +
/// nu))`), and the model's unit in metres (`1e-3` for millimetres).
///
/// # Errors
///
/// [`ParamError`] naming a non-finite gravity, or a density, stiffness,
/// Poisson ratio or unit out of range.
pub fn gravity_load(
    gravity: Vec3,
    density_kg_m3: f32,
    stiffness_kpa: f32,
    poisson: f32,
    metres_per_unit: f32,
) -> Result<Vec3, ParamError> {
    ParamError::check(gravity.is_finite(), "gravity", gravity, "a finite vector")?;
    ParamError::check(
        density_kg_m3.is_finite() && density_kg_m3 > 0.0,
        "density_kg_m3",
        density_kg_m3,
        "a positive density in kg/m^3 (soft tissue: about 1000)",
    )?;
    ParamError::check(
        stiffness_kpa.is_finite() && stiffness_kpa > 0.0,
        "stiffness_kpa",
        stiffness_kpa,
        "a positive Young's modulus in kPa (soft tissue: 0.5 to 50)",
    )?;
    ParamError::check(
        poisson.is_finite() && (0.0..0.5).contains(&poisson),
        "poisson",
        poisson,
        "0 to below 0.5",
    )?;
    ParamError::check(
        metres_per_unit.is_finite() && metres_per_unit > 0.0,
        "metres_per_unit",
        metres_per_unit,
        "a positive length in metres (1e-3 for millimetres)",
    )?;
    let shear_modulus = stiffness_kpa * 1000.0 / (2.0 * (1.0 + poisson));
    // rho g / (2 mu) is per metre; per model unit it is that times the unit.
    let per_metre = density_kg_m3 * STANDARD_GRAVITY / (2.0 * shear_modulus);
    Ok(gravity * (per_metre * metres_per_unit))
}

/// The surface's held region: the vertices that move less than
/// `tolerance` (model units) between `rest` and `deformed` (the chest
/// wall, say), one flag per vertex. `None` where the two surfaces differ
/// in vertex count.
pub fn held_vertices(
    rest: &SurfaceMesh,
    deformed: &SurfaceMesh,
    tolerance: f32,
) -> Option<Vec<bool>> {
    (rest.vertices.len() == deformed.vertices.len()).then(|| {
        rest.vertices
            .iter()
            .zip(&deformed.vertices)
            .map(|(a, b)| a.distance(*b) <= tolerance)
            .collect()
    })
}

/// How the unloaded shape is searched for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unloading {
    /// Stop when the loaded guess misses the rest shape by at most this
    /// (the RMS over the surface particles), in model units.
    pub tolerance: f32,
    /// At most this many rounds (stage-2 solves).
    pub max_rounds: usize,
    /// How closely the miss that decides is measured: [`Accuracy::Full`],
    /// the solve's own tolerance (the shape a solve is then made from);
    /// [`Accuracy::Round`], every round loose (the stiffness fit's trials,
    /// whose shapes only set the skin's move to a fraction of a percent).
    pub measure: Accuracy,
}

impl Unloading {
    /// 0.1 mm in a model in millimetres (the unloaded shape, loaded again,
    /// must give the rest surface within 0.1 mm RMS), at most 8 rounds (the
    /// phantoms need 3 and 4), measured in full.
    pub const MILLIMETRES: Self = Self {
        tolerance: 0.1,
        max_rounds: 8,
        measure: Accuracy::Full,
    };
}

/// How closely a solve of the unloaded shape's search must land.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accuracy {
    /// A round whose loaded shape only moves the guess: the solve's
    /// tolerance times [`ROUND_TOLERANCE`]. Its error is small beside the
    /// miss it measures (0.05 mm beside 0.3-3 mm on the breast phantoms),
    /// and the next round corrects it. The stiffness search's deformed
    /// postures too ([`crate::model::stiffness::fit_stiffness`]).
    Round,
    /// The solve's own tolerance: the round whose miss is reported.
    Full,
}

/// A round's solve runs to this many times the solve's tolerance
/// ([`Accuracy::Round`]). On breast_c at 10,000 particles the plain
/// step's warm rounds then take 49 and 23 iterations instead of 109 and
/// 78, and miss the rest surface by 0.362 and 0.069 mm instead of 0.365
/// and 0.071 (docs/METHOD.md, "Gravity and the unloaded shape").
pub const ROUND_TOLERANCE: f32 = 10.0;

/// A loose round whose miss is within this many times the search's
/// tolerance is solved again at [`Accuracy::Full`] from its loaded shape,
/// and the search decides on that solve's miss. A loose solve lands within
/// a few hundredths of a millimetre of the full one on the breast phantoms
/// (0.362 against 0.365 mm), so a loose miss above the tolerance stays
/// above it in full: the next round is made instead.
pub const CONFIRM_WITHIN: f32 = 1.0;

/// What a round is expected to leave of the last round's miss before two
/// rounds have measured it (each round cuts the miss 5 to 8 times on the
/// breast phantoms): a round whose expected miss is within the tolerance
/// is solved in full at once ([`Accuracy::Full`]), where a loose one would
/// be solved again in full.
pub const ROUND_CONTRACTION: f32 = 0.2;

/// The unloaded shape found, and how well it reproduces the rest shape.
#[derive(Debug, Clone)]
pub struct UnloadedShape {
    /// The particles' unloaded positions.
    pub positions: Vec<Vec3>,
    /// The RMS, over the surface particles, of the rest shape less these
    /// positions loaded (model units): measured, not extrapolated.
    pub residual: f32,
    /// The same over every particle.
    pub residual_all: f32,
    /// Stage-2 solves made.
    pub rounds: usize,
    /// Whether `residual` reached the tolerance with every solve converged.
    pub converged: bool,
    /// Whether `residual` and `residual_all` are the misses expected of
    /// `positions` rather than measured: a loose search
    /// ([`Unloading::measure`] [`Accuracy::Round`]) ends where its guess,
    /// moved by the last round's miss, is expected within the tolerance
    /// (that miss times the contraction the rounds measured), without
    /// loading the guess again.
    pub expected: bool,
    /// Each round's solve (a confirmed round's two solves as one).
    pub reports: Vec<DeformReport>,
}

/// The unloaded shape of particles at `rest` by backward displacement
/// (module docs). `forward` loads a guess: given the guess as the model's
/// positions, it solves stage 2 with the rest posture's gravity, the held
/// region observed where the rest surface puts it and the rest of the skin
/// free, and returns the loaded positions and the solve's report. Its
/// second argument, where there is one, is where the loaded positions are
/// expected (a warm start for the solve): the rest shape itself, from the
/// second round on, since each round's guess is made so that loading it
/// gives the rest shape. Its third says how closely to solve: a round at
/// [`Accuracy::Round`], but one whose miss is expected within the
/// tolerance (the last round's miss times the contraction the last two
/// rounds measured, [`ROUND_CONTRACTION`] before) at [`Accuracy::Full`]
/// where `unloading.measure` is; there a loose round that misses by at
/// most [`CONFIRM_WITHIN`] times the tolerance is solved once more in full
/// from where it landed (the second argument then), whose miss decides and
/// is reported; a `forward` may solve that again from its last solve's
/// state. `surface[i]` says whether particle `i` is on the surface.
///
/// Stops at the tolerance, after `max_rounds`, or when a round misses by
/// more than the one before (the search diverges: the load is too large
/// for the model, or a solve failed); the last two are reported as not
/// converged, with the best guess measured. A loose search
/// ([`Unloading::measure`] [`Accuracy::Round`]) also stops where the next
/// guess is expected within the tolerance, and returns that guess
/// ([`UnloadedShape::expected`]).
///
/// # Errors
///
/// What `forward` returns, and a loaded shape with other than one position
/// per particle or a non-finite one.
pub fn unloaded_shape(
    rest: &[Vec3],
    surface: &[bool],
    unloading: Unloading,
    forward: impl FnMut(&[Vec3], Option<&[Vec3]>, Accuracy) -> Result<(Vec<Vec3>, DeformReport), Error>,
) -> Result<UnloadedShape, Error> {
    unloaded_shape_from(rest, rest, surface, unloading, forward)
}

/// [`unloaded_shape`] from the guess `start` instead of the rest shape
/// (the unloaded shape for a nearby stiffness, say): its first round is
/// warm-started too.
///
/// # Errors
///
/// As [`unloaded_shape`]; and a `start` of other than one position per
/// particle.
pub fn unloaded_shape_from(
    rest: &[Vec3],
    start: &[Vec3],
    surface: &[bool],
    unloading: Unloading,
    forward: impl FnMut(&[Vec3], Option<&[Vec3]>, Accuracy) -> Result<(Vec<Vec3>, DeformReport), Error>,
) -> Result<UnloadedShape, Error> {
    unloaded_shape_near(rest, start, None, surface, unloading, forward)
}

/// [`unloaded_shape_from`] from a `start` whose miss, loaded at the
/// rounds' accuracy, is known (the shape of a search measured loosely):
/// the first round is then expected to leave [`ROUND_CONTRACTION`] of it,
/// and solved in full where that is within the tolerance.
///
/// # Errors
///
/// As [`unloaded_shape_from`].
pub fn unloaded_shape_near(
    rest: &[Vec3],
    start: &[Vec3],
    start_miss: Option<f32>,
    surface: &[bool],
    unloading: Unloading,
    mut forward: impl FnMut(
        &[Vec3],
        Option<&[Vec3]>,
        Accuracy,
    ) -> Result<(Vec<Vec3>, DeformReport), Error>,
) -> Result<UnloadedShape, Error> {
    if start.len() != rest.len() || surface.len() != rest.len() {
        return Err(Error::Param(ParamError {
            name: "unloaded shape",
            value: format!(
                "a start of {} positions and {} surface flags",
                start.len(),
                surface.len()
            ),
            expected: format!("{} of each", rest.len()),
        }));
    }
    let rms = |miss: &[Vec3], on: &dyn Fn(usize) -> bool| -> f32 {
        let (sum, count) = miss
            .iter()
            .enumerate()
            .filter(|&(i, _)| on(i))
            .fold((0.0f64, 0usize), |(s, n), (_, m)| {
                (s + f64::from(m.length_squared()), n + 1)
            });
        if count == 0 {
            0.0
        } else {
            (sum / count as f64).sqrt() as f32
        }
    };
    let check = |loaded: &[Vec3]| -> Result<(), Error> {
        if loaded.len() != rest.len() || loaded.iter().any(|p| !p.is_finite()) {
            return Err(Error::Param(ParamError {
                name: "unloaded shape",
                value: format!("a loaded shape of {} positions", loaded.len()),
                expected: format!("{} finite positions", rest.len()),
            }));
        }
        Ok(())
    };
    let mut guess = start.to_vec();
    let mut best: Option<UnloadedShape> = None;
    let mut reports = Vec::new();
    let full = unloading.measure == Accuracy::Full;
    // The last round's miss, and what a round leaves of the miss before it.
    let (mut last_miss, mut contraction) = (start_miss, ROUND_CONTRACTION);
    for round in 1..=unloading.max_rounds.max(1) {
        // Loading a guess made to give the rest shape gives about it.
        let expected = (round > 1 || start != rest).then_some(rest);
        let accuracy = match last_miss {
            Some(miss) if full && miss * contraction <= unloading.tolerance => Accuracy::Full,
            _ => Accuracy::Round,
        };
        let (mut loaded, mut report) = forward(&guess, expected, accuracy)?;
        check(&loaded)?;
        let mut miss: Vec<Vec3> = rest.iter().zip(&loaded).map(|(r, l)| *r - *l).collect();
        let mut residual = rms(&miss, &|i| surface[i]);
        // Near the tolerance, a loose round's miss is measured again at the
        // solve's own tolerance, from where the round landed.
        if full
            && accuracy == Accuracy::Round
            && report.converged
            && residual <= CONFIRM_WITHIN * unloading.tolerance
        {
            let (again, mut full) = forward(&guess, Some(&loaded), Accuracy::Full)?;
            check(&again)?;
            full.iterations += report.iterations;
            full.residual_history.splice(0..0, report.residual_history);
            (loaded, report) = (again, full);
            miss = rest.iter().zip(&loaded).map(|(r, l)| *r - *l).collect();
            residual = rms(&miss, &|i| surface[i]);
        }
        if let Some(last) = last_miss
            && last > 0.0
        {
            contraction = (residual / last).min(1.0);
        }
        last_miss = Some(residual);
        let solved = report.converged;
        reports.push(report);
        let residual_all = rms(&miss, &|_| true);
        log::debug!(
            "unloaded shape, round {round}: loaded, it misses the rest surface by {residual:.4} \
             (every particle {residual_all:.4}); {} iterations{}",
            reports.last().map_or(0, |r: &DeformReport| r.iterations),
            if solved { "" } else { ", not converged" }
        );
        let worse = best.as_ref().is_some_and(|b| residual > b.residual);
        if !worse {
            best = Some(UnloadedShape {
                positions: guess.clone(),
                residual,
                residual_all,
                rounds: round,
                converged: solved && residual <= unloading.tolerance,
                expected: false,
                reports: Vec::new(),
            });
        }
        if worse || !solved || residual <= unloading.tolerance {
            break;
        }
        for (g, m) in guess.iter_mut().zip(&miss) {
            *g += *m;
        }
        // A loose search ends where the moved guess is expected within the
        // tolerance.
        if !full && residual * contraction <= unloading.tolerance {
            best = Some(UnloadedShape {
                positions: guess.clone(),
                residual: residual * contraction,
                residual_all: residual_all * contraction,
                rounds: round,
                converged: true,
                expected: true,
                reports: Vec::new(),
            });
            break;
        }
    }
    let mut shape = best.ok_or_else(|| {
        Error::Param(ParamError {
            name: "unloading.max_rounds",
            value: unloading.max_rounds.to_string(),
            expected: "at least 1".into(),
        })
    })?;
    shape.converged &= reports.iter().all(|r| r.converged);
    shape.rounds = reports.len();
    shape.reports = reports;
    Ok(shape)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;
    use crate::stage2::report::StopReason;

    fn report(converged: bool) -> DeformReport {
        DeformReport {
            iterations: 10,
            residual: 0.0,
            residual_history: Vec::new(),
            converged,
            stopped_by: if converged {
                StopReason::Tolerance
            } else {
                StopReason::IterationCap
            },
            seconds: 0.0,
            elastic_retries: 0,
            backtracks: 0,
            potentials: Vec::new(),
        }
    }

    /// Breast tissue of 1.5 kPa at Poisson ratio 0.49 and 1000 kg/m^3:
    /// `mu` = 503 Pa, `rho g / (2 mu)` = 9.741 per metre, 0.009741 per mm.
    #[test]
    fn the_load_of_gravity_is_rho_g_over_two_mu() {
        let k = gravity_load(Vec3::new(0.0, 0.0, -1.0), 1000.0, 1.5, 0.49, 1e-3).unwrap();
        assert!((k.z + 0.009_741).abs() < 2e-6, "{k}");
        assert_eq!((k.x, k.y), (0.0, 0.0));
        // Stiffer tissue sags less, in proportion; no gravity, no load.
        let stiffer = gravity_load(Vec3::new(0.0, 0.0, -1.0), 1000.0, 3.0, 0.49, 1e-3).unwrap();
        assert!((stiffer.z * 2.0 - k.z).abs() < 1e-7);
        assert_eq!(
            gravity_load(Vec3::ZERO, 1000.0, 1.5, 0.49, 1e-3).unwrap(),
            Vec3::ZERO
        );
        for (g, rho, e, nu, unit) in [
            (Vec3::NAN, 1000.0, 1.5, 0.49, 1e-3),
            (Vec3::Z, 0.0, 1.5, 0.49, 1e-3),
            (Vec3::Z, 1000.0, -1.0, 0.49, 1e-3),
            (Vec3::Z, 1000.0, f32::INFINITY, 0.49, 1e-3),
            (Vec3::Z, 1000.0, 1.5, 0.5, 1e-3),
            (Vec3::Z, 1000.0, 1.5, 0.49, 0.0),
        ] {
            assert!(
                gravity_load(g, rho, e, nu, unit).is_err(),
                "{g} {rho} {e} {nu} {unit}"
            );
        }
    }

    #[test]
    fn the_held_region_is_what_did_not_move() {
        let rest = SurfaceMesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        );
        let mut deformed = rest.clone();
        deformed.vertices[3] += Vec3::new(0.0, 0.0, 0.3);
        deformed.vertices[1] += Vec3::new(1e-4, 0.0, 0.0);
        let held = held_vertices(&rest, &deformed, 1e-3).unwrap();
        assert_eq!(held, vec![true, true, true, false]);
        let fewer = SurfaceMesh::new(rest.vertices[..3].to_vec(), vec![[0, 2, 1]]);
        assert!(held_vertices(&rest, &fewer, 1e-3).is_none());
    }

    /// A linear stand-in for a solve, loading by `x -> x + s (x - c)` plus
    /// a fixed sag: the fixed point is found to the tolerance, the result
    /// measured (its loaded shape is the rest shape within it).
    #[test]
    fn backward_displacement_finds_the_shape_that_loads_to_the_rest_shape() {
        let rest: Vec<Vec3> = (0..50)
            .map(|i| Vec3::new(i as f32 * 0.1, (i % 7) as f32 * 0.2, (i % 3) as f32))
            .collect();
        let surface: Vec<bool> = (0..50).map(|i| i % 2 == 0).collect();
        let sag = Vec3::new(0.0, 0.0, -2.0);
        let load = |x: &[Vec3]| -> Vec<Vec3> {
            x.iter()
                .map(|&p| p + 0.15 * (p - Vec3::ONE) + sag)
                .collect()
        };
        let unloading = Unloading {
            tolerance: 1e-4,
            max_rounds: 20,
            measure: Accuracy::Full,
        };
        // The first round starts cold; each later one expects the rest
        // shape, which its guess was made to give.
        let mut expected = Vec::new();
        let shape = unloaded_shape(&rest, &surface, unloading, |x, warm, accuracy| {
            if accuracy == Accuracy::Round {
                expected.push(warm.map(<[Vec3]>::to_vec));
            }
            Ok((load(x), report(true)))
        })
        .unwrap();
        assert_eq!(expected[0], None);
        assert!(
            expected[1..]
                .iter()
                .all(|w| w.as_deref() == Some(&rest[..]))
        );
        assert!(shape.converged && shape.residual <= 1e-4, "{shape:?}");
        assert!(shape.rounds > 2 && shape.rounds < 20, "{}", shape.rounds);
        let again = load(&shape.positions);
        let worst = again
            .iter()
            .zip(&rest)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(worst <= 3e-4, "{worst}");
        // Unloaded, the body sits above where gravity put it.
        assert!(shape.positions.iter().zip(&rest).all(|(u, r)| u.z > r.z));
    }

    /// The rounds' looser tolerance, when a round is confirmed and what a
    /// round is expected to leave: the choices docs/METHOD.md records
    /// ("Gravity and the unloaded shape").
    #[test]
    fn the_rounds_accuracy_is_pinned() {
        assert_eq!(
            (ROUND_TOLERANCE, CONFIRM_WITHIN, ROUND_CONTRACTION),
            (10.0, 1.0, 0.2)
        );
        assert_eq!(Unloading::MILLIMETRES.measure, Accuracy::Full);
    }

    /// A linear stand-in for a solve, contracting the miss 10 times a
    /// round, whose loose solves stop 4e-3 short of the loaded shape.
    fn load(x: &[Vec3], accuracy: Accuracy) -> Vec<Vec3> {
        let short = match accuracy {
            Accuracy::Round => Vec3::new(0.0, 0.0, 4e-3),
            Accuracy::Full => Vec3::ZERO,
        };
        x.iter()
            .map(|&p| p + 0.1 * (p - Vec3::ONE) + Vec3::new(0.0, 0.0, -1.0) + short)
            .collect()
    }

    /// [`load`]'s rest shape, and a search to 5e-3 measured in full.
    fn loose_search() -> (Vec<Vec3>, Unloading) {
        let rest: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new((i % 5) as f32, (i / 5) as f32 * 0.5, (i % 3) as f32))
            .collect();
        let unloading = Unloading {
            tolerance: 5e-3,
            max_rounds: 20,
            measure: Accuracy::Full,
        };
        (rest, unloading)
    }

    fn rms_from(rest: &[Vec3], loaded: &[Vec3]) -> f32 {
        let sum: f32 = loaded
            .iter()
            .zip(rest)
            .map(|(l, r)| l.distance_squared(*r))
            .sum();
        (sum / rest.len() as f32).sqrt()
    }

    /// Rounds are solved at [`Accuracy::Round`] until one is expected
    /// within the tolerance (the last miss times the contraction the
    /// rounds measured), which is solved in full at once, expecting the
    /// rest shape; its miss is what decides and what is reported. A loose
    /// round that lands within [`CONFIRM_WITHIN`] times the tolerance
    /// unexpectedly (the first round from a good start) is solved again in
    /// full from where it landed.
    #[test]
    fn rounds_are_loose_and_the_last_is_measured_in_full() {
        let (rest, unloading) = loose_search();
        let surface = vec![true; rest.len()];
        type Call = (Accuracy, Option<Vec<Vec3>>, Vec<Vec3>);
        let log: std::cell::RefCell<Vec<Call>> = std::cell::RefCell::default();
        let forward = |x: &[Vec3], warm: Option<&[Vec3]>, accuracy| {
            let loaded = load(x, accuracy);
            log.borrow_mut()
                .push((accuracy, warm.map(<[Vec3]>::to_vec), loaded.clone()));
            Ok((loaded, report(true)))
        };
        let shape = unloaded_shape(&rest, &surface, unloading, forward).unwrap();
        let calls = log.take();
        let rounds: Vec<Accuracy> = calls.iter().map(|c| c.0).collect();
        assert_eq!(rounds.last(), Some(&Accuracy::Full), "{rounds:?}");
        assert!(
            rounds[..rounds.len() - 1]
                .iter()
                .all(|&a| a == Accuracy::Round),
            "{rounds:?}"
        );
        // Solved in full at once: it expects the rest shape, not where a
        // loose solve of the same guess landed.
        let n = calls.len();
        assert_eq!(calls[n - 1].1.as_deref(), Some(&rest[..]));
        assert_eq!(shape.reports.len(), shape.rounds);
        assert_eq!(shape.rounds, n);
        // The residual reported is the full solve's miss.
        let full = rms_from(&rest, &load(&shape.positions, Accuracy::Full));
        assert!(
            (shape.residual - full).abs() < 1e-5,
            "{} against {full}",
            shape.residual
        );
        assert!(shape.converged && !shape.expected && shape.residual <= unloading.tolerance);

        // From the shape found, the first round is loose (nothing is known
        // of the start's miss) and lands within the tolerance: confirmed.
        let again =
            unloaded_shape_from(&rest, &shape.positions, &surface, unloading, forward).unwrap();
        let calls = log.take();
        let rounds: Vec<Accuracy> = calls.iter().map(|c| c.0).collect();
        assert_eq!(rounds, [Accuracy::Round, Accuracy::Full]);
        assert_eq!(calls[1].1.as_deref(), Some(&calls[0].2[..]));
        assert!(again.converged && again.rounds == 1, "{again:?}");
        assert!((again.residual - rms_from(&rest, &calls[1].2)).abs() < 1e-6);
        assert!((again.residual - rms_from(&rest, &calls[0].2)).abs() > 1e-3);
    }

    /// A loose search ([`Accuracy::Round`]) solves nothing in full and ends
    /// where its guess, moved by the last miss, is expected within the
    /// tolerance, without loading it again: the shape it returns is that
    /// guess, its residual the expected miss, which the guess loaded in
    /// full is within.
    #[test]
    fn a_loose_search_ends_where_its_next_guess_is_expected_within_the_tolerance() {
        let (rest, unloading) = loose_search();
        let surface = vec![true; rest.len()];
        let loose = Unloading {
            measure: Accuracy::Round,
            ..unloading
        };
        let mut asked = Vec::new();
        let shape = unloaded_shape(&rest, &surface, loose, |x, _, accuracy| {
            asked.push(accuracy);
            Ok((load(x, accuracy), report(true)))
        })
        .unwrap();
        assert!(asked.iter().all(|&a| a == Accuracy::Round), "{asked:?}");
        assert!(shape.expected && shape.converged, "{shape:?}");
        assert!(shape.residual <= loose.tolerance);
        // One round fewer than the loose rounds would need to measure it.
        assert_eq!(shape.rounds, asked.len());
        let loaded = rms_from(&rest, &load(&shape.positions, Accuracy::Round));
        assert!(loaded <= loose.tolerance, "{loaded}");
        let full = rms_from(&rest, &load(&shape.positions, Accuracy::Full));
        assert!(full <= loose.tolerance, "{full}");
    }

    /// A load the fixed point cannot undo (the miss grows each round)
    /// stops at once with the best guess, not converged; so does a solve
    /// that did not converge.
    #[test]
    fn a_diverging_search_or_a_failed_solve_is_not_converged() {
        let rest = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        let surface = vec![true; 3];
        let unloading = Unloading {
            tolerance: 1e-6,
            max_rounds: 10,
            measure: Accuracy::Full,
        };
        let runaway =
            |x: &[Vec3], _: Option<&[Vec3]>, _| -> Result<(Vec<Vec3>, DeformReport), Error> {
                Ok((x.iter().map(|&p| 3.0 * p + Vec3::Z).collect(), report(true)))
            };
        let shape = unloaded_shape(&rest, &surface, unloading, runaway).unwrap();
        assert!(!shape.converged);
        assert_eq!(shape.rounds, 2, "stopped when the miss grew");
        assert_eq!(shape.positions, rest, "the first guess was the better");
        let failed =
            |x: &[Vec3], _: Option<&[Vec3]>, _| -> Result<(Vec<Vec3>, DeformReport), Error> {
                Ok((
                    x.iter().map(|&p| p + 0.5 * Vec3::Z).collect(),
                    report(false),
                ))
            };
        let shape = unloaded_shape(&rest, &surface, unloading, failed).unwrap();
        assert!(!shape.converged && shape.rounds == 1);
        let short =
            |_: &[Vec3], _: Option<&[Vec3]>, _| -> Result<(Vec<Vec3>, DeformReport), Error> {
                Ok((vec![Vec3::ZERO], report(true)))
            };
        assert!(unloaded_shape(&rest, &surface, unloading, short).is_err());
    }
}
