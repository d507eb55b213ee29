//! The organ's unloaded shape: a column standing on its
//! base, its side and top free, "imaged" hanging under gravity. Its
//! unloaded shape, loaded again, must give the imaged shape back, on the
//! CPU and on the GPU (lavapipe in CI) alike.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use tissue::advanced::model::{Accuracy, Unloading, gravity_load, unloaded_shape};
use tissue::backend::{Device, Solver};
use tissue::deformation::{DeformParams, ForceModel};
use tissue::{Error, ParticleModel, SamplingParams, SurfaceMesh, Vec3};

/// The cylinder of radius 1 and height 4 standing on z = 0 (read as
/// centimetres below), sampled with `particles`.
fn column(particles: usize) -> ParticleModel {
    let (vertices, triangles) = tissue_testkit::cylinder();
    let surface = SurfaceMesh::new(vertices, triangles);
    tissue::sample(&surface, &SamplingParams::with_particles(particles))
        .unwrap()
        .model
}

/// Tissue of 20 kPa, 1000 kg/m^3, Poisson ratio 0.45, the model in
/// centimetres, standing with gravity along -z: the top sinks about 0.5 mm
/// of the column's 40.
fn params(model: &ParticleModel) -> DeformParams {
    let poisson = 0.45;
    DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.poisson = poisson;
        p.observed = Some(common::column_base(model));
        p.load = gravity_load(Vec3::new(0.0, 0.0, -1.0), 1000.0, 20.0, poisson, 1e-2).unwrap();
    })
}

/// On `device`, the rest shape loaded from `unloaded` positions: the
/// model's positions replaced, the rest surface imposed where it is held.
fn load(
    device: &Device,
    model: &ParticleModel,
    unloaded: &[Vec3],
    warm: Option<&[Vec3]>,
) -> Result<(Vec<Vec3>, tissue::deformation::DeformReport), Error> {
    let guess = ParticleModel {
        positions: unloaded.to_vec(),
        ..model.clone()
    };
    let mut solver = Solver::new(device.clone(), &guess, params(model))?;
    solver.set_surface(&model.surface)?;
    if let Some(warm) = warm {
        solver.warm_start(warm)?;
    }
    let report = solver.solve()?;
    Ok((solver.positions().to_vec(), report))
}

fn surface_flags(model: &ParticleModel) -> Vec<bool> {
    (0..model.len()).map(|i| model.is_surface(i)).collect()
}

/// The unloaded column, loaded again, gives the imaged one back within
/// the tolerance asked (1e-4 of its height), in a few
/// rounds; and unloaded, the column stands taller than imaged, by about
/// what gravity made it sag.
#[test]
fn the_unloaded_shape_loaded_again_is_the_rest_shape() {
    let model = column(3_000);
    let unloading = Unloading {
        tolerance: 4e-4,
        max_rounds: 8,
        measure: Accuracy::Full,
    };
    let surface = surface_flags(&model);
    let shape = unloaded_shape(&model.positions, &surface, unloading, |x, warm, _| {
        load(&Device::Cpu, &model, x, warm)
    })
    .unwrap();
    eprintln!(
        "unloaded in {} rounds, residual {:.2e} (all {:.2e}); iterations {:?}",
        shape.rounds,
        shape.residual,
        shape.residual_all,
        shape
            .reports
            .iter()
            .map(|r| r.iterations)
            .collect::<Vec<_>>()
    );
    let stops: Vec<_> = shape
        .reports
        .iter()
        .map(|r| (r.iterations, r.stopped_by))
        .collect();
    assert!(shape.converged, "{stops:?}");
    assert!(shape.rounds >= 2 && shape.rounds <= 6, "{}", shape.rounds);
    let (again, report) = load(&Device::Cpu, &model, &shape.positions, None).unwrap();
    assert!(report.converged);
    let rms = (again
        .iter()
        .zip(&model.positions)
        .map(|(a, b)| a.distance_squared(*b))
        .sum::<f32>()
        / model.len() as f32)
        .sqrt();
    assert!(rms <= 4e-4, "loaded again: {rms} RMS from the rest shape");
    // The top particles rise when unloaded: what gravity pulled down.
    let top: Vec<usize> = (0..model.len())
        .filter(|&i| model.positions[i].z > 3.9)
        .collect();
    assert!(!top.is_empty());
    let lift = top
        .iter()
        .map(|&i| shape.positions[i].z - model.positions[i].z)
        .sum::<f32>()
        / top.len() as f32;
    let (sagged, _) = load(&Device::Cpu, &model, &model.positions, None).unwrap();
    let sag = top
        .iter()
        .map(|&i| model.positions[i].z - sagged[i].z)
        .sum::<f32>()
        / top.len() as f32;
    assert!(sag > 0.02, "the column sinks {sag}");
    assert!(
        (lift - sag).abs() <= 0.25 * sag,
        "unloaded it rises {lift}, loaded it sags {sag}"
    );
}

/// The GPU finds the same unloaded shape in the same rounds.
#[test]
fn the_gpu_finds_the_same_unloaded_shape() {
    let Some(gpu) = common::gpu() else {
        return;
    };
    let model = column(1_000);
    let unloading = Unloading {
        tolerance: 4e-4,
        max_rounds: 8,
        measure: Accuracy::Full,
    };
    let surface = surface_flags(&model);
    let shapes: Vec<_> = [Device::Cpu, gpu]
        .iter()
        .map(|device| {
            unloaded_shape(&model.positions, &surface, unloading, |x, warm, _| {
                load(device, &model, x, warm)
            })
            .unwrap()
        })
        .collect();
    let (cpu, gpu) = (&shapes[0], &shapes[1]);
    eprintln!(
        "CPU {} rounds {:.2e}, GPU {} rounds {:.2e}",
        cpu.rounds, cpu.residual, gpu.rounds, gpu.residual
    );
    assert!(cpu.converged && gpu.converged);
    assert_eq!(cpu.rounds, gpu.rounds);
    let apart = cpu
        .positions
        .iter()
        .zip(&gpu.positions)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0f32, f32::max);
    assert!(
        apart <= 4e-4,
        "the devices' unloaded shapes differ by {apart}"
    );
}

/// The stiffness fitted from the skin: a column made "imaged" by our own
/// solves, standing (gravity along -z) and lying (along +x) from its
/// unloaded shape with tissue of 60 kPa; the fit, from 20 kPa and seeing
/// only the lying column's skin, finds that stiffness within 5 %, and
/// within 2 % of each other on the CPU and the GPU.
#[test]
fn the_stiffness_is_fitted_from_the_skin_on_both_devices() {
    use tissue::advanced::model::{Postures, fit_stiffness};
    let model = column(1_000);
    let poisson = 0.45;
    let per_kpa = |g: Vec3| gravity_load(g, 1000.0, 1.0, poisson, 1e-2).unwrap();
    let (standing, lying) = (Vec3::new(0.0, 0.0, -1.0), Vec3::new(1.0, 0.0, 0.0));
    let truth = 60.0f32;
    let solve_on = |device: &Device, x: &[Vec3], body: Vec3, warm: Option<&[Vec3]>| {
        let guess = ParticleModel {
            positions: x.to_vec(),
            ..model.clone()
        };
        let params = DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
            p.poisson = poisson;
            p.observed = Some(common::column_base(&model));
            p.load = body;
        });
        let mut solver = Solver::new(device.clone(), &guess, params)?;
        solver.set_surface(&model.surface)?;
        if let Some(warm) = warm {
            solver.warm_start(warm)?;
        }
        let report = solver.solve()?;
        Ok::<_, Error>((solver.positions().to_vec(), report))
    };
    let (rest, r) = solve_on(
        &Device::Cpu,
        &model.positions,
        per_kpa(standing) / truth,
        None,
    )
    .unwrap();
    let (observed, o) =
        solve_on(&Device::Cpu, &model.positions, per_kpa(lying) / truth, None).unwrap();
    assert!(r.converged && o.converged);
    let tip = (0..model.len())
        .map(|i| observed[i].x - model.positions[i].x)
        .fold(0.0f32, f32::max);
    assert!(tip > 0.05, "the lying column bends by {tip}");
    let surface = surface_flags(&model);
    let held = common::column_base(&model);
    let targets: Vec<Option<Vec3>> = (0..model.len())
        .map(|i| {
            model.attachments[i]
                .filter(|a| {
                    !model.surface.triangles[a.triangle as usize]
                        .iter()
                        .all(|&v| held[v as usize])
                })
                .map(|_| observed[i])
        })
        .collect();
    let postures = Postures {
        rest: &rest,
        surface: &surface,
        targets: &targets,
        rest_load_per_kpa: per_kpa(standing),
        deformed_load_per_kpa: per_kpa(lying),
    };
    let unloading = Unloading {
        tolerance: 4e-4,
        max_rounds: 8,
        measure: Accuracy::Full,
    };
    let mut fits = Vec::new();
    // The GPU half needs an adapter (under `CI=true` it must have one).
    let gpu = common::gpu();
    for device in std::iter::once(Device::Cpu).chain(gpu) {
        let fit = fit_stiffness(
            &postures,
            20.0,
            (1.0, 1000.0),
            unloading,
            |x, body, warm, _| solve_on(&device, x, body, warm),
        )
        .unwrap();
        eprintln!(
            "{}: {:.2} kPa, free skin {:.2e} off, trials {:?}",
            device.name(),
            fit.stiffness_kpa,
            fit.residual,
            fit.trials
                .iter()
                .map(|t| (t.stiffness_kpa, t.residual))
                .collect::<Vec<_>>()
        );
        assert!(
            (fit.stiffness_kpa - truth).abs() <= 0.05 * truth,
            "{} kPa against {truth}",
            fit.stiffness_kpa
        );
        assert!(fit.unloaded.converged);
        fits.push(fit.stiffness_kpa);
    }
    if let [cpu, gpu] = fits[..] {
        assert!((cpu - gpu).abs() <= 0.02 * cpu, "CPU {cpu} GPU {gpu}");
    }
}

/// A solver stress-free in another shape (`Solver::unloaded`) still
/// measures from the model's positions, the rest posture: with that shape
/// the model's own it is `Solver::new` (the same positions, and points
/// carried to within 1e-4 of the size), and with another its reference is
/// the model's positions and its rest the shape given, on both devices.
/// The symmetric force: its rotations are those of each particle's
/// offsets product, which carrying from another reference turns points
/// by (the elastic force's, of its consistent gradient, carry 0.03 mm
/// apart on this phantom).
#[test]
fn an_unloaded_solver_measures_from_the_rest_posture() {
    let model = tissue::sample(
        &tissue::phantom::default_breast(),
        &SamplingParams::with_particles(2_000),
    )
    .unwrap()
    .model;
    let sag = tissue::deform::sagged_breast();
    let params = DeformParams::default().with(|p| p.force = ForceModel::Symmetric);
    let size = common_size(&model);
    let probes: Vec<Vec3> = model.positions.iter().step_by(97).copied().collect();
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    for device in devices {
        let name = device.name().to_owned();
        let mut plain = Solver::new(device.clone(), &model, params.clone()).unwrap();
        let mut same =
            Solver::unloaded(device.clone(), &model, &model.positions, params.clone()).unwrap();
        for solver in [&mut plain, &mut same] {
            solver.set_surface(&sag).unwrap();
            assert!(solver.solve().unwrap().converged, "{name}");
        }
        assert_eq!(plain.positions(), same.positions(), "{name}");
        let (a, b) = (
            plain.carry(&plain.bind(&probes).unwrap()).unwrap(),
            same.carry(&same.bind(&probes).unwrap()).unwrap(),
        );
        let apart = a
            .iter()
            .zip(&b)
            .map(|(p, q)| p.distance(*q))
            .fold(0.0f32, f32::max);
        assert!(apart <= 1e-4 * size, "{name}: carried {apart} apart");
        let moved: Vec<Vec3> = model
            .positions
            .iter()
            .map(|p| *p + Vec3::new(0.0, 0.0, 0.5))
            .collect();
        let shifted = Solver::unloaded(device, &model, &moved, params.clone()).unwrap();
        assert_eq!(shifted.reference(), &model.positions[..], "{name}");
        assert_eq!(shifted.rest(), &moved[..], "{name}");
        let short = &model.positions[1..];
        assert!(Solver::unloaded(Device::Cpu, &model, short, params.clone()).is_err());
    }
}

/// Bounding-box diagonal of the rest particles.
fn common_size(model: &ParticleModel) -> f32 {
    let (lo, hi) = model.positions.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    (hi - lo).length()
}

/// The facade's fit on a coarse model (`Gravity::fit_particles`), on both
/// devices: a column of 1,200 particles "imaged" by our own solves
/// standing and lying with tissue of 60 kPa (its lying skin carried from
/// the solve), fitted on 500 particles of the same surface from 3 kPa.
/// The fit runs on the coarse model (its trials counted there), lands
/// within 10 % of the stiffness the skin was made with (a coarser model
/// bends a little differently), the column's own unloaded shape at that
/// stiffness reaches the tolerance, and the two devices agree within 2 %.
/// The fit's guess of the deformed posture (`Unloaded::deformed_guess`)
/// starts its solve with the skin observed nearer the answer: fewer
/// iterations to the same positions; a given stiffness has no guess.
#[test]
fn the_stiffness_is_fitted_on_a_coarse_model_on_both_devices() {
    use tissue::gravity::{Gravity, unload};
    let model = column(1_200);
    let held = common::column_base(&model);
    let params = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.poisson = 0.45;
    });
    let truth = 60.0f32;
    let gravity = |stiffness_kpa: Option<f32>, fit_particles: Option<usize>| Gravity {
        rest: Vec3::new(0.0, 0.0, -1.0),
        deformed: Vec3::new(1.0, 0.0, 0.0),
        density_kg_m3: 1000.0,
        stiffness_kpa,
        metres_per_unit: 1e-2,
        fit_particles,
    };
    // The lying column's skin, imaged: the unloaded shape at the truth,
    // lying from it with the base held, the surface's vertices carried.
    let given = unload(
        &Device::Cpu,
        &model,
        &model.surface,
        &held,
        &gravity(Some(truth), None),
        &params,
        &mut |_| {},
    )
    .unwrap();
    assert!(given.shape.converged && given.fit.is_none());
    let lying = params.clone().with(|p| {
        p.observed = Some(held.clone());
        p.load = given.deformed_load;
    });
    let mut solver = Solver::unloaded(Device::Cpu, &model, &given.shape.positions, lying).unwrap();
    solver.set_surface(&model.surface).unwrap();
    assert!(solver.solve().unwrap().converged);
    let vertices = solver
        .carry(&solver.bind(&model.surface.vertices).unwrap())
        .unwrap();
    let bent = vertices
        .iter()
        .zip(&model.surface.vertices)
        .map(|(a, b)| a.x - b.x)
        .fold(0.0f32, f32::max);
    assert!(bent > 0.05, "the lying column bends by {bent}");
    let deformed = SurfaceMesh {
        vertices,
        ..model.surface.clone()
    };
    let mut fits = Vec::new();
    for device in std::iter::once(Device::Cpu).chain(common::gpu()) {
        let name = device.name().to_owned();
        let mut told = 0;
        let found = unload(
            &device,
            &model,
            &deformed,
            &held,
            &gravity(None, Some(500)),
            &params,
            &mut |p| told = p.solve,
        )
        .unwrap();
        let fit = found.fit.as_ref().unwrap();
        eprintln!(
            "{name}: {:.2} kPa on {} particles, trials {:?}, unloaded {:.2e} in {} rounds, {} solves",
            found.stiffness_kpa,
            fit.particles,
            fit.trials
                .iter()
                .map(|t| (t.stiffness_kpa, t.residual))
                .collect::<Vec<_>>(),
            found.shape.residual,
            found.shape.rounds,
            found.solves
        );
        assert_eq!(fit.particles, 500, "{name}");
        assert_eq!(told, found.solves, "{name}: every solve was told");
        assert!(
            (found.stiffness_kpa - truth).abs() <= 0.1 * truth,
            "{name}: {} kPa against {truth}",
            found.stiffness_kpa
        );
        assert!(
            found.shape.converged,
            "{name}: the column's own unloaded shape"
        );
        assert_eq!(found.shape.positions.len(), model.len(), "{name}");
        // The deformed posture with its skin observed, from the unloaded
        // shape and from the fit's guess: the same answer, the guess's in
        // fewer iterations.
        let guess = found.deformed_guess.as_ref().unwrap();
        assert_eq!(guess.len(), model.len(), "{name}");
        let solved = |guess: Option<&[Vec3]>| {
            let params = params.clone().with(|p| p.load = found.deformed_load);
            let mut solver =
                Solver::unloaded(device.clone(), &model, &found.shape.positions, params).unwrap();
            solver.set_surface(&deformed).unwrap();
            if let Some(guess) = guess {
                solver.warm_start(guess).unwrap();
            }
            let report = solver.solve().unwrap();
            assert!(report.converged, "{name}: {report:?}");
            (report.iterations, solver.positions().to_vec())
        };
        let (cold, cold_at) = solved(None);
        let (warm, warm_at) = solved(Some(guess));
        let apart = cold_at
            .iter()
            .zip(&warm_at)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        eprintln!(
            "{name}: the deformed posture in {cold} iterations, from the guess {warm}, {apart:.2e} apart"
        );
        assert!(warm < cold, "{name}: {warm} from the guess, {cold} without");
        assert!(apart < 1e-3 * common_size(&model), "{name}: {apart} apart");
        fits.push(found.stiffness_kpa);
    }
    assert!(given.deformed_guess.is_none(), "no trial, no guess");
    if let [cpu, gpu] = fits[..] {
        assert!((cpu - gpu).abs() <= 0.02 * cpu, "CPU {cpu} GPU {gpu}");
    }
}

/// Solvers of one column in other rest shapes, its base held, share what
/// depends only on the connections and the free particles: the
/// Laplacian's spectrum and its coarse space (the unloaded shape's rounds
/// and the stiffness search's trials do). On both devices a solver
/// prepared from a share solves to the same positions, to the bit, as one
/// prepared anew; a solver in another rest shape takes the same coarse
/// space; one with another region held makes its own.
#[test]
fn solvers_of_one_model_share_the_laplacians_preparation() {
    let model = column(2_000);
    let stretched = ParticleModel {
        positions: model
            .positions
            .iter()
            .map(|p| *p * Vec3::new(1.0, 1.0, 1.01))
            .collect(),
        ..model.clone()
    };
    let all_held = params(&model).with(|p| p.observed = None);
    let devices = [Some(Device::Cpu), common::gpu()];
    for device in devices.into_iter().flatten() {
        let solved = |mut solver: Solver| {
            solver.set_surface(&model.surface).unwrap();
            let report = solver.solve().unwrap();
            assert!(report.converged, "{:?}", report.stopped_by);
            solver.positions().to_vec()
        };
        let first = Solver::new(device.clone(), &model, params(&model)).unwrap();
        let shared = first.shared_laplacian();
        let from_share = |model: &ParticleModel, params: DeformParams| {
            Solver::new_shared(device.clone(), model, params, Some(&shared), &mut |_| {}).unwrap()
        };
        let space = shared
            .coarse()
            .expect("the column's two-level solve")
            .clone();
        let sharing = from_share(&model, params(&model));
        let again = sharing.shared_laplacian();
        assert!(std::sync::Arc::ptr_eq(again.coarse().unwrap(), &space));
        assert_eq!(solved(sharing), solved(first), "{device:?}");

        let moved = from_share(&stretched, params(&model));
        assert!(std::sync::Arc::ptr_eq(
            moved.shared_laplacian().coarse().unwrap(),
            &space
        ));
        let own = from_share(&model, all_held.clone());
        let theirs = own.shared_laplacian();
        assert!(!std::sync::Arc::ptr_eq(theirs.coarse().unwrap(), &space));
        assert_ne!(theirs.key(), shared.key());
        assert!(shared.spectrum_for(theirs.key()).is_none());
    }
}
