//! Parameters of stage 1 (uniform sampling). Every symbol of the paper's
//! Section 2 is a field here; `docs/METHOD.md` explains each default.

use serde::{Deserialize, Serialize};

use crate::error::ParamError;

/// How the surface keeps particles inside (Section 2.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SurfaceMode {
    /// A particle found outside is moved back onto the surface by exactly its
    /// penetration depth. Measured best (docs/METHOD.md, "Eq. (3): keeping
    /// particles inside").
    Projection,
    /// The paper's literal surface force, eq. (3): `-mu * n` while outside.
    PaperForce {
        /// The weight `mu` of eq. (2).
        mu: f32,
    },
}

/// How the initial particles are placed inside the surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialPlacement {
    /// A face-centred cubic lattice at the target density, jittered by the seed:
    /// already close to the relaxed state, so far fewer iterations.
    Lattice,
    /// Uniform random points inside the surface (rejection sampling by the seed),
    /// as a plain reading of the paper.
    Random,
}

/// Parameters of the uniform sampling stage. Lengths are in units of the
/// initial radius `r0 = (sqrt(2) V / N)^(1/3) / 1.5` unless said otherwise.
///
/// The struct is `#[non_exhaustive]`, so that a parameter can be added
/// without breaking callers: outside this crate, start from
/// [`SamplingParams::with_particles`] or `default()` and change fields with
/// [`SamplingParams::with`] or by assignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct SamplingParams {
    /// Number of particles `N`.
    pub particles: usize,
    /// Seed of the initial placement; the same seed gives a bit-identical model.
    pub seed: u64,
    /// Initial placement of particles.
    pub initial: InitialPlacement,
    /// `alpha` of eq. (4), the IMF softness. Paper: 0.5.
    pub alpha: f32,
    /// Neighbours of an ideally packed particle (close packing: 12), used in eq. (7).
    pub ideal_neighbours: f32,
    /// Equilibrium distance as a fraction of `r_i + r_j`, used in eq. (7). Paper: 0.75.
    pub equilibrium_ratio: f32,
    /// Balloon hardness `eta` of eq. (8). The paper gives no value.
    pub eta: f32,
    /// Largest change of `ln r` per iteration: the argument of eq. (8)'s `ln`
    /// is clamped to `[exp(-x), exp(x)]`, which also keeps it positive.
    pub max_log_radius_step: f32,
    /// Mass `m~` of eq. (1); the motion is `dp = F r0 / m~`, so steps scale with the model.
    pub mass: f32,
    /// Largest step of a particle per iteration, in `r0`.
    pub max_step: f32,
    /// Pair forces act only for `d < force_cutoff (r_i + r_j)`.
    pub force_cutoff: f32,
    /// Particles are connected when `d < connection_ratio (r_i + r_j)`, eq. (9).
    /// The paper's 0.6 gives no connections at its own 0.75 equilibrium.
    pub connection_ratio: f32,
    /// How the surface keeps particles inside.
    pub surface_mode: SurfaceMode,
    /// Count the wall's reaction on a particle in contact with the surface as
    /// one more compressing force in eq. (6).
    pub wall_in_compression: bool,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Converged when the RMS step of interior particles is below this (in `r0`)...
    pub step_tolerance: f32,
    /// ...and the RMS change of `ln r` is below this.
    pub radius_tolerance: f32,
    /// A particle within this distance of the surface (in its own radius) at the
    /// end is a surface particle: placed exactly on the surface and attached.
    pub surface_band: f32,
}

impl Default for SamplingParams {
    fn default() -> Self {
        Self {
            particles: 10_000,
            seed: 0,
            initial: InitialPlacement::Lattice,
            alpha: 0.5,
            ideal_neighbours: 12.0,
            equilibrium_ratio: 0.75,
            eta: 0.01,
            max_log_radius_step: 0.05,
            mass: 20.0,
            max_step: 0.5,
            force_cutoff: 1.0,
            connection_ratio: 0.9,
            surface_mode: SurfaceMode::Projection,
            wall_in_compression: true,
            max_iterations: 1000,
            step_tolerance: 2e-3,
            radius_tolerance: 1e-3,
            surface_band: 0.1,
        }
    }
}

impl SamplingParams {
    /// These parameters as `change` leaves them:
    /// `SamplingParams::with_particles(10_000).with(|p| p.seed = 7)`.
    #[must_use]
    pub fn with(mut self, change: impl FnOnce(&mut Self)) -> Self {
        change(&mut self);
        self
    }

    /// The defaults with `particles` particles.
    pub fn with_particles(particles: usize) -> Self {
        Self {
            particles,
            ..Self::default()
        }
    }

    /// The paper read literally, so its result can be reproduced: random start,
    /// constant surface force `-mu n`, no wall in the compression, the paper's
    /// connection threshold 0.6. The paper states no force cutoff; the grid needs
    /// one, and 1.2 is the largest before the attraction tail runs away.
    pub fn paper(particles: usize) -> Self {
        Self {
            particles,
            initial: InitialPlacement::Random,
            surface_mode: SurfaceMode::PaperForce { mu: 30.0 },
            wall_in_compression: false,
            force_cutoff: 1.2,
            connection_ratio: 0.6,
            ..Self::default()
        }
    }

    /// The ideal compression `|F_compress^ideal|` of eq. (7), computed from
    /// `ideal_neighbours`, `equilibrium_ratio` and `alpha` (8.8257 for the paper's).
    pub fn ideal_compression(&self) -> f32 {
        let h = 1.0 / (self.alpha * self.equilibrium_ratio + (1.0 - self.alpha));
        self.ideal_neighbours * (h.powi(6) - h.powi(3))
    }

    /// Checks every parameter, naming the first that is out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let finite_pos = |x: f32| x.is_finite() && x > 0.0;
        ParamError::check(
            (4..=50_000_000).contains(&self.particles),
            "particles",
            self.particles,
            "between 4 and 50,000,000",
        )?;
        ParamError::check(
            self.alpha.is_finite() && self.alpha > 0.0 && self.alpha <= 1.0,
            "alpha",
            self.alpha,
            "in (0, 1]",
        )?;
        ParamError::check(
            finite_pos(self.ideal_neighbours),
            "ideal_neighbours",
            self.ideal_neighbours,
            "positive",
        )?;
        ParamError::check(
            self.equilibrium_ratio.is_finite()
                && self.equilibrium_ratio > 0.0
                && self.equilibrium_ratio < 1.0,
            "equilibrium_ratio",
            self.equilibrium_ratio,
            "in (0, 1): the pair force must still repel at equilibrium",
        )?;
        ParamError::check(
            finite_pos(self.eta) && self.eta <= 1.0,
            "eta",
            self.eta,
            "in (0, 1]",
        )?;
        ParamError::check(
            finite_pos(self.max_log_radius_step) && self.max_log_radius_step <= 1.0,
            "max_log_radius_step",
            self.max_log_radius_step,
            "in (0, 1]",
        )?;
        ParamError::check(finite_pos(self.mass), "mass", self.mass, "positive")?;
        ParamError::check(
            finite_pos(self.max_step) && self.max_step <= 2.0,
            "max_step",
            self.max_step,
            "in (0, 2]",
        )?;
        ParamError::check(
            self.force_cutoff.is_finite()
                && self.force_cutoff >= self.equilibrium_ratio
                && self.force_cutoff <= 3.0,
            "force_cutoff",
            self.force_cutoff,
            "between equilibrium_ratio and 3",
        )?;
        ParamError::check(
            finite_pos(self.connection_ratio) && self.connection_ratio <= 3.0,
            "connection_ratio",
            self.connection_ratio,
            "in (0, 3]",
        )?;
        if let SurfaceMode::PaperForce { mu } = self.surface_mode {
            ParamError::check(finite_pos(mu), "mu", mu, "positive")?;
        }
        ParamError::check(
            (1..=1_000_000).contains(&self.max_iterations),
            "max_iterations",
            self.max_iterations,
            "between 1 and 1,000,000",
        )?;
        ParamError::check(
            finite_pos(self.step_tolerance),
            "step_tolerance",
            self.step_tolerance,
            "positive",
        )?;
        ParamError::check(
            finite_pos(self.radius_tolerance),
            "radius_tolerance",
            self.radius_tolerance,
            "positive",
        )?;
        ParamError::check(
            finite_pos(self.surface_band) && self.surface_band < 1.0,
            "surface_band",
            self.surface_band,
            "in (0, 1)",
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]
    use super::*;

    #[test]
    fn ideal_compression_is_computed_not_typed_and_matches_the_paper() {
        let p = SamplingParams::default();
        assert!(
            (p.ideal_compression() - 8.8257).abs() < 1e-3,
            "{}",
            p.ideal_compression()
        );
        let other = SamplingParams {
            equilibrium_ratio: 0.8,
            ..SamplingParams::default()
        };
        assert!(other.ideal_compression() < p.ideal_compression());
    }

    #[test]
    fn defaults_are_pinned() {
        let p = SamplingParams::default();
        assert_eq!(p.alpha, 0.5);
        assert_eq!(p.equilibrium_ratio, 0.75);
        assert_eq!(p.force_cutoff, 1.0);
        assert_eq!(p.connection_ratio, 0.9);
        assert_eq!(p.eta, 0.01);
        assert_eq!(p.mass, 20.0);
        assert_eq!(p.max_log_radius_step, 0.05);
        assert_eq!(p.surface_mode, SurfaceMode::Projection);
        assert!(p.wall_in_compression);
        assert_eq!(p.initial, InitialPlacement::Lattice);
        p.validate().expect("defaults are valid");
    }

    #[test]
    fn paper_preset_keeps_the_literal_choices() {
        let p = SamplingParams::paper(1000);
        assert_eq!(p.connection_ratio, 0.6);
        assert!(!p.wall_in_compression);
        assert!(matches!(p.surface_mode, SurfaceMode::PaperForce { .. }));
        p.validate().expect("paper preset is valid");
    }

    #[test]
    fn absurd_parameters_are_named() {
        let bad = SamplingParams {
            eta: f32::NAN,
            ..SamplingParams::default()
        };
        assert_eq!(bad.validate().unwrap_err().name, "eta");
        let bad = SamplingParams {
            particles: 1,
            ..SamplingParams::default()
        };
        assert_eq!(bad.validate().unwrap_err().name, "particles");
        let bad = SamplingParams {
            force_cutoff: 0.5,
            ..SamplingParams::default()
        };
        assert_eq!(bad.validate().unwrap_err().name, "force_cutoff");
        let bad = SamplingParams {
            surface_mode: SurfaceMode::PaperForce { mu: -1.0 },
            ..SamplingParams::default()
        };
        assert_eq!(bad.validate().unwrap_err().name, "mu");
    }
}
