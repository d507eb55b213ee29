//! Structures and landmarks on the GPU: `embedding_moved.wgsl`, the twin of
//! `tissue_solve::model::embedding_moved`, run on a [`DeformState`]'s
//! positions and rotations where they are; only the moved points come back.
//!
//! A rigid structure (`tissue_solve::model::RigidBinding`) is its centre
//! carried like any point plus a 3x3 fit over 16 particles: the centre goes
//! through [`GpuEmbedding`], the 16 positions are a small read.

use glam::Vec3;
use tissue_solve::model::Embedding;

use crate::buffer::Storage;
use crate::pipelines::{KernelId, KernelSet};
use crate::readback::Readback;
use crate::state::{DeformState, workgroups};
use crate::support::{Scopes, scoped};
use crate::{GpuError, shaders};

/// Mirror of WGSL `Carrier` (`shaders/embedding_moved.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Carrier {
    /// The carrying particle.
    pub particle: u32,
    /// Its weight (0 for an unused slot).
    pub weight: f32,
}

/// Mirror of WGSL `EmbeddingParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct EmbeddingParams {
    /// Number of points.
    pub count: u32,
    /// Particles in the model.
    pub particles: u32,
    /// Carrier slots per point.
    pub carriers: u32,
    /// Padding to 16 bytes.
    pub _pad: u32,
}

/// The one kernel of the structures' family: `embedding_moved.wgsl`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EmbeddingMoved;

impl KernelId for EmbeddingMoved {
    const KERNELS: &'static [Self] = &[EmbeddingMoved];
    const DYNAMIC_UNIFORM: bool = false;

    fn entry(self) -> (&'static str, &'static str) {
        ("embedding_moved", "embedding_moved")
    }

    fn index(self) -> usize {
        0
    }
}

/// The compiled `embedding_moved` kernel, built once per device.
#[derive(Debug)]
pub struct EmbeddingKernel {
    kernel: KernelSet<EmbeddingMoved>,
    /// Carrier slots per point (`CARRIERS` in the shader).
    slots: usize,
}

impl EmbeddingKernel {
    /// Compiles the kernel for `device`.
    pub fn new(device: &wgpu::Device) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: KernelSet::new(device)?,
            slots: carrier_slots()?,
        })
    }
}

/// `CARRIERS` of `embedding_moved.wgsl`, read from the module.
fn carrier_slots() -> Result<usize, GpuError> {
    let module = shaders::module("embedding_moved")?;
    module
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some("CARRIERS"))
        .and_then(|(_, c)| match module.global_expressions[c.init] {
            naga::Expression::Literal(naga::Literal::U32(n)) => Some(n as usize),
            _ => None,
        })
        .ok_or_else(|| GpuError::Shader {
            name: "embedding_moved".into(),
            message: "no u32 constant CARRIERS".into(),
        })
}

/// An [`Embedding`]'s points and carriers on the GPU.
#[derive(Debug)]
pub struct GpuEmbedding {
    /// Number of points.
    count: u32,
    /// One [`EmbeddingParams`] (a uniform buffer: raw).
    params: wgpu::Buffer,
    /// The points where the rest positions place them (`vec4`, w unused).
    points: Storage<[f32; 4]>,
    /// Per point, its carrier slots.
    carriers: Storage<Carrier>,
    /// Per point, where the kernel moved it (`vec4`, w unused).
    moved: Storage<[f32; 4]>,
}

impl GpuEmbedding {
    /// Uploads `embedding`, bound to a model of `particles` particles.
    /// Errors when a point has more carriers than the kernel has slots, a
    /// carrier is not a particle of the model, or a buffer breaks a limit.
    pub fn new(
        device: &wgpu::Device,
        kernel: &EmbeddingKernel,
        embedding: &Embedding,
        particles: usize,
    ) -> Result<Self, GpuError> {
        let count = embedding.points.len();
        if embedding.carriers.len() != count {
            return Err(GpuError::Length {
                what: "carrier lists (one per embedded point)",
                expected: count,
                got: embedding.carriers.len(),
            });
        }
        let mut carriers = vec![Carrier::default(); count * kernel.slots];
        for (point, list) in embedding.carriers.iter().enumerate() {
            if list.len() > kernel.slots {
                return Err(GpuError::Length {
                    what: "carriers of one embedded point (at most the kernel's slots)",
                    expected: kernel.slots,
                    got: list.len(),
                });
            }
            for (slot, &(particle, weight)) in list.iter().enumerate() {
                if particle as usize >= particles {
                    return Err(GpuError::Length {
                        what: "particles of the model (a carrier's index is beyond them)",
                        expected: particles,
                        got: particle as usize + 1,
                    });
                }
                carriers[point * kernel.slots + slot] = Carrier { particle, weight };
            }
        }
        let to_u32 = |n: usize, what: &str| {
            u32::try_from(n).map_err(|_| GpuError::LimitExceeded {
                limit: "u32 index",
                what: what.to_owned(),
                asked: n as u64,
                allowed: u64::from(u32::MAX),
            })
        };
        let params = EmbeddingParams {
            count: to_u32(count, "the embedded point count")?,
            particles: to_u32(particles, "the particle count")?,
            carriers: kernel.slots as u32,
            _pad: 0,
        };
        let what = format!("an embedding of {count} points");
        scoped(device, || {
            use wgpu::util::DeviceExt;
            Ok(Self {
                count: params.count,
                points: Storage::points(device, "embedded points", &embedding.points, &what)?,
                carriers: Storage::init(device, "carriers", &carriers, &what)?,
                moved: Storage::zeroed(device, "moved points", count, &what)?,
                params: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("embedding params"),
                    contents: bytemuck::bytes_of(&params),
                    usage: wgpu::BufferUsages::UNIFORM,
                }),
            })
        })
    }

    /// Number of embedded points.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Where the points are for `state`'s current positions and rotations
    /// (the model `state` holds must be the one the embedding was made for).
    pub fn moved(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        kernel: &EmbeddingKernel,
        state: &DeformState,
    ) -> Result<Vec<Vec3>, GpuError> {
        if self.count == 0 {
            return Ok(Vec::new());
        }
        let compiled = kernel.kernel.kernel(EmbeddingMoved);
        let [x, y] = workgroups(
            self.count,
            compiled.workgroup_size,
            device.limits().max_compute_workgroups_per_dimension,
        )?;
        let scopes = Scopes::push(device);
        let buffers = [
            ("embedding", &self.params),
            ("points", self.points.buffer()),
            ("carriers", self.carriers.buffer()),
            ("rest", state.rest.buffer()),
            ("current", state.current.buffer()),
            ("rotations", state.rotations.buffer()),
            ("moved", self.moved.buffer()),
        ];
        let entries: Vec<wgpu::BindGroupEntry> = compiled
            .bindings
            .iter()
            .filter_map(|b| {
                let (_, buffer) = buffers.iter().find(|(name, _)| *name == b.name)?;
                Some(wgpu::BindGroupEntry {
                    binding: b.binding,
                    resource: buffer.as_entire_binding(),
                })
            })
            .collect();
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("embedding_moved"),
            layout: &compiled.layout,
            entries: &entries,
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("embedding_moved"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("embedding_moved"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&compiled.pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        queue.submit([encoder.finish()]);
        scopes.pop()?;
        self.moved.read_points(device, queue, &Readback::default())
    }
}
