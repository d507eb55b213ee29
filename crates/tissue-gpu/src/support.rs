//! What every kernel family of this crate shares: compiling an entry point
//! with its bind group layout from naga's reflection, bind groups built by
//! the WGSL variables' names, the device's limits on a storage buffer
//! (which [`crate::buffer::Storage`] checks), and error scopes that turn
//! wgpu's errors into [`GpuError`]s.

use std::borrow::Cow;
use std::num::NonZeroU64;

use crate::pipelines::CompiledKernel;
use crate::{GpuError, shaders};

/// Compiles entry point `entry` of shader file `file`. Group 0 binds exactly
/// the globals the entry point uses, as the module declares them; uniforms
/// take a dynamic offset when `dynamic_uniform`.
pub(crate) fn compile(
    device: &wgpu::Device,
    file: &str,
    entry: &str,
    dynamic_uniform: bool,
) -> Result<CompiledKernel, GpuError> {
    let source = shaders::source(file)?;
    let module = shaders::module_from_source(file, &source)?;
    let [workgroup_size, ..] = shaders::workgroup_size(&module, entry)?;
    let used = shaders::used_globals(&module, &source, entry)?;
    let bindings: Vec<shaders::Binding> = shaders::bindings(&module)
        .into_iter()
        .filter(|b| used.contains(&b.name))
        .collect();
    let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
        .iter()
        .map(|b| wgpu::BindGroupLayoutEntry {
            binding: b.binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: if b.uniform {
                    wgpu::BufferBindingType::Uniform
                } else {
                    wgpu::BufferBindingType::Storage {
                        read_only: b.read_only,
                    }
                },
                has_dynamic_offset: b.uniform && dynamic_uniform,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(entry),
        entries: &entries,
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(entry),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(file),
        source: wgpu::ShaderSource::Wgsl(Cow::Owned(source)),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(&pipeline_layout),
        module: &shader,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions::default(),
        cache: None,
    });
    Ok(CompiledKernel {
        pipeline,
        layout,
        bindings,
        workgroup_size,
    })
}

/// The bind group of `kernel`'s group 0, labelled `label`: each binding
/// gets the buffer `buffer` gives for its WGSL variable's name. A uniform
/// binds its first `uniform_size` bytes (the slot a dynamic offset selects),
/// or the whole buffer when `None`; storage always binds the whole buffer.
/// A name with no buffer is an error naming the kernel `name`, its message
/// "binding N `NAME` " followed by `missing`.
pub(crate) fn bind_group<'a>(
    device: &wgpu::Device,
    kernel: &CompiledKernel,
    (name, label): (&str, &str),
    buffer: impl Fn(&str) -> Option<&'a wgpu::Buffer>,
    uniform_size: Option<u64>,
    missing: &str,
) -> Result<wgpu::BindGroup, GpuError> {
    let mut entries = Vec::with_capacity(kernel.bindings.len());
    for b in &kernel.bindings {
        let buffer = buffer(&b.name).ok_or_else(|| GpuError::Shader {
            name: name.to_owned(),
            message: format!("binding {} `{}` {missing}", b.binding, b.name),
        })?;
        let size = if b.uniform {
            uniform_size.and_then(NonZeroU64::new)
        } else {
            None
        };
        entries.push(wgpu::BindGroupEntry {
            binding: b.binding,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer,
                offset: 0,
                size,
            }),
        });
    }
    Ok(device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &kernel.layout,
        entries: &entries,
    }))
}

/// An error naming the limit when a storage binding of `size` bytes is
/// larger than the device allows.
pub(crate) fn check_size(device: &wgpu::Device, size: u64, what: &str) -> Result<(), GpuError> {
    let limits = device.limits();
    for (limit, allowed) in [
        (
            "max_storage_buffer_binding_size",
            limits.max_storage_buffer_binding_size,
        ),
        ("max_buffer_size", limits.max_buffer_size),
    ] {
        if size > allowed {
            return Err(GpuError::LimitExceeded {
                limit,
                what: what.to_owned(),
                asked: size,
                allowed,
            });
        }
    }
    Ok(())
}

/// Validation and out-of-memory error scopes around a group of calls.
pub(crate) struct Scopes {
    memory: wgpu::ErrorScopeGuard,
    validation: wgpu::ErrorScopeGuard,
}

impl Scopes {
    /// Opens both scopes.
    pub(crate) fn push(device: &wgpu::Device) -> Self {
        let memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        Self { memory, validation }
    }

    /// Closes both; the first error caught, if any.
    pub(crate) fn pop(self) -> Result<(), GpuError> {
        let validation = pollster::block_on(self.validation.pop());
        let memory = pollster::block_on(self.memory.pop());
        match memory.or(validation) {
            Some(e) => Err(e.into()),
            None => Ok(()),
        }
    }
}

/// Runs `f` inside both scopes: the first wgpu error caught, else `f`'s result.
pub(crate) fn scoped<T>(
    device: &wgpu::Device,
    f: impl FnOnce() -> Result<T, GpuError>,
) -> Result<T, GpuError> {
    let scopes = Scopes::push(device);
    let out = f();
    scopes.pop()?;
    out
}

/// Test helper: the size of Rust mirror `$ty` and the offsets of its
/// `$field`s, in order, equal naga's layout of WGSL struct `$wgsl` in shader
/// `$file` ([`shaders::assert_layout`]).
#[cfg(test)]
macro_rules! assert_mirror {
    ($file:literal, $wgsl:literal, $ty:ty { $($field:ident),* $(,)? }) => {
        $crate::shaders::assert_layout(
            $file,
            $wgsl,
            ::std::mem::size_of::<$ty>(),
            &[$((stringify!($field), ::std::mem::offset_of!($ty, $field))),*],
        )
    };
}
#[cfg(test)]
pub(crate) use assert_mirror;

/// Submits one dispatch of `kernel` over `[x, y]` workgroups, its uniform
/// at dynamic offset 0, in a command buffer of its own (the one-off
/// kernels: stage 1's placement, the field query).
pub(crate) fn submit_one(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    kernel: &CompiledKernel,
    group: &wgpu::BindGroup,
    [x, y]: [u32; 2],
    label: &str,
) {
    let mut encoder =
        device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
    {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: None,
        });
        pass.set_pipeline(&kernel.pipeline);
        pass.set_bind_group(0, group, &[0]);
        pass.dispatch_workgroups(x, y, 1);
    }
    queue.submit([encoder.finish()]);
}
