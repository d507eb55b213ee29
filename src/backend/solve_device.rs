//! [`SolveDevice`] for [`SolverDevice`]: each call forwarded to the CPU's
//! or the GPU's solve.

use std::sync::Arc;

use glam::{Mat3, Vec3};
use tissue_core::Error;
use tissue_core::field::SurfaceField;
use tissue_cpu::deformation::{DeformParams, SharedLaplacian};
use tissue_gpu::GpuSolve;
use tissue_solve::coarse::ElasticCoarse;
use tissue_solve::stage2::{DescentDots, Pairing, Potential, Spring};
use tissue_solve::{Iteration, Plan, SolveDevice};

use super::{SolverDevice, infallible};

/// Every call forwards to the device's own solve; a GPU failure comes back
/// as [`Error::Gpu`], saying what was being done on which GPU.
impl SolveDevice for SolverDevice {
    type Error = Error;

    fn batch(&self) -> usize {
        match self {
            Self::Cpu(cpu) => cpu.batch(),
            Self::Gpu(gpu) => gpu.solve.batch(),
        }
    }

    fn coarse_rho(&self) -> Option<f32> {
        match self {
            Self::Cpu(cpu) => cpu.coarse_rho(),
            Self::Gpu(gpu) => gpu.solve.coarse_rho(),
        }
    }

    fn elastic_rho(&self) -> Option<f32> {
        match self {
            Self::Cpu(cpu) => cpu.elastic_rho(),
            Self::Gpu(gpu) => gpu.solve.elastic_rho(),
        }
    }

    fn volume_smoother(&self) -> bool {
        match self {
            Self::Cpu(cpu) => SolveDevice::volume_smoother(cpu.as_ref()),
            Self::Gpu(gpu) => gpu.solve.volume_smoother(),
        }
    }

    fn elastic_smoothed(&self) -> bool {
        match self {
            Self::Cpu(cpu) => cpu.elastic_smoothed(),
            Self::Gpu(gpu) => gpu.solve.elastic_smoothed(),
        }
    }

    fn write_positions(&mut self, positions: &[Vec3], turn: Option<Mat3>) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.write_positions(positions, turn)),
            Self::Gpu(gpu) => gpu.on("uploading positions", |g| {
                g.write_positions(positions, turn)
            }),
        }
    }

    fn begin(&mut self, iteration: Iteration) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.begin(iteration)),
            Self::Gpu(gpu) => gpu.on("stage 2", |g| g.begin(iteration)),
        }
    }

    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.run(omegas)),
            Self::Gpu(gpu) => gpu.on("stage 2", |g| g.run(omegas)),
        }
    }

    fn replay(&mut self, count: usize) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.replay(count)),
            Self::Gpu(gpu) => gpu.on("stage 2", |g| g.replay(count)),
        }
    }

    fn read_positions(&mut self) -> Result<Vec<Vec3>, Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.read_positions()),
            Self::Gpu(gpu) => gpu.on("reading positions", GpuSolve::read_positions),
        }
    }

    fn read_rotations(&mut self) -> Result<Vec<Mat3>, Error> {
        match self {
            Self::Cpu(cpu) => infallible(SolveDevice::read_rotations(cpu.as_mut())),
            Self::Gpu(gpu) => gpu.on("reading rotations", SolveDevice::read_rotations),
        }
    }

    /// The CPU's state copies cheaply; a GPU's buffers are not copied.
    fn fork(&self) -> Option<Self> {
        match self {
            Self::Cpu(cpu) => cpu.fork().map(|c| Self::Cpu(Box::new(c))),
            Self::Gpu(_) => None,
        }
    }

    fn write_rotations(&mut self, rotations: &[Mat3]) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.write_rotations(rotations)),
            Self::Gpu(gpu) => gpu.on("writing rotations", |g| g.write_rotations(rotations)),
        }
    }

    /// Both devices keep the host's correction.
    type Correction = Option<Arc<ElasticCoarse>>;

    fn correction(&self) -> Self::Correction {
        match self {
            Self::Cpu(cpu) => cpu.correction(),
            Self::Gpu(gpu) => gpu.solve.correction(),
        }
    }

    fn put_correction(&mut self, correction: Self::Correction) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.put_correction(correction)),
            Self::Gpu(gpu) => gpu.on("uploading the elastic correction", |g| {
                g.put_correction(correction)
            }),
        }
    }

    fn potential(&mut self) -> Result<Option<Potential>, Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.potential()),
            Self::Gpu(gpu) => gpu.on("measuring the potential", GpuSolve::potential),
        }
    }

    fn descent_residual(&mut self) -> Result<Option<DescentDots>, Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.descent_residual()),
            Self::Gpu(gpu) => gpu.on("stage 2", SolveDevice::descent_residual),
        }
    }

    fn descent_direction(&mut self, beta: f32) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.descent_direction(beta)),
            Self::Gpu(gpu) => gpu.on("stage 2", |g| g.descent_direction(beta)),
        }
    }

    fn descent_move(&mut self, t: f32) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.descent_move(t)),
            Self::Gpu(gpu) => gpu.on("stage 2", |g| g.descent_move(t)),
        }
    }

    fn save(&mut self) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.save()),
            Self::Gpu(gpu) => gpu.on("stage 2", SolveDevice::save),
        }
    }

    fn restore(&mut self) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.restore()),
            Self::Gpu(gpu) => gpu.on("stage 2", SolveDevice::restore),
        }
    }

    fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian {
        match self {
            Self::Cpu(cpu) => cpu.shared_laplacian(plan, params),
            Self::Gpu(gpu) => gpu.solve.shared_laplacian(plan, params),
        }
    }

    fn set_springs(&mut self, springs: &[Spring]) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.as_mut().set_springs(springs)),
            Self::Gpu(gpu) => gpu.on("uploading the springs", |g| g.set_springs(springs)),
        }
    }

    fn set_springs_keeping_correction(&mut self, springs: &[Spring]) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.as_mut().set_springs_keeping_correction(springs)),
            Self::Gpu(gpu) => gpu.on("uploading the springs", |g| {
                g.set_springs_keeping_correction(springs)
            }),
        }
    }

    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.as_mut().set_loads(loads)),
            Self::Gpu(gpu) => gpu.on("uploading the loads", |g| g.set_loads(loads)),
        }
    }

    fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.as_mut().set_observation(field)),
            Self::Gpu(gpu) => gpu.on("uploading the observation", |g| g.set_observation(field)),
        }
    }

    fn set_pairing(&mut self, pairing: Option<&Pairing>) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(cpu.as_mut().set_pairing(pairing)),
            Self::Gpu(gpu) => gpu.on("uploading the pairing", |g| g.set_pairing(pairing)),
        }
    }

    fn reset(&mut self) -> Result<(), Error> {
        match self {
            Self::Cpu(cpu) => infallible(SolveDevice::reset(cpu.as_mut())),
            Self::Gpu(gpu) => gpu.on("resetting stage 2", SolveDevice::reset),
        }
    }
}
