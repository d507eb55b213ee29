//! Points bound to a [`Solver`]'s particles and carried by its solves:
//! landmarks, a surface's vertices, a rigid structure's centroid.

use glam::Vec3;
use tissue_cpu::model::Embedding;
use tissue_gpu::GpuEmbedding;
use tissue_solve::model::{RigidBinding, RigidMotion};

use super::{Solver, SolverDevice, gpu_error};
use crate::{DeformError, Error};

/// Points bound to the particles, ready to be carried on the solver's device.
#[derive(Debug)]
pub struct BoundPoints {
    embedding: Embedding,
    gpu: Option<GpuEmbedding>,
}

impl BoundPoints {
    /// The points at rest.
    pub fn rest(&self) -> &[Vec3] {
        &self.embedding.points
    }

    /// Per point, the particles that carry it and their weights (summing
    /// to one).
    pub fn carriers(&self) -> &[Vec<(u32, f32)>] {
        &self.embedding.carriers
    }

    /// The points bound to the reference positions, device aside (for
    /// [`Solver::bind_embedded`]).
    pub fn embedding(&self) -> &Embedding {
        &self.embedding
    }
}

impl Solver {
    /// Binds `points` (reference coordinates) to the reference particles,
    /// and on the GPU, where the reference is the rest shape, uploads the
    /// binding.
    pub fn bind(&self, points: &[Vec3]) -> Result<BoundPoints, Error> {
        self.bind_embedded(Embedding::new(self.reference(), points))
    }

    /// [`Solver::bind`] of points already bound to this solver's reference
    /// positions ([`BoundPoints::embedding`] of an earlier binding): for a
    /// sequence that carries the same points after every solve.
    ///
    /// # Errors
    ///
    /// As [`Solver::bind`].
    pub fn bind_embedded(&self, embedding: Embedding) -> Result<BoundPoints, Error> {
        let gpu = match self.tracker.device() {
            SolverDevice::Gpu(gpu) if self.reference.is_none() => Some(
                GpuEmbedding::new(
                    gpu.solve.device(),
                    &gpu.embedding,
                    &embedding,
                    self.tracker.rest().len(),
                )
                .map_err(|e| gpu_error(format!("binding points on {}", gpu.name), e))?,
            ),
            _ => None,
        };
        Ok(BoundPoints { embedding, gpu })
    }

    /// Where `bound`'s points are after the last solve.
    pub fn carry(&self, bound: &BoundPoints) -> Result<Vec<Vec3>, Error> {
        match (self.tracker.device(), &bound.gpu) {
            (SolverDevice::Gpu(gpu), Some(on_gpu)) => on_gpu
                .moved(
                    gpu.solve.device(),
                    gpu.solve.queue(),
                    &gpu.embedding,
                    gpu.solve.state(),
                )
                .map_err(|e| gpu_error(format!("carrying points on {}", gpu.name), e)),
            (SolverDevice::Cpu(cpu), None) if self.reference.is_none() => Ok(bound
                .embedding
                .moved(self.rest(), cpu.positions(), cpu.rotations())),
            (_, None) if self.reference.is_some() => {
                Ok(bound
                    .embedding
                    .moved(self.reference(), self.positions(), &self.rotations()?))
            }
            _ => Err(DeformError::OtherBackend.into()),
        }
    }

    /// Binds a rigid structure with rest `vertices` (reference
    /// coordinates): its centroid is carried like a landmark, its rotation
    /// fitted to the particles nearest that centroid
    /// ([`RigidBinding`](tissue_solve::model::RigidBinding)).
    pub fn bind_rigid(&self, vertices: &[Vec3]) -> Result<BoundRigid, Error> {
        let binding = RigidBinding::new(self.reference(), vertices);
        let centre = self.bind(&binding.centre().points)?;
        Ok(BoundRigid { binding, centre })
    }

    /// How `bound` moved in the last solve: a rotation about its rest
    /// centroid and where that centroid went.
    pub fn carry_rigid(&self, bound: &BoundRigid) -> Result<RigidMotion, Error> {
        let moved_centre = self
            .carry(&bound.centre)?
            .first()
            .copied()
            .unwrap_or_default();
        Ok(bound
            .binding
            .motion_from(moved_centre, self.reference(), self.positions()))
    }
}

/// A rigid structure bound to a [`Solver`]'s particles ([`Solver::bind_rigid`]).
#[derive(Debug)]
pub struct BoundRigid {
    binding: RigidBinding,
    centre: BoundPoints,
}

impl BoundRigid {
    /// The structure's rest centroid.
    pub fn rest_centre(&self) -> Vec3 {
        self.binding.centre().points[0]
    }

    /// Its centroid, bound as a landmark.
    pub fn centre(&self) -> &BoundPoints {
        &self.centre
    }
}
