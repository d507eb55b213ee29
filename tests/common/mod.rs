//! Helpers shared by the integration tests.
#![allow(dead_code, reason = "each test file uses a different subset")]

use std::path::PathBuf;

use glam::Vec3;
use tissue::backend::{Backend, Device};
use tissue::{Error, ParticleModel, SamplingReport};

/// A mesh from `../shared/meshes/`, or `None` (printing why) when that folder
/// is absent. Under `CI=true` its absence is a failure, not a skip.
pub fn shared_mesh(name: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
    let path = dir.join(name);
    if path.exists() {
        return Some(path);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared test mesh {} is missing",
        path.display()
    );
    eprintln!("SKIPPED: {} not found", path.display());
    None
}

/// A case of `../shared/cases/` (its folder), or `None` (printing why) when
/// that folder is absent. Under `CI=true` its absence is a failure.
pub fn shared_case(name: &str) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/cases")
        .join(name);
    if path.join("truth.json").exists() {
        return Some(path);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared case {} is missing",
        path.display()
    );
    eprintln!("SKIPPED: {} not found", path.display());
    None
}

/// The acceptance numbers of stage 1, with the failing value named.
pub fn assert_quality(what: &str, r: &SamplingReport) {
    assert!(
        r.converged,
        "{what}: not converged after {} iterations",
        r.iterations
    );
    assert!(
        r.max_outside <= 0.01,
        "{what}: max_outside {} > 0.01",
        r.max_outside
    );
    assert!(r.nn_cv <= 0.04, "{what}: nn_cv {} > 0.04", r.nn_cv);
    let c = r.connections;
    assert!(
        (10.0..=14.0).contains(&c.median),
        "{what}: median connections {}",
        c.median
    );
    assert!(c.p5 >= 6.0, "{what}: p5 connections {} < 6", c.p5);
    assert!(
        r.coverage <= 1.5,
        "{what}: coverage {} > 1.5 spacings",
        r.coverage
    );
}

/// Structural invariants every model must hold.
pub fn assert_consistent(what: &str, model: &ParticleModel, spacing: f32) {
    let n = model.len();
    assert_eq!(model.radii.len(), n);
    assert_eq!(model.attachments.len(), n);
    assert_eq!(model.connections.particles(), n);
    for i in 0..n {
        assert!(
            model.positions[i].is_finite() && model.radii[i] > 0.0,
            "{what}: particle {i}"
        );
        let row = model.connections.of(i);
        assert!(
            row.windows(2).all(|w| w[0] < w[1]),
            "{what}: row {i} not ascending"
        );
        for &j in row {
            assert!(
                model
                    .connections
                    .of(j as usize)
                    .binary_search(&(i as u32))
                    .is_ok(),
                "{what}: connection {i}-{j} is not symmetric"
            );
        }
        if let Some(a) = model.attachments[i] {
            let on = model.surface.point_on(a.triangle as usize, a.barycentric);
            let off = (on - model.positions[i]).length();
            assert!(
                off <= 1e-4 * spacing,
                "{what}: surface particle {i} is {off} from its attachment point"
            );
            let sum: f32 = a.barycentric.iter().sum();
            assert!((sum - 1.0).abs() < 1e-4, "{what}: barycentric sum {sum}");
        }
    }
    // What stage 2 checks of a model it reads: a sampled one passes.
    tissue::io::model::check_placement(model)
        .unwrap_or_else(|e| panic!("{what}: stage 2 would refuse the model: {e}"));
}

/// The GPU device, or `None` after printing "SKIPPED: no GPU adapter";
/// under `CI=true` a missing adapter is a failure (CI installs lavapipe).
pub fn gpu() -> Option<Device> {
    match Device::pick(Backend::Gpu) {
        Ok(picked) => {
            eprintln!("backend: {picked}");
            Some(picked.device)
        }
        Err(
            error @ Error::Gpu {
                kind: tissue::GpuFailure::NoAdapter,
                ..
            },
        ) => {
            let message = error.to_string();
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "no GPU adapter under CI=true ({message}); install Mesa lavapipe"
            );
            eprintln!("SKIPPED: no GPU adapter ({message})");
            None
        }
        Err(e) => panic!("the GPU backend failed: {e}"),
    }
}

/// The held base of `tissue_testkit::cylinder()`'s column: its base's
/// vertices and the lowest ring of the side's (so that the particles on
/// the rim's triangles are held too), one flag per surface vertex.
pub fn column_base(model: &ParticleModel) -> Vec<bool> {
    model
        .surface
        .vertices
        .iter()
        .map(|v| v.z < 0.1 + 1e-4)
        .collect()
}

/// The bundled phantom sampled with `particles` particles.
pub fn phantom_model(particles: usize) -> ParticleModel {
    tissue::sample(
        &tissue::phantom::default_breast(),
        &tissue::SamplingParams::with_particles(particles),
    )
    .unwrap_or_else(|e| panic!("{e}"))
    .model
}

/// The CPU's and the GPU's solves of one problem, each its iterations and
/// positions, agree: within 3 iterations, and every particle within a
/// thousandth of the model's size `size`.
pub fn assert_same_solve(cpu: (usize, &[Vec3]), gpu: (usize, &[Vec3]), size: f32) {
    let ((cpu, on_cpu), (gpu, on_gpu)) = (cpu, gpu);
    assert!(
        cpu.abs_diff(gpu) <= 3,
        "{cpu} iterations on the CPU, {gpu} on the GPU"
    );
    assert_same_positions(on_cpu, on_gpu, size);
}

/// Every particle of the CPU's solve within a thousandth of the model's
/// size `size` of the GPU's.
pub fn assert_same_positions(on_cpu: &[Vec3], on_gpu: &[Vec3], size: f32) {
    let worst = on_cpu
        .iter()
        .zip(on_gpu)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0f32, f32::max);
    eprintln!("the devices' particles at most {worst:.2e} apart");
    assert!(worst <= 1e-3 * size, "{worst} apart");
}
