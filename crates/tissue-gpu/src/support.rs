//! What every kernel family of this crate shares: compiling an entry point
//! with its bind group layout from naga's reflection, storage buffers
//! checked against the device's limits, and error scopes that turn wgpu's
//! errors into [`GpuError`]s.

use std::borrow::Cow;

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

/// A storage buffer holding `contents` (16 zero bytes when empty: a binding
/// may not be empty), or the limit it would break; `what` names it in the error.
pub(crate) fn storage_init(
    device: &wgpu::Device,
    label: &'static str,
    contents: &[u8],
    what: &str,
) -> Result<wgpu::Buffer, GpuError> {
    use wgpu::util::DeviceExt;
    let padded = [0u8; 16];
    let contents = if contents.is_empty() {
        &padded[..]
    } else {
        contents
    };
    check_size(device, contents.len() as u64, what)?;
    Ok(
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
        }),
    )
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
