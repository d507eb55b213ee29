//! The one place GPU tests get a device: from the environment
//! (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`). No adapter: the test reports
//! itself skipped, unless `CI=true`, where that is a failure.

#![allow(dead_code, reason = "each test binary uses a different part")]

use std::sync::OnceLock;

use tissue_core::ParticleModel;
use tissue_core::SamplingParams;

/// A device and queue, or `None` after printing "SKIPPED: no GPU adapter".
pub fn gpu(test: &str) -> Option<(wgpu::Device, wgpu::Queue)> {
    let adapter = adapter(test)?;
    Some(open(test, &adapter, tissue_gpu::limits_for(&adapter)))
}

/// [`gpu`]'s device with storage bindings of at most `bytes`: what a larger
/// device binds whole, this one has to split.
pub fn gpu_with_binding(test: &str, bytes: u64) -> Option<(wgpu::Device, wgpu::Queue)> {
    let adapter = adapter(test)?;
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: bytes,
        ..tissue_gpu::limits_for(&adapter)
    };
    Some(open(test, &adapter, limits))
}

fn adapter(test: &str) -> Option<wgpu::Adapter> {
    match tissue_gpu::adapter_from_env() {
        Ok(adapter) => {
            eprintln!("{test}: adapter {:?}", adapter.get_info());
            Some(adapter)
        }
        Err(tissue_gpu::GpuError::NoAdapter(why)) => {
            if std::env::var("CI").as_deref() == Ok("true") {
                panic!("{test}: no GPU adapter under CI=true ({why}); install Mesa lavapipe");
            }
            eprintln!("SKIPPED: no GPU adapter ({test}: {why})");
            None
        }
        Err(e) => panic!("{test}: no adapter: {e}"),
    }
}

fn open(test: &str, adapter: &wgpu::Adapter, limits: wgpu::Limits) -> (wgpu::Device, wgpu::Queue) {
    pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("tissue test"),
        required_limits: limits,
        ..Default::default()
    }))
    .unwrap_or_else(|e| panic!("{test}: the adapter would not open a device: {e}"))
}

/// The bundled phantom sampled to `n` particles (cached per size).
pub fn phantom(n: usize) -> &'static ParticleModel {
    static MODELS: OnceLock<std::sync::Mutex<Vec<(usize, &'static ParticleModel)>>> =
        OnceLock::new();
    let models = MODELS.get_or_init(Default::default);
    let mut models = models.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, m)) = models.iter().find(|(k, _)| *k == n) {
        return m;
    }
    let sampled = tissue_cpu::sample(
        &tissue_core::phantom::default_breast(),
        &SamplingParams::with_particles(n),
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("sampling the phantom at {n}: {e}"));
    let model: &'static ParticleModel = Box::leak(Box::new(sampled.model));
    models.push((n, model));
    model
}

/// Runs `entry` of the test-only shader `shader` (one of
/// `tissue_gpu::shaders::SHADERS`) once over a list: `inputs` at binding 0,
/// an output of `output_bytes` at binding 1, one thread an input. Returns
/// the output's bytes.
pub fn run_list_kernel<T: bytemuck::Pod>(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    (shader, entry): (&str, &str),
    inputs: &[T],
    output_bytes: u64,
) -> Vec<u8> {
    use wgpu::util::DeviceExt;
    let source = tissue_gpu::shaders::source(shader).unwrap_or_else(|e| panic!("{e}"));
    let module =
        tissue_gpu::shaders::module_from_source(shader, &source).unwrap_or_else(|e| panic!("{e}"));
    let [size, ..] =
        tissue_gpu::shaders::workgroup_size(&module, entry).unwrap_or_else(|e| panic!("{e}"));
    let shader_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(shader),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(shader),
        layout: None,
        module: &shader_module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    });
    let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("test inputs"),
        contents: bytemuck::cast_slice(inputs),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let output = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("test outputs"),
        size: output_bytes,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: input.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: output.as_entire_binding(),
            },
        ],
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.dispatch_workgroups((inputs.len() as u32).div_ceil(size), 1, 1);
    }
    queue.submit([encoder.finish()]);
    read(device, queue, &output)
}

/// Reads a whole buffer back through a staging copy.
pub fn read(device: &wgpu::Device, queue: &wgpu::Queue, buffer: &wgpu::Buffer) -> Vec<u8> {
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("test readback"),
        size: buffer.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, None);
    queue.submit([encoder.finish()]);
    staging.map_async(wgpu::MapMode::Read, .., |r| {
        if let Err(e) = r {
            panic!("map failed: {e}");
        }
    });
    if let Err(e) = device.poll(wgpu::PollType::wait_indefinitely()) {
        panic!("poll failed: {e}");
    }
    let bytes = match staging.get_mapped_range(..) {
        Ok(view) => view.to_vec(),
        Err(e) => panic!("mapped range: {e}"),
    };
    staging.unmap();
    bytes
}

/// The phantom's sag solved from rest by the GPU path with `params` and
/// by the CPU path as its twin (`GpuDeformer::cpu_twin`):
/// `(cpu, cpu report, gpu, gpu report)`.
pub fn solve_sag_on_both(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    model: &ParticleModel,
    params: tissue_cpu::deformation::DeformParams,
) -> (
    tissue_cpu::deformation::Deformer,
    tissue_cpu::deformation::DeformReport,
    tissue_gpu::GpuDeformer,
    tissue_cpu::deformation::DeformReport,
) {
    solve_on_both(
        device,
        queue,
        model,
        params,
        &tissue_core::deform::sagged_breast(),
    )
}

/// `model` solved for `deformed` from rest on the CPU (the GPU's twin
/// parameters) and on the GPU: both deformers and reports.
pub fn solve_on_both(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    model: &ParticleModel,
    params: tissue_cpu::deformation::DeformParams,
    deformed: &tissue_core::SurfaceMesh,
) -> (
    tissue_cpu::deformation::Deformer,
    tissue_cpu::deformation::DeformReport,
    tissue_gpu::GpuDeformer,
    tissue_cpu::deformation::DeformReport,
) {
    let mut cpu =
        tissue_cpu::deformation::Deformer::new(model, tissue_gpu::GpuDeformer::cpu_twin(&params))
            .unwrap_or_else(|e| panic!("{e}"));
    cpu.set_surface(deformed).unwrap_or_else(|e| panic!("{e}"));
    let cpu_report = cpu.solve();
    let mut gpu = tissue_gpu::GpuDeformer::new(device, queue, model, params)
        .unwrap_or_else(|e| panic!("{e}"));
    gpu.set_surface(deformed).unwrap_or_else(|e| panic!("{e}"));
    let gpu_report = gpu.solve().unwrap_or_else(|e| panic!("{e}"));
    (cpu, cpu_report, gpu, gpu_report)
}

/// Tells both devices' reports of a solve the tracker may have run again
/// (`elastic_retries`) or stepped back (`backtracks`), then asserts that
/// both converged after the same retries and steps back, every state
/// their elastic phases accepted lowering the potential, in the same
/// iterations within `within`, their positions within 1e-5 of the size of
/// each other. `context` names the case.
pub fn assert_same_retried_solve(
    (cpu, cpu_report, gpu, gpu_report): &(
        tissue_cpu::deformation::Deformer,
        tissue_cpu::deformation::DeformReport,
        tissue_gpu::GpuDeformer,
        tissue_cpu::deformation::DeformReport,
    ),
    within: usize,
    context: &str,
) {
    eprintln!(
        "{context}: CPU {} iterations, {} retries, {} steps back, {:?}; GPU {} iterations, \
         {} retries, {} steps back, {:?}",
        cpu_report.iterations,
        cpu_report.elastic_retries,
        cpu_report.backtracks,
        cpu_report.stopped_by,
        gpu_report.iterations,
        gpu_report.elastic_retries,
        gpu_report.backtracks,
        gpu_report.stopped_by
    );
    assert_eq!(
        (cpu_report.elastic_retries, cpu_report.backtracks),
        (gpu_report.elastic_retries, gpu_report.backtracks),
        "{context}"
    );
    assert!(
        cpu_report.potentials_fell() && gpu_report.potentials_fell(),
        "{context}: {:?} {:?}",
        cpu_report.potentials,
        gpu_report.potentials
    );
    assert!(cpu_report.converged && gpu_report.converged, "{context}");
    assert!(
        cpu_report.iterations.abs_diff(gpu_report.iterations) <= within,
        "{context}: CPU {} iterations, GPU {}",
        cpu_report.iterations,
        gpu_report.iterations
    );
    assert_same_positions(gpu, cpu, 1e-5, context);
}

/// Asserts that every position `gpu` holds lies within `fraction` of the
/// model's size of `cpu`'s; returns the worst distance, as a fraction of
/// the size. `context` names the case in a failure.
pub fn assert_same_positions(
    gpu: &tissue_gpu::GpuDeformer,
    cpu: &tissue_cpu::deformation::Deformer,
    fraction: f32,
    context: &str,
) -> f32 {
    let got = gpu.positions().unwrap_or_else(|e| panic!("{e}"));
    let tolerance = fraction * cpu.size();
    let mut worst = 0.0f32;
    for (i, (g, c)) in got.iter().zip(cpu.positions()).enumerate() {
        let off = g.distance(*c);
        worst = worst.max(off);
        assert!(
            off <= tolerance,
            "{context}, particle {i}: GPU {g} vs CPU {c}, distance {off:e} > {tolerance:e}"
        );
    }
    worst / cpu.size()
}
