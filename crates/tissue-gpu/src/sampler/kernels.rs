//! The stage-1 kernels: which WGSL entry points an iteration runs, and
//! their compiled pipelines.

use crate::GpuError;
use crate::pipelines::CompiledKernel;
use crate::support::Scopes;

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

/// The compiled stage-1 kernels, one field per kernel, built once per device.
#[derive(Debug)]
pub struct SamplingPipelines {
    kernels: Vec<CompiledKernel>,
}

impl SamplingPipelines {
    /// Compiles every stage-1 kernel for `device`; wgpu errors are returned.
    pub fn new(device: &wgpu::Device) -> Result<Self, GpuError> {
        let scope = Scopes::push(device);
        let built: Result<Vec<CompiledKernel>, GpuError> = SamplingKernel::ALL
            .into_iter()
            .map(|k| {
                let (file, entry) = k.entry();
                compile(device, file, entry)
            })
            .collect();
        scope.pop()?;
        Ok(Self { kernels: built? })
    }

    pub(super) fn kernel(&self, kernel: SamplingKernel) -> &CompiledKernel {
        &self.kernels[kernel.index()]
    }

    /// Threads per workgroup of `kernel`, as its module declares.
    pub fn workgroup_size(&self, kernel: SamplingKernel) -> u32 {
        self.kernel(kernel).workgroup_size
    }
}

/// A compute pipeline of `file::entry`, uniforms bound with a dynamic offset.
pub(super) fn compile(
    device: &wgpu::Device,
    file: &str,
    entry: &str,
) -> Result<CompiledKernel, GpuError> {
    crate::support::compile(device, file, entry, true)
}
