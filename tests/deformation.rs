//! Stage 2 against exact answers: rigid motion, an affine map, the torsion of
//! a circular cylinder; the force's invariants; frame-to-frame tracking.
//! The solves run the symmetric force (`symmetric()`) unless a test names
//! another: the elastic force, the default, has the patch tests here and
//! its own suite in `tests/elastic_solve.rs`.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

use std::sync::OnceLock;

use glam::{Mat3, Quat, Vec3};
use tissue::deform::{Affine, PointMap, Rigid, Twist, deform_surface, interpolate};
use tissue::{ParticleModel, SamplingParams, SurfaceMesh, phantom};
use tissue_cpu::deformation::{
    DeformParams, Deformer, Elastic, ForceModel, RotationMethod, deformation_force, elastic_force,
    elastic_terms, local_rotations,
};
use tissue_cpu::model::{Embedding, RigidBinding};

/// The library's defaults with the symmetric force.
fn symmetric() -> DeformParams {
    DeformParams::default().with(|p| p.force = ForceModel::Symmetric)
}

/// The phantom at 5,000 particles, sampled once for all tests.
fn breast_model() -> &'static ParticleModel {
    static MODEL: OnceLock<ParticleModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        tissue::sample(
            &phantom::default_breast(),
            &SamplingParams::with_particles(5_000),
        )
        .unwrap()
        .model
    })
}

/// A closed circular cylinder along z: radius 1, height 4, base at z = 0.
fn cylinder() -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::cylinder();
    SurfaceMesh::new(vertices, triangles)
}

fn solve(model: &ParticleModel, deformed: &SurfaceMesh, params: DeformParams) -> Deformer {
    let mut deformer = Deformer::new(model, params).unwrap();
    deformer.set_surface(deformed).unwrap();
    let report = deformer.solve();
    assert!(
        report.converged,
        "did not converge: {:?}",
        &report.residual_history[report.residual_history.len().saturating_sub(5)..]
    );
    deformer
}

/// Errors of interior particles against an exact map, relative to `scale`.
fn errors(model: &ParticleModel, deformer: &Deformer, map: &impl PointMap) -> (f32, f32) {
    let interior: Vec<usize> = (0..model.len()).filter(|&i| !model.is_surface(i)).collect();
    let e: Vec<f32> = interior
        .iter()
        .map(|&i| (deformer.positions()[i] - map.apply(model.positions[i])).length())
        .collect();
    let rms = (e.iter().map(|x| x * x).sum::<f32>() / e.len() as f32).sqrt();
    (rms, e.iter().copied().fold(0.0, f32::max))
}

fn max_displacement(model: &ParticleModel, map: &impl PointMap) -> f32 {
    model
        .positions
        .iter()
        .map(|&p| (map.apply(p) - p).length())
        .fold(0.0, f32::max)
}

/// Checked twice: as a user gets it (the frame's start predicted by the
/// surface's affine move, which is exact for a rigid one) and by the solver
/// alone from the rest shape (no prediction).
#[test]
fn rigid_motion_moves_every_particle_and_point_rigidly() {
    let model = breast_model();
    let rigid = Rigid::about_axis(
        Vec3::new(1.0, 2.0, 0.5),
        30f32.to_radians(),
        Vec3::new(0.0, 0.0, 25.0),
        Vec3::new(7.0, -3.0, 4.0),
    );
    let deformed = deform_surface(&model.surface, &rigid);
    let solver_alone = symmetric().with(|p| {
        p.tuning.extrapolate = false;
    });
    let unpredicted = solve(model, &deformed, solver_alone);
    let deformer = solve(model, &deformed, symmetric());
    let size = deformer.size();
    for (how, deformer) in [("solver alone", &unpredicted), ("predicted", &deformer)] {
        let mut worst = 0.0f32;
        for i in 0..model.len() {
            let err = (deformer.positions()[i] - rigid.apply(model.positions[i])).length();
            assert!(
                err <= 1e-4 * size,
                "{how}, particle {i}: error {err} > {} (1e-4 of size)",
                1e-4 * size
            );
            worst = worst.max(err);
        }
        eprintln!(
            "rigid, {how}: worst particle error {:.2e} of the size",
            worst / size
        );
    }
    let tumour = phantom::default_tumour();
    let embedding = Embedding::new(deformer.rest(), &tumour.vertices);
    let moved = embedding.moved(deformer.rest(), deformer.positions(), deformer.rotations());
    let mut worst = 0.0f32;
    for (k, (&x, &y)) in tumour.vertices.iter().zip(&moved).enumerate() {
        let err = (y - rigid.apply(x)).length();
        assert!(err <= 1e-4 * size, "tumour vertex {k}: error {err}");
        worst = worst.max(err);
    }
    eprintln!(
        "rigid: worst tumour vertex error {:.2e} of the size",
        worst / size
    );
    let binding = RigidBinding::new(deformer.rest(), &tumour.vertices);
    let motion = binding.motion(deformer.rest(), deformer.positions(), deformer.rotations());
    for &x in &tumour.vertices {
        assert!((motion.apply(x) - rigid.apply(x)).length() <= 1e-4 * size);
    }
}

#[test]
fn an_affine_map_is_reproduced_in_the_interior() {
    let model = breast_model();
    let affine = Affine {
        matrix: Mat3::from_cols(
            Vec3::new(1.2, 0.0, 0.05),
            Vec3::new(0.1, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 0.85),
        ),
        translation: Vec3::new(2.0, 0.0, -1.0),
        centre: Vec3::new(0.0, 0.0, 20.0),
    };
    let deformed = deform_surface(&model.surface, &affine);
    let deformer = solve(model, &deformed, symmetric());
    let (rms, max) = errors(model, &deformer, &affine);
    let scale = max_displacement(model, &affine);
    eprintln!(
        "affine: rms {:.4}%, max {:.4}% of the largest displacement {scale}",
        100.0 * rms / scale,
        100.0 * max / scale
    );
    assert!(rms <= 0.01 * scale, "rms {rms} > 1% of {scale}");
    assert!(max <= 0.03 * scale, "max {max} > 3% of {scale}");
}

/// The patch test: the elastic force's consistent gradients make an affine
/// move of the surface an equilibrium, so the interior follows it to the
/// solve's tolerance: every interior particle within 1e-4 of the model's
/// size (1.7e-5 measured, 2.5e-3 with least-squares gradients).
#[test]
fn the_elastic_force_reproduces_an_affine_map_in_the_interior() {
    let model = breast_model();
    let affine = Affine {
        matrix: Mat3::from_cols(
            Vec3::new(1.2, 0.0, 0.05),
            Vec3::new(0.1, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 0.85),
        ),
        translation: Vec3::new(2.0, 0.0, -1.0),
        centre: Vec3::new(0.0, 0.0, 20.0),
    };
    let deformed = deform_surface(&model.surface, &affine);
    let elastic = symmetric().with(|p| {
        p.force = ForceModel::Elastic;
    });
    let deformer = solve(model, &deformed, elastic);
    let (rms, max) = errors(model, &deformer, &affine);
    let scale = max_displacement(model, &affine);
    let size = deformer.size();
    eprintln!(
        "elastic affine: rms {:.4}%, max {:.4}% of the largest displacement {scale}; max {:.2e} of the size",
        100.0 * rms / scale,
        100.0 * max / scale,
        max / size
    );
    assert!(max <= 1e-4 * size, "max {max} > 1e-4 of the size {size}");
}

#[test]
fn svd_and_warm_polar_rotations_reach_the_same_solution() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let solve_with = |rotations| {
        let params = symmetric().with(|p| {
            p.tuning.rotations = rotations;
            p.tolerance = 1e-6;
        });
        solve(model, &sagged, params).positions().to_vec()
    };
    let svd = solve_with(RotationMethod::Svd);
    let warm = solve_with(RotationMethod::WarmPolar);
    let size = Deformer::new(model, symmetric()).unwrap().size();
    for (i, (a, b)) in svd.iter().zip(&warm).enumerate() {
        assert!(
            (*a - *b).length() <= 1e-4 * size,
            "particle {i}: {a} vs {b}"
        );
    }
}

#[test]
fn a_cylinder_twisted_by_30_degrees_matches_torsion_theory() {
    let surface = cylinder();
    let model = tissue::sample(&surface, &SamplingParams::with_particles(5_000))
        .unwrap()
        .model;
    let twist = Twist {
        axis_origin: Vec3::ZERO,
        axis: Vec3::Z,
        angle_per_length: 30f32.to_radians() / 4.0,
    };
    let deformed = deform_surface(&model.surface, &twist);
    for force in [ForceModel::Symmetric, ForceModel::Elastic] {
        let params = symmetric().with(|p| {
            p.force = force;
        });
        let deformer = solve(&model, &deformed, params);
        let (rms, max) = errors(&model, &deformer, &twist);
        let scale = max_displacement(&model, &twist);
        eprintln!(
            "{force:?} twist: rms {:.3}%, max {:.3}% of the largest displacement {scale}",
            100.0 * rms / scale,
            100.0 * max / scale
        );
        assert!(rms <= 0.02 * scale, "{force:?}: rms {rms} > 2% of {scale}");
        assert!(max <= 0.05 * scale, "{force:?}: max {max} > 5% of {scale}");
        if force == ForceModel::Elastic {
            // RMS at most 0.2 % (0.030 % measured).
            assert!(rms <= 0.002 * scale, "elastic: rms {rms} > 0.2% of {scale}");
        }
    }
}

#[test]
fn the_force_vanishes_under_rigid_motion_for_both_models() {
    let model = breast_model();
    let rotation = Mat3::from_quat(Quat::from_axis_angle(
        Vec3::new(0.3, -1.0, 0.2).normalize(),
        1.1,
    ));
    let current: Vec<Vec3> = model
        .positions
        .iter()
        .map(|&p| rotation * p + Vec3::new(5.0, 1.0, -2.0))
        .collect();
    let rotations = local_rotations(&model.positions, &current, &model.connections);
    for (i, r) in rotations.iter().enumerate() {
        let off = (*r - rotation)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(off < 1e-5, "particle {i}: rotation off by {off}");
    }
    let free: Vec<bool> = (0..model.len()).map(|i| !model.is_surface(i)).collect();
    let elastic = Elastic::new(&model.positions, &model.connections, 0.49, &free);
    let elastic_force_at = |q: &[Vec3]| {
        let rotations = local_rotations(&model.positions, q, &model.connections);
        let (terms, _) = elastic_terms(
            &model.positions,
            q,
            &model.connections,
            &rotations,
            &elastic,
            RotationMethod::Svd,
        );
        elastic_force(&model.positions, q, &model.connections, &terms, &elastic)
    };
    for force in [
        ForceModel::Paper,
        ForceModel::Symmetric,
        ForceModel::Elastic,
    ] {
        let f = if force == ForceModel::Elastic {
            elastic_force_at(&current)
        } else {
            deformation_force(
                &model.positions,
                &current,
                &rotations,
                &model.connections,
                force,
            )
        };
        let worst = f.iter().map(|v| v.length()).fold(0.0, f32::max);
        // The volume term's weight (24.5 times the shear's at 0.49) scales
        // the rounding of `J - 1` in f32: held against what a 0.1 % change
        // of volume gives instead.
        let limit = if force == ForceModel::Elastic {
            let swollen: Vec<Vec3> = current.iter().map(|&q| q * 1.000_33).collect();
            0.1 * elastic_force_at(&swollen)
                .iter()
                .map(|v| v.length())
                .fold(0.0, f32::max)
        } else {
            1e-3
        };
        assert!(
            worst < limit,
            "{force:?}: largest force {worst} under a rigid motion (limit {limit})"
        );
    }
}

/// The symmetric force is -1/2 the gradient of the energy (rotations held at
/// their optimum): checked by central differences.
#[test]
fn the_symmetric_force_is_the_energy_gradient() {
    let model = breast_model();
    let current = perturbed(model);
    let rotations = local_rotations(&model.positions, &current, &model.connections);
    let energy = |q: &[Vec3]| -> f64 {
        let mut e = 0.0f64;
        for i in 0..q.len() {
            for &j in model.connections.of(i) {
                let j = j as usize;
                let r = q[j] - q[i] - rotations[i] * (model.positions[j] - model.positions[i]);
                e += f64::from(r.length_squared());
            }
        }
        e
    };
    let force = deformation_force(
        &model.positions,
        &current,
        &rotations,
        &model.connections,
        ForceModel::Symmetric,
    );
    assert_half_gradient(&current, &force, |_, q| energy(q));
}

/// Checks by central differences that `force` is `-1/2` the gradient of
/// the energy at `current`, for a few particles `k` and every axis;
/// `energy(k, q)` may leave out the terms that do not depend on `q_k`.
fn assert_half_gradient(current: &[Vec3], force: &[Vec3], energy: impl Fn(usize, &[Vec3]) -> f64) {
    for k in [0usize, 17, 1234, 4321] {
        let energy = |q: &[Vec3]| energy(k, q);
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let h = 1e-2f32;
            let mut plus = current.to_vec();
            plus[k] += h * axis;
            let mut minus = current.to_vec();
            minus[k] -= h * axis;
            let gradient = (energy(&plus) - energy(&minus)) / (2.0 * f64::from(h));
            let expected = f64::from(force[k].dot(axis));
            assert!(
                (-0.5 * gradient - expected).abs() <= 1e-2 * (1.0 + expected.abs()),
                "particle {k} {axis}: -grad/2 {} vs force {expected}",
                -0.5 * gradient
            );
        }
    }
}

/// The phantom's rest shape stretched and perturbed particle by particle:
/// a state with real rotations and volume changes for the gradient checks.
fn perturbed(model: &ParticleModel) -> Vec<Vec3> {
    let affine = Affine {
        matrix: Mat3::from_diagonal(Vec3::new(1.1, 0.95, 1.0)),
        translation: Vec3::ZERO,
        centre: Vec3::ZERO,
    };
    model
        .positions
        .iter()
        .enumerate()
        .map(|(i, &p)| affine.apply(p) + Vec3::splat(0.05 * ((i % 7) as f32 - 3.0)))
        .collect()
}

/// The elastic force is -1/2 the gradient of the energy (rotations at
/// their optimum, the polar rotations of the consistent gradients):
/// checked by central differences on the phantom.
#[test]
fn the_elastic_force_is_the_energy_gradient() {
    let model = breast_model();
    let current = perturbed(model);
    let rest = &model.positions;
    let free: Vec<bool> = (0..model.len()).map(|i| !model.is_surface(i)).collect();
    let elastic = Elastic::new(rest, &model.connections, 0.45, &free);
    let rotations = local_rotations(rest, &current, &model.connections);
    let (terms, _) = elastic_terms(
        rest,
        &current,
        &model.connections,
        &rotations,
        &elastic,
        RotationMethod::Svd,
    );
    let force = elastic_force(rest, &current, &model.connections, &terms, &elastic);
    // Only particle k's and its neighbours' parts depend on q_k.
    assert_half_gradient(&current, &force, |k, q| {
        std::iter::once(k)
            .chain(model.connections.of(k).iter().map(|&j| j as usize))
            .map(|i| elastic.particle_energy(i, rest, q, &model.connections))
            .sum()
    });
}

/// Tracking starts each frame from the last solution: a small change then
/// costs far fewer iterations than solving from rest. (The target of
/// at most 10 iterations for a change of up to 2% of the size is not met yet:
/// this takes about 35; see the closing note.)
#[test]
fn a_warm_start_converges_much_faster_than_a_cold_one() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let mut deformer = Deformer::new(model, symmetric()).unwrap();
    deformer.set_surface(&sagged).unwrap();
    let cold = deformer.solve();
    assert!(cold.converged);
    // Frames 1% of the sag apart (0.12 mm at the apex).
    for k in 1..=3 {
        let frame = interpolate(&sagged, &model.surface, k as f32 * 0.01).unwrap();
        deformer.set_surface(&frame).unwrap();
        let warm = deformer.solve();
        assert!(warm.converged);
        eprintln!(
            "frame {k}: {} iterations warm, {} cold",
            warm.iterations, cold.iterations
        );
        assert!(
            2 * warm.iterations < cold.iterations,
            "warm {} vs cold {}",
            warm.iterations,
            cold.iterations
        );
    }
}

/// On a smooth sequence of frames, starting each from the last solution moved
/// on by the prediction beats starting from the last solution.
#[test]
fn prediction_cuts_tracking_iterations() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let run = |extrapolate| {
        let params = symmetric().with(|p| {
            p.tuning.extrapolate = extrapolate;
        });
        let mut deformer = Deformer::new(model, params).unwrap();
        (0..8)
            .map(|k| {
                let frame = interpolate(&model.surface, &sagged, 0.5 + 0.02 * k as f32).unwrap();
                deformer.set_surface(&frame).unwrap();
                let report = deformer.solve();
                assert!(report.converged);
                report.iterations
            })
            .collect::<Vec<_>>()
    };
    let plain = run(false);
    let predicted = run(true);
    eprintln!("iterations per frame: {plain:?} without, {predicted:?} with prediction");
    let tail = |v: &[usize]| v[3..].iter().sum::<usize>();
    assert!(
        2 * tail(&predicted) < tail(&plain),
        "{predicted:?} vs {plain:?}"
    );
}

/// Tracks `frames` with `history` and tolerance 1e-6; per frame, the
/// prediction's worst distance from the answer over the change's largest.
fn prediction_errors(history: usize, frames: &[SurfaceMesh]) -> Vec<f32> {
    let params = symmetric().with(|p| {
        p.tuning.history = history;
        p.tolerance = 1e-6;
    });
    let mut deformer = Deformer::new(breast_model(), params).unwrap();
    let mut solution = deformer.positions().to_vec();
    let worst = |a: &[Vec3], b: &[Vec3]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max)
    };
    frames
        .iter()
        .enumerate()
        .map(|(k, frame)| {
            deformer.set_surface(frame).unwrap();
            let start = deformer.positions().to_vec();
            assert!(deformer.solve().converged, "history {history}, frame {k}");
            let previous = std::mem::replace(&mut solution, deformer.positions().to_vec());
            worst(&start, &solution) / worst(&previous, &solution)
        })
        .collect()
}

/// A sag breathing in and out (its depth `0.5 - 0.5 cos(k / 2)` of the full
/// 12 mm at frame `k`: accelerating, turning back): the prediction fits this
/// frame's surface move with the last two frames' changes, so every frame
/// starts within 2 % of its change of the answer (0.4 % measured); the
/// affine map alone (`history = 0`) leaves 17 % of it to the solve.
#[test]
fn the_prediction_follows_a_breathing_sag() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let frames: Vec<SurfaceMesh> = (0..12)
        .map(|k| {
            let depth = 0.5 - 0.5 * (0.5 * k as f32).cos();
            interpolate(&model.surface, &sagged, depth).unwrap()
        })
        .collect();
    let (fitted, affine) = (prediction_errors(2, &frames), prediction_errors(0, &frames));
    eprintln!("start error / change: {fitted:?} fitted, {affine:?} affine only");
    assert!(
        fitted[3..].iter().all(|&r| r < 0.02),
        "{fitted:?} (affine only: {affine:?})"
    );
    assert!(
        affine[3..].iter().all(|&r| r > 0.1),
        "{affine:?} (fitted: {fitted:?})"
    );
}

/// A sag and an indentation at two rhythms (depths `0.5 - 0.5 cos(k / 2)`
/// and `0.5 - 0.5 cos(0.8 k)`): two changes span both shapes, so from the
/// third frame on every frame starts within 5 % of its change of the answer
/// (2.5 % measured at 5k particles). Fitting each change's affine part on
/// its own base (where that change started) instead of the current one
/// left up to 9 %.
#[test]
fn the_prediction_follows_a_sag_and_an_indentation_out_of_step() {
    let model = breast_model();
    let (sagged, indented) = (
        tissue::deform::sagged_breast(),
        tissue::deform::indented_breast(),
    );
    let frames: Vec<SurfaceMesh> = (0..12)
        .map(|k| {
            let (a, b) = (
                0.5 - 0.5 * (0.5 * k as f32).cos(),
                0.5 - 0.5 * (0.8 * k as f32).cos(),
            );
            let vertices = (model.surface.vertices.iter())
                .zip(&sagged.vertices)
                .zip(&indented.vertices)
                .map(|((&p, &s), &i)| p + a * (s - p) + b * (i - p))
                .collect();
            SurfaceMesh::new(vertices, model.surface.triangles.clone())
        })
        .collect();
    let fitted = prediction_errors(2, &frames);
    eprintln!("start error / change: {fitted:?}");
    assert!(fitted[3..].iter().all(|&r| r < 0.05), "{fitted:?}");
}

/// The rest shape counts as a solved frame: after a first frame of half
/// the sag, a frame grown by 2 % of the sag starts from the change rest to
/// half (the same shape), within 1 % of its change of the answer (0.65 %
/// measured), and takes a few iterations (2, here and at 10k; 8 here and
/// 11 at 10k, 17 % of the change off, without the rest frame); `reset`
/// puts the rest frame back.
#[test]
fn the_first_tracked_frame_fits_the_change_from_rest() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let frames = [
        interpolate(&model.surface, &sagged, 0.5).unwrap(),
        interpolate(&model.surface, &sagged, 0.52).unwrap(),
    ];
    let mut deformer = Deformer::new(model, symmetric()).unwrap();
    for round in ["new", "after reset"] {
        deformer.set_surface(&frames[0]).unwrap();
        assert!(deformer.solve().converged);
        let first = deformer.positions().to_vec();
        deformer.set_surface(&frames[1]).unwrap();
        let start = deformer.positions().to_vec();
        let report = deformer.solve();
        assert!(report.converged);
        let worst = |a: &[Vec3], b: &[Vec3]| {
            a.iter()
                .zip(b)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max)
        };
        let off = worst(&start, deformer.positions()) / worst(&first, deformer.positions());
        eprintln!(
            "{round}: {} iterations, start {off:.4} of the change",
            report.iterations
        );
        assert!(off < 0.01, "{round}: start {off} of the change");
        assert!(report.iterations <= 5, "{round}: {report:?}");
        deformer.reset();
    }
}

/// `rest + a (first - rest) + b (second - rest)`, vertex by vertex.
fn mixed(
    rest: &SurfaceMesh,
    first: &SurfaceMesh,
    a: f32,
    second: &SurfaceMesh,
    b: f32,
) -> SurfaceMesh {
    let vertices = (rest.vertices.iter())
        .zip(&first.vertices)
        .zip(&second.vertices)
        .map(|((&p, &f), &s)| p + a * (f - p) + b * (s - p))
        .collect();
    SurfaceMesh::new(vertices, rest.triangles.clone())
}

/// By default (the two-level solve) every tracking frame whose surface
/// moves by at most 2 % of the size takes at most 10 iterations, the first
/// change away from rest included (nothing to predict it from), and fewer
/// in all than without it; every frame is within the tolerance of a
/// tight reference solve:
/// - a sag in 3 mm steps (1.6 % of the size a frame) and an indentation
///   growing 1.6 mm a frame;
/// - a sag and an indentation at two rhythms (up to 2.1 % of the size a
///   frame; the frames over 2 % are solved and checked but not counted).
#[test]
fn small_tracking_frames_take_at_most_ten_iterations_with_the_symmetric_force() {
    let model = breast_model();
    let defaults = symmetric();
    let tight = symmetric().with(|p| {
        p.tolerance = 1e-6;
    });
    let mut reference = Deformer::new(model, tight).unwrap();
    let rest = &model.surface;
    let (sagged, indented) = (
        tissue::deform::sagged_breast(),
        tissue::deform::indented_breast(),
    );
    let steps = |target: &SurfaceMesh, count: usize| -> Vec<SurfaceMesh> {
        (1..=count)
            .map(|k| interpolate(rest, target, 0.2 * k as f32).unwrap())
            .collect()
    };
    let out_of_step: Vec<SurfaceMesh> = (1..12)
        .map(|k| {
            let t = k as f32;
            let (a, b) = (0.5 - 0.5 * (0.5 * t).cos(), 0.5 - 0.5 * (0.8 * t).cos());
            mixed(rest, &sagged, a, &indented, b)
        })
        .collect();
    let sequences = [
        ("sag", steps(&sagged, 6)),
        ("indentation", steps(&indented, 5)),
        ("sag and indentation out of step", out_of_step),
    ];
    for (name, frames) in sequences {
        let mut plain = Deformer::new(
            model,
            symmetric().with(|p| {
                p.tuning.coarse = 0.0;
            }),
        )
        .unwrap();
        let mut deformer = Deformer::new(model, defaults.clone()).unwrap();
        assert!(deformer.coarse().is_some() && plain.coarse().is_none());
        let size = deformer.size();
        reference.reset();
        let (mut with, mut without, mut small) = (Vec::new(), Vec::new(), Vec::new());
        let mut last = rest;
        for (k, frame) in frames.iter().enumerate() {
            let moved = (last.vertices.iter())
                .zip(&frame.vertices)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max);
            small.push(moved <= 0.02 * size);
            last = frame;
            plain.set_surface(frame).unwrap();
            deformer.set_surface(frame).unwrap();
            reference.set_surface(frame).unwrap();
            let (a, b) = (plain.solve(), deformer.solve());
            assert!(a.converged && b.converged && reference.solve().converged);
            without.push(a.iterations);
            with.push(b.iterations);
            let worst = (0..model.len())
                .map(|i| (deformer.positions()[i] - reference.positions()[i]).length())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= defaults.tolerance * size,
                "{name}, frame {k}: error {:.2e} of the size after {} iterations",
                worst / size,
                b.iterations
            );
        }
        eprintln!(
            "{name}: iterations {with:?} by default, {without:?} without the two-level solve (small: {small:?})"
        );
        assert!(small[0] && small.iter().filter(|&&s| s).count() >= frames.len() - 2);
        assert!(
            with.iter().zip(&small).all(|(&n, &s)| !s || n <= 10),
            "{name}: iterations {with:?} by default ({without:?} without the two-level solve)"
        );
        assert!(
            with.iter().sum::<usize>() < without.iter().sum::<usize>(),
            "{name}: {with:?} vs {without:?}"
        );
    }
}

/// A surface turning at a steady rate, 1 and 3 degrees a frame (a change of
/// up to 2 % of the size): the affine prediction carries the interior and
/// the rotations along exactly, so each frame takes a few iterations and
/// the answer stays rigid.
#[test]
fn a_turning_surface_is_tracked_in_a_few_iterations_per_frame() {
    let model = breast_model();
    let (lo, hi) = model.surface.bounds().unwrap();
    let axis = Vec3::new(1.0, 0.3, 0.2).normalize();
    for degrees in [1.0f32, 3.0] {
        let mut deformer = Deformer::new(model, symmetric()).unwrap();
        let size = deformer.size();
        let mut iterations = Vec::new();
        for k in 1..=8 {
            let rigid = Rigid::about_axis(
                axis,
                (degrees * k as f32).to_radians(),
                0.5 * (lo + hi),
                Vec3::ZERO,
            );
            deformer
                .set_surface(&deform_surface(&model.surface, &rigid))
                .unwrap();
            let report = deformer.solve();
            assert!(report.converged, "{degrees}°, frame {k}: {report:?}");
            iterations.push(report.iterations);
            let worst = (0..model.len())
                .map(|i| (deformer.positions()[i] - rigid.apply(model.positions[i])).length())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-5 * size,
                "{degrees}°, frame {k}: worst error {:.2e} of the size",
                worst / size
            );
        }
        eprintln!("{degrees}° a frame: iterations {iterations:?}");
        assert!(
            iterations.iter().all(|&n| n <= 6),
            "{degrees}° a frame: iterations {iterations:?}"
        );
    }
}

#[test]
fn a_surface_that_is_not_the_rest_surface_is_refused() {
    let model = breast_model();
    let mut deformer = Deformer::new(model, symmetric()).unwrap();
    let err = deformer
        .set_surface(&phantom::default_tumour())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("vertices") && err.contains("same mesh"),
        "{err}"
    );
    let mut shuffled = model.surface.clone();
    shuffled.triangles.swap(0, 1);
    let err = deformer.set_surface(&shuffled).unwrap_err().to_string();
    assert!(err.contains("triangle 0"), "{err}");
    let mut nan = model.surface.clone();
    nan.vertices[3].x = f32::NAN;
    let err = deformer.set_surface(&nan).unwrap_err().to_string();
    assert!(err.contains("not finite"), "{err}");
}

/// Particles with too few connections for a rotation (0, 1 or 2, or all in
/// one plane) and a particle cut off from the surface: the solve stays finite,
/// converges, and the cut-off particle stays where it was.
#[test]
fn degenerate_neighbourhoods_do_not_break_the_solve() {
    let model = breast_model();
    let interior: Vec<u32> = (0..model.len() as u32)
        .filter(|&i| !model.is_surface(i as usize))
        .collect();
    let (isolated, lonely, pair) = (interior[100], interior[200], interior[300]);
    let keep_one = model.connections.of(lonely as usize)[0];
    let keep_two = &model.connections.of(pair as usize)[..2];
    let pairs = model.connections.pair_list().into_iter().filter(|&(a, b)| {
        let touches = |p: u32| a == p || b == p;
        if touches(isolated) {
            return false;
        }
        if touches(lonely) {
            return a == keep_one || b == keep_one;
        }
        if touches(pair) {
            return keep_two.contains(&a) || keep_two.contains(&b);
        }
        true
    });
    let mut degenerate = model.clone();
    degenerate.connections = tissue::Connections::from_pairs(model.len(), pairs);
    assert!(degenerate.connections.of(isolated as usize).is_empty());
    assert_eq!(degenerate.connections.of(lonely as usize).len(), 1);
    assert_eq!(degenerate.connections.of(pair as usize).len(), 2);

    let mut deformer = Deformer::new(&degenerate, symmetric()).unwrap();
    deformer
        .set_surface(&tissue::deform::sagged_breast())
        .unwrap();
    let report = deformer.solve();
    assert!(report.converged, "{:?}", report.stopped_by);
    assert!(deformer.positions().iter().all(|q| q.is_finite()));
    assert!(
        deformer
            .rotations()
            .iter()
            .all(|r| (r.determinant() - 1.0).abs() < 1e-4)
    );
    assert_eq!(
        deformer.positions()[isolated as usize],
        model.positions[isolated as usize]
    );
    let mut intact = Deformer::new(model, symmetric()).unwrap();
    intact
        .set_surface(&tissue::deform::sagged_breast())
        .unwrap();
    let normal = intact.solve().iterations;
    assert!(
        report.iterations <= 2 * normal,
        "a floating particle must not stall the acceleration: {} iterations",
        report.iterations
    );
}

/// Above `coarse_direct_max_aggregates` the coarse Laplacian is solved by
/// two-grid cycles over groups of aggregates instead of its factor
/// (`tissue_solve::coarse::multilevel`, what a million particles need): the sag
/// from rest lands on the factored solve's answer within the tolerance,
/// in at most a few more iterations.
#[test]
fn the_cycled_coarse_solve_lands_where_the_factored_one_does() {
    let model = breast_model();
    let sagged = tissue::deform::sagged_breast();
    let factored = symmetric().with(|p| {
        p.tuning.extrapolate = false;
    });
    let cycled = factored.clone().with(|p| {
        p.tuning.coarse_direct_max_aggregates = 100;
    });
    let mut exact = Deformer::new(model, factored).unwrap();
    let mut approximate = Deformer::new(model, cycled).unwrap();
    let space = exact.coarse().unwrap();
    assert!(space.factor().is_some() && space.count() > 100);
    let space = approximate.coarse().unwrap();
    let multilevel = space.multilevel().expect("cycles above 100 aggregates");
    assert!(space.factor().is_none());
    assert!(multilevel.groups() <= 100 && multilevel.groups() > 1);
    let mut iterations = Vec::new();
    for deformer in [&mut exact, &mut approximate] {
        deformer.set_surface(&sagged).unwrap();
        let report = deformer.solve();
        assert!(report.converged, "{report:?}");
        iterations.push(report.iterations);
    }
    eprintln!("iterations factored / cycled: {iterations:?}");
    assert!(iterations[1] <= iterations[0] + 5, "{iterations:?}");
    let worst = (0..model.len())
        .map(|i| exact.positions()[i].distance(approximate.positions()[i]))
        .fold(0.0f32, f32::max);
    assert!(worst < 2.0 * 3e-5 * exact.size(), "{worst}");
}

/// The pipeline in any length unit (issue: a surface 1e6 times larger,
/// inside the documented size range, once had every particle "flat"):
/// the phantom scaled by 1e6 and by 1e-6 samples, and its sag solves with
/// both forces in the same iterations as at its own scale, with no particle
/// judged inverted and the same displacement, scaled. Moment matrices'
/// determinants (sixth powers of lengths) leave single precision at those
/// scales unless formed in their own unit (`elastic::moment_unit`).
#[test]
fn the_pipeline_is_the_same_in_any_length_unit() {
    use tissue::deform::Sag;
    let breast = phantom::default_breast();
    let sagged = deform_surface(&breast, &Sag::default());
    let scaled = |mesh: &SurfaceMesh, by: f32| {
        SurfaceMesh::new(
            mesh.vertices.iter().map(|v| *v * by).collect(),
            mesh.triangles.clone(),
        )
    };
    let run = |by: f32, force: ForceModel| {
        let model = tissue::sample(&scaled(&breast, by), &SamplingParams::with_particles(1_500))
            .unwrap_or_else(|e| panic!("scale {by}: {e}"))
            .model;
        let params = symmetric().with(|p| p.force = force);
        let mut deformer = Deformer::new(&model, params).unwrap();
        deformer.set_surface(&scaled(&sagged, by)).unwrap();
        let report = deformer.solve();
        assert!(report.converged, "scale {by}, {force:?}: {report:?}");
        let inverted = tissue::deformation::inversions(
            &model.positions,
            deformer.positions(),
            &model.connections,
        );
        assert_eq!(inverted.count, 0, "scale {by}, {force:?}");
        let largest = deformer
            .positions()
            .iter()
            .zip(&model.positions)
            .map(|(a, b)| a.distance(*b) / by)
            .fold(0.0, f32::max);
        (report.iterations, largest)
    };
    for force in [ForceModel::Symmetric, ForceModel::Elastic] {
        let (iterations, largest) = run(1.0, force);
        for by in [1e6, 1e-6] {
            let (i, l) = run(by, force);
            assert!(
                i.abs_diff(iterations) <= 1,
                "scale {by}, {force:?}: {i} iterations, {iterations} at scale 1"
            );
            assert!(
                (l - largest).abs() <= 1e-3 * largest,
                "scale {by}, {force:?}: moved {l}, {largest} at scale 1"
            );
        }
    }
}
