//! How sure an answer is (`tissue::uncertainty`): the spread is made of
//! the unknowns asked for and nothing else, a held target has none, and
//! the same seed gives the same regions on the CPU and on the GPU
//! (lavapipe in CI).
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use tissue::backend::{Device, Solver};
use tissue::deformation::DeformParams;
use tissue::uncertainty::{Answered, Priors, Spread, Unknown, exact_vertices, explore};
use tissue::{ParticleModel, SurfaceMesh};

/// The phantom at `particles` sagged on `device`, and the spread of that
/// answer under `priors`.
fn sagged_spread(
    device: &Device,
    model: &ParticleModel,
    priors: &Priors,
) -> (Spread, Vec<bool>, SurfaceMesh) {
    let deformed = tissue::deform::sagged_breast();
    let mut solver = Solver::new(device.clone(), model, DeformParams::default()).unwrap();
    solver.set_surface(&deformed).unwrap();
    assert!(solver.solve().unwrap().converged);
    let answer = solver.positions().to_vec();
    let inside: Vec<tissue::Vec3> = model.positions.iter().step_by(37).copied().collect();
    let bound = solver.bind(&inside).unwrap();
    let carried = solver.carry(&bound).unwrap();
    let exact = exact_vertices(&model.surface, &deformed);
    let answered = Answered {
        surface: &deformed,
        exact: &exact,
        rest_load: None,
        metres_per_unit: 1e-3,
        held_by: None,
    };
    let spread = explore(&mut solver, model, answered, priors).unwrap();
    assert!(spread.converged, "every re-solve converges");
    assert_eq!(solver.positions(), answer.as_slice(), "left at the answer");
    assert_eq!(
        solver.carry(&bound).unwrap(),
        carried,
        "points carried as at the answer, its rotations put back"
    );
    (spread, exact, deformed)
}

/// Nothing unknown but the Poisson ratio, its range a point at the
/// solve's own ratio: no column, no spread anywhere. Its range widened,
/// every particle's spread is the Poisson ratio's.
#[test]
fn the_poisson_ratio_alone_spreads_only_when_its_range_does() {
    let model = common::phantom_model(1_000);
    let nu = DeformParams::default().poisson;
    let none = Priors::default().with(|p| {
        p.poisson = (nu, nu);
        p.surface_noise = 0.0;
        p.posture_g = 0.0;
    });
    let (spread, _, _) = sagged_spread(&Device::Cpu, &model, &none);
    assert!(spread.columns.is_empty());
    assert_eq!(spread.solves, 0);
    assert!(
        spread
            .particle_regions()
            .iter()
            .all(|r| r.radius == 0.0 && r.dominant.is_none())
    );

    let poisson = none.with(|p| p.poisson = (0.45, 0.495));
    let (spread, _, _) = sagged_spread(&Device::Cpu, &model, &poisson);
    let regions = spread.particle_regions();
    let largest = regions.iter().map(|r| r.radius).fold(0.0, f32::max);
    eprintln!(
        "Poisson ratio alone: {} solves, largest radius {largest:.3} mm",
        spread.solves
    );
    assert!(largest > 0.05, "the ratio moves the interior: {largest}");
    assert!(
        regions
            .iter()
            .all(|r| r.dominant.is_none_or(|u| u == Unknown::Poisson))
    );
}

/// The unmodelled posture is solved at every Poisson ratio and integrated
/// over the range: nearly incompressible tissue answers a change of
/// gravity with its skin held mostly with pressure, so the response grows
/// as the ratio falls, and the spread over the range is wider than the
/// answer's own ratio gives.
#[test]
fn the_unmodelled_posture_is_integrated_over_the_poisson_ratios() {
    let model = common::phantom_model(1_000);
    let nu = DeformParams::default().poisson;
    let at_answer = Priors::default().with(|p| {
        p.poisson = (nu, nu);
        p.surface_noise = 0.0;
    });
    let over_range = at_answer.clone().with(|p| p.poisson = (0.45, 0.495));
    let (one, _, _) = sagged_spread(&Device::Cpu, &model, &at_answer);
    let (all, _, _) = sagged_spread(&Device::Cpu, &model, &over_range);
    fn posture(s: &Spread) -> Vec<&tissue::uncertainty::Column> {
        s.columns
            .iter()
            .filter(|c| c.unknown == Unknown::Posture)
            .collect()
    }
    assert_eq!(posture(&one).len(), 3, "one column per axis");
    assert_eq!(posture(&all).len(), 9, "per axis, one per quadrature node");
    let weights: f64 = posture(&all).iter().map(|c| c.weight).sum();
    assert!((weights - 3.0).abs() < 1e-9, "{weights}");
    // Two other ratios, the lower one with its three postures (every
    // quadrature node lies below the answer's 0.49), and the answer's own.
    assert_eq!(all.solves, 2 + 3 + 3);
    // Each particle's variance owed to the posture.
    let variance = |s: &Spread| -> Vec<f64> {
        (0..model.len())
            .map(|i| {
                posture(s)
                    .iter()
                    .map(|c| c.weight * f64::from((c.positions[i] - s.answer[i]).length_squared()))
                    .sum()
            })
            .collect()
    };
    let (one, all) = (variance(&one), variance(&all));
    let mut ratios: Vec<f64> = (0..model.len())
        .filter(|&i| !model.is_surface(i) && one[i] > 0.0)
        .map(|i| all[i] / one[i])
        .collect();
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    eprintln!(
        "the posture's variance over the range against at the answer's ratio: median {median:.2}"
    );
    assert!(median > 1.5, "{median}");
}

/// With every default unknown, the particles held on the chest wall
/// (control points on triangles that did not move) have no spread at
/// all; the free interior has.
#[test]
fn a_target_on_the_held_chest_wall_has_no_spread() {
    let model = common::phantom_model(1_000);
    let priors = Priors::default().with(|p| p.samples = 4);
    let (spread, exact, _) = sagged_spread(&Device::Cpu, &model, &priors);
    assert!(
        exact.iter().filter(|&&e| e).count() > 10,
        "the phantom has a chest wall"
    );
    let regions = spread.particle_regions();
    let held: Vec<usize> = (0..model.len())
        .filter(|&i| {
            model.attachments[i].is_some_and(|a| {
                model.surface.triangles[a.triangle as usize]
                    .iter()
                    .all(|&v| exact[v as usize])
            })
        })
        .collect();
    assert!(held.len() > 5, "{} particles on the chest wall", held.len());
    for &i in &held {
        assert_eq!(regions[i].radius, 0.0, "held particle {i}");
    }
    let inside = (0..model.len()).filter(|&i| !model.is_surface(i));
    assert!(inside.map(|i| regions[i].radius).fold(0.0, f32::max) > 0.1);
}

/// The same seed gives the same regions on the CPU and on the GPU: each
/// particle's 95 % radius within a thousandth of the model's size.
#[test]
fn the_same_seed_gives_the_same_regions_on_cpu_and_gpu() {
    let Some(gpu) = common::gpu() else {
        return;
    };
    let model = common::phantom_model(1_000);
    let priors = Priors::default().with(|p| p.samples = 4);
    let (on_cpu, _, deformed) = sagged_spread(&Device::Cpu, &model, &priors);
    let (on_gpu, _, _) = sagged_spread(&gpu, &model, &priors);
    assert_eq!(on_cpu.columns.len(), on_gpu.columns.len());
    let (lo, hi) = deformed.bounds().unwrap();
    let size = (hi - lo).length();
    let (cpu, gpu) = (on_cpu.particle_regions(), on_gpu.particle_regions());
    let worst = cpu
        .iter()
        .zip(&gpu)
        .map(|(a, b)| (a.radius - b.radius).abs())
        .fold(0.0, f32::max);
    eprintln!(
        "{} and {} iterations; radii at most {worst:.2e} apart",
        on_cpu.iterations, on_gpu.iterations
    );
    assert!(worst <= 1e-3 * size, "{worst}");
}

/// The surface's samples run in chains, side by side on the CPU: the same
/// columns to the bit on one thread as on three, every sample in its
/// place.
#[test]
fn the_chains_give_the_same_columns_on_any_number_of_threads() {
    let model = common::phantom_model(1_000);
    let priors = Priors::default().with(|p| p.samples = 5);
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| sagged_spread(&Device::Cpu, &model, &priors).0)
    };
    let (one, three) = (on(1), on(3));
    assert_eq!(one.columns, three.columns);
    assert_eq!(
        (one.solves, one.iterations),
        (three.solves, three.iterations)
    );
    let samples: Vec<_> = one
        .columns
        .iter()
        .filter(|c| c.unknown == Unknown::Surface)
        .collect();
    assert_eq!(samples.len(), 5);
    // Five samples, five different surfaces.
    for (k, a) in samples.iter().enumerate() {
        for b in &samples[k + 1..] {
            assert_ne!(a.positions, b.positions);
        }
    }
}

/// An explorer kept over a sequence gives the next answer the regions a
/// fresh estimate gives it, each particle's radius within a thousandth of
/// the model's size, in fewer iterations: its other Poisson ratios'
/// solvers are kept and each re-solve starts from the last one's.
#[test]
fn an_explorer_carries_its_columns_from_answer_to_answer() {
    use tissue::uncertainty::Explorer;
    let model = common::phantom_model(1_000);
    let sagged = tissue::deform::sagged_breast();
    let half = tissue::deform::interpolate(&model.surface, &sagged, 0.5).unwrap();
    let priors = Priors::default().with(|p| p.samples = 4);
    let mut solver = Solver::new(Device::Cpu, &model, DeformParams::default()).unwrap();
    let mut explorer = Explorer::new(priors.clone());
    let mut spreads = Vec::new();
    for surface in [&half, &sagged] {
        solver.set_surface(surface).unwrap();
        assert!(solver.solve().unwrap().converged);
        let exact = exact_vertices(&model.surface, surface);
        let answered = Answered {
            surface,
            exact: &exact,
            rest_load: None,
            metres_per_unit: 1e-3,
            held_by: None,
        };
        spreads.push(explorer.explore(&mut solver, &model, answered).unwrap());
    }
    let (fresh, _, _) = sagged_spread(&Device::Cpu, &model, &priors);
    let carried = &spreads[1];
    assert!(carried.converged);
    eprintln!(
        "the second answer: {} iterations carried, {} fresh",
        carried.iterations, fresh.iterations
    );
    assert!(carried.iterations < fresh.iterations);
    let (lo, hi) = sagged.bounds().unwrap();
    let size = (hi - lo).length();
    let worst = carried
        .particle_regions()
        .iter()
        .zip(fresh.particle_regions())
        .map(|(a, b)| (a.radius - b.radius).abs())
        .fold(0.0, f32::max);
    assert!(worst <= 1e-3 * size, "{worst}");
}

/// The spreads of the phantom sagged in four steps on `device`, by an
/// explorer that refreshes two re-solves an answer.
fn refreshed_sag(device: &Device, model: &ParticleModel, priors: &Priors) -> Vec<Spread> {
    use tissue::uncertainty::{Explorer, Refresh};
    let mut explorer = Explorer::new(priors.clone()).refreshing(Refresh::every(2));
    let mut spreads = Vec::new();
    sag_in_steps(device, model, |solver, surface| {
        let exact = exact_vertices(&model.surface, surface);
        let answered = Answered {
            surface,
            exact: &exact,
            rest_load: None,
            metres_per_unit: 1e-3,
            held_by: None,
        };
        spreads.push(explorer.explore(solver, model, answered).unwrap());
    });
    spreads
}

/// The phantom's sag tracked on `device` in four steps, `between` run
/// after each answer: each step's positions and iterations.
fn sag_in_steps(
    device: &Device,
    model: &ParticleModel,
    mut between: impl FnMut(&mut Solver, &SurfaceMesh),
) -> Vec<(Vec<tissue::Vec3>, usize)> {
    let sagged = tissue::deform::sagged_breast();
    let mut solver = Solver::new(device.clone(), model, DeformParams::default()).unwrap();
    let mut answers = Vec::new();
    for step in [0.25, 0.5, 0.75, 1.0] {
        let surface = tissue::deform::interpolate(&model.surface, &sagged, step).unwrap();
        solver.set_surface(&surface).unwrap();
        let report = solver.solve().unwrap();
        assert!(report.converged);
        answers.push((solver.positions().to_vec(), report.iterations));
        between(&mut solver, &surface);
    }
    answers
}

/// An estimate between two frames leaves no trace on the frames after
/// it: a sag matched without correspondence in two frames, the second
/// keeping the first's elastic correction as a tracked scan does, with
/// an estimate of the first answer between them (its re-solves, paired
/// with the observation, make corrections of their own) takes the second
/// frame's iterations and answer to the bit, on the CPU and on the GPU
/// (lavapipe in CI), where the correction is put back on the device.
#[test]
fn an_estimate_between_frames_leaves_the_frames_as_they_were() {
    use tissue::observation::{MatchParams, Observation, match_observation};
    let model = common::phantom_model(1_000);
    let (params, whole, _) = sag_without_correspondence(&model);
    let halfway =
        tissue::deform::interpolate(&model.surface, &tissue::deform::sagged_breast(), 0.5).unwrap();
    let (vertices, triangles) = tissue_testkit::cut_in_four(&halfway.vertices, &halfway.triangles);
    let half = Observation::surface(&SurfaceMesh::new(vertices, triangles)).unwrap();
    let priors = Priors::default().with(|p| p.samples = 2);
    let devices = std::iter::once(Device::Cpu).chain(common::gpu());
    for device in devices {
        let track = |explored: bool| {
            let mut solver = Solver::new(device.clone(), &model, params.clone()).unwrap();
            let on = solver.backend();
            solver.set_surface(&model.surface).unwrap();
            let first = MatchParams {
                keep_correction: true,
                ..MatchParams::default()
            };
            let matched = match_observation(&mut solver, &model, &half, &first).unwrap();
            assert!(matched.converged, "{on}");
            if explored {
                let exact = exact_vertices(&model.surface, &matched.surface);
                let answered = matched_answer(&matched, &exact, None);
                assert!(
                    explore(&mut solver, &model, answered, &priors)
                        .unwrap()
                        .converged
                );
            }
            let next = MatchParams {
                keep_correction: true,
                ..MatchParams::next_frame(None)
            };
            let matched = match_observation(&mut solver, &model, &whole, &next).unwrap();
            assert!(matched.converged, "{on}");
            (on, matched.iterations, solver.positions().to_vec())
        };
        let (on, iterations, answer) = track(false);
        let explored = track(true);
        assert_eq!(iterations, explored.1, "{on}: the next frame's iterations");
        assert!(answer == explored.2, "{on}: the next frame's answer");
    }
}

/// An explorer that refreshes two re-solves an answer makes them all at
/// the first answer, then two at each (in turn) and carries the others
/// from the answer that made them last, each its offset put on the new
/// answer: over a sag in four steps its last regions are a fresh
/// estimate's, each particle's radius within 8 % at the median (carried
/// from where the sag was a quarter shallower or more) and within half
/// at most; on the GPU the same re-solves give the CPU's regions.
#[test]
fn an_explorer_refreshing_two_re_solves_an_answer_carries_the_others() {
    let model = common::phantom_model(1_000);
    let priors = Priors::default().with(|p| p.samples = 4);
    let spreads = refreshed_sag(&Device::Cpu, &model, &priors);
    // Two other Poisson ratios, four samples, three unmodelled postures at
    // the answer's ratio and three at the range's lower end.
    let all = 2 + 4 + 3 + 3;
    assert_eq!((spreads[0].solves, spreads[0].carried), (all, 0));
    for spread in &spreads[1..] {
        assert!(spread.converged);
        assert_eq!((spread.solves, spread.carried), (2, all - 2));
    }
    let (fresh, _, deformed) = sagged_spread(&Device::Cpu, &model, &priors);
    let last = &spreads[3];
    assert_eq!(last.columns.len(), fresh.columns.len());
    let mut off: Vec<f32> = last
        .particle_regions()
        .iter()
        .zip(fresh.particle_regions())
        .map(|(a, b)| (a.radius - b.radius).abs() / b.radius.max(1e-3))
        .collect();
    off.sort_by(f32::total_cmp);
    let (median, worst) = (off[off.len() / 2], off[off.len() - 1]);
    eprintln!("radii off a fresh estimate's: median {median:.4}, at most {worst:.4}");
    assert!(median <= 0.08 && worst <= 0.5, "{median} {worst}");
    let Some(gpu) = common::gpu() else {
        return;
    };
    let on_gpu = refreshed_sag(&gpu, &model, &priors);
    for (cpu, gpu) in spreads.iter().zip(&on_gpu) {
        assert_eq!((cpu.solves, cpu.carried), (gpu.solves, gpu.carried));
    }
    let (lo, hi) = deformed.bounds().unwrap();
    let size = (hi - lo).length();
    let worst = last
        .particle_regions()
        .iter()
        .zip(on_gpu[3].particle_regions())
        .map(|(a, b)| (a.radius - b.radius).abs())
        .fold(0.0, f32::max);
    eprintln!("on the GPU: radii at most {worst:.2e} from the CPU's");
    assert!(worst <= 1e-3 * size, "{worst}");
}

/// Another Poisson ratio's solver prepared from a solver's shared
/// preparation (as the explorer prepares its other ratios) takes the
/// elastic model with only its weights made again: a higher ratio (which
/// estimates its own volume smoother's contraction) has the plan, the
/// iterations and the answer of a solver made from nothing, to the bit; a
/// lower one the same plan. The model is offered only for the rest shape
/// it was made in.
#[test]
fn another_poisson_ratio_shares_the_elastic_model_and_solves_the_same() {
    let model = common::phantom_model(1_000);
    let base = Solver::new(Device::Cpu, &model, DeformParams::default()).unwrap();
    let shared = base.shared_laplacian();
    let deformed = tissue::deform::sagged_breast();
    let answer = |mut solver: Solver| {
        solver.set_surface(&deformed).unwrap();
        let report = solver.solve().unwrap();
        assert!(report.converged);
        let positions = solver.positions().to_vec();
        (
            positions,
            report.iterations,
            solver.into_tracker().plan().clone(),
        )
    };
    for nu in [0.495, 0.45] {
        let other = DeformParams::default().with(|p| p.poisson = nu);
        let from_shared = answer(
            Solver::new_shared(
                Device::Cpu,
                &model,
                other.clone(),
                Some(&shared),
                &mut |_| {},
            )
            .unwrap(),
        );
        let fresh = answer(Solver::new(Device::Cpu, &model, other).unwrap());
        assert_eq!(
            from_shared.2, fresh.2,
            "the same plan, elastic model included"
        );
        assert_eq!(from_shared.2.elastic.as_ref().unwrap().poisson, nu);
        if nu > DeformParams::default().poisson {
            assert_eq!(from_shared.1, fresh.1);
            assert_eq!(from_shared.0, fresh.0, "the same answer to the bit");
        }
    }

    let key = base.into_tracker().plan().elastic_key.unwrap();
    let (rest, connections) = (&model.positions, &model.connections);
    let elastic = shared.elastic().unwrap();
    assert!(elastic.for_ratio(key, 0.45, rest, connections).is_some());
    assert!(
        elastic
            .for_ratio(key ^ 1, 0.45, rest, connections)
            .is_none()
    );
}

/// A matched answer (`exact` its surface's vertices given exactly, in
/// millimetres), its skin paired with the observation it was matched to,
/// its rest posture's load `rest_load` where it has one.
fn matched_answer<'a>(
    matched: &'a tissue::observation::MatchReport,
    exact: &'a [bool],
    rest_load: Option<tissue::Vec3>,
) -> Answered<'a> {
    Answered {
        surface: &matched.surface,
        exact,
        rest_load,
        metres_per_unit: 1e-3,
        held_by: Some(&matched.held),
    }
}

/// The phantom's sag as an observation without correspondence (its
/// surface cut in four), the parameters that hold `model`'s chest wall
/// where the sag leaves it, and the sag's size.
fn sag_without_correspondence(
    model: &ParticleModel,
) -> (DeformParams, tissue::observation::Observation, f32) {
    let sagged = tissue::deform::sagged_breast();
    let (lo, hi) = sagged.bounds().unwrap();
    let size = (hi - lo).length();
    let held = tissue::gravity::held_vertices(&model.surface, &sagged, 1e-3 * size).unwrap();
    let params = DeformParams::default().with(|p| p.observed = Some(held));
    let (vertices, triangles) = tissue_testkit::cut_in_four(&sagged.vertices, &sagged.triangles);
    let observation =
        tissue::observation::Observation::surface(&SurfaceMesh::new(vertices, triangles)).unwrap();
    (params, observation, size)
}

/// An answer matched to another triangulation of the sag (no
/// correspondence: the chest wall held, the skin paired with the surface
/// inside the solve) spreads with its skin paired with the observation
/// again in every re-solve: the answer is the re-solves' own equilibrium
/// (the spread's answer is the solver's, to the bit), every re-solve
/// converges and leaves the solver at the answer with no springs, the
/// chest wall has no spread, the interior has, the surface's error alone
/// spreads the skin by about its size, the Poisson ratio's range spreads
/// the skin by about what matching again at the range's ends moves it
/// (not by sliding it along the observation), and the CPU and the GPU
/// (lavapipe in CI) give the same regions.
#[test]
fn a_matched_answer_spreads_with_its_skin_paired_with_the_observation() {
    use tissue::observation::{MatchParams, match_observation};
    let model = common::phantom_model(1_000);
    let (params, observation, size) = sag_without_correspondence(&model);
    let sigma = 0.5;
    let nu = DeformParams::default().poisson;
    let everything = Priors::default().with(|p| p.samples = 4);
    let surface_alone = everything.clone().with(|p| {
        p.poisson = (nu, nu);
        p.posture_g = 0.0;
        p.surface_noise = sigma;
    });
    let poisson_alone = everything.clone().with(|p| {
        p.posture_g = 0.0;
        p.surface_noise = 0.0;
    });
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let mut radii = Vec::new();
    for device in devices {
        let mut solver = Solver::new(device.clone(), &model, params.clone()).unwrap();
        let on = solver.backend();
        solver.set_surface(&model.surface).unwrap();
        let matched =
            match_observation(&mut solver, &model, &observation, &MatchParams::default()).unwrap();
        assert!(matched.converged, "{on}: {:?}", matched.last);
        let answer = solver.positions().to_vec();
        let exact = exact_vertices(&model.surface, &matched.surface);
        let answered = matched_answer(&matched, &exact, None);
        let mut spreads = Vec::new();
        for priors in [&everything, &surface_alone, &poisson_alone] {
            let spread = explore(&mut solver, &model, answered, priors).unwrap();
            assert!(spread.converged, "{on}: every re-solve converges");
            assert_eq!(
                spread.answer, answer,
                "{on}: the answer is the re-solves' own"
            );
            assert_eq!(
                solver.positions(),
                answer.as_slice(),
                "{on}: left at the answer"
            );
            assert!(solver.plan().springs.is_empty(), "{on}: no springs left");
            spreads.push(spread.particle_regions());
        }
        let (all, surface, poisson) = (&spreads[0], &spreads[1], &spreads[2]);
        let on_wall = |i: usize| {
            model.attachments[i].is_some_and(|a| {
                model.surface.triangles[a.triangle as usize]
                    .iter()
                    .all(|&v| exact[v as usize])
            })
        };
        let wall: Vec<usize> = (0..model.len()).filter(|&i| on_wall(i)).collect();
        assert!(
            wall.len() > 5,
            "{on}: {} particles on the chest wall",
            wall.len()
        );
        for &i in &wall {
            assert_eq!(all[i].radius, 0.0, "{on}: held particle {i}");
        }
        let inside = (0..model.len()).filter(|&i| !model.is_surface(i));
        assert!(inside.map(|i| all[i].radius).fold(0.0, f32::max) > 0.1);
        let skin = &matched.held.pairing().skin;
        let median = |regions: &[tissue::uncertainty::Region]| {
            let mut r: Vec<f32> = skin.iter().map(|&i| regions[i as usize].radius).collect();
            r.sort_by(f32::total_cmp);
            r[r.len() / 2]
        };
        // The paired skin moves with the observation's error: its 95 %
        // radius a few times the error's deviation.
        let under_error = median(surface);
        // Matched again at each end of the range, from rest: how far the
        // skin moves (RMS), the farther end's.
        let mut moved = 0.0f32;
        for end in [poisson_alone.poisson.0, poisson_alone.poisson.1] {
            let mut again = Solver::new(
                device.clone(),
                &model,
                params.clone().with(|p| p.poisson = end),
            )
            .unwrap();
            again.set_surface(&model.surface).unwrap();
            let rematched =
                match_observation(&mut again, &model, &observation, &MatchParams::default())
                    .unwrap();
            assert!(rematched.converged, "{on}: {:?}", rematched.last);
            let rms = (skin
                .iter()
                .map(|&i| again.positions()[i as usize].distance_squared(answer[i as usize]))
                .sum::<f32>()
                / skin.len() as f32)
                .sqrt();
            moved = moved.max(rms);
        }
        let under_poisson = median(poisson);
        eprintln!(
            "{on}: {} skin particles paired; their median 95 % radius {under_error:.3} mm under \
             the surface's error alone ({sigma} mm), {under_poisson:.3} mm under the Poisson \
             ratio's range alone; matched again at its ends the skin moves up to {moved:.3} mm (RMS)",
            skin.len()
        );
        assert!(
            (0.5 * sigma..4.0 * sigma).contains(&under_error),
            "{on}: median radius {under_error}"
        );
        assert!(
            (0.1 * moved..3.0 * moved + 0.05).contains(&under_poisson),
            "{on}: the Poisson ratio's median radius {under_poisson} against a match again \
             moving the skin {moved}"
        );
        radii.push(all.iter().map(|r| r.radius).collect::<Vec<f32>>());
    }
    if let [cpu, gpu] = radii.as_slice() {
        let worst = cpu
            .iter()
            .zip(gpu)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        eprintln!("radii at most {worst:.2e} apart on the CPU and the GPU");
        assert!(worst <= 2e-3 * size, "{worst}");
    }
}

/// With a load, a matched answer's Poisson columns are the response to
/// the change of load at the range's ends, taken linear in the stiffness
/// ratio `(1 - 2 nu) / (2 nu)` between them (its own ratio's response is
/// not solved, docs/METHOD.md "Uncertainty"): each particle's three
/// columns lie on one line through the answer, at the Gauss nodes'
/// ratios less the answer's.
#[test]
fn a_matched_answer_under_a_load_spreads_linearly_in_the_stiffness_ratio() {
    use tissue::observation::{MatchParams, match_observation};
    let model = common::phantom_model(1_000);
    let (params, observation, _) = sag_without_correspondence(&model);
    let load = tissue::Vec3::new(0.0, 0.0, -0.002);
    let params = params.with(|p| p.load = load);
    let mut solver = Solver::new(Device::Cpu, &model, params.clone()).unwrap();
    solver.set_surface(&model.surface).unwrap();
    let matched =
        match_observation(&mut solver, &model, &observation, &MatchParams::default()).unwrap();
    assert!(matched.converged, "{:?}", matched.last);
    let answer = solver.positions().to_vec();
    let exact = exact_vertices(&model.surface, &matched.surface);
    let answered = matched_answer(&matched, &exact, Some(-load));
    let priors = Priors::default().with(|p| {
        p.surface_noise = 0.0;
        p.load_spread = 0.0;
        p.gravity_degrees = 0.0;
    });
    let spread = explore(&mut solver, &model, answered, &priors).unwrap();
    assert!(spread.converged, "every re-solve converges");
    assert_eq!(spread.answer, answer, "the answer is the re-solves' own");
    let columns: Vec<_> = spread
        .columns
        .iter()
        .filter(|c| c.unknown == Unknown::Poisson)
        .collect();
    assert_eq!(columns.len(), 3, "three Gauss nodes");
    let ratio = |nu: f64| (1.0 - 2.0 * nu) / (2.0 * nu);
    let (a, b) = (f64::from(priors.poisson.0), f64::from(priors.poisson.1));
    let (mid, half) = (0.5 * (a + b), 0.5 * (b - a));
    let nodes = [mid - 0.6f64.sqrt() * half, mid, mid + 0.6f64.sqrt() * half];
    let own = ratio(f64::from(params.poisson));
    let s: Vec<f32> = nodes.iter().map(|&nu| (ratio(nu) - own) as f32).collect();
    let offsets = |k: usize, i: usize| columns[k].positions[i] - answer[i];
    let largest = (0..answer.len())
        .flat_map(|i| (0..3).map(move |k| (k, i)))
        .map(|(k, i)| offsets(k, i).length())
        .fold(0.0, f32::max);
    assert!(largest > 1e-3, "the ratio moves the answer: {largest}");
    let off_line = (0..answer.len())
        .map(|i| {
            let (o0, o1, o2) = (offsets(0, i), offsets(1, i), offsets(2, i));
            (o0 * s[1] - o1 * s[0])
                .length()
                .max((o2 * s[1] - o1 * s[2]).length())
        })
        .fold(0.0, f32::max);
    let scale = largest * s.iter().map(|v| v.abs()).fold(0.0, f32::max);
    eprintln!(
        "largest Poisson offset {largest:.4} mm, off its line {off_line:.2e} (scale {scale:.2e})"
    );
    assert!(off_line <= 1e-3 * scale, "{off_line} against {scale}");
}
