//! Bytes: what a model holds on the CPU and on the GPU, and what one
//! deformation iteration must move at the least.

use std::mem::size_of;

use serde::Serialize;
use tissue_core::{Attachment, ParticleModel};
use tissue_gpu::{Kernel, Pipelines, SLOTS};

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

/// Bytes of the GPU buffers of one model.
///
/// `DeformState` keeps its buffers private, so these are computed from the
/// same formulas `tissue_gpu::DeformState::new` and `GpuDeformer::new` size
/// them with (`crates/tissue-gpu/src/{state,deformer}.rs`); a change there
/// must be mirrored here.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct GpuStateBytes {
    /// rest, current, previous, plain and force: `vec4<f32>` per particle each.
    pub positions: u64,
    /// Rotations: three `vec4<f32>` columns per particle.
    pub rotations: u64,
    /// Free flags, `u32` per particle.
    pub free: u64,
    /// Connection offsets and indices, `u32` each.
    pub connections: u64,
    /// Step-norm partials: `SLOTS` rows of one `vec2<f32>` per step_norms workgroup.
    pub partials: u64,
    /// Uniform parameters: `SLOTS` slots at the device's uniform offset alignment.
    pub params: u64,
    /// `DeformState`'s total: the sum of the above.
    pub state_total: u64,
    /// `state_total` over the particle count.
    pub state_per_particle: f64,
    /// `GpuDeformer`'s two backup buffers (current, previous) for replaying a batch.
    pub deformer_backups: u64,
    /// Everything the deformer allocates, over the particle count.
    pub deformer_per_particle: f64,
}

impl GpuStateBytes {
    /// The buffers `DeformState::new` allocates for `model` on `device`.
    pub fn of(model: &ParticleModel, device: &wgpu::Device, pipelines: &Pipelines) -> Self {
        let n = model.len() as u64;
        let vec4 = 16;
        // Empty arrays are padded to 16 bytes (zero-sized bindings are invalid).
        let padded = |bytes: u64| bytes.max(16);
        let positions = 5 * padded(n * vec4);
        let rotations = padded(n * size_of::<tissue_gpu::Rotation>() as u64);
        let free = padded(n * 4);
        let connections = padded(model.connections.offsets.len() as u64 * 4)
            + padded(model.connections.indices.len() as u64 * 4);
        let limits = device.limits();
        let groups = u64::from(
            (n as u32)
                .div_ceil(pipelines.workgroup_size(Kernel::StepNorms).max(1))
                .max(1),
        );
        let per_dimension = u64::from(limits.max_compute_workgroups_per_dimension.max(1));
        let x = groups.min(per_dimension);
        let step_groups = x * groups.div_ceil(x);
        let partials = padded(u64::from(SLOTS) * step_groups * 8);
        let params = u64::from(SLOTS)
            * u64::from(limits.min_uniform_buffer_offset_alignment)
                .max(size_of::<tissue_gpu::Params>() as u64);
        let state_total = positions + rotations + free + connections + partials + params;
        let deformer_backups = 2 * n * vec4;
        Self {
            positions,
            rotations,
            free,
            connections,
            partials,
            params,
            state_total,
            state_per_particle: state_total as f64 / n.max(1) as f64,
            deformer_backups,
            deformer_per_particle: (state_total + deformer_backups) as f64 / n.max(1) as f64,
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
