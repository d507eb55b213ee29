//! What crosses between the host and a [`DeformState`]'s buffers: the
//! control points, positions, rotations and forces written, and the
//! positions, steps, forces, rotations, elastic terms and step-norm
//! partials read back.

use glam::{Mat3, Vec3};

use super::{DeformState, SLOTS};
use crate::buffer::Storage;
use crate::{GpuError, Kernel, Pipelines, Rotation};

impl DeformState {
    pub(super) fn check_len(&self, what: &'static str, got: usize) -> Result<(), GpuError> {
        if got == self.len() {
            Ok(())
        } else {
            Err(GpuError::Length {
                what,
                expected: self.len(),
                got,
            })
        }
    }

    /// Uploads the placed control points (one per surface particle, in
    /// particle order) into the current positions; at frame boundaries.
    pub fn set_control_points(&self, queue: &wgpu::Queue, points: &[Vec3]) -> Result<(), GpuError> {
        if points.len() != self.controls.len() {
            return Err(GpuError::Length {
                what: "control points",
                expected: self.controls.len(),
                got: points.len(),
            });
        }
        for &(first, from, len) in &self.control_runs {
            self.current
                .write_points(queue, first as usize, &points[from..from + len])?;
        }
        Ok(())
    }

    /// Overwrites every current position (tests, or a fresh start).
    pub fn write_current(&self, queue: &wgpu::Queue, positions: &[Vec3]) -> Result<(), GpuError> {
        self.check_len("current positions", positions.len())?;
        self.current.write_points(queue, 0, positions)
    }

    /// Overwrites every rotation (tests of the force kernel, and of the
    /// elastic terms' kernels, which start from them).
    pub fn write_rotations(&self, queue: &wgpu::Queue, rotations: &[Mat3]) -> Result<(), GpuError> {
        self.check_len("rotations", rotations.len())?;
        let data: Vec<Rotation> = rotations.iter().map(|&r| Rotation::from(r)).collect();
        self.rotations.write(queue, 0, &data)
    }

    /// Sets the turn [`Kernel::TurnRotations`] applies (taking effect at
    /// the next submit).
    pub fn write_turn(&self, queue: &wgpu::Queue, turn: Mat3) -> Result<(), GpuError> {
        self.turn.write(queue, 0, &[Rotation::from(turn)])
    }

    /// Overwrites every force (tests of the integrate kernel).
    pub fn write_force(&self, queue: &wgpu::Queue, force: &[Vec3]) -> Result<(), GpuError> {
        self.check_len("forces", force.len())?;
        self.force.write_points(queue, 0, force)
    }

    /// Reads the current positions back (stalls until the GPU is done: frame boundaries only).
    pub fn read_positions(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<Vec3>, GpuError> {
        self.current.read_points(device, queue, &self.readback)
    }

    /// Reads the last plain step `q̂` back.
    pub fn read_plain(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<Vec3>, GpuError> {
        self.plain.read_points(device, queue, &self.readback)
    }

    /// Reads the last forces back.
    pub fn read_force(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<Vec3>, GpuError> {
        self.force.read_points(device, queue, &self.readback)
    }

    /// Reads the last rotations back.
    pub fn read_rotations(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<Mat3>, GpuError> {
        self.read_matrices(device, queue, &self.rotations)
    }

    /// Reads the last elastic terms back, each as its target and stress
    /// (an elastic state's; without [`DeformState::set_elastic`] there are
    /// none, and this is empty).
    pub fn read_terms(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<(Mat3, Mat3)>, GpuError> {
        let read = self.elastic_terms.read(device, queue, &self.readback)?;
        Ok(read
            .into_iter()
            .map(|t| (Mat3::from(t.rest_term), Mat3::from(t.multiplier_term)))
            .collect())
    }

    /// Each particle's part of the potential the elastic force descends,
    /// at the current positions (`elastic_targets.wgsl::elastic_potential`,
    /// dispatched here), and with a pairing whose springs were held since
    /// it was set each one's held part (its spring's part from the held
    /// springs, [`DeformState::hold_springs`]);
    /// empty without [`DeformState::set_elastic`]. Stalls until the GPU is
    /// done: frame boundaries only.
    pub fn read_potential(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &Pipelines,
    ) -> Result<(Vec<f32>, Option<Vec<f32>>), GpuError> {
        if !self.elastic {
            return Ok((Vec::new(), None));
        }
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("potential"),
        });
        // Paired at the positions measured: the potential is then a
        // function of the positions alone, whatever pairing the last
        // iteration had.
        let pairs = self.pairing.pairs();
        if pairs {
            pipelines.dispatch(&mut encoder, self, Kernel::Pair, 0);
        }
        pipelines.dispatch(&mut encoder, self, Kernel::ElasticPotential, 0);
        pipelines.dispatch(&mut encoder, self, Kernel::ElasticPotentialWork, 0);
        queue.submit([encoder.finish()]);
        let n = self.len();
        if !self.pairing.measures_held() {
            let parts = self
                .potential
                .read_first(device, queue, &self.readback, n)?;
            return Ok((parts, None));
        }
        let mut parts = self.potential.read(device, queue, &self.readback)?;
        let held = parts.split_off(n);
        Ok((parts, Some(held)))
    }

    /// Reads `buffer`'s matrices back.
    fn read_matrices(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        buffer: &Storage<Rotation>,
    ) -> Result<Vec<Mat3>, GpuError> {
        let read = buffer.read(device, queue, &self.readback)?;
        Ok(read.into_iter().map(Mat3::from).collect())
    }

    /// Reads the step-norm partials of the first `slots` slots: per slot,
    /// per workgroup, `(max |q̂ − q|², sum |q̂ − q|²)`.
    pub fn read_partials(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        slots: u32,
    ) -> Result<Vec<Vec<[f32; 2]>>, GpuError> {
        let row = self.step_groups as usize;
        let rows = slots.min(SLOTS) as usize;
        let all = self
            .partials
            .read_first(device, queue, &self.readback, rows * row)?;
        Ok(all.chunks(row.max(1)).map(<[_]>::to_vec).collect())
    }
}
