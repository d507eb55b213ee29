//! What the program does not know, each with its prior ([`Priors`]): the
//! defaults, their units and their ranges (docs/METHOD.md, "Uncertainty").

use serde::Serialize;
use tissue_core::ParamError;

use crate::stage2::posture::MAX_GRAVITY_G;

/// The Poisson ratio's range for soft tissue, uniform.
pub const POISSON_RANGE: (f32, f32) = (0.45, 0.495);
/// The observed surface's error along its normals, standard deviation, mm:
/// a segmentation or a surface scan to about half a millimetre.
pub const SURFACE_NOISE_MM: f32 = 0.5;
/// The surface error's correlation length, mm.
pub const SURFACE_CORRELATION_MM: f32 = 10.0;
/// The surface error's samples.
pub const SURFACE_SAMPLES: usize = 16;
/// The load's relative standard deviation: the density's (10 %) and the
/// fitted stiffness's (10 %) together.
pub const LOAD_SPREAD: f32 = 0.14;
/// Each posture's gravity direction, standard deviation about each axis
/// across it, degrees.
pub const GRAVITY_DEGREES: f32 = 3.0;
/// Without a posture's gravity: the RMS change of gravity between the
/// scans the answer did not model, in g. `sqrt(2)`: nothing is known of
/// either posture, so each scan's gravity is taken as any direction,
/// independently, and `E |g2 - g1|^2 = 2 g^2`.
pub const POSTURE_G: f32 = std::f32::consts::SQRT_2;
/// The Young's modulus that unmodelled change acts on, kPa.
pub const POSTURE_KPA: f32 = 2.0;
/// The tissue density the unmodelled change acts on, kg/m^3.
pub const TISSUE_DENSITY_KG_M3: f32 = 1000.0;
/// The re-solves' tolerance, a multiple of the answer's. A column's error
/// need only be small against the ensemble's own: on the shared cases at
/// 10,000 particles (24 settings, docs/ACCURACY.md) 8 against 3 takes
/// 8-26 % fewer iterations and moves the probes' 95 % radii by 0.01-1 %
/// at the median (13 % at most, one probe), while another seed of the
/// surface's samples moves them by 3 % at the median (86 % at most).
pub const COLUMN_TOLERANCE: f32 = 8.0;
/// The samples' seed.
pub const SEED: u64 = 0x5eed;

/// What the program does not know, each with its spread; lengths in the
/// model's units (millimetres by default).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Priors {
    /// The Poisson ratio's range (uniform); a point range at the solve's
    /// own ratio is no unknown.
    pub poisson: (f32, f32),
    /// The surface error's standard deviation along the normals; zero:
    /// the surface is exact.
    pub surface_noise: f32,
    /// The surface error's correlation length.
    pub surface_correlation: f32,
    /// The surface error's samples.
    pub samples: usize,
    /// The load's relative standard deviation (with a load only).
    pub load_spread: f32,
    /// Each posture's gravity direction's standard deviation, degrees
    /// (with a load only).
    pub gravity_degrees: f32,
    /// Without a load: the RMS change of gravity between the scans that
    /// the answer did not model, in g (0: the posture did not change).
    pub posture_g: f32,
    /// The Young's modulus that change acts on, kPa.
    pub posture_kpa: f32,
    /// The re-solves' tolerance as a multiple of the answer's (at least
    /// 1): each column needs to be accurate against the spread, not the
    /// organ's size.
    pub column_tolerance: f32,
    /// The surface samples' seed.
    pub seed: u64,
}

impl Default for Priors {
    fn default() -> Self {
        Self {
            poisson: POISSON_RANGE,
            surface_noise: SURFACE_NOISE_MM,
            surface_correlation: SURFACE_CORRELATION_MM,
            samples: SURFACE_SAMPLES,
            load_spread: LOAD_SPREAD,
            gravity_degrees: GRAVITY_DEGREES,
            posture_g: POSTURE_G,
            posture_kpa: POSTURE_KPA,
            column_tolerance: COLUMN_TOLERANCE,
            seed: SEED,
        }
    }
}

impl Priors {
    /// Changes fields in a closure: `Priors::default().with(|p| p.samples = 32)`.
    pub fn with(mut self, change: impl FnOnce(&mut Self)) -> Self {
        change(&mut self);
        self
    }

    /// The defaults for a model in units of `mm_per_unit` millimetres.
    pub fn in_units(mm_per_unit: f32) -> Self {
        Self::default().with(|p| {
            p.surface_noise /= mm_per_unit;
            p.surface_correlation /= mm_per_unit;
        })
    }

    /// Checks every field's range.
    ///
    /// # Errors
    ///
    /// [`ParamError`] naming the first field out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let (lo, hi) = self.poisson;
        ParamError::check(
            lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi && hi < 0.5,
            "uncertainty poisson",
            format!("{lo} to {hi}"),
            "a range inside (0, 0.5), its low end first",
        )?;
        ParamError::check(
            self.surface_noise.is_finite() && self.surface_noise >= 0.0,
            "uncertainty surface_noise",
            self.surface_noise,
            "a length of at least zero",
        )?;
        ParamError::check(
            self.surface_correlation.is_finite() && self.surface_correlation > 0.0,
            "uncertainty surface_correlation",
            self.surface_correlation,
            "a positive length",
        )?;
        ParamError::check(
            (2..=1024).contains(&self.samples) || self.surface_noise == 0.0,
            "uncertainty samples",
            self.samples,
            "2 to 1024 surface samples",
        )?;
        ParamError::check(
            self.load_spread.is_finite() && (0.0..1.0).contains(&self.load_spread),
            "uncertainty load_spread",
            self.load_spread,
            "a relative spread from 0 to under 1",
        )?;
        ParamError::check(
            self.gravity_degrees.is_finite() && (0.0..=30.0).contains(&self.gravity_degrees),
            "uncertainty gravity_degrees",
            self.gravity_degrees,
            "0 to 30 degrees",
        )?;
        ParamError::check(
            self.posture_g.is_finite() && (0.0..=MAX_GRAVITY_G).contains(&self.posture_g),
            "uncertainty posture_g",
            self.posture_g,
            format!("0 to {MAX_GRAVITY_G} g"),
        )?;
        ParamError::check(
            self.posture_kpa.is_finite() && self.posture_kpa > 0.0,
            "uncertainty posture_kpa",
            self.posture_kpa,
            "a positive Young's modulus in kPa",
        )?;
        ParamError::check(
            self.column_tolerance.is_finite() && (1.0..=100.0).contains(&self.column_tolerance),
            "uncertainty column_tolerance",
            self.column_tolerance,
            "1 to 100 times the answer's tolerance",
        )
    }
}
