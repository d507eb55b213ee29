//! `embedding_moved.wgsl` against its CPU twin, on the GPU's own solve of the
//! sag: the tumour's vertices and landmarks, carried on the GPU, must land
//! where `tissue_cpu::model::embedding_moved` puts them for the same
//! positions and rotations; and a rigid motion must move them rigidly.

mod common;

use glam::Vec3;
use tissue_core::deform::{Rigid, deform_surface};
use tissue_core::phantom;
use tissue_cpu::deformation::DeformParams;
use tissue_cpu::model::Embedding;
use tissue_gpu::{EmbeddingKernel, GpuDeformer, GpuEmbedding, GpuError};

#[test]
fn embedded_points_move_as_the_cpu_twin_moves_them() {
    let Some((device, queue)) = common::gpu("embedded_points_move_as_the_cpu_twin_moves_them")
    else {
        return;
    };
    // 2,003 particles: not a multiple of the workgroup size.
    let model = common::phantom(2_003);
    let (_, _, gpu, report) =
        common::solve_sag_on_both(&device, &queue, model, DeformParams::default());
    assert!(report.converged, "{report:?}");
    let kernel = EmbeddingKernel::new(&device).unwrap_or_else(|e| panic!("{e}"));
    // The tumour's vertices plus a few landmarks, 1,000 points or so: more
    // than one workgroup, not a multiple of it.
    let mut points = phantom::default_tumour().vertices;
    points.extend((0..37).map(|k| Vec3::new(k as f32 - 18.0, 0.5 * k as f32, 30.0)));
    let embedding = Embedding::new(&model.positions, &points);
    let on_gpu = GpuEmbedding::new(&device, &kernel, &embedding, model.len())
        .unwrap_or_else(|e| panic!("{e}"));
    let moved = on_gpu
        .moved(&device, &queue, &kernel, gpu.state())
        .unwrap_or_else(|e| panic!("{e}"));
    let current = gpu.positions().unwrap_or_else(|e| panic!("{e}"));
    let rotations = gpu.read_rotations().unwrap_or_else(|e| panic!("{e}"));
    let expected = embedding.moved(&model.positions, &current, &rotations);
    assert_eq!(moved.len(), expected.len());
    // f32 sums of 8 terms of ~100 mm, summed in another order: a few ulps
    // (an ulp at 128 mm is 1.5e-5 mm; the size is 192 mm).
    let tolerance = 1e-6 * gpu.size();
    let mut worst = 0.0f32;
    for (k, (a, b)) in moved.iter().zip(&expected).enumerate() {
        let error = (*a - *b).length();
        assert!(
            error <= tolerance,
            "point {k}: GPU {a}, CPU {b}, |difference| {error} > {tolerance}"
        );
        worst = worst.max(error);
    }
    let displacement = moved
        .iter()
        .zip(&points)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f32::max);
    eprintln!(
        "embedding on the GPU: {} points, worst difference from the CPU twin {worst:.2e} mm \
         (tolerance {tolerance:.2e}); largest displacement {displacement:.2} mm",
        moved.len()
    );
    assert!(displacement > 1.0, "the sag should move the points");
}

#[test]
fn a_rigid_motion_carries_embedded_points_rigidly_on_the_gpu() {
    let Some((device, queue)) =
        common::gpu("a_rigid_motion_carries_embedded_points_rigidly_on_the_gpu")
    else {
        return;
    };
    let model = common::phantom(2_003);
    let rigid = Rigid::about_axis(
        Vec3::new(1.0, 2.0, 0.5),
        30f32.to_radians(),
        Vec3::new(0.0, 0.0, 25.0),
        Vec3::new(7.0, -3.0, 4.0),
    );
    let mut gpu = GpuDeformer::new(&device, &queue, model, DeformParams::default())
        .unwrap_or_else(|e| panic!("{e}"));
    gpu.set_surface(&deform_surface(&model.surface, &rigid))
        .unwrap_or_else(|e| panic!("{e}"));
    let report = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
    assert!(report.converged, "{report:?}");
    let kernel = EmbeddingKernel::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let tumour = phantom::default_tumour().vertices;
    let embedding = Embedding::new(&model.positions, &tumour);
    let moved = GpuEmbedding::new(&device, &kernel, &embedding, model.len())
        .and_then(|e| e.moved(&device, &queue, &kernel, gpu.state()))
        .unwrap_or_else(|e| panic!("{e}"));
    let tolerance = 1e-4 * gpu.size();
    for (k, (&x, y)) in tumour.iter().zip(&moved).enumerate() {
        let error = (*y - rigid.apply(x)).length();
        assert!(
            error <= tolerance,
            "tumour vertex {k}: moved to {y}, rigidly {}, error {error} > {tolerance}",
            rigid.apply(x)
        );
    }
}

#[test]
fn an_embedding_that_names_a_particle_beyond_the_model_is_refused() {
    let Some((device, _queue)) =
        common::gpu("an_embedding_that_names_a_particle_beyond_the_model_is_refused")
    else {
        return;
    };
    let kernel = EmbeddingKernel::new(&device).unwrap_or_else(|e| panic!("{e}"));
    let embedding = Embedding {
        points: vec![Vec3::ZERO],
        carriers: vec![vec![(0, 0.5), (10, 0.5)]],
    };
    match GpuEmbedding::new(&device, &kernel, &embedding, 10) {
        Err(GpuError::Length { expected, got, .. }) => assert_eq!((expected, got), (10, 11)),
        other => panic!("expected a length error, got {other:?}"),
    }
    let too_many = Embedding {
        points: vec![Vec3::ZERO],
        carriers: vec![(0..9).map(|j| (j, 1.0 / 9.0)).collect()],
    };
    assert!(matches!(
        GpuEmbedding::new(&device, &kernel, &too_many, 10),
        Err(GpuError::Length { .. })
    ));
}
