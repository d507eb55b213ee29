//! Bytes: what a model holds on the CPU and on the GPU, and what one
//! deformation iteration must move at the least.

use std::mem::size_of;

use serde::Serialize;
use tissue_core::{Attachment, ParticleModel};
use tissue_gpu::GpuSolve;

/// Bytes of a [`ParticleModel`] on the CPU (the surface mesh excluded).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct CpuModelBytes {
    /// Positions, `Vec3` each.
    pub positions: u64,
    /// Radii, `f32` each.
    pub radii: u64,
    /// Attachments, `Option<Attachment>` each.
    pub attachments: u64,
    /// Connections: offsets and indices, `u32` each.
    pub connections: u64,
    /// Their sum.
    pub total: u64,
    /// `total` over the particle count.
    pub per_particle: f64,
}

impl CpuModelBytes {
    /// Counts `model`'s arrays by their lengths (not their capacities).
    pub fn of(model: &ParticleModel) -> Self {
        let n = model.len() as u64;
        let positions = n * size_of::<glam::Vec3>() as u64;
        let radii = model.radii.len() as u64 * size_of::<f32>() as u64;
        let attachments = model.attachments.len() as u64 * size_of::<Option<Attachment>>() as u64;
        let connections = (model.connections.offsets.len() + model.connections.indices.len())
            as u64
            * size_of::<u32>() as u64;
        let total = positions + radii + attachments + connections;
        Self {
            positions,
            radii,
            attachments,
            connections,
            total,
            per_particle: total as f64 / n.max(1) as f64,
        }
    }
}

/// Bytes of the GPU buffers of one model, as `tissue-gpu` allocated them.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct GpuStateBytes {
    /// `DeformState`'s buffers (positions, rotations, forces, flags,
    /// connections, step-norm partials, parameters).
    pub state_total: u64,
    /// `state_total` over the particle count.
    pub state_per_particle: f64,
    /// Everything the deformer holds: the state and the three backups a batch
    /// is replayed from.
    pub deformer_total: u64,
    /// `deformer_total` over the particle count.
    pub deformer_per_particle: f64,
}

impl GpuStateBytes {
    /// The buffers `solve` holds for a model of `particles` particles.
    pub fn of(solve: &GpuSolve, particles: usize) -> Self {
        let state_total = solve.state().buffer_bytes();
        let deformer_total = solve.buffer_bytes();
        let n = particles.max(1) as f64;
        Self {
            state_total,
            state_per_particle: state_total as f64 / n,
            deformer_total,
            deformer_per_particle: deformer_total as f64 / n,
        }
    }
}

/// The least traffic of one deformation iteration, as if every array were
/// read or written once per use from memory with no reuse between particles.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct IterationFloor {
    /// Mean connections per particle `k`.
    pub mean_connections: f64,
    /// Bytes per particle, by the formula in [`IterationFloor::new`].
    pub bytes_per_particle: f64,
    /// Bytes per iteration over the whole model.
    pub bytes_per_iteration: f64,
}

impl IterationFloor {
    /// Per particle `i` with `k` connections, position size `p` bytes and
    /// rotation size `r` bytes (CPU: `Vec3` 12, `Mat3` 36; GPU: `vec4` 16,
    /// three `vec4` 48):
    ///
    /// `bytes = (1 + k) · (2p + r) + 4 (k + 1) + 2p`
    ///
    /// - `(1 + k) · 2p`: rest and current positions of `i` and of its `k`
    ///   neighbours (read for `M_i` and the force);
    /// - `(1 + k) · r`: the rotations of `i` and its neighbours (the
    ///   symmetric force uses `R_i + R_j`);
    /// - `4 (k + 1)`: the connection indices of `i` and its offset;
    /// - `2p`: the force and the new position written.
    ///
    /// Intermediate traffic (the plain step, the previous positions for
    /// Chebyshev, the step norms) is left out: this is a floor.
    pub fn new(model: &ParticleModel, position_bytes: f64, rotation_bytes: f64) -> Self {
        let n = model.len() as f64;
        let k = model.connections.indices.len() as f64 / n.max(1.0);
        let p = position_bytes;
        let bytes_per_particle = (1.0 + k) * (2.0 * p + rotation_bytes) + 4.0 * (k + 1.0) + 2.0 * p;
        Self {
            mean_connections: k,
            bytes_per_particle,
            bytes_per_iteration: bytes_per_particle * n,
        }
    }

    /// Effective bandwidth in GB/s (1e9 bytes) at `seconds` per iteration.
    pub fn gigabytes_per_second(&self, seconds: f64) -> f64 {
        if seconds > 0.0 {
            self.bytes_per_iteration / seconds / 1e9
        } else {
            0.0
        }
    }
}
