//! A deep, narrow indentation: the phantom's tip pushed 40 mm down (of its
//! 55 mm height) by a probe 15 mm wide. The symmetric force folds the
//! tissue under it (particles turned inside out, which `tissue deform`
//! flags). The elastic phase folds nothing and converges without running
//! again: its two-level solve, linearised where the phase starts (the
//! particles under the probe are far from it), raises the potential its
//! force descends within its first steps; the phase goes back to the state
//! it accepted and on with half its step (`phase::ENERGY_WATCH`), and
//! every state it accepts lowers the potential. Half as deep and 30 mm
//! deep it does the same.
#![allow(clippy::unwrap_used, reason = "tests")]

use tissue::deform::{Indentation, deform_surface};
use tissue::deformation::{
    DeformParams, Deformer, ElasticSolve, ForceModel, StopReason, inversions,
};
use tissue::{SamplingParams, phantom};

fn poked_model() -> (tissue::ParticleModel, tissue::SurfaceMesh) {
    poked_model_at(40.0)
}

/// The phantom at 2,000 particles and its surface poked `depth_mm` deep at
/// its tip by a probe 15 mm wide.
fn poked_model_at(depth_mm: f32) -> (tissue::ParticleModel, tissue::SurfaceMesh) {
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(2_000),
    )
    .unwrap()
    .model;
    let probe = Indentation::down_at_top(&model.surface, depth_mm, 15.0).unwrap();
    let poked = deform_surface(&model.surface, &probe);
    (model, poked)
}

#[test]
fn a_deep_narrow_indentation_converges_with_the_elastic_force_stepping_back() {
    let (model, poked) = poked_model();
    let solve = |force| {
        let mut deformer = Deformer::new(
            &model,
            DeformParams::default().with(|p| {
                p.force = force;
            }),
        )
        .unwrap();
        deformer.set_surface(&poked).unwrap();
        let report = deformer.solve();
        let judged = inversions(&model.positions, deformer.positions(), &model.connections);
        eprintln!(
            "{force:?}: {} iterations, {:?}, {} retries, {} steps back; {judged:?}",
            report.iterations, report.stopped_by, report.elastic_retries, report.backtracks
        );
        (report, judged)
    };
    let (elastic, folded) = solve(ForceModel::Elastic);
    assert!(elastic.converged, "{:?}", elastic.stopped_by);
    assert_eq!(elastic.elastic_retries, 0, "{elastic:?}");
    assert!(
        elastic.backtracks >= 1,
        "the full step did not raise the potential: the test no longer tests the step back"
    );
    assert!(elastic.potentials_fell(), "{:?}", elastic.potentials);
    assert_eq!(folded.count, 0, "{folded:?}");
    let (symmetric, folded) = solve(ForceModel::Symmetric);
    assert!(symmetric.converged);
    assert_eq!(symmetric.elastic_retries, 0);
    assert!(
        folded.count > 0,
        "the symmetric force no longer folds this poke: {folded:?}"
    );
}

/// Half as deep (20 mm), the corrected elastic phase's first steps raise
/// the potential too; with half its step from the state it accepted it
/// converges to the tolerance in 50 iterations in all, where running it
/// again after a stall, linearised there, took 54.
#[test]
fn a_shallower_indentation_converges_stepping_back_once() {
    converges_stepping_back(20.0);
}

/// 30 mm deep: the same, 56 iterations in all, nothing folded.
#[test]
fn a_deeper_indentation_converges_stepping_back() {
    converges_stepping_back(30.0);
}

/// The phantom poked `depth_mm` deep, solved with the elastic force: to
/// the tolerance in fewer than 100 iterations with no retry, after at least
/// one step back, every accepted state lowering the potential, nothing
/// folded.
fn converges_stepping_back(depth_mm: f32) {
    let (model, poked) = poked_model_at(depth_mm);
    let mut deformer = Deformer::new(
        &model,
        DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
        }),
    )
    .unwrap();
    deformer.set_surface(&poked).unwrap();
    let report = deformer.solve();
    let folded = inversions(&model.positions, deformer.positions(), &model.connections);
    eprintln!(
        "{depth_mm} mm: {} iterations, {:?}, {} retries, {} steps back; {folded:?}",
        report.iterations, report.stopped_by, report.elastic_retries, report.backtracks
    );
    assert_eq!(report.stopped_by, StopReason::Tolerance, "{report:?}");
    assert_eq!(report.elastic_retries, 0, "{report:?}");
    assert!(
        report.backtracks >= 1,
        "the full step did not raise the potential: the test no longer tests the step back"
    );
    assert!(report.potentials_fell(), "{:?}", report.potentials);
    assert!(report.iterations < 100, "{report:?}");
    assert_eq!(folded.count, 0, "{folded:?}");
}

/// The bench's sixteen probes (`tissue-bench --probes`: 15-30 mm deep, 8-35
/// mm wide, solved from rest without the prediction's extrapolation) at
/// 10,000 particles, where the deepest compress their particles far from
/// where the two-level solve was linearised: each converges, none
/// diverges, and its elastic phases are one descent whose every accepted
/// state has a potential at most the one before. By Chebyshev's phases
/// alone the deepest stall and are linearised again where they stalled;
/// by default none runs again, the conjugate gradient going on where
/// Chebyshev's phase first rose. The GPU's twins of this run the same
/// probes at 2,000 particles on lavapipe
/// (`crates/tissue-gpu/tests/solve.rs::every_probe_descends_the_potential_on_both_devices`,
/// `crates/tissue-gpu/tests/conjugate.rs`).
#[test]
fn the_sixteen_probes_at_10k_descend_the_potential_and_converge() {
    let model = tissue::sample(
        &phantom::default_breast(),
        &SamplingParams::with_particles(10_000),
    )
    .unwrap()
    .model;
    for chebyshev_alone in [true, false] {
        let params = DeformParams::default().with(|p| {
            p.tuning.extrapolate = false;
            if chebyshev_alone {
                p.tuning.elastic_solve = ElasticSolve::Chebyshev;
            }
        });
        let (relinearised, turned) = probes_descend(&model, params);
        if chebyshev_alone {
            // The deepest stall and go on from where they stalled.
            assert!(relinearised > 0);
        } else {
            assert_eq!(relinearised, 0);
            assert!(turned > 0);
        }
    }
}

/// Solves the sixteen probes with `params`, asserting that each
/// converges as one descent whose accepted potentials fall; returns how
/// many times they were linearised again, and how many stepped back (by
/// default, turned to the conjugate gradient).
fn probes_descend(model: &tissue::ParticleModel, params: DeformParams) -> (usize, usize) {
    let mut deformer = Deformer::new(model, params).unwrap();
    let (mut relinearised, mut turned) = (0, 0);
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            let probe = Indentation::down_at_top(&model.surface, depth, width).unwrap();
            deformer.reset();
            deformer
                .set_surface(&deform_surface(&model.surface, &probe))
                .unwrap();
            let report = deformer.solve();
            eprintln!(
                "{depth} x {width} mm: {} iterations, {:?}, {} linearised again, {} steps back",
                report.iterations, report.stopped_by, report.elastic_retries, report.backtracks
            );
            assert!(report.converged, "{depth} x {width}: {report:?}");
            assert_eq!(report.potentials.len(), 1, "{depth} x {width}");
            assert!(report.potentials[0].len() > 2, "{depth} x {width}");
            assert!(
                report.potentials_fell(),
                "{depth} x {width}: {:?}",
                report.potentials
            );
            relinearised += report.elastic_retries;
            turned += usize::from(report.backtracks > 0);
        }
    }
    (relinearised, turned)
}
