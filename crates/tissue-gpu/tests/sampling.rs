//! Stage 1 on the GPU against its CPU twins in `tissue_cpu::sampling`: each
//! kernel on identical inputs (the phantom's prepared state after a few CPU
//! iterations, some particles pushed outside the surface), the field query at
//! points inside, near and outside, then whole runs to convergence compared
//! by their quality numbers. Sizes 1,000 and 3,001 (not a multiple of the
//! workgroup size). Tolerances are explicit; a failure names the particle,
//! both values and the tolerance.

mod common;

use glam::{Vec3, Vec4};
use tissue_core::field::{Side, SurfaceField};
use tissue_core::{SamplingParams, SamplingReport, SurfaceMesh, SurfaceMode};
use tissue_cpu::sampling::{
    ForceOut, Prepared, SKIN_IN_R0, SamplingState, change, imf_force, integrate, needs_rebuild,
    place_surface_particles, prepare, radius_update,
};
use tissue_cpu::stage1::neighbour_rows;
use tissue_gpu::SamplingPipelines;
use tissue_gpu::sampler::{SamplingBuffers, SamplingKernel, query_field};

const SIZES: [usize; 2] = [1_000, 3_001];

/// The phantom prepared for `n` particles, moved by five CPU iterations so
/// radii differ and some particles touch the wall; then (unless `push` is
/// false) every 11th particle pushed out along its offset from the centroid
/// by half a radius to two radii (some end outside the surface, a few far
/// outside).
struct Case {
    prepared: Prepared,
    params: SamplingParams,
    rows: (Vec<u32>, Vec<u32>),
}

fn case(mesh: &SurfaceMesh, n: usize, mode: SurfaceMode) -> Case {
    case_pushed(mesh, n, mode, true)
}

fn case_pushed(mesh: &SurfaceMesh, n: usize, mode: SurfaceMode, push: bool) -> Case {
    let params = SamplingParams::with_particles(n).with(|p| {
        p.surface_mode = mode;
    });
    let mut prepared = prepare(mesh, &params).unwrap_or_else(|e| panic!("{e}"));
    let r0 = prepared.r0;
    let skin = SKIN_IN_R0 * r0;
    let rows = |s: &SamplingState| {
        neighbour_rows(&s.positions, &s.radii, params.force_cutoff, skin, false)
    };
    let field = &prepared.field;
    let mut state = prepared.state.clone();
    for _ in 0..5 {
        let (o, i) = rows(&state);
        let forces = imf_force(&state, &o, &i, field, &params);
        let radii = radius_update(&state.radii, &forces, &params);
        let (positions, contact) = integrate(&state, &forces, field, &params, r0);
        state = SamplingState {
            positions,
            radii,
            contact,
        };
    }
    let centroid = state.positions.iter().copied().sum::<Vec3>() / state.positions.len() as f32;
    let pushed = if push { state.positions.len() } else { 0 };
    for (k, i) in (0..pushed).step_by(11).enumerate() {
        let out = (state.positions[i] - centroid).normalize_or_zero();
        state.positions[i] += out * (0.5 + 1.5 * (k % 4) as f32 / 3.0) * state.radii[i];
    }
    let rows = rows(&state);
    prepared.state = state;
    Case {
        prepared,
        params,
        rows,
    }
}

fn buffers(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipelines: &SamplingPipelines,
    c: &Case,
) -> SamplingBuffers {
    let mut b = SamplingBuffers::new(
        device,
        queue,
        pipelines,
        &c.prepared.field,
        &c.prepared.state,
        &c.params,
        c.prepared.r0,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    b.set_rows(device, pipelines, &c.rows.0, &c.rows.1)
        .unwrap_or_else(|e| panic!("{e}"));
    b
}

fn run(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipelines: &SamplingPipelines,
    b: &SamplingBuffers,
    kernel: SamplingKernel,
) {
    let mut encoder = device.create_command_encoder(&Default::default());
    b.record(&mut encoder, pipelines, &[kernel], 0, 0);
    queue.submit([encoder.finish()]);
}

/// Asserts `|got - expected| <= tolerance` per particle; returns the worst difference.
fn check(what: &str, got: &[f32], expected: &[f32], tolerance: impl Fn(usize) -> f32) -> f32 {
    assert_eq!(got.len(), expected.len(), "{what}: lengths");
    let mut worst = 0.0f32;
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        let off = (g - e).abs();
        let tol = tolerance(i);
        assert!(
            off <= tol,
            "{what}, particle {i}: GPU {g} vs CPU {e}, difference {off:e} > tolerance {tol:e}"
        );
        worst = worst.max(off / tol.max(f32::MIN_POSITIVE));
    }
    worst
}

fn check_vec(what: &str, got: &[Vec3], expected: &[Vec3], tolerance: impl Fn(usize) -> f32) -> f32 {
    let mut worst = 0.0f32;
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        let off = (*g - *e).length();
        let tol = tolerance(i);
        assert!(
            off <= tol,
            "{what}, particle {i}: GPU {g} vs CPU {e}, difference {off:e} > tolerance {tol:e}"
        );
        worst = worst.max(off / tol.max(f32::MIN_POSITIVE));
    }
    worst
}

#[test]
fn imf_force_matches_the_cpu_twin_in_both_surface_modes() {
    let Some((device, queue)) = common::gpu("imf_force parity") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let mesh = tissue_core::phantom::default_breast();
    for n in SIZES {
        for mode in [
            SurfaceMode::Projection,
            SurfaceMode::PaperForce { mu: 30.0 },
        ] {
            let c = case(&mesh, n, mode);
            let expected = imf_force(
                &c.prepared.state,
                &c.rows.0,
                &c.rows.1,
                &c.prepared.field,
                &c.params,
            );
            // Both wall branches of eq. (3) are exercised: near and deep outside.
            let (mut near, mut deep) = (0, 0);
            for &p in &c.prepared.state.positions {
                match c.prepared.field.query(p) {
                    Side::Near(n) if n.distance > 0.0 => near += 1,
                    Side::DeepOutside => deep += 1,
                    _ => {}
                }
            }
            assert!(
                near > 0 && deep > 0,
                "n = {n}: {near} near and {deep} deep outside"
            );
            let b = buffers(&device, &queue, &pipelines, &c);
            run(&device, &queue, &pipelines, &b, SamplingKernel::ImfForce);
            let got = b
                .read_forces(&device, &queue)
                .unwrap_or_else(|e| panic!("{e}"));
            // Up to ~50 pair terms of size up to 56 each (eq. (5) at d = 0):
            // rounding is a few ulp of their sum of magnitudes, which bounds
            // both the force and the compression.
            let scale: Vec<f32> = expected
                .iter()
                .map(|f| f.force.length() + f.compression + 1.0)
                .collect();
            let what = format!("imf_force force, n = {n}, {mode:?}");
            let worst_f = check_vec(
                &what,
                &got.iter().map(|f| f.force).collect::<Vec<_>>(),
                &expected.iter().map(|f| f.force).collect::<Vec<_>>(),
                |i| 2e-5 * scale[i],
            );
            let what = format!("imf_force compression, n = {n}, {mode:?}");
            let worst_c = check(
                &what,
                &got.iter().map(|f| f.compression).collect::<Vec<_>>(),
                &expected.iter().map(|f| f.compression).collect::<Vec<_>>(),
                |i| 2e-5 * scale[i],
            );
            eprintln!(
                "imf_force, n = {n}, {mode:?}: worst force {worst_f:.3}, compression {worst_c:.3} of tolerance"
            );
        }
    }
}

#[test]
fn radius_update_matches_the_cpu_twin() {
    let Some((device, queue)) = common::gpu("radius_update parity") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let mesh = tissue_core::phantom::default_breast();
    for n in SIZES {
        let c = case(&mesh, n, SurfaceMode::Projection);
        let s = &c.prepared.state;
        // Compressions across the whole clamp range, both clamps included.
        let ideal = c.params.ideal_compression();
        let forces: Vec<ForceOut> = (0..s.positions.len())
            .map(|i| ForceOut {
                force: Vec3::ZERO,
                compression: ideal + (i as f32 % 41.0 - 20.0) * 0.4,
            })
            .collect();
        let expected = radius_update(&s.radii, &forces, &c.params);
        let b = buffers(&device, &queue, &pipelines, &c);
        b.write_forces(&queue, &forces)
            .unwrap_or_else(|e| panic!("{e}"));
        run(
            &device,
            &queue,
            &pipelines,
            &b,
            SamplingKernel::RadiusUpdate,
        );
        let got = b
            .read_state(&device, &queue, 1)
            .unwrap_or_else(|e| panic!("{e}"))
            .radii;
        // One division (2.5 ulp in WGSL) and a multiply-add that may be fused.
        let worst = check(&format!("radius_update, n = {n}"), &got, &expected, |i| {
            8.0 * f32::EPSILON * expected[i]
        });
        eprintln!("radius_update, n = {n}: worst {worst:.3} of tolerance");
    }
}

#[test]
fn integrate_matches_the_cpu_twin_with_particles_pushed_outside() {
    let Some((device, queue)) = common::gpu("integrate parity") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let mesh = tissue_core::phantom::default_breast();
    for n in SIZES {
        for mode in [
            SurfaceMode::Projection,
            SurfaceMode::PaperForce { mu: 30.0 },
        ] {
            let c = case(&mesh, n, mode);
            let s = &c.prepared.state;
            let r0 = c.prepared.r0;
            let forces = imf_force(s, &c.rows.0, &c.rows.1, &c.prepared.field, &c.params);
            let (positions, contact) = integrate(s, &forces, &c.prepared.field, &c.params, r0);
            let held = contact.iter().filter(|c| c.w > 0.0).count();
            if mode == SurfaceMode::Projection {
                assert!(
                    held > n / 20,
                    "n = {n}: only {held} particles ended outside"
                );
            }
            let b = buffers(&device, &queue, &pipelines, &c);
            b.write_forces(&queue, &forces)
                .unwrap_or_else(|e| panic!("{e}"));
            run(&device, &queue, &pipelines, &b, SamplingKernel::Integrate);
            let got = b
                .read_state(&device, &queue, 1)
                .unwrap_or_else(|e| panic!("{e}"));
            // Positions: an f32 sum plus, for projected ones, a closest point
            // on a triangle: a few ulp of the coordinates' size.
            let size = s
                .positions
                .iter()
                .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
            let tol = 8.0 * f32::EPSILON * size;
            let worst_p = check_vec(
                &format!("integrate positions, n = {n}, {mode:?}"),
                &got.positions,
                &positions,
                |_| tol,
            );
            // The reaction is depth m~ / r0: the position tolerance in force units.
            let tol_w = tol * c.params.mass / r0;
            // The normal where both held the particle. A particle within
            // rounding of the surface may be held by one side only; its
            // reaction is then within `tol_w` of zero (checked below).
            let both: Vec<usize> = (0..n)
                .filter(|&i| got.contact[i].w > 0.0 && contact[i].w > 0.0)
                .collect();
            let normal = |v: &[Vec4]| both.iter().map(|&i| v[i].truncate()).collect::<Vec<_>>();
            let worst_n = check_vec(
                &format!("integrate contact normal, n = {n}, {mode:?} (held particle index)"),
                &normal(&got.contact),
                &normal(&contact),
                |_| 1e-5,
            );
            let worst_w = check(
                &format!("integrate contact reaction, n = {n}, {mode:?}"),
                &got.contact.iter().map(|c| c.w).collect::<Vec<_>>(),
                &contact.iter().map(|c| c.w).collect::<Vec<_>>(),
                |_| tol_w,
            );
            eprintln!(
                "integrate, n = {n}, {mode:?} ({held} held): worst position {worst_p:.3}, \
                 normal {worst_n:.3}, reaction {worst_w:.3} of tolerance"
            );
        }
    }
}

#[test]
fn change_and_needs_rebuild_match_the_cpu_twins() {
    let Some((device, queue)) = common::gpu("change and needs_rebuild parity") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let mesh = tissue_core::phantom::default_breast();
    for n in SIZES {
        for push in [true, false] {
            let c = case_pushed(&mesh, n, SurfaceMode::Projection, push);
            let (s, r0) = (&c.prepared.state, c.prepared.r0);
            let field = &c.prepared.field;
            let forces = imf_force(s, &c.rows.0, &c.rows.1, field, &c.params);
            let radii = radius_update(&s.radii, &forces, &c.params);
            let (positions, contact) = integrate(s, &forces, field, &c.params, r0);
            let (step_rms, radius_rms) = change(s, &positions, &contact, &radii, r0);
            let next = SamplingState {
                positions,
                radii,
                contact,
            };
            let built = (s.positions.clone(), s.radii.clone());
            let rebuild = needs_rebuild(&next, &built, c.params.force_cutoff, SKIN_IN_R0 * r0);

            // One whole iteration; the rows' build state is the uploaded one.
            let b = buffers(&device, &queue, &pipelines, &c);
            let mut encoder = device.create_command_encoder(&Default::default());
            b.record_iterations(&mut encoder, &pipelines, 1, 0);
            queue.submit([encoder.finish()]);
            let (sums, halt) = b
                .read_change(&device, &queue, 1)
                .unwrap_or_else(|e| panic!("{e}"));
            let [steps, free, logs] = sums[0];
            let gpu_step = (steps / free.round().max(1.0)).sqrt() as f32 / r0;
            let gpu_radius = (logs / n as f64).sqrt() as f32;
            // Per-workgroup f32 partials against an f64 sum: a relative 1e-5.
            let what = format!("n = {n}, pushed {push}");
            check(
                &format!("change step_rms, {what}"),
                &[gpu_step],
                &[step_rms],
                |_| 1e-5 * step_rms,
            );
            check(
                &format!("change radius_rms, {what}"),
                &[gpu_radius],
                &[radius_rms],
                |_| 1e-5 * radius_rms,
            );
            assert_eq!(halt != 0, rebuild, "needs_rebuild, {what}: GPU halt {halt}");
            if rebuild {
                assert_eq!(halt, 1, "the halt flag records slot 0 + 1");
            }
            eprintln!(
                "change, {what}: step_rms {gpu_step:e} vs {step_rms:e}, radius_rms \
                 {gpu_radius:e} vs {radius_rms:e}; needs_rebuild {rebuild}"
            );
        }
    }
}

/// Points inside, near and outside the surface: a jittered lattice over the
/// bounds grown by a fifth, and every vertex moved along ±0.3 cells.
fn query_points(mesh: &SurfaceMesh, field: &SurfaceField) -> Vec<Vec3> {
    let (lo, hi) = mesh.bounds().unwrap_or_else(|| panic!("empty mesh"));
    let pad = 0.2 * (hi - lo);
    let (lo, hi) = (lo - pad, hi + pad);
    let mut points = Vec::new();
    let k = 18;
    for z in 0..k {
        for y in 0..k {
            for x in 0..k {
                let t = (Vec3::new(x as f32, y as f32, z as f32) + 0.37) / k as f32;
                points.push(lo + (hi - lo) * t);
            }
        }
    }
    for (v, p) in mesh.vertices.iter().enumerate() {
        let s = if v % 2 == 0 { 0.3 } else { -0.3 };
        let d = Vec3::new(0.6, -0.3, 1.0).normalize() * s * field.cell;
        points.push(*p + d);
    }
    points
}

#[test]
fn field_query_matches_the_cpu_inside_near_and_outside() {
    let Some((device, queue)) = common::gpu("field query parity") else {
        return;
    };
    for (name, mesh) in [
        ("breast", tissue_core::phantom::default_breast()),
        ("tumour", tissue_core::phantom::default_tumour()),
    ] {
        let prepared = prepare(&mesh, &SamplingParams::with_particles(3_001))
            .unwrap_or_else(|e| panic!("{e}"));
        let field = &prepared.field;
        let points = query_points(&mesh, field);
        let got = query_field(&device, &queue, field, &points).unwrap_or_else(|e| panic!("{e}"));
        let counts = compare_queries(name, field, &points, &got);
        assert!(
            counts.iter().all(|&c| c > 50),
            "{name}: inside / outside / near counts {counts:?} do not cover every case"
        );
    }
}

/// A point cloud's field (the phantom's vertices, each with the mean of
/// its triangles' normals) answers on the GPU as on the CPU: the nearest
/// point within the margin, nothing beyond it.
#[test]
fn a_clouds_field_query_matches_the_cpu() {
    let Some((device, queue)) = common::gpu("cloud field query parity") else {
        return;
    };
    let mesh = tissue_core::phantom::default_breast();
    let mut normals = vec![Vec3::ZERO; mesh.vertices.len()];
    for (t, triangle) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t);
        for &v in triangle {
            normals[v as usize] += (b - a).cross(c - a);
        }
    }
    let normals: Vec<Vec3> = normals.iter().map(|n| n.normalize_or(Vec3::Z)).collect();
    let (lo, hi) = mesh.bounds().unwrap_or_else(|| panic!("empty mesh"));
    let size = (hi - lo).max_element();
    let field = SurfaceField::of_cloud(&mesh.vertices, &normals, size / 40.0, size / 20.0)
        .unwrap_or_else(|e| panic!("{e}"));
    let points = query_points(&mesh, &field);
    let got = query_field(&device, &queue, &field, &points).unwrap_or_else(|e| panic!("{e}"));
    let [inside, outside, near] = compare_queries("cloud", &field, &points, &got);
    assert!(
        inside == 0 && outside > 50 && near > 50,
        "cloud: inside / outside / near counts {:?}: a cloud has no inside, and both others must come",
        [inside, outside, near]
    );
}

/// Holds the GPU's answers `got` at `points` to the CPU's field query:
/// the same side, and near the surface the same nearest point and distance
/// within 8 ulp of the coordinates. Returns how many points were inside,
/// outside and near.
fn compare_queries(name: &str, field: &SurfaceField, points: &[Vec3], got: &[Side]) -> [usize; 3] {
    let size = points
        .iter()
        .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
    let tol = 8.0 * f32::EPSILON * size;
    let mut counts = [0usize; 3];
    let mut worst = 0.0f32;
    for (i, (&p, g)) in points.iter().zip(got).enumerate() {
        let e = field.query(p);
        match (g, e) {
            (Side::DeepInside, Side::DeepInside) => counts[0] += 1,
            (Side::DeepOutside, Side::DeepOutside) => counts[1] += 1,
            (Side::Near(g), Side::Near(e)) => {
                counts[2] += 1;
                let off = (g.distance - e.distance)
                    .abs()
                    .max((g.point - e.point).length());
                worst = worst.max(off / tol);
                assert!(
                    off <= tol,
                    "{name}, point {i} at {p}: GPU {g:?} vs CPU {e:?}, difference {off:e} > tolerance {tol:e}"
                );
                // A tie between triangles may pick another one; the
                // normal then may differ, the point and distance may not.
                if g.triangle == e.triangle {
                    let n = (g.normal - e.normal).length();
                    assert!(
                        n <= 1e-6,
                        "{name}, point {i}: GPU normal {} vs CPU {}, difference {n:e} > 1e-6",
                        g.normal,
                        e.normal
                    );
                }
            }
            (g, e) => panic!("{name}, point {i} at {p}: GPU {g:?} vs CPU {e:?}"),
        }
    }
    eprintln!("field query, {name}: {counts:?} inside/outside/near, worst {worst:.3} of tolerance");
    counts
}

/// The quality numbers of a GPU run against the CPU's on the same input.
fn compare(what: &str, cpu: &SamplingReport, gpu: &SamplingReport) {
    eprintln!(
        "{what}: iterations {} vs {}, nn_cv {:.4} vs {:.4}, connections median {} / {}, \
         p5 {} / {}, p95 {} / {}, coverage {:.4} vs {:.4}, max_outside {:.2e} vs {:.2e}, \
         rebuilds {} vs {}, {:.2} s vs {:.2} s (CPU vs GPU)",
        cpu.iterations,
        gpu.iterations,
        cpu.nn_cv,
        gpu.nn_cv,
        cpu.connections.median,
        gpu.connections.median,
        cpu.connections.p5,
        gpu.connections.p5,
        cpu.connections.p95,
        gpu.connections.p95,
        cpu.coverage,
        gpu.coverage,
        cpu.max_outside,
        gpu.max_outside,
        cpu.neighbour_rebuilds,
        gpu.neighbour_rebuilds,
        cpu.seconds,
        gpu.seconds,
    );
    assert_eq!(gpu.converged, cpu.converged, "{what}: converged");
    assert_eq!(gpu.particles, cpu.particles, "{what}: particles");
    let near = |name: &str, g: f32, c: f32, tol: f32| {
        assert!(
            (g - c).abs() <= tol,
            "{what}: {name} GPU {g} vs CPU {c}, difference {} > tolerance {tol}",
            (g - c).abs()
        );
    };
    // Same start, same rules, different rounding: the runs part ways after a
    // few iterations, so the numbers agree statistically, not exactly.
    let iterations = cpu.iterations as f32;
    near(
        "iterations",
        gpu.iterations as f32,
        iterations,
        0.25 * iterations + 10.0,
    );
    near("nn_cv", gpu.nn_cv, cpu.nn_cv, 0.1 * cpu.nn_cv + 0.005);
    near(
        "connection median",
        gpu.connections.median,
        cpu.connections.median,
        1.0,
    );
    near("connection p5", gpu.connections.p5, cpu.connections.p5, 2.0);
    near(
        "connection p95",
        gpu.connections.p95,
        cpu.connections.p95,
        2.0,
    );
    near("coverage", gpu.coverage, cpu.coverage, 0.02);
    near("max_outside", gpu.max_outside, cpu.max_outside, 0.01);
}

#[test]
fn whole_runs_match_the_cpu_by_their_quality_numbers() {
    let Some((device, queue)) = common::gpu("whole sampling runs") else {
        return;
    };
    for (name, mesh) in [
        ("breast", tissue_core::phantom::default_breast()),
        ("tumour", tissue_core::phantom::default_tumour()),
    ] {
        for n in SIZES {
            let params = SamplingParams::with_particles(n);
            let cpu =
                tissue_cpu::sample(&mesh, &params, &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
            let mut last = 0;
            let gpu = tissue_gpu::sampler::sample(&device, &queue, &mesh, &params, &mut |p| {
                assert_eq!(p.iteration, last + 1, "progress comes once per iteration");
                last = p.iteration;
            })
            .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(last, gpu.report.iterations);
            compare(&format!("{name}, n = {n}"), &cpu.report, &gpu.report);
            let moved = gpu
                .model
                .positions
                .iter()
                .zip(&cpu.model.positions)
                .map(|(g, c)| (*g - *c).length())
                .fold(0.0f32, f32::max);
            eprintln!(
                "{name}, n = {n}: largest GPU - CPU position difference {moved:e}, \
                 connections identical: {}",
                gpu.model.connections == cpu.model.connections
            );
        }
    }
}

/// A run stopped by the iteration cap (20: inside the second batch of 16)
/// ends where the CPU's does, not at a batch boundary.
#[test]
fn the_iteration_cap_inside_a_batch_is_honoured() {
    let Some((device, queue)) = common::gpu("iteration cap") else {
        return;
    };
    let mesh = tissue_core::phantom::default_breast();
    let params = SamplingParams::with_particles(1_000).with(|p| {
        p.max_iterations = 20;
    });
    let cpu = tissue_cpu::sample(&mesh, &params, &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
    let gpu = tissue_gpu::sampler::sample(&device, &queue, &mesh, &params, &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(gpu.report.iterations, 20);
    assert!(!gpu.report.converged);
    assert_eq!(cpu.report.iterations, 20);
    compare("capped at 20", &cpu.report, &gpu.report);
}

/// Rows of the wrong length are an error, not a panic or a GPU fault.
#[test]
fn rows_of_the_wrong_length_are_refused() {
    let Some((device, queue)) = common::gpu("row lengths") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let c = case(
        &tissue_core::phantom::default_tumour(),
        1_000,
        SurfaceMode::Projection,
    );
    let mut b = buffers(&device, &queue, &pipelines, &c);
    let short = &c.rows.0[..c.rows.0.len() - 1];
    assert!(matches!(
        b.set_rows(&device, &pipelines, short, &c.rows.1),
        Err(tissue_gpu::GpuError::Length { .. })
    ));
    let few = &c.rows.1[..c.rows.1.len() - 1];
    assert!(matches!(
        b.set_rows(&device, &pipelines, &c.rows.0, few),
        Err(tissue_gpu::GpuError::Length { .. })
    ));
}

/// Four particles: one partly filled workgroup, rows of a few entries.
#[test]
fn a_handful_of_particles_samples_as_on_the_cpu() {
    let Some((device, queue)) = common::gpu("a handful of particles") else {
        return;
    };
    let mesh = tissue_core::phantom::default_tumour();
    let params = SamplingParams::with_particles(4);
    let cpu = tissue_cpu::sample(&mesh, &params, &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
    let gpu = tissue_gpu::sampler::sample(&device, &queue, &mesh, &params, &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(gpu.model.len(), 4);
    assert!(gpu.report.max_outside <= 0.01, "{}", gpu.report.max_outside);
    assert_eq!(gpu.report.converged, cpu.report.converged);
    eprintln!(
        "4 particles: iterations {} vs {} (CPU vs GPU)",
        cpu.report.iterations, gpu.report.iterations
    );
}

/// A device whose storage bindings hold 384 KiB samples 3,001 particles in
/// a coarse ellipsoid of 80 triangles (so that its surface field fits)
/// as a device that binds the rows whole: the Verlet rows, about 650 KB, go
/// over one binding and their entries past it follow the row starts. The
/// same iterations, rebuilds, particles and connections.
#[test]
fn rows_split_over_two_bindings_sample_as_rows_in_one() {
    let Some((device, queue)) = common::gpu("rows in one binding") else {
        return;
    };
    let Some((small, small_queue)) = common::gpu_with_binding("rows split", 3 << 17) else {
        return;
    };
    let mesh = tissue_core::phantom::tumour(&tissue_core::phantom::TumourPhantom {
        subdivisions: 1,
        ..Default::default()
    });
    let params = SamplingParams::with_particles(3_001);
    let whole = tissue_gpu::sampler::sample(&device, &queue, &mesh, &params, &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    let split = tissue_gpu::sampler::sample(&small, &small_queue, &mesh, &params, &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    // The first rows the runs build: those of the prepared state.
    let prepared = prepare(&mesh, &params).unwrap_or_else(|e| panic!("{e}"));
    let (positions, radii) = (&prepared.state.positions, &prepared.state.radii);
    let skin = SKIN_IN_R0 * prepared.r0;
    let entries = neighbour_rows(positions, radii, params.force_cutoff, skin, false)
        .1
        .len();
    eprintln!("3,001 particles: {entries} Verlet entries at the start, 98,304 in one binding");
    assert!(
        entries > 3 << 15,
        "the rows fit one binding: the split is not tested"
    );
    assert_eq!(split.report.iterations, whole.report.iterations);
    assert_eq!(
        split.report.neighbour_rebuilds,
        whole.report.neighbour_rebuilds
    );
    assert_eq!(split.model.connections, whole.model.connections);
    let moved = split
        .model
        .positions
        .iter()
        .zip(&whole.model.positions)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0f32, f32::max);
    assert!(
        moved <= 1e-6 * whole.model.radii[0],
        "particles differ by {moved:e}"
    );
}

/// The surface placement on the GPU (`SamplingBuffers::placement`) against
/// `place_surface_particles` on the same state: particles pushed outside,
/// near the surface and deep inside; with the default band and with a band
/// wider than the field's margin (deep-inside particles then asked exactly).
#[test]
fn the_surface_placement_matches_the_cpu_twin() {
    let Some((device, queue)) = common::gpu("surface placement parity") else {
        return;
    };
    let pipelines = SamplingPipelines::new(&device).unwrap_or_else(|e| panic!("{e}"));
    for (name, mesh) in [
        ("breast", tissue_core::phantom::default_breast()),
        ("tumour", tissue_core::phantom::default_tumour()),
    ] {
        for n in SIZES {
            let mut c = case(&mesh, n, SurfaceMode::Projection);
            let field = &c.prepared.field;
            let r_max = c.prepared.state.radii.iter().copied().fold(0.0, f32::max);
            for band in [c.params.surface_band, 2.0 * field.margin / r_max] {
                c.params.surface_band = band;
                let b = buffers(&device, &queue, &pipelines, &c);
                let gpu = b
                    .placement(&device, &queue, 0)
                    .unwrap_or_else(|e| panic!("{e}"));
                let (positions, attachments) =
                    place_surface_particles(&c.prepared.field, &c.prepared.state, &c.params);
                let size = positions
                    .iter()
                    .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
                let tol = 8.0 * f32::EPSILON * size;
                let what = format!("{name}, n = {n}, band {band}");
                let mut attached = 0;
                for (i, (g, e)) in gpu.attachments.iter().zip(&attachments).enumerate() {
                    let off = (gpu.positions[i] - positions[i]).length();
                    assert!(
                        off <= tol,
                        "{what}, particle {i}: GPU {} vs CPU {}, {off:e} > {tol:e}",
                        gpu.positions[i],
                        positions[i]
                    );
                    match (g, e) {
                        (None, None) => {}
                        (Some(g), Some(e)) => {
                            attached += 1;
                            // A tie between triangles may pick another one
                            // at the same point.
                            if g.triangle == e.triangle {
                                for k in 0..3 {
                                    let d = (g.barycentric[k] - e.barycentric[k]).abs();
                                    assert!(d <= 1e-5, "{what}, particle {i}: {g:?} vs {e:?}");
                                }
                            }
                        }
                        (g, e) => panic!("{what}, particle {i}: GPU {g:?} vs CPU {e:?}"),
                    }
                }
                assert!(attached > n / 20, "{what}: only {attached} attached");
                eprintln!("{what}: {attached} attached on both");
            }
        }
    }
}
