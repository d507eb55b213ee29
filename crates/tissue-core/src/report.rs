//! The quality report of a sampling run.

use serde::{Deserialize, Serialize};

/// Percentiles of the number of connections over interior particles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConnectionStats {
    /// Median.
    pub median: f32,
    /// 5th percentile.
    pub p5: f32,
    /// 95th percentile.
    pub p95: f32,
}

/// Where the time of a sampling run went, in seconds.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct StageSeconds {
    /// Building the surface field.
    pub field: f64,
    /// Placing the initial particles.
    pub initial: f64,
    /// The relaxation iterations.
    pub iterations: f64,
    /// Of which rebuilding neighbour rows.
    pub neighbours: f64,
    /// Placing surface particles and building connections.
    pub connections: f64,
    /// Computing this report.
    pub report: f64,
}

/// How well a sampling run went; written as JSON by `tissue sample --report`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SamplingReport {
    /// Number of particles.
    pub particles: usize,
    /// Iterations run.
    pub iterations: usize,
    /// Wall-clock seconds of the whole sampling (setup included).
    pub seconds: f64,
    /// Whether the convergence test held before the iteration cap.
    pub converged: bool,
    /// Standard deviation over mean of the nearest-neighbour distance, interior particles.
    pub nn_cv: f32,
    /// Connections per interior particle.
    pub connections: ConnectionStats,
    /// Number of surface particles (control points).
    pub surface_particles: usize,
    /// Largest distance from a surface point to its nearest surface particle, in mean spacings.
    pub coverage: f32,
    /// Largest distance of a particle outside the surface, in mean spacings.
    pub max_outside: f32,
    /// Mean nearest-neighbour distance (the "mean spacing"), in the mesh's units.
    pub mean_spacing: f32,
    /// How many times the neighbour rows were rebuilt.
    pub neighbour_rebuilds: usize,
    /// Two triangles of the surface that cross, where it passes through
    /// itself (the first pair, [`crate::crossing::first_crossing`]): near
    /// them the inside is ambiguous, and particles may sit on the wrong
    /// side of a sheet. `None` for a surface that does not.
    #[serde(default)]
    pub surface_crossing: Option<[usize; 2]>,
    /// Where the time went.
    pub stage_seconds: StageSeconds,
}
