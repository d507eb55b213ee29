//! The stage-1 kernels: which WGSL entry points an iteration runs, and
//! their compiled pipelines.

use crate::GpuError;
use crate::pipelines::{CompiledKernel, KernelId, KernelSet};

/// One stage-1 kernel (a WGSL entry point), in the order of an iteration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SamplingKernel {
    /// `imf_force.wgsl`: eqs. (2)-(6).
    ImfForce,
    /// `radius_update.wgsl`: eqs. (7)-(8).
    RadiusUpdate,
    /// `sampling_integrate.wgsl::integrate`: eq. (1) and the projection.
    Integrate,
    /// `sampling_change.wgsl::change`: per-workgroup partials of the change.
    Change,
    /// `needs_rebuild.wgsl`: the Verlet check; halts the batch when it holds.
    NeedsRebuild,
}

impl SamplingKernel {
    /// Every kernel, in the order of one iteration.
    pub const ALL: [SamplingKernel; 5] = [
        SamplingKernel::ImfForce,
        SamplingKernel::RadiusUpdate,
        SamplingKernel::Integrate,
        SamplingKernel::Change,
        SamplingKernel::NeedsRebuild,
    ];

    /// `(shader file, entry point)`.
    pub fn entry(self) -> (&'static str, &'static str) {
        match self {
            SamplingKernel::ImfForce => ("imf_force", "imf_force"),
            SamplingKernel::RadiusUpdate => ("radius_update", "radius_update"),
            SamplingKernel::Integrate => ("sampling_integrate", "integrate"),
            SamplingKernel::Change => ("sampling_change", "change"),
            SamplingKernel::NeedsRebuild => ("needs_rebuild", "needs_rebuild"),
        }
    }

    pub(super) fn index(self) -> usize {
        self as usize
    }
}

impl KernelId for SamplingKernel {
    const KERNELS: &'static [Self] = &SamplingKernel::ALL;

    fn entry(self) -> (&'static str, &'static str) {
        SamplingKernel::entry(self)
    }

    fn index(self) -> usize {
        SamplingKernel::index(self)
    }
}

/// The compiled stage-1 kernels, built once per device.
pub type SamplingPipelines = KernelSet<SamplingKernel>;

/// A compute pipeline of `file::entry`, uniforms bound with a dynamic offset.
pub(super) fn compile(
    device: &wgpu::Device,
    file: &str,
    entry: &str,
) -> Result<CompiledKernel, GpuError> {
    crate::support::compile(device, file, entry, true)
}
