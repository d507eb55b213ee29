//! The observation a [`DeformState`] pairs the skin with: its field's
//! buffers, the pairing's parameters and paired particles
//! (`shaders/pair.wgsl`, [`Pass::Pair`](tissue_solve::stage2::Pass::Pair)).

use bytemuck::{Pod, Zeroable};
use tissue_core::field::SurfaceField;
use tissue_solve::stage2::Pairing;

use super::{DeformState, workgroups};
use crate::buffer::Storage;
use crate::sampler::FieldBuffers;
use crate::support::scoped;
use crate::{GpuError, Kernel, Pipelines};

/// `FieldGrid` of `shaders/shared/field_grid.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct FieldGridParams {
    /// The corner of cell (0, 0, 0) (xyz) and the cell edge (w).
    pub origin: [f32; 4],
    /// Cells along x, y, z; w the number of triangles.
    pub dims: [u32; 4],
    /// Where the field's cells buffer holds its CSR starts, candidates and
    /// candidate distances.
    pub sections: [u32; 4],
}

/// `Pairing` of `shaders/pair.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct PairingParams {
    /// The observation's field.
    pub grid: FieldGridParams,
    /// Particles paired.
    pub skin_count: u32,
    /// 1 for a point cloud.
    pub cloud: u32,
    /// The springs' weight.
    pub weight: f32,
    /// A cloud's edge.
    pub edge: f32,
    /// The robust scale (Huber's).
    pub robust: f32,
    /// A cloud's smoothing radius (0: the nearest point's plane).
    pub smoothing: f32,
    /// Padding to the WGSL struct's size.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

/// What a state holds for the pairing: the observation's field (or
/// one-entry placeholders), the pairing's parameters and particles.
#[derive(Debug)]
pub(crate) struct PairingBuffers {
    /// The observation's field cells (`field_cells`).
    pub(crate) field_cells: Storage<u32>,
    /// Its triangles (`field_triangles`).
    pub(crate) field_triangles: Storage<[f32; 4]>,
    /// Its grid, where an observation is held.
    pub(crate) grid: Option<FieldGridParams>,
    /// The pairing's parameters (`pairing`, one struct).
    pub(crate) params: Storage<PairingParams>,
    /// What `params` holds.
    pub(crate) host: PairingParams,
    /// The paired particles (`skin`).
    pub(crate) skin: Storage<u32>,
    /// Whether a pairing is set.
    pub(crate) pairing: bool,
    /// With a pairing, the springs as they were where the solve last kept
    /// a state ([`DeformState::hold_springs`], two entries per particle as
    /// the loads buffer holds them): the potential's held parts are
    /// measured with them (`held_springs`). One zero entry without.
    pub(crate) held_springs: Storage<[f32; 4]>,
    /// Whether `held_springs` holds springs kept since the pairing was set.
    pub(crate) held: bool,
}

impl PairingBuffers {
    /// No observation and no pairing.
    pub(crate) fn empty(device: &wgpu::Device) -> Result<Self, GpuError> {
        let none = "(no observation)";
        Ok(Self {
            field_cells: Storage::zeroed(device, "field_cells", 1, none)?,
            field_triangles: Storage::zeroed(device, "field_triangles", 1, none)?,
            grid: None,
            params: Storage::zeroed(device, "pairing", 1, none)?,
            host: PairingParams::default(),
            skin: Storage::zeroed(device, "skin", 1, none)?,
            pairing: false,
            held_springs: Storage::zeroed(device, "held_springs", 1, none)?,
            held: false,
        })
    }

    /// Whether the iterations pair ([`Pass::Pair`](tissue_solve::stage2::Pass::Pair)).
    pub(crate) fn pairs(&self) -> bool {
        self.grid.is_some() && self.pairing
    }

    /// Whether the potential's held parts are measured: the iterations
    /// pair, and springs were held since the pairing was set.
    pub(crate) fn measures_held(&self) -> bool {
        self.pairs() && self.held
    }

    /// Every buffer, by the WGSL variable's name.
    pub(crate) fn named(&self) -> [(&'static str, &wgpu::Buffer); 5] {
        [
            ("field_cells", self.field_cells.buffer()),
            ("field_triangles", self.field_triangles.buffer()),
            ("pairing", self.params.buffer()),
            ("skin", self.skin.buffer()),
            ("held_springs", self.held_springs.buffer()),
        ]
    }
}

impl DeformState {
    /// Uploads the observation the skin is paired with (its nearest
    /// points' field), or with `None` lets it go.
    pub fn set_observation(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        field: Option<&SurfaceField>,
    ) -> Result<(), GpuError> {
        let held = &mut self.pairing;
        match field {
            Some(field) => {
                let buffers = FieldBuffers::new(device, field)?;
                held.grid = Some(FieldGridParams {
                    origin: buffers.origin,
                    dims: buffers.dims,
                    sections: buffers.layout,
                });
                held.field_cells = buffers.cells;
                held.field_triangles = buffers.triangles;
            }
            None => {
                let empty = PairingBuffers::empty(device)?;
                (held.field_cells, held.field_triangles, held.grid) =
                    (empty.field_cells, empty.field_triangles, None);
            }
        }
        self.refresh_pairing(device, pipelines, None)
    }

    /// Sets how the elastic iterations pair the skin with the observation
    /// held, or with `None` stops pairing. The loads buffer must hold
    /// springs ([`DeformState::set_loads`]): the pairing writes them.
    pub fn set_pairing(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        pairing: Option<&Pairing>,
    ) -> Result<(), GpuError> {
        if pairing.is_some() && !self.holds_springs() {
            return Err(GpuError::Length {
                what: "springs (one per particle) before a pairing",
                expected: self.len(),
                got: 0,
            });
        }
        self.pairing.pairing = pairing.is_some();
        self.pairing.held = false;
        let n = self.len();
        let entries = if pairing.is_some() { 2 * n } else { 1 };
        if self.pairing.held_springs.len() != entries {
            self.pairing.held_springs = scoped(device, || {
                Storage::zeroed(
                    device,
                    "held_springs",
                    entries,
                    &format!("the held springs buffer ({n} particles)"),
                )
            })?;
        }
        self.refresh_pairing(device, pipelines, pairing)
    }

    /// Keeps the springs the loads buffer holds now as the held springs
    /// (`tissue_solve::SolveDevice::save` with a pairing: the springs the
    /// potential measured last paired at the state kept). Nothing without
    /// a pairing.
    pub(crate) fn hold_springs(&mut self, encoder: &mut wgpu::CommandEncoder) {
        let n = self.len() as u64;
        if !self.pairing.pairing || self.pairing.held_springs.len() as u64 != 2 * n {
            return;
        }
        self.pairing.held = true;
        let entry = std::mem::size_of::<[f32; 4]>() as u64;
        encoder.copy_buffer_to_buffer(
            self.loads.buffer(),
            n * entry,
            self.pairing.held_springs.buffer(),
            0,
            Some(2 * n * entry),
        );
    }

    /// Whether the loads buffer holds a spring per particle.
    pub(crate) fn holds_springs(&self) -> bool {
        self.loads.len() == 3 * self.len()
    }

    /// Uploads the pairing's parameters and particles (`pairing` where it
    /// changes, else the grid alone) and binds them.
    fn refresh_pairing(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        pairing: Option<&Pairing>,
    ) -> Result<(), GpuError> {
        let held = &mut self.pairing;
        let mut params = held.host;
        params.grid = held.grid.unwrap_or_default();
        if let Some(pairing) = pairing {
            let count = pairing.skin.len();
            params.skin_count = u32::try_from(count).map_err(|_| GpuError::Length {
                what: "paired particles",
                expected: u32::MAX as usize,
                got: count,
            })?;
            params.cloud = u32::from(pairing.rule.cloud);
            params.weight = pairing.rule.weight;
            params.edge = pairing.rule.edge;
            params.robust = pairing.rule.robust;
            params.smoothing = pairing.rule.smooth;
            let skin: &[u32] = if pairing.skin.is_empty() {
                &[0]
            } else {
                &pairing.skin
            };
            held.skin = scoped(device, || {
                Storage::init(
                    device,
                    "skin",
                    skin,
                    &format!("the skin buffer ({count} paired)"),
                )
            })?;
            self.workgroups[Kernel::Pair.index()] = workgroups(
                params.skin_count.max(1),
                pipelines.workgroup_size(Kernel::Pair),
                device.limits().max_compute_workgroups_per_dimension,
            )?;
        }
        held.params = scoped(device, || {
            Storage::init(
                device,
                "pairing",
                &[params],
                "the pairing buffer (one struct)",
            )
        })?;
        held.host = params;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::support::assert_mirror;

    #[test]
    fn pairing_params_match_the_wgsl_layout() {
        assert_mirror!(
            "pair",
            "Pairing",
            PairingParams {
                grid,
                skin_count,
                cloud,
                weight,
                edge,
                robust,
                smoothing,
                pad1,
                pad2,
            }
        );
        assert_mirror!(
            "pair",
            "FieldGrid",
            FieldGridParams {
                origin,
                dims,
                sections
            }
        );
    }
}
