//! The compiled kernels and the step that records them.

use crate::state::DeformState;
use crate::{GpuError, shaders};

/// One stage-2 kernel (a WGSL entry point).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// `local_rotations.wgsl`: `R_i` from `M_i` through the 3x3 SVD.
    LocalRotations,
    /// `deformation_force.wgsl`: the force, paper or symmetric.
    DeformationForce,
    /// `integrate.wgsl::integrate`: `q̂ = q + alpha F` into the plain buffer.
    Integrate,
    /// `step_norms.wgsl`: per-workgroup max and sum of `|q̂ − q|²`.
    StepNorms,
    /// `integrate.wgsl::chebyshev`: the Chebyshev combine; updates current and previous.
    Chebyshev,
}

impl Kernel {
    /// Every kernel, in the order of one iteration.
    pub const ALL: [Kernel; 5] = [
        Kernel::LocalRotations,
        Kernel::DeformationForce,
        Kernel::Integrate,
        Kernel::StepNorms,
        Kernel::Chebyshev,
    ];

    /// `(shader file, entry point)`.
    pub fn entry(self) -> (&'static str, &'static str) {
        match self {
            Kernel::LocalRotations => ("local_rotations", "local_rotations"),
            Kernel::DeformationForce => ("deformation_force", "deformation_force"),
            Kernel::Integrate => ("integrate", "integrate"),
            Kernel::StepNorms => ("step_norms", "step_norms"),
            Kernel::Chebyshev => ("integrate", "chebyshev"),
        }
    }
}

/// A compute pipeline with its bind group layout (group 0, from naga's
/// reflection of the module) and its workgroup size (from the module).
#[derive(Debug)]
pub(crate) struct CompiledKernel {
    pub(crate) pipeline: wgpu::ComputePipeline,
    pub(crate) layout: wgpu::BindGroupLayout,
    pub(crate) bindings: Vec<shaders::Binding>,
    pub(crate) workgroup_size: u32,
}

/// The compiled stage-2 kernels, one field per kernel, built once per device.
#[derive(Debug)]
pub struct Pipelines {
    pub(crate) local_rotations: CompiledKernel,
    pub(crate) deformation_force: CompiledKernel,
    pub(crate) integrate: CompiledKernel,
    pub(crate) step_norms: CompiledKernel,
    pub(crate) chebyshev: CompiledKernel,
}

impl Pipelines {
    /// Compiles every kernel for `device`; any wgpu error is returned, not panicked on.
    pub fn new(device: &wgpu::Device) -> Result<Self, GpuError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let built = (|| {
            Ok::<_, GpuError>(Self {
                local_rotations: compile(device, Kernel::LocalRotations)?,
                deformation_force: compile(device, Kernel::DeformationForce)?,
                integrate: compile(device, Kernel::Integrate)?,
                step_norms: compile(device, Kernel::StepNorms)?,
                chebyshev: compile(device, Kernel::Chebyshev)?,
            })
        })();
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(error.into());
        }
        built
    }

    pub(crate) fn kernel(&self, kernel: Kernel) -> &CompiledKernel {
        match kernel {
            Kernel::LocalRotations => &self.local_rotations,
            Kernel::DeformationForce => &self.deformation_force,
            Kernel::Integrate => &self.integrate,
            Kernel::StepNorms => &self.step_norms,
            Kernel::Chebyshev => &self.chebyshev,
        }
    }

    /// Threads per workgroup of `kernel`, as its module declares.
    pub fn workgroup_size(&self, kernel: Kernel) -> u32 {
        self.kernel(kernel).workgroup_size
    }

    /// Records one dispatch of `kernel` over every particle, with the
    /// parameters of `slot` (see [`DeformState::write_params`]).
    pub fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
    ) {
        self.dispatch_timed(encoder, state, kernel, slot, None);
    }

    /// [`Pipelines::dispatch`] in a pass of its own that writes `timestamps`
    /// at its start and end (the benchmark's per-kernel timing; the device
    /// must have been opened with `wgpu::Features::TIMESTAMP_QUERY`).
    pub fn dispatch_timed(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 2"),
            timestamp_writes: timestamps,
        });
        self.dispatch_in(&mut pass, state, kernel, slot);
    }

    fn dispatch_in(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
    ) {
        let compiled = self.kernel(kernel);
        let [x, y] = state.workgroups(kernel);
        pass.set_pipeline(&compiled.pipeline);
        pass.set_bind_group(0, state.bind_group(kernel), &[state.params_offset(slot)]);
        pass.dispatch_workgroups(x, y, 1);
    }

    /// The step: `iterations` solver iterations (at most [`crate::SLOTS`]),
    /// iteration `k` with the parameters of slot `k`, in one compute pass:
    /// rotations, force, plain step, its norms, Chebyshev combine.
    pub fn record_iterations(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        iterations: u32,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 2 iterations"),
            timestamp_writes: None,
        });
        for slot in 0..iterations.min(crate::SLOTS) {
            for kernel in Kernel::ALL {
                self.dispatch_in(&mut pass, state, kernel, slot);
            }
        }
    }
}

fn compile(device: &wgpu::Device, kernel: Kernel) -> Result<CompiledKernel, GpuError> {
    let (file, entry) = kernel.entry();
    crate::support::compile(device, file, entry, true)
}
