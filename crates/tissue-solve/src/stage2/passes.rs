//! What one stage-2 iteration runs, written once for every device: the
//! iteration's choices ([`Choices`], from the solve's [`Iteration`] and
//! what the device holds) and the passes they make ([`Choices::passes`]).
//!
//! Each device runs the list in order: the CPU calls its twin of each pass,
//! the GPU records each pass's kernels. A new option is a new [`Pass`] (or
//! a new field of [`Choices`]) and its place in [`Choices::passes`]; the
//! devices then add its work and nothing else (`docs/ARCHITECTURE.md`,
//! "Adding a pass").

use crate::coarse::elastic::FREE_SKIN_SWEEPS;
use crate::coarse::volume_smoother::SMOOTHER_SWEEPS;
use crate::stage2::device::Iteration;
use crate::stage2::params::{ForceModel, RotationMethod};

/// One pass of a stage-2 iteration. Each is the work of one shader file
/// (several kernels of it on the GPU) and of its CPU twin of the same name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Pass {
    /// `pair`: each paired particle's spring set towards the observation
    /// at its nearest point ([`crate::stage2::pairing`]), first in
    /// the elastic force's iterations where the device holds an
    /// observation and a pairing.
    Pair,
    /// `local_rotations`: each particle's rotation from its `M_i`, by the
    /// SVD or warm-started from its stored rotation.
    Rotations(RotationMethod),
    /// `elastic_targets`: the elastic model's terms, each particle's
    /// rotation that of its gradient, by the SVD or warm-started.
    ElasticTerms(RotationMethod),
    /// `deformation_force`: the paper's or the symmetric force.
    Force,
    /// `elastic_targets::elastic_force`: the elastic force gathered over the terms.
    ElasticForce,
    /// `integrate`: the plain step `q + alpha F`, loads included.
    PlainStep,
    /// `volume_smoother`: the elastic phase's step from its residual by the
    /// volume smoother, less its part on the elastic aggregates
    /// (`coarse_elastic`); it stands in for [`Pass::PlainStep`] and
    /// [`Pass::ElasticCorrection`] together.
    SmoothedStep {
        /// The aggregates' system solved by two-grid cycles
        /// (`block_multilevel`), not by its factor.
        cycled: bool,
        /// The smoother's Jacobi sweeps on the pressures
        /// ([`crate::coarse::volume_smoother::Smoothing`]).
        sweeps: usize,
    },
    /// `coarse`: the two-level solve's correction of the plain step over
    /// the Laplacian's aggregates.
    CoarseCorrection {
        /// The coarse Laplacian solved by two-grid cycles (`multilevel`),
        /// not by its factor.
        cycled: bool,
    },
    /// `coarse_elastic`: the elastic phase's correction of the plain step
    /// over the elastic aggregates.
    ElasticCorrection {
        /// The aggregates' system solved by two-grid cycles
        /// (`block_multilevel`), not by its factor.
        cycled: bool,
    },
    /// `step_norms`: the largest and summed `|plain - q|²`, what the
    /// stopping rule measures on an uncorrected iteration.
    StepNorms,
    /// `integrate::chebyshev`: the Chebyshev combine of the step with the
    /// previous positions; `current` moves on.
    Combine,
    /// `step_norms` on the update the combine made, what the stopping rule
    /// measures on a corrected iteration (the plain step no longer bounds
    /// the error of the modes coupled to the rotations).
    UpdateNorms,
}

impl Pass {
    /// The shader file the pass runs (its CPU twin's module is named the same).
    pub fn shader(self) -> &'static str {
        match self {
            Pass::Pair => "pair",
            Pass::Rotations(_) => "local_rotations",
            Pass::ElasticTerms(_) | Pass::ElasticForce => "elastic_targets",
            Pass::Force => "deformation_force",
            Pass::PlainStep | Pass::Combine => "integrate",
            Pass::SmoothedStep { .. } => "volume_smoother",
            Pass::CoarseCorrection { .. } => "coarse",
            Pass::ElasticCorrection { .. } => "coarse_elastic",
            Pass::StepNorms | Pass::UpdateNorms => "step_norms",
        }
    }

    /// A name for reports and the benchmark's breakdown.
    pub fn name(self) -> &'static str {
        match self {
            Pass::Pair => "pair",
            Pass::Rotations(RotationMethod::Svd) => "local_rotations",
            Pass::Rotations(RotationMethod::WarmPolar) => "local_rotations_warm",
            Pass::ElasticTerms(RotationMethod::Svd) => "elastic_targets",
            Pass::ElasticTerms(RotationMethod::WarmPolar) => "elastic_targets_warm",
            Pass::Force => "deformation_force",
            Pass::ElasticForce => "elastic_force",
            Pass::PlainStep => "integrate",
            Pass::SmoothedStep { cycled: false, .. } => "smoothed step (factored)",
            Pass::SmoothedStep { cycled: true, .. } => "smoothed step (cycled)",
            Pass::CoarseCorrection { cycled: false } => "coarse correction (factored)",
            Pass::CoarseCorrection { cycled: true } => "coarse correction (cycled)",
            Pass::ElasticCorrection { cycled: false } => "elastic correction (factored)",
            Pass::ElasticCorrection { cycled: true } => "elastic correction (cycled)",
            Pass::StepNorms => "step_norms",
            Pass::Combine => "chebyshev",
            Pass::UpdateNorms => "step_norms (update)",
        }
    }
}

/// How an iteration corrects its plain step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Correction {
    /// Not at all: the plain step, its norms, the combine.
    None,
    /// The two-level solve over the Laplacian's aggregates.
    Coarse {
        /// Its coarse system solved by cycles.
        cycled: bool,
    },
    /// The elastic phase's two-level solve.
    Elastic {
        /// Its coarse system solved by cycles.
        cycled: bool,
        /// The step made by the volume smoother ([`Pass::SmoothedStep`])
        /// with this many Jacobi sweeps; `None`: the plain step.
        smoothed: Option<usize>,
    },
}

/// What a device holds for its iterations: the rule of
/// [`Choices::of`] picks among them for each solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Holds {
    /// The elastic model's rest data.
    pub elastic: bool,
    /// The Laplacian's coarse space; `Some(true)` where it is solved by cycles.
    pub coarse: Option<bool>,
    /// The elastic phase's correction, linearised at the state; `Some((cycled,
    /// smoothed))`, `smoothed` the volume smoother's Jacobi sweeps where it
    /// smooths.
    pub elastic_correction: Option<(bool, Option<usize>)>,
    /// An observation and a pairing of the skin with it
    /// ([`crate::stage2::pairing`]).
    pub pairs: bool,
}

/// The choices that make one iteration's pass list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Choices {
    /// The elastic force (its terms and force), not the rotations' one.
    pub elastic: bool,
    /// How the rotations are found.
    pub rotations: RotationMethod,
    /// How the plain step is corrected.
    pub correction: Correction,
    /// The skin paired with the observation first ([`Pass::Pair`]).
    pub pairs: bool,
}

impl Choices {
    /// The choices of an iteration run with `force`, correcting where
    /// `correct`, on a device that `holds` what it holds. The elastic force
    /// runs where the device has the elastic data; its correction is the
    /// elastic one (the Laplacian's corrections assume the Laplacian's
    /// modes, not the elastic operator's). The other forces take the
    /// Laplacian's coarse space where there is one. The elastic force's
    /// iterations pair the skin with the observation where the device
    /// holds one (its springs act in those iterations only).
    pub fn of(force: ForceModel, rotations: RotationMethod, correct: bool, holds: Holds) -> Self {
        let elastic_force = force == ForceModel::Elastic;
        let correction = match (correct, elastic_force) {
            (false, _) => Correction::None,
            (true, true) => match holds.elastic_correction {
                Some((cycled, smoothed)) => Correction::Elastic { cycled, smoothed },
                None => Correction::None,
            },
            (true, false) => match holds.coarse {
                Some(cycled) => Correction::Coarse { cycled },
                None => Correction::None,
            },
        };
        Self {
            elastic: elastic_force && holds.elastic,
            rotations,
            correction,
            pairs: elastic_force && holds.elastic && holds.pairs,
        }
    }

    /// [`Choices::of`] for one solve's iteration.
    pub fn of_iteration(iteration: &Iteration, holds: Holds) -> Self {
        Self::of(
            iteration.force,
            iteration.rotations,
            iteration.correct,
            holds,
        )
    }

    /// The passes of one iteration, in order: the pairing where it pairs,
    /// the rotations (with the elastic terms in the elastic phase), the force, the step and its
    /// correction, then the combine. An uncorrected iteration measures its
    /// plain step before the combine; a corrected one, the update the
    /// combine made.
    pub fn passes(&self) -> Vec<Pass> {
        let mut passes = if self.pairs {
            vec![Pass::Pair]
        } else {
            Vec::new()
        };
        if self.elastic {
            passes.extend([Pass::ElasticTerms(self.rotations), Pass::ElasticForce]);
        } else {
            passes.extend([Pass::Rotations(self.rotations), Pass::Force]);
        }
        match self.correction {
            Correction::None => {
                passes.extend([Pass::PlainStep, Pass::StepNorms, Pass::Combine]);
                return passes;
            }
            Correction::Coarse { cycled } => {
                passes.extend([Pass::PlainStep, Pass::CoarseCorrection { cycled }]);
            }
            Correction::Elastic {
                cycled,
                smoothed: None,
            } => passes.extend([Pass::PlainStep, Pass::ElasticCorrection { cycled }]),
            Correction::Elastic {
                cycled,
                smoothed: Some(sweeps),
            } => passes.push(Pass::SmoothedStep { cycled, sweeps }),
        }
        passes.extend([Pass::Combine, Pass::UpdateNorms]);
        passes
    }

    /// Whether the iteration corrects its plain step.
    pub fn corrected(&self) -> bool {
        self.correction != Correction::None
    }

    /// Every combination of choices, for the devices' tables and tests.
    pub fn all() -> Vec<Choices> {
        let mut corrections = vec![Correction::None];
        for cycled in [false, true] {
            corrections.push(Correction::Coarse { cycled });
            for smoothed in [None, Some(SMOOTHER_SWEEPS), Some(FREE_SKIN_SWEEPS)] {
                corrections.push(Correction::Elastic { cycled, smoothed });
            }
        }
        let mut all = Vec::new();
        for elastic in [false, true] {
            for rotations in [RotationMethod::Svd, RotationMethod::WarmPolar] {
                for &correction in &corrections {
                    let elastic_correction = matches!(correction, Correction::Elastic { .. });
                    // An elastic correction comes with the elastic force
                    // only, the Laplacian's without it.
                    if correction == Correction::None || elastic == elastic_correction {
                        // Only the elastic force's iterations pair.
                        for pairs in [false, true].into_iter().take(1 + usize::from(elastic)) {
                            all.push(Choices {
                                elastic,
                                rotations,
                                correction,
                                pairs,
                            });
                        }
                    }
                }
            }
        }
        all
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_iteration_rotates_forces_steps_combines_and_measures_once() {
        for choices in Choices::all() {
            let passes = choices.passes();
            let count = |f: fn(&Pass) -> bool| passes.iter().filter(|p| f(p)).count();
            assert_eq!(
                count(|p| matches!(p, Pass::Rotations(_) | Pass::ElasticTerms(_))),
                1,
                "{choices:?}"
            );
            assert_eq!(count(|p| matches!(p, Pass::Force | Pass::ElasticForce)), 1);
            assert_eq!(
                count(|p| matches!(p, Pass::PlainStep | Pass::SmoothedStep { .. })),
                1
            );
            assert_eq!(count(|p| *p == Pass::Combine), 1);
            assert_eq!(
                count(|p| matches!(p, Pass::StepNorms | Pass::UpdateNorms)),
                1
            );
            // The pairing first where it pairs, then the rotations, then
            // the force that uses them.
            assert_eq!(count(|p| *p == Pass::Pair), usize::from(choices.pairs));
            let passes = &passes[usize::from(choices.pairs)..];
            assert!(matches!(
                passes[..2],
                [Pass::Rotations(_), Pass::Force] | [Pass::ElasticTerms(_), Pass::ElasticForce]
            ));
            // A corrected step is measured after the combine, a plain one before.
            let combine = passes.iter().position(|p| *p == Pass::Combine);
            let combine = combine.unwrap_or_else(|| panic!("{choices:?} does not combine"));
            if choices.corrected() {
                assert_eq!(passes.last(), Some(&Pass::UpdateNorms), "{choices:?}");
            } else {
                assert_eq!(passes[combine - 1], Pass::StepNorms, "{choices:?}");
                assert_eq!(combine, passes.len() - 1);
            }
        }
    }

    #[test]
    fn the_elastic_force_takes_only_the_elastic_correction() {
        let holds = Holds {
            elastic: true,
            coarse: Some(false),
            elastic_correction: None,
            pairs: false,
        };
        let elastic = Choices::of(ForceModel::Elastic, RotationMethod::Svd, true, holds);
        assert_eq!(elastic.correction, Correction::None);
        assert!(elastic.elastic);
        let symmetric = Choices::of(ForceModel::Symmetric, RotationMethod::Svd, true, holds);
        assert_eq!(symmetric.correction, Correction::Coarse { cycled: false });
        assert!(!symmetric.elastic);
        let held = Holds {
            elastic_correction: Some((true, Some(2))),
            ..holds
        };
        let smoothed = Choices::of(ForceModel::Elastic, RotationMethod::WarmPolar, true, held);
        assert_eq!(
            smoothed.passes(),
            [
                Pass::ElasticTerms(RotationMethod::WarmPolar),
                Pass::ElasticForce,
                Pass::SmoothedStep {
                    cycled: true,
                    sweeps: 2
                },
                Pass::Combine,
                Pass::UpdateNorms,
            ]
        );
        let uncorrected = Choices::of(ForceModel::Elastic, RotationMethod::Svd, false, held);
        assert_eq!(uncorrected.correction, Correction::None);
    }

    #[test]
    fn the_laplacian_forces_take_the_coarse_space_and_the_elastic_force_needs_its_data() {
        let holds = Holds {
            elastic: false,
            coarse: Some(true),
            elastic_correction: None,
            pairs: false,
        };
        let choices = Choices::of(ForceModel::Paper, RotationMethod::Svd, true, holds);
        assert_eq!(choices.correction, Correction::Coarse { cycled: true });
        let without = Holds {
            coarse: None,
            ..holds
        };
        let choices = Choices::of(ForceModel::Symmetric, RotationMethod::Svd, true, without);
        assert_eq!(choices.correction, Correction::None);
        let choices = Choices::of(ForceModel::Elastic, RotationMethod::Svd, true, holds);
        assert!(!choices.elastic, "no elastic data, no elastic terms");
        assert_eq!(choices.correction, Correction::None);
    }

    #[test]
    fn every_combination_is_listed_once() {
        let all = Choices::all();
        let unique: std::collections::HashSet<_> = all.iter().collect();
        assert_eq!(unique.len(), all.len());
        // Rotations 2 x (3 without the elastic force: none, coarse
        // factored or cycled; 7 with it, each paired or not: none, and the
        // elastic correction factored or cycled, plain or smoothed with a
        // whole skin's sweeps or a free skin's).
        assert_eq!(all.len(), 2 * 3 + 2 * 7 * 2);
    }

    #[test]
    fn only_the_elastic_force_pairs_and_only_with_an_observation() {
        let holds = Holds {
            elastic: true,
            coarse: Some(false),
            elastic_correction: Some((false, Some(2))),
            pairs: true,
        };
        let elastic = Choices::of(ForceModel::Elastic, RotationMethod::Svd, true, holds);
        assert_eq!(elastic.passes()[0], Pass::Pair);
        let shear = Choices::of(ForceModel::Symmetric, RotationMethod::Svd, true, holds);
        assert!(!shear.pairs && !shear.passes().contains(&Pass::Pair));
        let unobserved = Holds {
            pairs: false,
            ..holds
        };
        let elastic = Choices::of(ForceModel::Elastic, RotationMethod::Svd, true, unobserved);
        assert!(!elastic.passes().contains(&Pass::Pair));
    }
}
