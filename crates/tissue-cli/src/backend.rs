//! `--backend auto|gpu|cpu`: where stage 2 runs, and for `tissue sample`
//! where stage 1's iterations run. [`Device::pick`] chooses once per
//! command; [`Solver`] hides which one was chosen from `deform`, `track` and
//! `demo`. `demo` samples on the CPU.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use glam::Vec3;
use tissue::{ParticleModel, SurfaceMesh};
use tissue_cpu::deformation::{DeformParams, DeformReport, Deformer};
use tissue_cpu::structures::Embedding;
use tissue_gpu::{EmbeddingKernel, GpuDeformer, GpuEmbedding, GpuError};

/// Where stage 2 runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// A hardware GPU when there is one, otherwise the CPU (a software
    /// adapter such as lavapipe is slower than the CPU path).
    Auto,
    /// The GPU adapter `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` name, or the
    /// default one; an error when there is none. Rotations by SVD (see
    /// `GpuDeformer`).
    Gpu,
    /// The CPU path.
    Cpu,
}

/// The `--backend` option shared by `deform`, `track` and `demo`.
#[derive(Debug, clap::Args)]
pub struct BackendArgs {
    /// Where stage 2 (the deformation) runs: `gpu` through wgpu (honours
    /// WGPU_BACKEND and WGPU_ADAPTER_NAME), `cpu`, or `auto` (a hardware GPU
    /// when there is one, else the CPU). Stage 1 (sampling) always runs on the CPU.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
}

/// The chosen device: the CPU, or an opened GPU.
#[derive(Debug)]
pub enum Device {
    /// The CPU path.
    Cpu,
    /// A GPU device and its queue.
    Gpu {
        /// The adapter's name and graphics backend, e.g. `NVIDIA H100, Vulkan`.
        name: String,
        /// The device.
        device: wgpu::Device,
        /// Its queue.
        queue: wgpu::Queue,
    },
}

/// Whether `info` is a hardware GPU (not a software rasteriser like lavapipe).
fn is_hardware(info: &wgpu::AdapterInfo) -> bool {
    matches!(
        info.device_type,
        wgpu::DeviceType::DiscreteGpu
            | wgpu::DeviceType::IntegratedGpu
            | wgpu::DeviceType::VirtualGpu
    )
}

/// `name, Vulkan`.
fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{}, {:?}", info.name, info.backend)
}

impl Device {
    /// Chooses where stage 2 runs and, unless `quiet`, prints one line
    /// saying which backend was taken and why (`auto` and `gpu` only).
    pub fn pick(backend: Backend, quiet: bool) -> Result<Self> {
        let say = |line: String| {
            if !quiet {
                println!("{line}");
            }
        };
        match backend {
            Backend::Cpu => Ok(Self::Cpu),
            Backend::Gpu => {
                let (adapter, device, queue) =
                    tissue_gpu::device_from_env().context("--backend gpu")?;
                let name = describe(&adapter.get_info());
                say(format!("backend: gpu ({name}; asked for by --backend gpu)"));
                Ok(Self::Gpu {
                    name,
                    device,
                    queue,
                })
            }
            Backend::Auto => {
                let (device, why) = Self::auto();
                match &device {
                    Self::Cpu => say(format!("backend: cpu ({why})")),
                    Self::Gpu { name, .. } => say(format!("backend: gpu ({name}; {why})")),
                }
                Ok(device)
            }
        }
    }

    /// `--backend auto`: the best hardware adapter among those the
    /// environment allows, else the CPU; and why.
    fn auto() -> (Self, String) {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle().with_env());
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        if let Ok(wanted) = std::env::var("WGPU_ADAPTER_NAME") {
            let wanted = wanted.to_lowercase();
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(&wanted));
        }
        let rank = |a: &wgpu::Adapter| match a.get_info().device_type {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            _ => 3,
        };
        adapters.sort_by_key(rank);
        // One adapter may be listed once per graphics backend (Vulkan, GL).
        let mut software: Vec<String> = Vec::new();
        for info in adapters.iter().map(wgpu::Adapter::get_info) {
            if !is_hardware(&info) && !software.contains(&info.name) {
                software.push(info.name);
            }
        }
        let Some(adapter) = adapters.into_iter().find(|a| is_hardware(&a.get_info())) else {
            let why = match software.as_slice() {
                [] => "no GPU adapter found".to_owned(),
                [one] => format!(
                    "the only GPU adapter is {one}, a software device slower than the CPU path"
                ),
                many => format!(
                    "the GPU adapters ({}) are software devices slower than the CPU path",
                    many.join("; ")
                ),
            };
            return (Self::Cpu, why);
        };
        let info = adapter.get_info();
        let name = describe(&info);
        let opened = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("tissue"),
            required_limits: wgpu::Limits::default(),
            ..Default::default()
        }));
        match opened {
            Ok((device, queue)) => (
                Self::Gpu {
                    name,
                    device,
                    queue,
                },
                format!("a hardware GPU, {:?}", info.device_type),
            ),
            Err(e) => (Self::Cpu, format!("{name} refused a device: {e}")),
        }
    }
}

/// Stage 2 on the chosen device, with the positions of the last solve at
/// hand on the host (read back once per solve, a frame boundary). Structures
/// and landmarks are carried where the particles are: on the GPU, by
/// `embedding_moved.wgsl`, reading back only the moved points.
#[derive(Debug)]
pub enum Solver {
    /// The CPU path.
    Cpu(Box<Deformer>),
    /// The GPU path.
    Gpu(Box<GpuSolver>),
}

/// The GPU half of [`Solver`].
#[derive(Debug)]
pub struct GpuSolver {
    name: String,
    device: wgpu::Device,
    queue: wgpu::Queue,
    deformer: GpuDeformer,
    embedding: EmbeddingKernel,
    rest: Vec<Vec3>,
    /// Read back after each solve.
    current: Vec<Vec3>,
}

/// Points bound to the particles, ready to be carried on the solver's device.
#[derive(Debug)]
pub struct Carrier {
    embedding: Embedding,
    gpu: Option<GpuEmbedding>,
}

impl Carrier {
    /// The points at rest.
    pub fn rest(&self) -> &[Vec3] {
        &self.embedding.points
    }
}

impl Solver {
    /// Prepares stage 2 for `model` on `device`.
    pub fn new(device: Device, model: &ParticleModel, params: DeformParams) -> Result<Self> {
        Ok(match device {
            Device::Cpu => Self::Cpu(Box::new(Deformer::new(model, params)?)),
            Device::Gpu {
                name,
                device,
                queue,
            } => {
                let deformer = GpuDeformer::new(&device, &queue, model, params)?;
                let embedding = EmbeddingKernel::new(&device)?;
                Self::Gpu(Box::new(GpuSolver {
                    name,
                    device,
                    queue,
                    deformer,
                    embedding,
                    rest: model.positions.clone(),
                    current: model.positions.clone(),
                }))
            }
        })
    }

    /// `cpu`, or the GPU adapter's name and graphics backend (for the reports).
    pub fn backend(&self) -> String {
        match self {
            Self::Cpu(_) => "cpu".to_owned(),
            Self::Gpu(gpu) => gpu.name.clone(),
        }
    }

    /// Places the control points on `deformed`, the rest surface with moved vertices.
    pub fn set_surface(&mut self, deformed: &SurfaceMesh) -> Result<()> {
        match self {
            Self::Cpu(cpu) => cpu.set_surface(deformed)?,
            Self::Gpu(gpu) => gpu.deformer.set_surface(&gpu.queue, deformed)?,
        }
        Ok(())
    }

    /// Solves, and on the GPU reads the positions back.
    pub fn solve(&mut self) -> Result<DeformReport> {
        match self {
            Self::Cpu(cpu) => Ok(cpu.solve()),
            Self::Gpu(gpu) => {
                let read = |gpu: &mut GpuSolver| -> Result<DeformReport, GpuError> {
                    let report = gpu.deformer.solve(&gpu.device, &gpu.queue)?;
                    gpu.current = gpu.deformer.host_positions().to_vec();
                    Ok(report)
                };
                read(gpu).with_context(|| format!("stage 2 on {}", gpu.name))
            }
        }
    }

    /// Back to the rest shape.
    pub fn reset(&mut self) -> Result<()> {
        match self {
            Self::Cpu(cpu) => cpu.reset(),
            Self::Gpu(gpu) => {
                gpu.deformer.reset(&gpu.device, &gpu.queue)?;
                gpu.current.clone_from(&gpu.rest);
            }
        }
        Ok(())
    }

    /// Rest particle positions.
    pub fn rest(&self) -> &[Vec3] {
        match self {
            Self::Cpu(cpu) => cpu.rest(),
            Self::Gpu(gpu) => &gpu.rest,
        }
    }

    /// Particle positions after the last solve.
    pub fn positions(&self) -> &[Vec3] {
        match self {
            Self::Cpu(cpu) => cpu.positions(),
            Self::Gpu(gpu) => &gpu.current,
        }
    }

    /// Binds `points` (rest coordinates) to the rest particles, and on the
    /// GPU uploads the binding.
    pub fn bind(&self, points: &[Vec3]) -> Result<Carrier> {
        let embedding = Embedding::new(self.rest(), points);
        let gpu = match self {
            Self::Cpu(_) => None,
            Self::Gpu(gpu) => Some(
                GpuEmbedding::new(&gpu.device, &gpu.embedding, &embedding, gpu.rest.len())
                    .with_context(|| format!("binding points on {}", gpu.name))?,
            ),
        };
        Ok(Carrier { embedding, gpu })
    }

    /// Where `carrier`'s points are after the last solve.
    pub fn carry(&self, carrier: &Carrier) -> Result<Vec<Vec3>> {
        match (self, &carrier.gpu) {
            (Self::Gpu(gpu), Some(on_gpu)) => on_gpu
                .moved(
                    &gpu.device,
                    &gpu.queue,
                    &gpu.embedding,
                    gpu.deformer.state(),
                )
                .with_context(|| format!("carrying points on {}", gpu.name)),
            (Self::Cpu(cpu), None) => {
                Ok(carrier
                    .embedding
                    .moved(cpu.rest(), cpu.positions(), cpu.rotations()))
            }
            _ => bail!("points bound for one backend were carried by another"),
        }
    }
}
