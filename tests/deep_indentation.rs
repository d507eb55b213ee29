//! A deep, narrow indentation: the phantom's tip pushed 40 mm down (of its
//! 55 mm height) by a probe 15 mm wide. The symmetric force folds the
//! tissue under it (particles turned inside out, which `tissue deform`
//! flags). The elastic phase fails, then converges and folds nothing:
//! with its two-level solve, linearised where the phase starts (the
//! particles under the probe are far from it), it diverges; run again
//! from the end of the shear phase with half its step it stalls, and
//! linearised again where it stalled it converges (83 iterations in all;
//! 271 and five failures with the shear phase run to its tolerance, before
//! it stopped on the volumes' misfit, the damped phases and the
//! uncorrected full step failing too, until the uncorrected half step
//! converged: `tracker::ELASTIC_RETRIES`). Half as
//! deep, the corrected phase stalls instead, and goes on linearised again
//! where it stalled; 30 mm deep it diverges, and converges with half its
//! step.
#![allow(clippy::unwrap_used, reason = "tests")]

use tissue::deform::{Indentation, deform_surface};
use tissue::deformation::{DeformParams, Deformer, ForceModel, StopReason, inversions};
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
fn a_deep_narrow_indentation_converges_with_the_elastic_force_after_a_retry() {
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
            "{force:?}: {} iterations, {:?}, {} retries; {judged:?}",
            report.iterations, report.stopped_by, report.elastic_retries
        );
        (report, judged)
    };
    let (elastic, folded) = solve(ForceModel::Elastic);
    assert!(elastic.converged, "{:?}", elastic.stopped_by);
    assert_ne!(elastic.stopped_by, StopReason::Diverged);
    assert!(
        elastic.elastic_retries >= 1,
        "the full step did not diverge: the test no longer tests the retry"
    );
    assert_eq!(folded.count, 0, "{folded:?}");
    let (symmetric, folded) = solve(ForceModel::Symmetric);
    assert!(symmetric.converged);
    assert_eq!(symmetric.elastic_retries, 0);
    assert!(
        folded.count > 0,
        "the symmetric force no longer folds this poke: {folded:?}"
    );
}

/// Half as deep (20 mm), the corrected elastic phase does not diverge but
/// stalls: its steps stop falling once the particles under the probe are
/// taken away from the state its correction was linearised at. The
/// tracker goes on from where it stalled with the correction made there,
/// and the solve converges to the tolerance in 54 iterations (60 with the
/// shear phase run to its tolerance, before it stopped on the volumes'
/// misfit); run again from the end of the shear phase without its
/// correction, as before that, it took 150 to the float floor.
#[test]
fn a_stalled_elastic_phase_converges_linearised_again_where_it_stalled() {
    converges_after_one_retry(20.0, "the phase did not stall once");
}

/// 30 mm deep, the corrected elastic phase diverges (its first steps too
/// long for the linearisation they were made from) and is run again from
/// the end of the shear phase with its correction and half its step
/// (`tracker::ELASTIC_DAMPING`): it converges to the tolerance in 56
/// iterations in all (63 with the shear phase run to its tolerance),
/// nothing folded; without its correction, as before that, it took 146 to
/// the float floor.
#[test]
fn a_diverged_elastic_phase_converges_with_half_its_smoothed_step() {
    converges_after_one_retry(30.0, "the phase did not diverge once");
}

/// The phantom poked `depth_mm` deep, solved with the elastic force:
/// after one retry, to the tolerance in fewer than 100 iterations, nothing
/// folded. `otherwise` says what a retry count other than one means.
fn converges_after_one_retry(depth_mm: f32, otherwise: &str) {
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
        "{depth_mm} mm: {} iterations, {:?}, {} retries; {folded:?}",
        report.iterations, report.stopped_by, report.elastic_retries
    );
    assert_eq!(report.stopped_by, StopReason::Tolerance, "{report:?}");
    assert_eq!(
        report.elastic_retries, 1,
        "{otherwise}: the test no longer tests that retry"
    );
    assert!(report.iterations < 100, "{report:?}");
    assert_eq!(folded.count, 0, "{folded:?}");
}
