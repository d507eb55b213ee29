//! The stage-2 options `deform` and `track` share: the force, how the
//! elastic phase descends, the solver's tolerance and cap, the observed
//! vertices and the posture's gravity.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::ValueEnum;
use tissue::deformation::{DeformParams, ElasticSolve, ForceModel};

use crate::posture::GravityArgs;

/// The force of stage 2.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Force {
    /// The paper's one-sided force (slower; not the gradient of an energy).
    Paper,
    /// The symmetric force, the gradient of the rotation-aware energy (docs/METHOD.md).
    Symmetric,
    /// The symmetric force plus a volume term set by `--poisson` (docs/METHOD.md, "Elastic model").
    Elastic,
}

/// How the elastic phase of a solve from rest descends its potential.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Descent {
    /// The two-level iteration with Chebyshev's weights, the potential
    /// watched every 8 iterations.
    Chebyshev,
    /// A conjugate gradient preconditioned by the same two-level step,
    /// every step accepted only where the potential fell (docs/METHOD.md,
    /// "Elastic model", *The conjugate-gradient phase*).
    ConjugateGradient,
    /// Chebyshev's iterations until the potential first rises or they
    /// stall, then the conjugate gradient from the state they accepted last.
    ChebyshevThenConjugateGradient,
}

impl Descent {
    /// The library's choice.
    fn solve(self) -> ElasticSolve {
        match self {
            Self::Chebyshev => ElasticSolve::Chebyshev,
            Self::ConjugateGradient => ElasticSolve::ConjugateGradient,
            Self::ChebyshevThenConjugateGradient => ElasticSolve::ChebyshevThenConjugateGradient,
        }
    }

    /// The option's value of the library's choice.
    fn of(solve: ElasticSolve) -> Self {
        match solve {
            ElasticSolve::Chebyshev => Self::Chebyshev,
            ElasticSolve::ConjugateGradient => Self::ConjugateGradient,
            ElasticSolve::ChebyshevThenConjugateGradient => Self::ChebyshevThenConjugateGradient,
        }
    }
}

/// Stage-2 options shared by `deform` and `track`.
#[derive(Debug, clap::Args)]
pub struct SolveArgs {
    /// Force model (default: elastic; symmetric is the fastest frame, without a volume term).
    #[arg(long, value_enum)]
    pub force: Option<Force>,
    /// Poisson ratio of the elastic force (0 to 0.499; soft tissue is 0.45 to 0.49).
    /// With the posture options the tissue's own ratio matters most: give it
    /// where it is known (docs/ACCURACY.md, "The Poisson ratio, with gravity").
    #[arg(long, default_value_t = DeformParams::default().poisson)]
    pub poisson: f32,
    /// Iteration cap per solve.
    #[arg(long, default_value_t = DeformParams::default().max_iterations)]
    pub max_iterations: usize,
    /// Stop when every particle's error estimate is below this fraction of the model's size.
    #[arg(long, default_value_t = DeformParams::default().tolerance)]
    pub tolerance: f32,
    /// Two-level solve: every iteration removes the error's part that is
    /// constant over aggregates of particles (grid cells of this many mean
    /// connection lengths) exactly (docs/METHOD.md, "Two-level solve"), on
    /// both backends. 0 turns it off.
    #[arg(long, default_value_t = DeformParams::default().tuning.coarse)]
    pub coarse: f32,
    /// How the elastic phase of a solve from rest descends its potential
    /// (a tracking frame's warm phase takes Chebyshev's steps either way).
    #[arg(long, value_enum, default_value_t = Descent::of(DeformParams::default().tuning.elastic_solve))]
    pub elastic_solve: Descent,
    /// Only these vertices of the surface were observed: the observed patch
    /// of the rest surface as a surface file, or its vertices as points
    /// (.csv, .ply), in the rest posture (docs/FORMATS.md). Surface
    /// particles on a triangle with an unobserved vertex move with the
    /// solve instead of following the surface. Default: every vertex.
    #[arg(long, value_name = "FILE")]
    pub observed: Option<PathBuf>,
    #[command(flatten)]
    pub gravity: GravityArgs,
}

impl SolveArgs {
    /// The stage-2 parameters, checked.
    pub fn params(&self) -> Result<DeformParams> {
        let force = match (self.force, self.gravity.given()) {
            (Some(Force::Symmetric), false) => ForceModel::Symmetric,
            (None, _) | (Some(Force::Elastic), _) => ForceModel::Elastic,
            (Some(Force::Paper), false) => ForceModel::Paper,
            (Some(other), true) => bail!(
                "--gravity-rest and --gravity-deformed need the elastic force (the default), not \
                 --force {}: the unloaded shape is that of an elastic body",
                format!("{other:?}").to_lowercase()
            ),
        };
        let params = DeformParams::default().with(|p| {
            p.force = force;
            p.poisson = self.poisson;
            p.max_iterations = self.max_iterations;
            p.tolerance = self.tolerance;
            p.tuning.coarse = self.coarse;
            p.tuning.elastic_solve = self.elastic_solve.solve();
        });
        params.validate()?;
        Ok(params)
    }
}
