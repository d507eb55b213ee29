//! The buffers of one stage-1 run: the mirror of the WGSL uniforms, one
//! slot per iteration of a batch, and the particle, contact, force, row and
//! convergence buffers the kernels bind, with the recording of a batch.

use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec4};
use tissue_core::Attachment;
use tissue_core::field::SurfaceField;
use tissue_core::{SamplingParams, SurfaceMode};
use tissue_solve::stage1::{ForceOut, SKIN_IN_R0, SamplingState};

use super::field::FieldBuffers;
use super::kernels::{SamplingKernel, SamplingPipelines};
use crate::GpuError;
use crate::buffer::{Storage, vec4, xyz};
use crate::grid::GpuRows;
use crate::readback::Readback;
use crate::state::workgroups;
use crate::support::{bind_group, scoped, submit_one};

/// Iterations one command buffer records: one uniform slot and one row of
/// change partials each.
pub const BATCH: u32 = 16;

/// Mirror of WGSL `Sampling` (`shaders/shared/sampling.wgsl`): one
/// iteration's parameters, one slot per iteration of a batch.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SamplingUniforms {
    /// Field grid corner (xyz) and cell edge (w).
    pub field_origin: [f32; 4],
    /// Field cells along x, y, z; w the triangle count.
    pub field_dims: [u32; 4],
    /// Where `field_cells` holds the CSR starts, candidates and candidate distances.
    pub field_layout: [u32; 4],
    /// Number of particles.
    pub count: u32,
    /// 0 projection, 1 paper force.
    pub surface_mode: u32,
    /// 1 when the wall counts in the compression.
    pub wall_in_compression: u32,
    /// Row of the partials `change` writes.
    pub slot: u32,
    /// Workgroups of a dispatch, the length of a partials row.
    pub groups: u32,
    /// `alpha` of eq. (4).
    pub alpha: f32,
    /// Force cutoff in `r_i + r_j`.
    pub cutoff: f32,
    /// `mu` of eq. (2).
    pub mu: f32,
    /// Ideal compression, eq. (7).
    pub ideal: f32,
    /// `eta` of eq. (8).
    pub eta: f32,
    /// `exp(max_log_radius_step)`.
    pub radius_bound: f32,
    /// `1 / radius_bound`.
    pub radius_bound_inv: f32,
    /// `r0 / m~`.
    pub step_scale: f32,
    /// `max_step r0`.
    pub max_step: f32,
    /// `m~`.
    pub mass: f32,
    /// Initial radius.
    pub r0: f32,
    /// Half the Verlet skin.
    pub half_skin: f32,
    /// Entries of the neighbour rows the `neighbours` binding holds
    /// ([`crate::grid::row_split`]); the rest follow the row starts in `offsets`.
    pub row_split: u32,
    /// Particles within `surface_band r` of the surface are placed on it.
    pub surface_band: f32,
    /// The field's margin (`SurfaceField::margin`).
    pub field_margin: f32,
}

impl SamplingUniforms {
    /// The parameters for `count` particles of initial radius `r0` on
    /// `field`, derived values computed as the CPU twins compute them, with
    /// rows split at `row_split` entries.
    pub fn new(
        field: &FieldBuffers,
        params: &SamplingParams,
        r0: f32,
        count: u32,
        row_split: u32,
    ) -> Self {
        let bound = params.max_log_radius_step.exp();
        let (surface_mode, mu) = match params.surface_mode {
            SurfaceMode::Projection => (0, 0.0),
            SurfaceMode::PaperForce { mu } => (1, mu),
        };
        Self {
            field_origin: field.origin,
            field_dims: field.dims,
            field_layout: field.layout,
            count,
            surface_mode,
            wall_in_compression: u32::from(params.wall_in_compression),
            slot: 0,
            groups: 1,
            alpha: params.alpha,
            cutoff: params.force_cutoff,
            mu,
            ideal: params.ideal_compression(),
            eta: params.eta,
            radius_bound: bound,
            radius_bound_inv: 1.0 / bound,
            step_scale: r0 / params.mass,
            max_step: params.max_step * r0,
            mass: params.mass,
            r0,
            half_skin: 0.5 * (SKIN_IN_R0 * r0),
            row_split,
            surface_band: params.surface_band,
            field_margin: field.margin,
        }
    }
}

/// A storage buffer holding `contents` ([`Storage::init`]); `what` says
/// what it serves in the error.
pub(super) fn storage<T: Pod>(
    device: &wgpu::Device,
    label: &'static str,
    contents: &[T],
    what: &dyn Fn() -> String,
) -> Result<Storage<T>, GpuError> {
    Storage::init(
        device,
        label,
        contents,
        &format!("the {label} buffer ({})", what()),
    )
}

/// A storage buffer of `len` zeroed elements ([`Storage::zeroed`]); `what`
/// says what it serves in the error.
pub(super) fn zeroed<T: Pod>(
    device: &wgpu::Device,
    label: &'static str,
    len: usize,
    what: &dyn Fn() -> String,
) -> Result<Storage<T>, GpuError> {
    Storage::zeroed(
        device,
        label,
        len,
        &format!("the {label} buffer ({})", what()),
    )
}

/// The buffers of one stage-1 run. States and contacts come in pairs used in
/// turn: an iteration of parity `p` reads `states[p]`, `contacts[p]` and
/// writes `states[1 - p]`, `contacts[1 - p]`.
#[derive(Debug)]
pub struct SamplingBuffers {
    /// Number of particles.
    pub(super) count: u32,
    /// Bytes from one uniform slot to the next.
    uniforms_stride: u64,
    /// [`BATCH`] [`SamplingUniforms`], `uniforms_stride` apart (a uniform
    /// buffer: raw, as its slots sit at the dynamic offset alignment).
    uniforms: wgpu::Buffer,
    /// The two particle states: xyz position, w radius.
    pub(super) states: [Storage<[f32; 4]>; 2],
    /// The two contact arrays (`vec4` each).
    pub(super) contacts: [Storage<[f32; 4]>; 2],
    /// Per particle: xyz force, w compression.
    forces: Storage<[f32; 4]>,
    /// The neighbour rows' starts (`count + 1` u32), then their entries from
    /// `row_split` on, if any (raw, as [`SamplingBuffers::set_row_buffers`]
    /// takes rows built elsewhere).
    offsets: wgpu::Buffer,
    /// The neighbour rows' entries below `row_split` (u32; raw, likewise).
    neighbours: wgpu::Buffer,
    /// Entries `neighbours` holds at most ([`crate::grid::row_split`]).
    row_split: u32,
    /// 0, or the slot + 1 of the first iteration that needed a rebuild.
    halt: Storage<u32>,
    /// Per slot, per `change` workgroup: its share of the change sums (`vec4`).
    partials: Storage<[f32; 4]>,
    /// The state the neighbour rows were built from.
    built: Storage<[f32; 4]>,
    /// The surface field.
    field: FieldBuffers,
    /// Workgroups `[x, y]` per kernel, in [`SamplingKernel::ALL`] order.
    workgroups: [[u32; 2]; 5],
    /// Length of a partials row (workgroups of `change`).
    change_groups: u32,
    /// Per kernel, per parity.
    bind_groups: Vec<[wgpu::BindGroup; 2]>,
    /// The staging buffer of the change read back every batch.
    readback: Readback,
}

/// The triangle of an interior particle in `sampling_place.wgsl`'s output.
const NOT_ATTACHED: u32 = u32::MAX;

/// A particle's attachment as `sampling_place.wgsl` writes it: the
/// triangle ([`NOT_ATTACHED`] inside), the barycentric coordinates' bits.
type Attached = [u32; 4];

/// Stage 1's surface placement done on the GPU ([`SamplingBuffers::placement`]).
#[derive(Debug)]
pub struct Placement {
    /// Every particle's position, surface particles on the surface.
    pub positions: Vec<Vec3>,
    /// Where each surface particle is attached (`None` inside).
    pub attachments: Vec<Option<Attachment>>,
    /// The placed particles on the GPU (`vec4`: position, radius), the
    /// connections' input.
    pub(super) placed: Storage<[f32; 4]>,
}

/// Particles as the kernels hold them: xyz the position, w from `w`.
pub(super) fn vec4s(positions: &[Vec3], w: &[f32]) -> Vec<[f32; 4]> {
    positions.iter().zip(w).map(|(&p, &w)| vec4(p, w)).collect()
}

impl SamplingBuffers {
    /// Uploads `field` and `state` (into parity 0, which is also the
    /// rows' build state) for particles of initial radius `r0`, and binds
    /// them to `pipelines`' kernels. The neighbour rows start empty: set
    /// them with [`SamplingBuffers::set_rows`] or [`SamplingBuffers::set_row_buffers`].
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &SamplingPipelines,
        field: &SurfaceField,
        state: &SamplingState,
        params: &SamplingParams,
        r0: f32,
    ) -> Result<Self, GpuError> {
        let n = state.positions.len();
        for (what, got) in [
            ("radii (one per particle)", state.radii.len()),
            ("contacts (one per particle)", state.contact.len()),
        ] {
            if got != n {
                return Err(GpuError::Length {
                    what,
                    expected: n,
                    got,
                });
            }
        }
        let count = u32::try_from(n)
            .ok()
            .filter(|&c| c > 0 && c < u32::MAX)
            .ok_or(GpuError::Length {
                what: "particles (at least one, below u32::MAX)",
                expected: 1,
                got: n,
            })?;
        let limits = device.limits();
        let mut workgroups_of = [[0u32; 2]; 5];
        for kernel in SamplingKernel::ALL {
            workgroups_of[kernel.index()] = workgroups(
                count,
                pipelines.workgroup_size(kernel),
                limits.max_compute_workgroups_per_dimension,
            )?;
        }
        let row_split = crate::grid::row_split(&limits);
        let [cx, cy] = workgroups_of[SamplingKernel::Change.index()];
        let change_groups = cx * cy;
        let uniforms_stride = u64::from(limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<SamplingUniforms>() as u64);
        let field = FieldBuffers::new(device, field)?;
        let what = || format!("{n} particles");
        let current = vec4s(&state.positions, &state.radii);
        let contact: Vec<[f32; 4]> = state.contact.iter().map(|c| c.to_array()).collect();
        let partials = (BATCH * change_groups) as usize;
        let (states, contacts, forces, offsets, neighbours, halt, partials, built) =
            scoped(device, || {
                Ok((
                    [
                        storage(device, "state 0", &current, &what)?,
                        storage(device, "state 1", &current, &what)?,
                    ],
                    [
                        storage(device, "contact 0", &contact, &what)?,
                        storage(device, "contact 1", &contact, &what)?,
                    ],
                    zeroed(device, "forces", n, &what)?,
                    storage(device, "offsets", &vec![0u32; n + 1], &what)?.into_buffer(),
                    storage::<u32>(device, "neighbours", &[], &what)?.into_buffer(),
                    zeroed(device, "halt", 1, &what)?,
                    zeroed(device, "partials", partials, &what)?,
                    storage(device, "built", &current, &what)?,
                ))
            })?;
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("sampling uniforms"),
            size: uniforms_stride * u64::from(BATCH),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut buffers = Self {
            count,
            uniforms_stride,
            uniforms,
            states,
            contacts,
            forces,
            offsets,
            neighbours,
            row_split,
            halt,
            partials,
            built,
            field,
            workgroups: workgroups_of,
            change_groups,
            bind_groups: Vec::new(),
            readback: Readback::default(),
        };
        let mut uniforms = SamplingUniforms::new(&buffers.field, params, r0, count, row_split);
        uniforms.groups = change_groups;
        for slot in 0..BATCH {
            uniforms.slot = slot;
            queue.write_buffer(
                &buffers.uniforms,
                u64::from(slot) * uniforms_stride,
                bytemuck::bytes_of(&uniforms),
            );
        }
        buffers.bind(device, pipelines)?;
        Ok(buffers)
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// Always false: the buffers hold at least one particle.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The buffer bound to the WGSL variable `name` in an iteration of `parity`.
    fn buffer(&self, name: &str, parity: usize) -> Option<&wgpu::Buffer> {
        Some(match name {
            "sampling" => &self.uniforms,
            "current" => self.states[parity].buffer(),
            "next" => self.states[1 - parity].buffer(),
            "contact" => self.contacts[parity].buffer(),
            "contact_next" => self.contacts[1 - parity].buffer(),
            "forces" => self.forces.buffer(),
            "offsets" => &self.offsets,
            "neighbours" => &self.neighbours,
            "halt" => self.halt.buffer(),
            "partials" => self.partials.buffer(),
            "built" => self.built.buffer(),
            "field_cells" => self.field.cells.buffer(),
            "field_triangles" => self.field.triangles.buffer(),
            _ => return None,
        })
    }

    fn bind(
        &mut self,
        device: &wgpu::Device,
        pipelines: &SamplingPipelines,
    ) -> Result<(), GpuError> {
        let groups = scoped(device, || {
            SamplingKernel::ALL
                .into_iter()
                .map(|kernel| {
                    let group = |parity| {
                        bind_group(
                            device,
                            pipelines.kernel(kernel),
                            kernel.entry(),
                            |name| self.buffer(name, parity),
                            Some(std::mem::size_of::<SamplingUniforms>() as u64),
                            "names no stage-1 buffer",
                        )
                    };
                    Ok([group(0)?, group(1)?])
                })
                .collect::<Result<Vec<_>, GpuError>>()
        })?;
        self.bind_groups = groups;
        Ok(())
    }

    /// Uploads neighbour rows (CSR, as `tissue_solve::stage1::neighbour_rows` returns them).
    pub fn set_rows(
        &mut self,
        device: &wgpu::Device,
        pipelines: &SamplingPipelines,
        offsets: &[u32],
        neighbours: &[u32],
    ) -> Result<(), GpuError> {
        if offsets.len() != self.len() + 1 {
            return Err(GpuError::Length {
                what: "row offsets (particles + 1)",
                expected: self.len() + 1,
                got: offsets.len(),
            });
        }
        let last = offsets.last().copied().unwrap_or(0) as usize;
        if last != neighbours.len() {
            return Err(GpuError::Length {
                what: "neighbour indices (the last row offset)",
                expected: last,
                got: neighbours.len(),
            });
        }
        let what = || format!("{} particles", self.len());
        // Entries past one binding follow the row starts, as the GPU's rows keep them.
        let (low, high) = neighbours.split_at(neighbours.len().min(self.row_split as usize));
        let starts: Vec<u32> = offsets.iter().chain(high).copied().collect();
        let (o, i) = scoped(device, || {
            Ok((
                storage(device, "offsets", &starts, &what)?,
                storage(device, "neighbours", low, &what)?,
            ))
        })?;
        self.offsets = o.into_buffer();
        self.neighbours = i.into_buffer();
        self.bind(device, pipelines)
    }

    /// Takes neighbour rows already on the GPU, as a GPU grid builds them
    /// ([`crate::GridPipelines::neighbour_rows`]).
    pub fn set_row_buffers(
        &mut self,
        device: &wgpu::Device,
        pipelines: &SamplingPipelines,
        rows: GpuRows,
    ) -> Result<(), GpuError> {
        for (what, expected, got) in [
            ("neighbour rows (one per particle)", self.count, rows.count),
            (
                "neighbour-row entries in one binding (rows built on another device?)",
                self.row_split,
                rows.split,
            ),
        ] {
            if got != expected {
                return Err(GpuError::Length {
                    what,
                    expected: expected as usize,
                    got: got as usize,
                });
            }
        }
        self.offsets = rows.offsets;
        self.neighbours = rows.indices;
        self.bind(device, pipelines)
    }

    /// Overwrites the state of `parity` (tests, or a fresh start).
    pub fn write_state(
        &self,
        queue: &wgpu::Queue,
        parity: usize,
        state: &SamplingState,
    ) -> Result<(), GpuError> {
        for (what, got) in [
            ("positions", state.positions.len()),
            ("radii", state.radii.len()),
            ("contacts", state.contact.len()),
        ] {
            if got != self.len() {
                return Err(GpuError::Length {
                    what,
                    expected: self.len(),
                    got,
                });
            }
        }
        let parity = parity & 1;
        self.states[parity].write(queue, 0, &vec4s(&state.positions, &state.radii))?;
        let contact: Vec<[f32; 4]> = state.contact.iter().map(|c| c.to_array()).collect();
        self.contacts[parity].write(queue, 0, &contact)
    }

    /// Overwrites the forces (tests of `radius_update` and `integrate`).
    pub fn write_forces(&self, queue: &wgpu::Queue, forces: &[ForceOut]) -> Result<(), GpuError> {
        if forces.len() != self.len() {
            return Err(GpuError::Length {
                what: "forces",
                expected: self.len(),
                got: forces.len(),
            });
        }
        let data: Vec<[f32; 4]> = forces
            .iter()
            .map(|f| vec4(f.force, f.compression))
            .collect();
        self.forces.write(queue, 0, &data)
    }

    /// Reads the state of `parity` back (stalls until the GPU is done).
    pub fn read_state(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        parity: usize,
    ) -> Result<SamplingState, GpuError> {
        let parity = parity & 1;
        let once = Readback::default();
        let states = self.states[parity].read(device, queue, &once)?;
        let contact = self.contacts[parity].read(device, queue, &once)?;
        Ok(SamplingState {
            positions: states.iter().map(|&s| xyz(s)).collect(),
            radii: states.iter().map(|s| s[3]).collect(),
            contact: contact.into_iter().map(Vec4::from_array).collect(),
        })
    }

    /// Reads the last forces back.
    pub fn read_forces(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<ForceOut>, GpuError> {
        let forces = self.forces.read(device, queue, &Readback::default())?;
        Ok(forces
            .into_iter()
            .map(|f| ForceOut {
                force: xyz(f),
                compression: f[3],
            })
            .collect())
    }

    /// Records, in one compute pass, `kernels` of iteration `slot` on the state
    /// of `parity`.
    pub fn record(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipelines: &SamplingPipelines,
        kernels: &[SamplingKernel],
        slot: u32,
        parity: usize,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 1"),
            timestamp_writes: None,
        });
        self.record_in(&mut pass, pipelines, kernels, slot, parity);
    }

    fn record_in(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        pipelines: &SamplingPipelines,
        kernels: &[SamplingKernel],
        slot: u32,
        parity: usize,
    ) {
        let offset = (u64::from(slot.min(BATCH - 1)) * self.uniforms_stride) as u32;
        for &kernel in kernels {
            let [x, y] = self.workgroups[kernel.index()];
            pass.set_pipeline(&pipelines.kernel(kernel).pipeline);
            pass.set_bind_group(0, &self.bind_groups[kernel.index()][parity & 1], &[offset]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }

    /// Records `iterations` (at most [`BATCH`]) full iterations from the
    /// state of `parity`, iteration `k` in slot `k`, after clearing the halt
    /// flag: force, radius, move, change, rebuild check.
    pub fn record_iterations(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipelines: &SamplingPipelines,
        iterations: u32,
        parity: usize,
    ) {
        encoder.clear_buffer(self.halt.buffer(), 0, None);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 1 iterations"),
            timestamp_writes: None,
        });
        for slot in 0..iterations.min(BATCH) {
            self.record_in(
                &mut pass,
                pipelines,
                &SamplingKernel::ALL,
                slot,
                parity + slot as usize,
            );
        }
    }

    /// Stage 1's surface placement of the state of `parity` on the GPU
    /// (`shaders/sampling_place.wgsl`, the twin of
    /// `tissue_solve::stage1::place_surface_particles`), read back; the
    /// placed particles stay on the GPU for the connections as well.
    pub fn placement(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        parity: usize,
    ) -> Result<Placement, GpuError> {
        let (placed, attached) = self.place_surface(device, queue, parity)?;
        let once = Readback::default();
        let positions = placed
            .read(device, queue, &once)?
            .into_iter()
            .map(xyz)
            .collect();
        let attachments = attached
            .read(device, queue, &once)?
            .into_iter()
            .map(|[triangle, b0, b1, b2]| {
                (triangle != NOT_ATTACHED).then(|| Attachment {
                    triangle,
                    barycentric: [f32::from_bits(b0), f32::from_bits(b1), f32::from_bits(b2)],
                })
            })
            .collect();
        Ok(Placement {
            positions,
            attachments,
            placed,
        })
    }

    /// [`SamplingBuffers::placement`]'s dispatch: the placed particles
    /// (`vec4`: position, radius) and per particle `[triangle, barycentric
    /// bits]`. Submits the work and returns without waiting.
    fn place_surface(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        parity: usize,
    ) -> Result<(Storage<[f32; 4]>, Storage<Attached>), GpuError> {
        let n = self.len();
        let what = || format!("{n} particles");
        scoped(device, || {
            let kernel = super::kernels::compile(device, "sampling_place", "place_surface")?;
            let placed: Storage<[f32; 4]> = zeroed(device, "placed", n, &what)?;
            let attached: Storage<Attached> = zeroed(device, "attached", n, &what)?;
            let group = bind_group(
                device,
                &kernel,
                ("sampling_place", "surface placement"),
                |name| match name {
                    "placed" => Some(placed.buffer()),
                    "attached" => Some(attached.buffer()),
                    _ => self.buffer(name, parity & 1),
                },
                Some(std::mem::size_of::<SamplingUniforms>() as u64),
                "names no stage-1 buffer",
            )?;
            let [x, y] = workgroups(
                self.count,
                kernel.workgroup_size,
                device.limits().max_compute_workgroups_per_dimension,
            )?;
            submit_one(device, queue, &kernel, &group, [x, y], "sampling placement");
            Ok((placed, attached))
        })
    }

    /// Reads the change partials of the first `slots` slots and the halt flag
    /// (0, or the slot + 1 of the first iteration that needed a rebuild). Per
    /// slot: (sum of squared free steps, free particles, sum of ln² r change), f64.
    pub fn read_change(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        slots: u32,
    ) -> Result<(Vec<[f64; 3]>, u32), GpuError> {
        let row = self.change_groups as usize;
        let rows = slots.min(BATCH) as usize;
        let all = self
            .partials
            .read_first(device, queue, &self.readback, rows * row)?;
        let sums = all
            .chunks(row.max(1))
            .map(|r| {
                r.iter().fold([0.0f64; 3], |a, x| {
                    [
                        a[0] + f64::from(x[0]),
                        a[1] + f64::from(x[1]),
                        a[2] + f64::from(x[2]),
                    ]
                })
            })
            .collect();
        let halt = self
            .halt
            .read(device, queue, &self.readback)?
            .first()
            .copied()
            .ok_or_else(|| GpuError::Map("the halt flag came back empty".into()))?;
        Ok((sums, halt))
    }

    /// Copies the state of `parity` into the rows' build state.
    pub(super) fn mark_built(&self, encoder: &mut wgpu::CommandEncoder, parity: usize) {
        let state = self.states[parity & 1].buffer();
        encoder.copy_buffer_to_buffer(state, 0, self.built.buffer(), 0, None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaders;
    use crate::support::assert_mirror;

    #[test]
    fn sampling_uniforms_match_the_wgsl_layout() {
        assert_mirror!(
            "imf_force",
            "Sampling",
            SamplingUniforms {
                field_origin,
                field_dims,
                field_layout,
                count,
                surface_mode,
                wall_in_compression,
                slot,
                groups,
                alpha,
                cutoff,
                mu,
                ideal,
                eta,
                radius_bound,
                radius_bound_inv,
                step_scale,
                max_step,
                mass,
                r0,
                half_skin,
                row_split,
                surface_band,
                field_margin,
            }
        );
    }

    /// The names `SamplingBuffers::buffer` resolves: a kernel binding any
    /// other would fail `SamplingBuffers::new` at run time.
    #[test]
    fn every_stage_1_kernel_binds_only_known_buffers() {
        let known = [
            "sampling",
            "current",
            "next",
            "contact",
            "contact_next",
            "forces",
            "offsets",
            "neighbours",
            "halt",
            "partials",
            "built",
            "field_cells",
            "field_triangles",
        ];
        for kernel in SamplingKernel::ALL {
            let (file, _) = kernel.entry();
            let module = shaders::module(file).unwrap_or_else(|e| panic!("{e}"));
            for b in shaders::bindings(&module) {
                assert!(known.contains(&b.name.as_str()), "{file}: `{}`", b.name);
            }
        }
    }
}
