//! Springs towards observed planes inside the elastic solve: the free
//! skin is pulled onto the planes along their normals and slides along
//! them where the mechanics sends it, on both devices.
#![allow(clippy::unwrap_used, reason = "tests")]

mod common;

use glam::{Vec3, Vec4};
use tissue::backend::{Device, Solver};
use tissue::{ParticleModel, SurfaceMesh};
use tissue_cpu::deformation::DeformParams;
use tissue_solve::model::held_vertices;
use tissue_solve::stage2::{SPRING_WEIGHT, Spring, spring};

/// Each surface particle's triangle's unit normal on `surface` (the rest
/// surface's triangles, moved), zero inside.
fn particle_normals(model: &ParticleModel, surface: &SurfaceMesh) -> Vec<Vec3> {
    model
        .attachments
        .iter()
        .map(|a| {
            a.map_or(Vec3::ZERO, |a| {
                let [i, j, k] = surface.triangles[a.triangle as usize].map(|v| v as usize);
                let v = &surface.vertices;
                (v[j] - v[i]).cross(v[k] - v[i]).normalize_or_zero()
            })
        })
        .collect()
}

/// The sag solved with every surface vertex observed, then again with
/// only the chest wall held and each other surface particle pulled towards
/// the plane through where it went, along the sagged surface's normal: the
/// skin lands on the planes (it slides along them: the interior lands
/// where the mechanics sends it, not where the sag's map put it), every
/// accepted step lowers the potential, and the CPU and the GPU take the
/// same steps.
#[test]
fn springs_pull_the_free_skin_onto_its_planes_on_both_devices() {
    let model = common::phantom_model(3_000);
    let sagged = tissue::deform::sagged_breast();
    let params = DeformParams::default();
    let mut truth = Solver::new(Device::Cpu, &model, params.clone()).unwrap();
    truth.set_surface(&sagged).unwrap();
    assert!(truth.solve().unwrap().converged);
    let truth = truth.positions().to_vec();
    let size = Solver::new(Device::Cpu, &model, params.clone())
        .unwrap()
        .plan()
        .size;

    let held = held_vertices(&model.surface, &sagged, 1e-3 * size).unwrap();
    assert!(held.contains(&true) && held.contains(&false));
    let observed = params.clone().with(|p| p.observed = Some(held.clone()));
    let normals = particle_normals(&model, &sagged);

    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let mut solved = Vec::new();
    for device in devices {
        let mut solver = Solver::new(device, &model, observed.clone()).unwrap();
        let on = solver.backend();
        let plan = solver.plan().clone();
        let springs = skin_springs(&model, &plan, &truth, &normals, false);
        let pulled = springs.iter().filter(|s| !s.is_zero()).count();
        assert!(pulled > 100, "{pulled} springs");
        solver.set_springs(springs).unwrap();
        solver.set_surface(&sagged).unwrap();
        let report = solver.solve().unwrap();
        assert!(report.converged, "{on}: {report:?}");
        assert!(report.potentials_fell(), "{on}: {:?}", report.potentials);
        let positions = solver.positions().to_vec();
        // The skin on its planes.
        let misses: Vec<f32> = (0..model.len())
            .filter(|&i| model.attachments[i].is_some() && plan.free[i])
            .map(|i| normals[i].dot(positions[i] - truth[i]).abs())
            .collect();
        let rms_miss = (misses.iter().map(|m| m * m).sum::<f32>() / misses.len() as f32).sqrt();
        // Near the sag: what the sag moved the particles, against how far
        // they are from it.
        let moved = rms(&model.positions, &truth);
        let off = rms(&positions, &truth);
        eprintln!(
            "{on}: {} iterations, {} steps back, {} retries; the skin {rms_miss:.4} from its \
             planes (RMS), the particles {off:.3} from the truth after moving {moved:.3}",
            report.iterations, report.backtracks, report.elastic_retries
        );
        assert!(rms_miss < 0.01 * moved, "{on}: {rms_miss} off the planes");
        assert!(off < 0.5 * moved, "{on}: {off} from the sag, {moved} moved");
        solved.push((report.iterations, positions));
    }
    if let [(cpu, on_cpu), (gpu, on_gpu)] = &solved[..] {
        common::assert_same_solve((*cpu, on_cpu), (*gpu, on_gpu), size);
    }
}

/// A model hanging from its held chest wall under a load (the truth: its
/// free skin sags where the mechanics sends it), solved again from rest
/// under the same load with each free surface particle pulled towards a
/// plane, a line or a point through where it went (the plane across its
/// rest normal, the line along it: any spring through the answer leaves
/// it an equilibrium): the solve lands on the truth on both devices, its
/// steps lowering the potential.
#[test]
fn springs_through_an_equilibrium_leave_it_the_answer_on_both_devices() {
    let model = common::phantom_model(3_000);
    let sagged = tissue::deform::sagged_breast();
    let size = Solver::new(Device::Cpu, &model, DeformParams::default())
        .unwrap()
        .plan()
        .size;
    let held = held_vertices(&model.surface, &sagged, 1e-3 * size).unwrap();
    let params = DeformParams::default().with(|p| {
        p.observed = Some(held.clone());
        p.load = Vec3::new(0.0, 0.3 / size, 0.0);
    });
    let mut devices = vec![Device::Cpu];
    devices.extend(common::gpu());
    let mut solved = Vec::new();
    for device in devices {
        let mut hanging = Solver::new(device.clone(), &model, params.clone()).unwrap();
        let on = hanging.backend();
        hanging.set_surface(&model.surface).unwrap();
        assert!(hanging.solve().unwrap().converged);
        let truth = hanging.positions().to_vec();
        let moved = rms(&model.positions, &truth);
        assert!(
            moved > 1e-3 * size,
            "{on}: the load moved the model {moved}"
        );

        let mut solver = Solver::new(device, &model, params.clone()).unwrap();
        let plan = solver.plan().clone();
        let normals = particle_normals(&model, &model.surface);
        let springs = skin_springs(&model, &plan, &truth, &normals, true);
        solver.set_springs(springs).unwrap();
        solver.set_surface(&model.surface).unwrap();
        let report = solver.solve().unwrap();
        assert!(report.converged, "{on}: {report:?}");
        assert!(report.potentials_fell(), "{on}: {:?}", report.potentials);
        let off = rms(solver.positions(), &truth);
        eprintln!(
            "{on}: {} iterations, {} steps back; {off:.5} from the truth after it moved {moved:.3}",
            report.iterations, report.backtracks
        );
        assert!(
            off < 0.01 * moved,
            "{on}: {off} from the truth, {moved} moved"
        );
        solved.push(report.iterations);
    }
    if let [cpu, gpu] = solved[..] {
        assert!(
            cpu.abs_diff(gpu) <= 3,
            "{cpu} iterations on the CPU, {gpu} on the GPU"
        );
    }
}

/// Springs that do not fit the solve are refused with what is wrong: not
/// one per particle, not finite, pushing away, or without the elastic
/// force; an empty list takes them away.
#[test]
fn springs_that_do_not_fit_are_refused_with_the_reason() {
    let model = common::phantom_model(2_000);
    let mut solver = Solver::new(Device::Cpu, &model, DeformParams::default()).unwrap();
    let short = solver
        .set_springs(vec![Spring::ZERO; 3])
        .unwrap_err()
        .to_string();
    assert!(
        short.contains("springs")
            && short.contains("3 springs")
            && short.contains("one per particle"),
        "{short}"
    );
    let mut nan = vec![Spring::ZERO; model.len()];
    nan[7].anchor = Vec4::new(f32::NAN, 0.0, 0.0, 0.0);
    let nan = solver.set_springs(nan).unwrap_err().to_string();
    assert!(
        nan.contains("particle 7") && nan.contains("not finite"),
        "{nan}"
    );
    let mut pushing = vec![Spring::ZERO; model.len()];
    pushing[9] = Spring {
        anchor: Vec4::new(0.0, 0.0, 0.0, 1.0),
        axis: Vec4::new(0.0, 0.0, 1.0, -3.0),
    };
    let pushing = solver.set_springs(pushing).unwrap_err().to_string();
    assert!(
        pushing.contains("particle 9") && pushing.contains("pushes away"),
        "{pushing}"
    );
    let symmetric =
        DeformParams::default().with(|p| p.force = tissue_cpu::deformation::ForceModel::Symmetric);
    let mut other = Solver::new(Device::Cpu, &model, symmetric).unwrap();
    let refused = other
        .set_springs(vec![Spring::ZERO; model.len()])
        .unwrap_err()
        .to_string();
    assert!(refused.contains("elastic force"), "{refused}");
    // None at all: the springs taken away, the solve as without.
    assert!(solver.set_springs(Vec::new()).is_ok());
    assert!(solver.plan().springs.is_empty());
}

/// A spring of the default weight on every free surface particle, towards
/// the plane through its point in `points` with its normal in `normals`;
/// with `mixed`, every third towards the line along the normal instead
/// and every third towards the point.
fn skin_springs(
    model: &ParticleModel,
    plan: &tissue_solve::Plan,
    points: &[Vec3],
    normals: &[Vec3],
    mixed: bool,
) -> Vec<Spring> {
    let weight = SPRING_WEIGHT * plan.lambda_max;
    (0..model.len())
        .map(|i| {
            if !(model.attachments[i].is_some() && plan.free[i]) {
                return Spring::ZERO;
            }
            match (mixed, i % 3) {
                (true, 1) => Spring::line(points[i], normals[i], weight),
                (true, 2) => Spring::point(points[i], weight),
                _ => spring(points[i], normals[i], weight),
            }
        })
        .collect()
}

/// The RMS distance between two sets of positions.
fn rms(a: &[Vec3], b: &[Vec3]) -> f32 {
    (a.iter()
        .zip(b)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum::<f32>()
        / a.len() as f32)
        .sqrt()
}
