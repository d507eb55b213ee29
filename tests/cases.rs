//! Stage 2 against finite-element truth: the breast phantoms of
//! `../shared/cases/` (a nonlinear, nearly incompressible FEM loaded by
//! gravity in two postures), sampled at 10,000 particles and deformed by
//! their surfaces alone. The elastic force must land within the linear
//! elastic FEM's millimetres (`peers.json`, `linfem_p1`); docs/ACCURACY.md
//! has the full table.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use glam::Vec3;
use serde_json::Value;
use tissue::SamplingParams;
use tissue::structures::Embedding;
use tissue_cpu::deformation::{DeformParams, Deformer, ForceModel};

/// `[x, y, z]` rows of a JSON array.
fn points(value: &Value) -> Vec<Vec3> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let p: Vec<f32> = p
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32)
                .collect();
            Vec3::new(p[0], p[1], p[2])
        })
        .collect()
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Probe RMSE and tumour-centre error (mm) of `params` on `case`, and the
/// linear FEM's, from its `peers.json`.
fn score(case: &Path, params: DeformParams) -> ((f32, f32), (f32, f32)) {
    let rest = tissue::load_closed_surface(&case.join("rest.obj")).unwrap();
    let deformed = tissue::load_surface(&case.join("deformed.obj")).unwrap();
    let truth = json(&case.join("truth.json"));
    let peers = json(&case.join("peers.json"));
    let model = tissue::sample(&rest, &SamplingParams::with_particles(10_000))
        .unwrap()
        .model;
    let mut deformer = Deformer::new(&model, params).unwrap();
    deformer.set_surface(&deformed).unwrap();
    let report = deformer.solve();
    assert!(report.converged, "{}: {report:?}", case.display());
    let mut probes = points(&truth["probes_rest"]);
    let centre = points(&Value::Array(vec![truth["tumour_centroid_rest"].clone()]))[0];
    probes.push(centre);
    let moved = Embedding::new(deformer.rest(), &probes).moved(
        deformer.rest(),
        deformer.positions(),
        deformer.rotations(),
    );
    let want = points(&truth["probes_deformed"]);
    let squares: f64 = moved
        .iter()
        .zip(&want)
        .map(|(a, b)| f64::from(a.distance_squared(*b)))
        .sum();
    let rmse = (squares / want.len() as f64).sqrt() as f32;
    let centre_want = points(&Value::Array(vec![
        truth["tumour_centroid_deformed"].clone(),
    ]))[0];
    let tumour = moved[want.len()].distance(centre_want);
    let fem = &peers["peers"]["linfem_p1"];
    let fem = (
        fem["probe_rmse_mm"].as_f64().unwrap() as f32,
        fem["tumour_centroid_error_mm"].as_f64().unwrap() as f32,
    );
    ((rmse, tumour), fem)
}

#[test]
fn the_elastic_force_beats_linear_fem_on_both_breast_phantoms() {
    for name in ["breast_c", "breast_d"] {
        let Some(case) = common::shared_case(name) else {
            continue;
        };
        let elastic = DeformParams {
            force: ForceModel::Elastic,
            ..DeformParams::default()
        };
        let ((rmse, tumour), (fem_rmse, fem_tumour)) = score(&case, elastic);
        eprintln!(
            "{name}: elastic probe RMSE {rmse:.2} mm, tumour centre {tumour:.2} mm; linear FEM {fem_rmse:.2} / {fem_tumour:.2} mm"
        );
        assert!(
            rmse <= fem_rmse,
            "{name}: probe RMSE {rmse} > FEM's {fem_rmse}"
        );
        assert!(
            tumour <= fem_tumour,
            "{name}: tumour centre {tumour} > FEM's {fem_tumour}"
        );
    }
}
