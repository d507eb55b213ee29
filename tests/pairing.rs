//! The skin matched to an observation without correspondence inside the
//! elastic solve: each elastic iteration pairs it with its nearest points
//! of the observation (the pairing pass, on both devices) and pulls it
//! onto the planes there.
#![allow(clippy::unwrap_used, reason = "tests")]

mod common;

use glam::Vec3;
use tissue::backend::{Device, Solver};
use tissue::observation::{MatchParams, Observation, SURFACE_SMOOTHING, match_observation};
use tissue::{ParticleModel, SurfaceMesh};
use tissue_cpu::deformation::{DeformParams, ForceModel, StopReason};
use tissue_solve::model::held_vertices;
use tissue_solve::stage2::{NO_LIMIT, Pairing, PairingRule};

/// `mesh` with every triangle cut into four: the same surface in another
/// triangulation (other vertices, other triangles).
fn subdivided(mesh: &SurfaceMesh) -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::cut_in_four(&mesh.vertices, &mesh.triangles);
    SurfaceMesh::new(vertices, triangles)
}

/// The sag solved with every surface vertex observed (the truth), then
/// again with only the chest wall held and the skin matched to the sagged
/// surface in another triangulation: the skin lands on it, the interior
/// near the truth (the skin slides where the mechanics sends it, not where
/// the sag's map put it), and the CPU and the GPU take the same steps.
#[test]
fn the_skin_lands_on_another_triangulation_of_the_sag_on_both_devices() {
    let model = common::phantom_model(3_000);
    let sagged = tissue::deform::sagged_breast();
    let params = DeformParams::default();
    let mut truth = Solver::new(Device::Cpu, &model, params.clone()).unwrap();
    truth.set_surface(&sagged).unwrap();
    assert!(truth.solve().unwrap().converged);
    let truth = truth.positions().to_vec();
    let size = truth_size(&model);
    let held = held_vertices(&model.surface, &sagged, 1e-3 * size).unwrap();
    let observed = params.with(|p| p.observed = Some(held));
    let observation = Observation::surface(&subdivided(&sagged)).unwrap();
    let moved = rms(&model.positions, &truth);

    // Paired with the plane smoothed over the surface's vertices (the
    // default), and with its nearest point and the distance's curvature.
    for smoothing in [SURFACE_SMOOTHING, 0.0] {
        let matching = MatchParams {
            surface_smoothing: smoothing,
            ..MatchParams::default()
        };
        let mut devices = vec![Device::Cpu];
        devices.extend(common::gpu());
        let mut solved = Vec::new();
        for device in devices {
            let mut solver = Solver::new(device, &model, observed.clone()).unwrap();
            let on = format!("{}, smoothing {smoothing}", solver.backend());
            solver.set_surface(&model.surface).unwrap();
            let report = match_observation(&mut solver, &model, &observation, &matching).unwrap();
            let positions = solver.positions().to_vec();
            let off = rms(&positions, &truth);
            eprintln!(
                "{on}: {} iterations over {} stages, {}/{} pulled, residual {:?}, stopped by \
                 {:?}; the particles {off:.3} from the truth after moving {moved:.3}",
                report.iterations,
                report.stages,
                report.pulled,
                report.skin,
                report.residual,
                report.last.stopped_by
            );
            assert!(report.converged, "{on}: {:?}", report.last);
            // The smoothed plane moves with the skin: the last stage ends at
            // the tolerance, not where the nearest point's jumps leave it.
            if smoothing > 0.0 {
                assert_eq!(report.last.stopped_by, StopReason::Tolerance, "{on}");
            }
            assert_eq!(
                report.pulled, report.skin,
                "{on}: every free skin particle pulled"
            );
            // The skin on the sag: the observed points on the model's surface.
            assert!(
                report.residual.rms < 0.01 * moved,
                "{on}: residual {:?}, {moved} moved",
                report.residual
            );
            assert!(off < 0.5 * moved, "{on}: {off} from the sag, {moved} moved");
            // Nothing is left pulling: a solve after it has no springs.
            assert!(solver.plan().springs.is_empty() && solver.plan().pairing.is_none());
            solved.push((report.iterations, positions));
        }
        // Near ties of the nearest points round apart on the two devices,
        // the energy watch then steps back at other iterations, and the
        // stages' solves stop up to a fifth of their iterations apart; the
        // skin and the interior land in the same place.
        assert_same_match(&solved, size);
    }
}

/// The sag's front half as a scan (the sagged surface's vertices above
/// the middle height, cut into four first, noiseless): the seen skin lands
/// on the scan, the skin past its edge goes where the mechanics sends it,
/// and the CPU and the GPU agree.
#[test]
fn the_seen_skin_lands_on_a_scan_of_the_sag_on_both_devices() {
    let model = common::phantom_model(3_000);
    let sagged = tissue::deform::sagged_breast();
    let size = truth_size(&model);
    let held = chest_wall(&model);
    let observed = DeformParams::default().with(|p| p.observed = Some(held));
    let dense = subdivided(&sagged);
    let mut heights: Vec<f32> = dense.vertices.iter().map(|v| v.z).collect();
    heights.sort_by(f32::total_cmp);
    let middle = heights[heights.len() / 2];
    let seen: Vec<Vec3> = dense
        .vertices
        .iter()
        .copied()
        .filter(|v| v.z > middle)
        .collect();
    let cloud = tissue::observation::Cloud::new(seen).unwrap();
    let centre = model.positions.iter().copied().sum::<Vec3>() / model.len() as f32;
    let observation = Observation::cloud(&cloud, None, centre).unwrap();
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let mut solved = Vec::new();
    for device in devices {
        let mut solver = Solver::new(device, &model, observed.clone()).unwrap();
        let on = solver.backend();
        solver.set_surface(&model.surface).unwrap();
        let report =
            match_observation(&mut solver, &model, &observation, &MatchParams::default()).unwrap();
        eprintln!(
            "{on}: {} iterations, {}/{} pulled, {} outliers, residual {:?}",
            report.iterations,
            report.pulled,
            report.skin,
            observation.outliers(),
            report.residual
        );
        assert!(report.converged, "{on}: {:?}", report.last);
        assert!(
            report.pulled > report.skin / 4 && report.pulled < report.skin,
            "{on}: {} of {} pulled",
            report.pulled,
            report.skin
        );
        assert!(
            report.residual.rms < 2e-3 * size,
            "{on}: {:?}",
            report.residual
        );
        solved.push((report.iterations, solver.positions().to_vec()));
    }
    assert_same_match(&solved, size);
}

/// A deep indentation (a probe pressing the top of the phantom in by a
/// quarter of its height) seen by a scan of the upper skin only: the
/// skin that has far to go is pulled with a bounded force (Huber's)
/// rather than set aside, so it reaches the scan, the scan lies on the
/// model's surface to a small part of the indentation, and the CPU and
/// the GPU agree. Set aside as it once was, the dent's skin stayed up to
/// 15 mm off and the scan lay 3.9 mm from the surface (RMS) at 10,000
/// particles.
#[test]
fn the_skin_follows_a_scan_of_a_deep_indentation_on_both_devices() {
    let model = common::phantom_model(3_000);
    let rest = &model.surface;
    let (low, high) = rest
        .vertices
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), v| {
            (lo.min(v.z), hi.max(v.z))
        });
    let height = high - low;
    let depth = 0.27 * height;
    let width = 0.33 * height;
    let dented: Vec<Vec3> = rest
        .vertices
        .iter()
        .map(|&v| {
            let up = v.z - low;
            let fade = (up / (0.55 * height)).min(1.0);
            let across = v.x * v.x + v.y * v.y;
            v - Vec3::Z * depth * fade * (-across / (2.0 * width * width)).exp()
        })
        .collect();
    let dented = SurfaceMesh {
        vertices: dented,
        ..rest.clone()
    };
    let size = truth_size(&model);
    let held: Vec<bool> = rest.vertices.iter().map(|v| v.z < low + 1e-4).collect();
    let observed = DeformParams::default().with(|p| p.observed = Some(held));
    let dense = subdivided(&dented);
    let seen: Vec<Vec3> = subdivided(&dense)
        .vertices
        .iter()
        .copied()
        .filter(|v| v.z > low + 0.5 * height)
        .collect();
    let cloud = tissue::observation::Cloud::new(seen).unwrap();
    let centre = model.positions.iter().copied().sum::<Vec3>() / model.len() as f32;
    let observation = Observation::cloud(&cloud, None, centre).unwrap();
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let mut solved = Vec::new();
    for device in devices {
        let mut solver = Solver::new(device, &model, observed.clone()).unwrap();
        let on = solver.backend();
        solver.set_surface(rest).unwrap();
        let report =
            match_observation(&mut solver, &model, &observation, &MatchParams::default()).unwrap();
        eprintln!(
            "{on}: {} iterations, {}/{} pulled, {} beyond the robust scale {:?}, residual {:?}",
            report.iterations,
            report.pulled,
            report.skin,
            report.beyond_robust,
            report.robust,
            report.residual
        );
        assert!(report.converged, "{on}: {:?}", report.last);
        assert!(
            report.residual.rms < 0.02 * depth,
            "{on}: the scan {:?} from the skin, the indentation {depth} deep",
            report.residual
        );
        assert!(
            report.beyond_robust * 50 < report.pulled,
            "{on}: {} of {} pulled still beyond the robust scale",
            report.beyond_robust,
            report.pulled
        );
        // The skin at the top of the dent went down with it.
        let top = Vec3::new(0.0, 0.0, high);
        let dent_skin = report
            .surface
            .vertices
            .iter()
            .zip(&rest.vertices)
            .filter(|(_, r)| (**r - top).length() < 0.5 * width)
            .map(|(v, r)| r.z - v.z)
            .fold(f32::MAX, f32::min);
        eprintln!("{on}: the dent's top skin pressed in by at least {dent_skin:.2} of {depth:.2}");
        assert!(
            dent_skin > 0.7 * depth,
            "{on}: the skin at the dent's top pressed in by {dent_skin} of {depth}"
        );
        solved.push((report.iterations, solver.positions().to_vec()));
    }
    assert_same_match(&solved, size);
}

/// Tracking frames of scans of a growing sag (the phantom's front half
/// sagging 3 mm more each frame), each matched from the last frame's
/// answer: after the first two, a frame starts where the last frames'
/// changes put the skin on its scan, and lands where the frame started
/// from the last answer lands, in at most two thirds of its iterations;
/// with the elastic correction kept from frame to frame
/// (`MatchParams::keep_correction`) it lands there too, in about as many
/// iterations as with the correction made again; the CPU and the GPU take
/// the same steps.
#[test]
fn tracking_frames_of_scans_start_where_the_last_changes_lead_on_both_devices() {
    let model = common::phantom_model(3_000);
    let size = truth_size(&model);
    let held = chest_wall(&model);
    let observed = DeformParams::default().with(|p| p.observed = Some(held));
    let mut heights: Vec<f32> = model.surface.vertices.iter().map(|v| v.z).collect();
    heights.sort_by(f32::total_cmp);
    let middle = heights[heights.len() / 2];
    let centre = model.positions.iter().copied().sum::<Vec3>() / model.len() as f32;
    let scans: Vec<Observation> = (1..=4)
        .map(|k| {
            let sag = tissue::deform::Sag {
                magnitude_mm: 3.0 * k as f32,
                ..Default::default()
            };
            let sagged = tissue::deform::deform_surface(&model.surface, &sag);
            let seen: Vec<Vec3> = sagged
                .vertices
                .iter()
                .zip(&model.surface.vertices)
                .filter(|(_, rest)| rest.z > middle)
                .map(|(v, _)| *v)
                .collect();
            let cloud = tissue::observation::Cloud::new(seen).unwrap();
            Observation::cloud(&cloud, None, centre).unwrap()
        })
        .collect();
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let (mut solved, mut kept_solved) = (Vec::new(), Vec::new());
    for device in devices {
        // Every frame's iterations and the last frame's answer.
        let track = |predict: bool, keep_correction: bool| {
            let mut solver = Solver::new(device.clone(), &model, observed.clone()).unwrap();
            let on = solver.backend();
            solver.set_surface(&model.surface).unwrap();
            let mut iterations = Vec::new();
            for (k, scan) in scans.iter().enumerate() {
                let params = if k == 0 {
                    MatchParams {
                        keep_correction,
                        ..MatchParams::default()
                    }
                } else {
                    MatchParams {
                        predict,
                        keep_correction,
                        ..MatchParams::next_frame(None)
                    }
                };
                let report = match_observation(&mut solver, &model, scan, &params).unwrap();
                assert!(report.converged, "{on}, frame {k}: {:?}", report.last);
                assert!(
                    report.residual.rms < 2e-3 * size,
                    "{on}, frame {k}: {:?}",
                    report.residual
                );
                iterations.push(report.iterations);
            }
            eprintln!(
                "{on}, predicted {predict}, correction kept {keep_correction}: {iterations:?} \
                 iterations"
            );
            (iterations, solver.positions().to_vec())
        };
        let (predicted, at) = track(true, false);
        let (plain, plain_at) = track(false, false);
        let (kept, kept_at) = track(true, true);
        let later = |iterations: &[usize]| iterations[2..].iter().sum::<usize>();
        assert!(
            3 * later(&predicted) <= 2 * later(&plain),
            "{predicted:?} iterations predicted against {plain:?}"
        );
        assert!(
            rms(&at, &plain_at) < 1e-3 * size,
            "{} apart",
            rms(&at, &plain_at)
        );
        assert!(
            2 * later(&kept) <= 3 * later(&predicted) + 4,
            "{kept:?} iterations with the correction kept against {predicted:?}"
        );
        assert!(
            rms(&kept_at, &at) < 1e-3 * size,
            "{} apart",
            rms(&kept_at, &at)
        );
        solved.push((predicted.iter().sum(), at));
        kept_solved.push((kept.iter().sum(), kept_at));
    }
    assert_same_match(&solved, size);
    assert_same_match(&kept_solved, size);
}

/// A pairing that does not fit the solve is refused with what is wrong:
/// without the elastic force, of a particle the solve does not move, with
/// a weight or a limit that is not a positive number.
#[test]
fn a_pairing_that_does_not_fit_is_refused_with_the_reason() {
    let model = common::phantom_model(2_000);
    let held = chest_wall(&model);
    let params = DeformParams::default().with(|p| p.observed = Some(held));
    let mut solver = Solver::new(Device::Cpu, &model, params.clone()).unwrap();
    let plan = solver.plan().clone();
    let free = (0..model.len()).find(|&i| plan.free[i]).unwrap() as u32;
    let fixed = (0..model.len()).find(|&i| !plan.free[i]).unwrap() as u32;
    let rule = PairingRule {
        weight: plan.lambda_max,
        edge: NO_LIMIT,
        robust: NO_LIMIT,
        cloud: false,
        smooth: 0.0,
    };
    let pairing = |skin: Vec<u32>, rule: PairingRule| Some(Pairing { skin, rule });
    let error = |solver: &mut Solver, pairing| solver.set_pairing(pairing).unwrap_err().to_string();
    let not_free = error(&mut solver, pairing(vec![free, fixed], rule));
    assert!(
        not_free.contains(&format!("particle {fixed}")) && not_free.contains("not a free"),
        "{not_free}"
    );
    let weightless = error(
        &mut solver,
        pairing(
            vec![free],
            PairingRule {
                weight: f32::NAN,
                ..rule
            },
        ),
    );
    assert!(weightless.contains("weight"), "{weightless}");
    let trimmed = error(
        &mut solver,
        pairing(
            vec![free],
            PairingRule {
                robust: -1.0,
                ..rule
            },
        ),
    );
    assert!(trimmed.contains("robust scale"), "{trimmed}");
    let rough = error(
        &mut solver,
        pairing(
            vec![free],
            PairingRule {
                smooth: -1.0,
                ..rule
            },
        ),
    );
    assert!(rough.contains("smoothing radius"), "{rough}");
    assert!(solver.set_pairing(pairing(vec![free], rule)).is_ok());
    assert!(solver.set_pairing(None).is_ok());

    let symmetric = params.with(|p| p.force = ForceModel::Symmetric);
    let mut other = Solver::new(Device::Cpu, &model, symmetric).unwrap();
    let refused = error(&mut other, pairing(vec![free], rule));
    assert!(refused.contains("elastic force"), "{refused}");
}

/// An observation that cannot be of the model's skin is refused, saying
/// why: a cloud a metre off (another frame or unit), one half a metre
/// beside it, and one near it whose every point lies past its edge for
/// every particle.
#[test]
fn a_cloud_nowhere_near_the_skin_is_refused() {
    let model = common::phantom_model(2_000);
    let held = chest_wall(&model);
    let params = DeformParams::default().with(|p| p.observed = Some(held));
    let mut solver = Solver::new(Device::Cpu, &model, params).unwrap();
    solver.set_surface(&model.surface).unwrap();
    // A small patch of a plane, a metre away.
    let points: Vec<Vec3> = (0..100)
        .map(|k| Vec3::new((k % 10) as f32, (k / 10) as f32, 1000.0))
        .collect();
    let cloud = tissue::observation::Cloud::new(points).unwrap();
    let observation = Observation::cloud(&cloud, None, Vec3::ZERO).unwrap();
    let error = match_observation(&mut solver, &model, &observation, &MatchParams::default())
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("a quarter of the model's size") && error.contains("another frame"),
        "{error}"
    );
    assert!(solver.plan().pairing.is_none() && solver.plan().springs.is_empty());
    // A patch beside the model, under the chest wall's plane: nothing of
    // the skin is over it.
    let beside: Vec<Vec3> = (0..100)
        .map(|k| Vec3::new(75.0 + (k % 10) as f32, (k / 10) as f32, -5.0))
        .collect();
    let cloud = tissue::observation::Cloud::new(beside).unwrap();
    let observation = Observation::cloud(&cloud, None, Vec3::ZERO).unwrap();
    let error = match_observation(&mut solver, &model, &observation, &MatchParams::default())
        .unwrap_err()
        .to_string();
    assert!(error.contains("lies near the observation"), "{error}");
    let far: Vec<Vec3> = (0..100)
        .map(|k| Vec3::new(500.0 + (k % 10) as f32, (k / 10) as f32, 0.0))
        .collect();
    let cloud = tissue::observation::Cloud::new(far).unwrap();
    let observation = Observation::cloud(&cloud, None, Vec3::ZERO).unwrap();
    let error = match_observation(&mut solver, &model, &observation, &MatchParams::default())
        .unwrap_err()
        .to_string();
    assert!(error.contains("a quarter of the model's size"), "{error}");
}

/// The phantom's chest wall: the surface vertices the sag does not move.
fn chest_wall(model: &ParticleModel) -> Vec<bool> {
    let sagged = tissue::deform::sagged_breast();
    held_vertices(&model.surface, &sagged, 1e-3 * truth_size(model)).unwrap()
}

/// The CPU's and the GPU's matches (iterations, positions), where both ran:
/// within a fifth of the iterations, every particle within a thousandth of
/// the size.
fn assert_same_match(solved: &[(usize, Vec<Vec3>)], size: f32) {
    if let [(cpu, on_cpu), (gpu, on_gpu)] = solved {
        let within = 3.max(cpu / 5);
        assert!(
            cpu.abs_diff(*gpu) <= within,
            "{cpu} iterations on the CPU, {gpu} on the GPU"
        );
        common::assert_same_positions(on_cpu, on_gpu, size);
    }
}

fn truth_size(model: &ParticleModel) -> f32 {
    Solver::new(Device::Cpu, model, DeformParams::default())
        .unwrap()
        .plan()
        .size
}

fn rms(a: &[Vec3], b: &[Vec3]) -> f32 {
    (a.iter()
        .zip(b)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum::<f32>()
        / a.len() as f32)
        .sqrt()
}

/// The phantom at 3,000 particles with its chest wall held, a
/// subdivision of its sag to match it to, and a solver on the CPU.
fn sag_match() -> (ParticleModel, Observation, Solver) {
    let model = common::phantom_model(3_000);
    let sagged = tissue::deform::sagged_breast();
    let observed = DeformParams::default().with(|p| p.observed = Some(chest_wall(&model)));
    let observation = Observation::surface(&subdivided(&sagged)).unwrap();
    let solver = Solver::new(Device::Cpu, &model, observed).unwrap();
    (model, observation, solver)
}

/// A surface's smoothing is a radius of 0 to 8 of its mean edges; any
/// other is refused, naming it, before the match starts.
#[test]
fn a_match_refuses_a_smoothing_out_of_its_range() {
    let (model, observation, mut solver) = sag_match();
    for smoothing in [-1.0, f32::NAN, 9.0] {
        let params = MatchParams {
            surface_smoothing: smoothing,
            ..MatchParams::default()
        };
        let error = match_observation(&mut solver, &model, &observation, &params)
            .unwrap_err()
            .to_string();
        assert!(error.contains("surface_smoothing"), "{smoothing}: {error}");
    }
    assert_eq!(solver.positions(), model.positions.as_slice());
}

/// A noise scale beyond a quarter of the organ's size (the farthest the
/// skin may lie from an observation) is refused before any solve, naming
/// the bound; one just below it is taken.
#[test]
fn a_match_refuses_a_noise_beyond_the_organs_reach() {
    let (model, observation, mut solver) = sag_match();
    let reach = tissue::observation::MAX_REACH * solver.plan().size;
    for noise in [1e30, 1.01 * reach, -1.0, f32::NAN] {
        let params = MatchParams {
            noise: Some(noise),
            ..MatchParams::default()
        };
        let error = match_observation(&mut solver, &model, &observation, &params)
            .unwrap_err()
            .to_string();
        assert!(error.contains("noise"), "{noise}: {error}");
        if noise > reach {
            assert!(error.contains("a quarter of the organ's size"), "{error}");
            // The value as a number, as the user gave it.
            assert!(error.contains(&format!("noise is {noise},")), "{error}");
        }
    }
    assert_eq!(solver.positions(), model.positions.as_slice());
    let params = MatchParams {
        noise: Some(0.99 * reach),
        ..MatchParams::default()
    };
    assert!(match_observation(&mut solver, &model, &observation, &params).is_ok());
}
