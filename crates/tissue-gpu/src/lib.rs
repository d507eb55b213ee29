//! The GPU path of tissue: stage 2 (deformation) as WGSL compute shaders
//! through wgpu, each shader the twin of the `tissue_cpu::kernels` module of
//! its name, with the same inputs in the same order.
//!
//! - [`Pipelines`]: the compiled kernels, built once from a `&Device`.
//! - [`DeformState`]: the buffers of one particle model.
//! - [`Pipelines::record_iterations`]: the step, each pass of the
//!   iteration's list (`tissue_solve::stage2::passes`: rotations → force →
//!   integrate → the correction → Chebyshev, the step norms before or after
//!   it) by its kernels ([`Kernel::of_pass`]), K times into one command
//!   buffer.
//! - [`GpuDeformer`]: stage 2 on the GPU, `tissue_solve::Tracker` over [`GpuSolve`].
//! - [`GridPipelines`]: stage 1's uniform grid and neighbour rows
//!   (`tissue_cpu::grid`) on the GPU, [`GpuGrid`] and [`GpuRows`].
//! - [`sampler::sample`]: stage 1 (`tissue_cpu::sample`) with its iterations
//!   on the GPU, kernels in [`SamplingPipelines`], buffers in
//!   [`sampler::SamplingBuffers`].
//! - [`timing::KernelTimer`]: each stage-2 kernel's GPU time by timestamp
//!   queries, for a caller whose device has `TIMESTAMP_QUERY` (the benchmark).
//!
//! The library takes `&Device, &Queue` and chooses no adapter; asks for no
//! optional features and only default limits.

mod buffer;
mod coarse;
mod coarse_elastic;
mod deformer;
pub mod grid;
mod multilevel;
mod pipelines;
pub mod quiet;
mod readback;
pub mod sampler;
pub mod shaders;
mod state;
pub mod structures;
mod support;
#[cfg(test)]
mod testing;
pub mod timing;

pub use deformer::{GPU_COARSE_UNKNOWNS, GpuDeformer, GpuSolve};
pub use grid::{GpuGrid, GpuRows, GridKernel, GridPipelines};
pub use pipelines::{Kernel, KernelId, KernelSet, Pipelines};
pub use sampler::SamplingPipelines;
pub use state::{DeformState, FieldGridParams, PairingParams, SLOTS};
pub use structures::{EmbeddingKernel, EmbeddingMoved, GpuEmbedding};

use bytemuck::{Pod, Zeroable};

/// Errors of the GPU path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter (GPU or software rasteriser) was found.
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    /// The adapter would not open a device.
    #[error("the adapter refused a device: {0}")]
    RequestDevice(String),
    /// A buffer or dispatch is larger than a device limit allows.
    #[error("{what} needs {asked}, above the device's {limit} of {allowed}")]
    LimitExceeded {
        /// The `wgpu::Limits` field.
        limit: &'static str,
        /// What asked for it.
        what: String,
        /// The size asked for.
        asked: u64,
        /// The device's limit.
        allowed: u64,
    },
    /// A shader failed to preprocess, parse or validate.
    #[error("shader {name}: {message}")]
    Shader {
        /// The shader or entry point.
        name: String,
        /// naga's report.
        message: String,
    },
    /// The device ran out of memory.
    #[error("the GPU ran out of memory: {0}")]
    OutOfMemory(String),
    /// wgpu rejected a call (a bug in this crate, reported instead of panicking).
    #[error("wgpu validation error: {0}")]
    Validation(String),
    /// wgpu reported an internal error.
    #[error("wgpu internal error: {0}")]
    Internal(String),
    /// The device was lost or did not finish the work.
    #[error("the device was lost or stopped responding: {0}")]
    DeviceLost(String),
    /// Mapping a buffer for readback failed.
    #[error("reading a buffer back failed: {0}")]
    Map(String),
    /// The model, the surface or the parameters were refused.
    #[error(transparent)]
    Model(#[from] tissue_core::Error),
    /// An input slice has the wrong length.
    #[error("{what}: expected {expected} entries, got {got}")]
    Length {
        /// Which input.
        what: &'static str,
        /// Entries expected.
        expected: usize,
        /// Entries given.
        got: usize,
    },
}

impl From<wgpu::Error> for GpuError {
    fn from(e: wgpu::Error) -> Self {
        match e {
            wgpu::Error::OutOfMemory { source } => Self::OutOfMemory(source.to_string()),
            wgpu::Error::Validation { description, .. } => Self::Validation(description),
            wgpu::Error::Internal { description, .. } => Self::Internal(description),
        }
    }
}

/// Mirror of WGSL `Params` (`shaders/shared/layout.wgsl`): one iteration's
/// parameters, one slot per iteration of a batch.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Params {
    /// Number of particles.
    pub count: u32,
    /// Force model: 0 the paper's, 1 symmetric, 2 elastic (whose
    /// iterations run `elastic_targets.wgsl`'s kernels).
    pub model: u32,
    /// Step `alpha = sigma / m`.
    pub alpha: f32,
    /// Chebyshev weight; exactly 1 is a plain step.
    pub omega: f32,
    /// Which row of the partials `step_norms` writes.
    pub slot: u32,
    /// Workgroups of a `step_norms` dispatch: the length of a partials row.
    pub groups: u32,
    /// The volume smoother's `delta` in a smoothed elastic iteration
    /// (`volume_smoother.wgsl`); 0 in every other.
    pub volume_delta: f32,
    /// The relaxation of its Jacobi sweeps.
    pub volume_relaxation: f32,
    /// The fraction of the smoothed two-level step taken
    /// (`tissue_solve::stage2::Iteration::damping`): the residual is
    /// scaled by it.
    pub volume_damping: f32,
}

/// Mirror of WGSL `Rotation` (`shaders/shared/layout.wgsl`): three columns,
/// each padded to a `vec4`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Rotation {
    /// First column (w unused).
    pub x_axis: [f32; 4],
    /// Second column (w unused).
    pub y_axis: [f32; 4],
    /// Third column (w unused).
    pub z_axis: [f32; 4],
}

impl From<glam::Mat3> for Rotation {
    fn from(m: glam::Mat3) -> Self {
        Self {
            x_axis: m.x_axis.extend(0.0).to_array(),
            y_axis: m.y_axis.extend(0.0).to_array(),
            z_axis: m.z_axis.extend(0.0).to_array(),
        }
    }
}

impl From<Rotation> for glam::Mat3 {
    fn from(r: Rotation) -> Self {
        let column = |c: [f32; 4]| glam::Vec3::new(c[0], c[1], c[2]);
        Self::from_cols(column(r.x_axis), column(r.y_axis), column(r.z_axis))
    }
}

/// Mirror of WGSL `ElasticParticle` (`shaders/shared/layout.wgsl`): the
/// elastic model's rest data of a particle.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ElasticParticle {
    /// `A_i^-1`, with the volume weight `W_i` in `x_axis[3]`.
    pub inverse: Rotation,
    /// `B_i`, with the stress weight `a_i` in `x_axis[3]`.
    pub correction: Rotation,
    /// The multiplier `mu_i` (w unused).
    pub multiplier: [f32; 4],
}

impl ElasticParticle {
    /// Particle `i` of `elastic`.
    pub fn of(elastic: &tissue_solve::model::Elastic, i: usize) -> Self {
        let c = &elastic.consistency;
        let mut inverse = Rotation::from(elastic.inverse_moments[i]);
        inverse.x_axis[3] = elastic.weights[i];
        let mut correction = Rotation::from(c.corrections[i]);
        correction.x_axis[3] = c.scales[i];
        Self {
            inverse,
            correction,
            multiplier: c.multipliers[i].extend(0.0).to_array(),
        }
    }
}

/// Mirror of WGSL `ElasticTerms`: a particle's target and stress.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ElasticTerms {
    /// The target `T_i`, gathered against the rest offsets.
    pub rest_term: Rotation,
    /// The stress `U_i`, gathered against the multipliers' offsets.
    pub multiplier_term: Rotation,
}

/// Mirror of WGSL `ElasticGradient`: the volume term's gradient at a
/// linearisation, `sqrt(W_i) cof(F_i) B_i` and `sqrt(W_i) a_i cof(F_i)`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ElasticGradient {
    /// `sqrt(W_i) cof(F_i) B_i`.
    pub correction: Rotation,
    /// `sqrt(W_i) a_i cof(F_i)`.
    pub scale: Rotation,
}

/// The limits the CLI, the benchmark and the tests open a device with:
/// wgpu's defaults, but storage buffers as large as `adapter` allows.
/// Stage 1's neighbour rows at a million particles take 217 MB in one
/// binding, above the default 128 MiB (measured on the phantom, lavapipe:
/// refused with the default limits).
pub fn limits_for(adapter: &wgpu::Adapter) -> wgpu::Limits {
    let has = adapter.limits();
    wgpu::Limits {
        max_storage_buffer_binding_size: has.max_storage_buffer_binding_size,
        max_buffer_size: has.max_buffer_size,
        ..wgpu::Limits::default()
    }
}

/// For the CLI, the benchmark and tests (the library itself takes a device):
/// the adapter `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` name, or the default
/// one, and a device with [`limits_for`] it and no optional features.
pub fn device_from_env() -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), GpuError> {
    let adapter = adapter_from_env()?;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("tissue"),
        required_limits: limits_for(&adapter),
        ..Default::default()
    }))
    .map_err(|e| GpuError::RequestDevice(e.to_string()))?;
    Ok((adapter, device, queue))
}

/// The adapter [`device_from_env`] opens, for a caller that asks for its own
/// device (the benchmark adds `TIMESTAMP_QUERY` where the adapter has it).
pub fn adapter_from_env() -> Result<wgpu::Adapter, GpuError> {
    let (instance, adapters) = quiet::instance_and_adapters();
    // wgpu's own `initialize_adapter_from_env` panics when the named adapter
    // is missing; the same choice here returns an error instead.
    let adapter = match std::env::var("WGPU_ADAPTER_NAME") {
        Ok(wanted) => {
            let wanted = wanted.to_lowercase();
            let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
            adapters
                .into_iter()
                .find(|a| a.get_info().name.to_lowercase().contains(&wanted))
                .ok_or_else(|| {
                    GpuError::NoAdapter(format!(
                        "WGPU_ADAPTER_NAME={wanted} matches none of {names:?}"
                    ))
                })?
        }
        Err(_) => quiet::hushed(|| {
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::from_env().unwrap_or_default(),
                ..Default::default()
            }))
        })
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?,
    };
    Ok(adapter)
}

/// Waits for the queue, turning a lost device or a timeout into an error.
pub(crate) fn wait(device: &wgpu::Device) -> Result<(), GpuError> {
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(|e| GpuError::DeviceLost(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Size and offsets of a Rust mirror must equal naga's layout of the WGSL struct.
    fn check_layout(name: &str, rust_size: usize, rust_offsets: &[(&str, usize)]) {
        shaders::assert_layout("local_rotations", name, rust_size, rust_offsets);
    }

    #[test]
    fn params_matches_the_wgsl_layout() {
        use std::mem::{offset_of, size_of};
        check_layout(
            "Params",
            size_of::<Params>(),
            &[
                ("count", offset_of!(Params, count)),
                ("model", offset_of!(Params, model)),
                ("alpha", offset_of!(Params, alpha)),
                ("omega", offset_of!(Params, omega)),
                ("slot", offset_of!(Params, slot)),
                ("groups", offset_of!(Params, groups)),
                ("volume_delta", offset_of!(Params, volume_delta)),
                ("volume_relaxation", offset_of!(Params, volume_relaxation)),
                ("volume_damping", offset_of!(Params, volume_damping)),
            ],
        );
    }

    #[test]
    fn the_elastic_structs_match_the_wgsl_layout() {
        use std::mem::{offset_of, size_of};
        let check = |name, size, offsets: &[(&str, usize)]| {
            shaders::assert_layout("elastic_targets", name, size, offsets);
        };
        check(
            "ElasticParticle",
            size_of::<ElasticParticle>(),
            &[
                ("inverse", offset_of!(ElasticParticle, inverse)),
                ("correction", offset_of!(ElasticParticle, correction)),
                ("multiplier", offset_of!(ElasticParticle, multiplier)),
            ],
        );
        check(
            "ElasticTerms",
            size_of::<ElasticTerms>(),
            &[
                ("rest_term", offset_of!(ElasticTerms, rest_term)),
                ("multiplier_term", offset_of!(ElasticTerms, multiplier_term)),
            ],
        );
        shaders::assert_layout(
            "coarse_elastic",
            "ElasticGradient",
            size_of::<ElasticGradient>(),
            &[
                ("correction", offset_of!(ElasticGradient, correction)),
                ("scale", offset_of!(ElasticGradient, scale)),
            ],
        );
    }

    #[test]
    fn rotation_matches_the_wgsl_layout() {
        use std::mem::{offset_of, size_of};
        check_layout(
            "Rotation",
            size_of::<Rotation>(),
            &[
                ("x_axis", offset_of!(Rotation, x_axis)),
                ("y_axis", offset_of!(Rotation, y_axis)),
                ("z_axis", offset_of!(Rotation, z_axis)),
            ],
        );
    }
}
