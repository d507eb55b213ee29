//! Where the work runs: `auto`, `gpu` or `cpu`, chosen once; then both
//! stages on the chosen device behind one interface.
//!
//! ```
//! use tissue::backend::{Backend, Device, Solver};
//! use tissue::deformation::DeformParams;
//! use tissue::{SamplingParams, phantom};
//!
//! // The CPU path here; `Backend::Auto` takes a hardware GPU when there is one.
//! let picked = Device::pick(Backend::Cpu)?;
//! assert_eq!(picked.device.name(), "cpu");
//! let skin = phantom::default_breast();
//! let sampled = tissue::backend::sample_on(
//!     &picked.device,
//!     &skin,
//!     &SamplingParams::with_particles(1_000),
//!     &mut |_| {},
//! )?;
//! let mut solver = Solver::new(picked.device, &sampled.model, DeformParams::default())?;
//! solver.set_surface(&tissue::deform::sagged_breast())?;
//! let report = solver.solve()?;
//! assert!(report.converged);
//! # Ok::<(), tissue::Error>(())
//! ```

use std::convert::Infallible;
use std::fmt;
use std::str::FromStr;

use glam::{Mat3, Vec3};
use tissue_core::field::SurfaceField;
use tissue_core::{Connections, Error, GpuFailure, ParticleModel, SamplingParams, SurfaceMesh};
use tissue_cpu::deformation::{CpuSolve, DeformParams, DeformReport, SharedLaplacian};
use tissue_cpu::{Progress, Sampled};
use tissue_gpu::{EmbeddingKernel, GpuError, GpuSolve};
use tissue_solve::model::{offsets_product, rotation_of};
use tissue_solve::stage2::{Pairing, Spring};
use tissue_solve::{Plan, PrepareStage, SolveStep, Tracker};

mod bound;
mod solve_device;

pub use bound::{BoundPoints, BoundRigid};

/// Which device to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Backend {
    /// A hardware GPU when there is one, otherwise the CPU: a software
    /// adapter such as Mesa lavapipe is slower than the CPU path.
    #[default]
    Auto,
    /// The GPU adapter `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` name, or the
    /// default one (a software adapter too); an error when there is none.
    Gpu,
    /// The CPU path.
    Cpu,
}

impl FromStr for Backend {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self, Error> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            _ => Err(Error::UnknownBackend(s.to_owned())),
        }
    }
}

impl fmt::Display for Backend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Auto => "auto",
            Self::Gpu => "gpu",
            Self::Cpu => "cpu",
        })
    }
}

/// The chosen device: the CPU, or an opened GPU. A clone shares the GPU
/// (its device and queue are handles), for solvers made one after another
/// on it.
#[derive(Debug, Clone)]
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

/// What [`Device::pick`] chose, and why.
#[derive(Debug)]
pub struct Picked {
    /// The device.
    pub device: Device,
    /// Why: asked for, or what `auto` found.
    pub reason: String,
}

impl fmt::Display for Picked {
    /// `cpu (asked for)`, `gpu (NVIDIA H100, Vulkan; a hardware GPU, DiscreteGpu)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.device {
            Device::Cpu => write!(f, "cpu ({})", self.reason),
            Device::Gpu { name, .. } => write!(f, "gpu ({name}; {})", self.reason),
        }
    }
}

/// `error`, with what was being done; the model's own errors pass unchanged.
pub(crate) fn gpu_error(context: impl Into<String>, error: GpuError) -> Error {
    let kind = match &error {
        GpuError::NoAdapter(_) => GpuFailure::NoAdapter,
        GpuError::RequestDevice(_) => GpuFailure::NoDevice,
        GpuError::LimitExceeded { .. } => GpuFailure::LimitExceeded,
        GpuError::OutOfMemory(_) => GpuFailure::OutOfMemory,
        GpuError::DeviceLost(_) => GpuFailure::DeviceLost,
        _ => GpuFailure::Other,
    };
    match error {
        GpuError::Model(e) => e,
        other => Error::Gpu {
            context: context.into(),
            kind,
            source: Box::new(other),
        },
    }
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
    /// Chooses the device for `backend`. `gpu` fails when no adapter opens;
    /// `auto` never fails: without a hardware GPU it takes the CPU and says why.
    pub fn pick(backend: Backend) -> Result<Picked, Error> {
        match backend {
            Backend::Cpu => Ok(Picked {
                device: Self::Cpu,
                reason: "asked for".into(),
            }),
            Backend::Gpu => {
                let (adapter, device, queue) =
                    tissue_gpu::device_from_env().map_err(|e| gpu_error("the GPU backend", e))?;
                Ok(Picked {
                    device: Self::Gpu {
                        name: describe(&adapter.get_info()),
                        device,
                        queue,
                    },
                    reason: "asked for".into(),
                })
            }
            Backend::Auto => Ok(Self::auto()),
        }
    }

    /// `auto`: the best hardware adapter among those the environment allows
    /// (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`), else the CPU; and why.
    fn auto() -> Picked {
        let cpu = |reason: String| Picked {
            device: Self::Cpu,
            reason,
        };
        let (_instance, mut adapters) = tissue_gpu::quiet::instance_and_adapters();
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
            return cpu(match software.as_slice() {
                [] => "no GPU adapter found".to_owned(),
                [one] => format!(
                    "the only GPU adapter is {one}, a software device slower than the CPU path"
                ),
                many => format!(
                    "the GPU adapters ({}) are software devices slower than the CPU path",
                    many.join("; ")
                ),
            });
        };
        let info = adapter.get_info();
        let name = describe(&info);
        let opened = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("tissue"),
            required_limits: tissue_gpu::limits_for(&adapter),
            ..Default::default()
        }));
        match opened {
            Ok((device, queue)) => Picked {
                device: Self::Gpu {
                    name,
                    device,
                    queue,
                },
                reason: format!("a hardware GPU, {:?}", info.device_type),
            },
            Err(e) => cpu(format!("{name} refused a device: {e}")),
        }
    }

    /// `cpu`, or the GPU adapter's name and graphics backend.
    pub fn name(&self) -> &str {
        match self {
            Self::Cpu => "cpu",
            Self::Gpu { name, .. } => name,
        }
    }
}

/// Stage 1 on `device`: validates `surface` as [`crate::sample`] does (one
/// closed, consistently oriented shell, turned outward if it faced inward)
/// and fills it with `params.particles` particles; `progress` is called after every iteration
/// (after every batch of iterations on the GPU). Both devices give the same
/// model (the GPU kernels are twins of the CPU stages; `tests/` holds them
/// to it).
pub fn sample_on(
    device: &Device,
    surface: &SurfaceMesh,
    params: &SamplingParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Sampled, Error> {
    params.validate()?;
    let surface = &crate::checked(surface)?;
    let sampled = match device {
        Device::Cpu => tissue_cpu::sample(surface, params, progress),
        Device::Gpu {
            name,
            device,
            queue,
        } => tissue_gpu::sampler::sample(device, queue, surface, params, progress)
            .map_err(|e| gpu_error(format!("sampling on {name}"), e)),
    }?;
    crate::usable(sampled)
}

/// Stage 2 on the chosen device: the one [`Tracker`] over a
/// [`SolverDevice`], with the positions of the last solve at hand on the
/// host (read back once per solve, a frame boundary). Structures and
/// landmarks are carried where the particles are: on the GPU, by
/// `embedding_moved.wgsl`, reading back only the moved points.
///
/// Its reference, the posture displacements, structures and landmarks are
/// measured from, is the model's rest shape; a solver made by
/// [`Solver::unloaded`] is stress-free in another shape (the organ's
/// unloaded one) and still measures from the model's rest posture,
/// carrying on the host.
#[derive(Debug)]
pub struct Solver {
    tracker: Tracker<SolverDevice>,
    /// The model's rest posture and connections, where the solver's rest
    /// shape is another ([`Solver::unloaded`]).
    reference: Option<Reference>,
}

/// The device half of a [`Solver`]: the CPU's or the GPU's kernels and
/// buffers, one [`SolveDevice`] that forwards to either, their errors made
/// the library's.
#[derive(Debug)]
pub enum SolverDevice {
    /// The CPU path.
    Cpu(Box<CpuSolve>),
    /// The GPU path.
    Gpu(Box<GpuSolver>),
}

/// A reference posture other than the solver's rest shape.
#[derive(Debug)]
struct Reference {
    positions: Vec<Vec3>,
    connections: Connections,
}

/// The GPU half of [`SolverDevice`]: the solve's kernels and buffers, and
/// the kernel that carries bound points.
#[derive(Debug)]
pub struct GpuSolver {
    name: String,
    solve: GpuSolve,
    embedding: EmbeddingKernel,
}

impl GpuSolver {
    /// The GPU solve, for what the facade does not wrap (its kernels and
    /// buffers).
    pub fn solve(&self) -> &GpuSolve {
        &self.solve
    }

    /// `what` on the GPU solve, its failure said to be `doing` on this GPU.
    fn on<T>(
        &mut self,
        doing: &str,
        what: impl FnOnce(&mut GpuSolve) -> Result<T, GpuError>,
    ) -> Result<T, Error> {
        what(&mut self.solve).map_err(|e| gpu_error(format!("{doing} on {}", self.name), e))
    }
}

/// The CPU solve's result, which cannot fail.
fn infallible<T>(done: Result<T, Infallible>) -> Result<T, Error> {
    done.map_err(|never| match never {})
}

impl Solver {
    /// Prepares stage 2 for `model` on `device`.
    pub fn new(device: Device, model: &ParticleModel, params: DeformParams) -> Result<Self, Error> {
        Self::new_with_progress(device, model, params, &mut |_| {})
    }

    /// [`Solver::new`], telling `progress` as each stage of the preparation
    /// starts ([`PrepareStage`]: the plan, the elastic model, the upload,
    /// the coarse spaces), on either device in the same order.
    pub fn new_with_progress(
        device: Device,
        model: &ParticleModel,
        params: DeformParams,
        progress: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        Self::new_shared(device, model, params, None, progress)
    }

    /// [`Solver::new_with_progress`], taking what another solver of the
    /// same connections and free particles prepared where it matches
    /// (`shared`, that solver's [`Solver::shared_laplacian`]): the
    /// connection Laplacian's spectrum and its coarse space, which do not
    /// depend on the positions. Anything that does not match is made anew.
    pub fn new_shared(
        device: Device,
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
        progress: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        let tracker =
            Tracker::new_shared(model, params, shared, progress, |plan, params, observe| {
                Ok::<_, Error>(match device {
                    Device::Cpu => SolverDevice::Cpu(Box::new(CpuSolve::new_shared(
                        model, plan, params, shared, observe,
                    ))),
                    Device::Gpu {
                        name,
                        device,
                        queue,
                    } => {
                        let context = format!("preparing stage 2 on {name}");
                        let solve = GpuSolve::prepare(
                            &device, &queue, model, plan, params, shared, observe,
                        )
                        .map_err(|e| gpu_error(&context, e))?;
                        let embedding =
                            EmbeddingKernel::new(&device).map_err(|e| gpu_error(&context, e))?;
                        SolverDevice::Gpu(Box::new(GpuSolver {
                            name,
                            solve,
                            embedding,
                        }))
                    }
                })
            })?;
        Ok(Self {
            tracker,
            reference: None,
        })
    }

    /// Prepares stage 2 for `model` stress-free in the shape `unloaded`
    /// (one position per particle: the organ's unloaded shape,
    /// `tissue_solve::model::gravity`), whose surface attachments and connections
    /// are the model's; displacements, structures and landmarks are still
    /// measured from the model's own positions, its rest posture
    /// ([`Solver::reference`]).
    ///
    /// # Errors
    ///
    /// A shape of other than one finite position per particle; what
    /// [`Solver::new`] refuses.
    pub fn unloaded(
        device: Device,
        model: &ParticleModel,
        unloaded: &[Vec3],
        params: DeformParams,
    ) -> Result<Self, Error> {
        Self::unloaded_with_progress(device, model, unloaded, params, &mut |_| {})
    }

    /// [`Solver::unloaded`], telling `progress` as each stage of the
    /// preparation starts, as [`Solver::new_with_progress`] does.
    pub fn unloaded_with_progress(
        device: Device,
        model: &ParticleModel,
        unloaded: &[Vec3],
        params: DeformParams,
        progress: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, Error> {
        if unloaded.len() != model.len() || unloaded.iter().any(|p| !p.is_finite()) {
            return Err(tissue_core::ParamError {
                name: "unloaded shape",
                value: format!("{} positions", unloaded.len()),
                expected: format!("{} finite positions, one per particle", model.len()),
            }
            .into());
        }
        let stress_free = ParticleModel {
            positions: unloaded.to_vec(),
            ..model.clone()
        };
        let mut solver = Self::new_with_progress(device, &stress_free, params, progress)?;
        solver.reference = Some(Reference {
            positions: model.positions.clone(),
            connections: model.connections.clone(),
        });
        Ok(solver)
    }

    /// The device the solver runs on (another solver made there shares
    /// its GPU).
    pub fn on_device(&self) -> Device {
        match self.tracker.device() {
            SolverDevice::Cpu(_) => Device::Cpu,
            SolverDevice::Gpu(gpu) => Device::Gpu {
                name: gpu.name.clone(),
                device: gpu.solve.device().clone(),
                queue: gpu.solve.queue().clone(),
            },
        }
    }

    /// The tracker over the device, in place.
    pub(crate) fn tracker_mut(&mut self) -> &mut Tracker<SolverDevice> {
        &mut self.tracker
    }

    /// The tracker over the device (a solver with a reference of its own,
    /// [`Solver::unloaded`], leaves it behind).
    pub fn into_tracker(self) -> Tracker<SolverDevice> {
        self.tracker
    }

    /// The device's solve, for what the facade does not wrap.
    pub fn device(&self) -> &SolverDevice {
        self.tracker.device()
    }

    /// `cpu`, or the GPU adapter's name and graphics backend (for the reports).
    pub fn backend(&self) -> String {
        match self.tracker.device() {
            SolverDevice::Cpu(_) => "cpu".to_owned(),
            SolverDevice::Gpu(gpu) => gpu.name.clone(),
        }
    }

    /// The solve's plan: free particles, spectrum, size, float floor.
    pub fn plan(&self) -> &Plan {
        self.tracker.plan()
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        self.tracker.params()
    }

    /// Places the control points on `deformed`, the rest surface with moved vertices.
    pub fn set_surface(&mut self, deformed: &SurfaceMesh) -> Result<(), Error> {
        self.tracker.set_surface(deformed)
    }

    /// Sets every particle's spring towards the observation
    /// ([`tissue_solve::stage2::spring`]: one per particle, zero where none,
    /// or an empty list to take them away) for the next solves: the
    /// elastic force's iterations pull each free particle towards its
    /// plane along the plane's normal and leave it free along the plane.
    ///
    /// # Errors
    ///
    /// [`Error::Deformation`] for a list that is not one per particle,
    /// holds a value that is not finite, or comes without the elastic
    /// force; [`Error::Gpu`] where the GPU cannot take them.
    pub fn set_springs(&mut self, springs: Vec<Spring>) -> Result<(), Error> {
        self.tracker.set_springs(springs)
    }

    /// [`Solver::set_springs`] with the elastic correction in hand kept
    /// whatever the springs' stiffness, a preconditioner for springs that
    /// change little ([`SolveDevice::set_springs_keeping_correction`]: a
    /// tracking sequence's next scan).
    ///
    /// # Errors
    ///
    /// As [`Solver::set_springs`].
    pub fn set_springs_keeping_correction(&mut self, springs: Vec<Spring>) -> Result<(), Error> {
        self.tracker.set_springs_keeping_correction(springs)
    }

    /// Holds the observation the skin is paired with (its nearest points'
    /// field: a surface's, or a point cloud's), or none; the state is kept.
    ///
    /// # Errors
    ///
    /// [`Error::Gpu`] where the GPU cannot take it.
    pub fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), Error> {
        self.tracker.set_observation(field)
    }

    /// Sets how the elastic force's iterations pair the skin with the
    /// observation held ([`tissue_solve::stage2::pairing`]): each one
    /// first sets every paired particle's spring towards the observation's
    /// plane at its nearest point. `None` stops pairing.
    ///
    /// # Errors
    ///
    /// [`Error::Deformation`] for a pairing without the elastic force, of a
    /// particle that is not free, or with absurd weights or limits;
    /// [`Error::Gpu`] where the GPU cannot take it.
    pub fn set_pairing(&mut self, pairing: Option<Pairing>) -> Result<(), Error> {
        self.tracker.set_pairing(pairing)
    }

    /// Starts the next solve from `positions` (one per particle; the
    /// control points stay where [`Solver::set_surface`] put them) as from
    /// a converged solve: the elastic force's elastic phase alone, and both
    /// phases from `positions` if that fails. Call it after
    /// `set_surface`. For a search whose solves are near each other.
    pub fn warm_start(&mut self, positions: &[Vec3]) -> Result<(), Error> {
        self.tracker.warm_start(positions)
    }

    /// Changes the parameters of the next solves (the tolerance, say); the
    /// state is kept. What was prepared for the model (the force, the
    /// Poisson ratio, the observed vertices, the load, the coarse space)
    /// cannot change: build a new solver for those.
    ///
    /// # Errors
    ///
    /// [`Error::Param`] for parameters out of range or a change of what
    /// was prepared.
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), Error> {
        self.tracker.set_params(params)
    }

    /// Changes the body force of the next solves (`DeformParams::load`),
    /// the state kept (`Tracker::set_load`): a nearby posture's gravity.
    ///
    /// # Errors
    ///
    /// [`Error::Param`] for a solver without the elastic force or a load
    /// out of range; the GPU's error where it cannot take it.
    pub fn set_load(&mut self, load: Vec3) -> Result<(), Error> {
        self.tracker.set_load(load)
    }

    /// Solves, and on the GPU reads the positions back.
    pub fn solve(&mut self) -> Result<DeformReport, Error> {
        self.solve_with_progress(&mut |_| {})
    }

    /// [`Solver::solve`], telling `progress` where the solve is after every
    /// iteration ([`SolveStep`]: the iterations so far and the error
    /// estimate), on either device at the same iterations.
    pub fn solve_with_progress(
        &mut self,
        progress: &mut dyn FnMut(&SolveStep),
    ) -> Result<DeformReport, Error> {
        self.tracker.solve_observed(progress)
    }

    /// Back to the rest shape.
    pub fn reset(&mut self) -> Result<(), Error> {
        self.tracker.reset()
    }

    /// The potential the elastic force descends at the current positions,
    /// `E / 2 - sum b . q` (docs/METHOD.md, "Elastic model"); `None` for the
    /// other forces. On the GPU, measured there and read back (a frame
    /// boundary).
    pub fn potential(&mut self) -> Result<Option<f64>, Error> {
        self.tracker.potential()
    }

    /// [`Solver::potential`] with the magnitude of its parts, the scale of
    /// its rounding (`Potential::magnitude`).
    pub fn potential_parts(&mut self) -> Result<Option<tissue_solve::stage2::Potential>, Error> {
        self.tracker.potential_parts()
    }

    /// Rest particle positions: the shape the solve is stress-free in.
    pub fn rest(&self) -> &[Vec3] {
        self.tracker.rest()
    }

    /// What this solver prepared that depends only on the model's
    /// connections and free particles, for another solver of the same
    /// model in another rest shape ([`Solver::new_shared`]).
    pub fn shared_laplacian(&self) -> SharedLaplacian {
        self.tracker.shared_laplacian()
    }

    /// The posture displacements, structures and landmarks are measured
    /// from: the model's positions ([`Solver::rest`] but for a solver made
    /// by [`Solver::unloaded`]).
    pub fn reference(&self) -> &[Vec3] {
        match &self.reference {
            Some(reference) => &reference.positions,
            None => self.rest(),
        }
    }

    /// The last frames' converged solutions (`Tracker::history`).
    pub fn history(&self) -> &tissue_solve::stage2::FrameHistory {
        self.tracker.history()
    }

    /// Makes `from` and the positions now the only frames the next
    /// prediction takes changes from (`Tracker::restart_history`).
    pub fn restart_history(&mut self, from: &[Vec3]) {
        self.tracker.restart_history(from);
    }

    /// Particle positions after the last solve (or the last
    /// [`Solver::set_surface`], [`Solver::warm_start`] or [`Solver::reset`]).
    pub fn positions(&self) -> &[Vec3] {
        self.tracker.positions()
    }

    /// Each particle's rotation (reference offsets onto current offsets)
    /// after the last solve; on the GPU, read back (a frame boundary). From
    /// a reference other than the rest shape, the polar rotation of each
    /// particle's offsets product, on the host.
    pub fn rotations(&self) -> Result<Vec<Mat3>, Error> {
        if let Some(reference) = &self.reference {
            let current = self.positions();
            return Ok((0..current.len())
                .map(|i| {
                    let m =
                        offsets_product(&reference.positions, current, &reference.connections, i);
                    rotation_of(m)
                })
                .collect());
        }
        match self.tracker.device() {
            SolverDevice::Cpu(cpu) => Ok(cpu.rotations().to_vec()),
            SolverDevice::Gpu(gpu) => gpu
                .solve
                .read_rotations()
                .map_err(|e| gpu_error(format!("reading rotations from {}", gpu.name), e)),
        }
    }
}

/// Runs `work` on `device`. Where `backend` is `auto` and the work failed
/// for want of room on the GPU it picked (`capacity` says which errors
/// those are: [`Error::is_gpu_capacity`] for the library's own), runs it
/// again on the CPU and says so: the second value is the reason, to print
/// or warn with. Any other failure, or one under `gpu`, is returned as it
/// is.
pub fn with_cpu_fallback<T, E: fmt::Display>(
    backend: Backend,
    device: Device,
    capacity: impl Fn(&E) -> bool,
    mut work: impl FnMut(Device) -> Result<T, E>,
) -> Result<(T, Option<String>), E> {
    let on_gpu = matches!(device, Device::Gpu { .. });
    let name = device.name().to_owned();
    match work(device) {
        Err(error) if backend == Backend::Auto && on_gpu && capacity(&error) => {
            let reason = format!("{name} has no room for this model ({error}); running on the CPU");
            work(Device::Cpu).map(|done| (done, Some(reason)))
        }
        other => other.map(|done| (done, None)),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests")]
mod tests {
    use super::*;

    /// A no-op GPU device (wgpu's no-op backend): something `auto` may
    /// have picked, without a GPU in the machine.
    fn noop_gpu() -> Device {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = wgpu::Backends::NOOP;
        descriptor.backend_options.noop.enable = true;
        let instance = wgpu::Instance::new(descriptor);
        let adapter = pollster::block_on(instance.request_adapter(&Default::default())).unwrap();
        let (device, queue) =
            pollster::block_on(adapter.request_device(&Default::default())).unwrap();
        Device::Gpu {
            name: "no-op".into(),
            device,
            queue,
        }
    }

    fn out_of_memory() -> Error {
        gpu_error("stage 2 on no-op", GpuError::OutOfMemory("4 EiB".into()))
    }

    /// `auto` runs the work again on the CPU where the GPU it picked has
    /// no room (out of memory, or a limit), and says why; `gpu` returns
    /// the failure; any other failure is returned under `auto` too.
    #[test]
    fn auto_falls_back_to_the_cpu_where_the_gpu_has_no_room() {
        let work = |device: Device| match device {
            Device::Gpu { .. } => Err(out_of_memory()),
            Device::Cpu => Ok("cpu"),
        };
        let (done, reason) =
            with_cpu_fallback(Backend::Auto, noop_gpu(), Error::is_gpu_capacity, work).unwrap();
        assert_eq!(done, "cpu");
        let reason = reason.unwrap();
        assert!(
            reason.contains("no-op") && reason.contains("4 EiB"),
            "{reason}"
        );
        let refused = with_cpu_fallback(Backend::Gpu, noop_gpu(), Error::is_gpu_capacity, work);
        assert!(refused.is_err_and(|e| e.is_gpu_capacity()));
        let limit = |device: Device| match device {
            Device::Gpu { .. } => Err(gpu_error(
                "stage 2",
                GpuError::LimitExceeded {
                    limit: "max_storage_buffer_binding_size",
                    what: "positions".into(),
                    asked: 1 << 40,
                    allowed: 1 << 27,
                },
            )),
            Device::Cpu => Ok(()),
        };
        let (_, reason) =
            with_cpu_fallback(Backend::Auto, noop_gpu(), Error::is_gpu_capacity, limit).unwrap();
        assert!(reason.is_some());
        let lost = |_: Device| -> Result<(), Error> {
            Err(gpu_error("stage 2", GpuError::DeviceLost("gone".into())))
        };
        let kept = with_cpu_fallback(Backend::Auto, noop_gpu(), Error::is_gpu_capacity, lost);
        assert!(kept.is_err_and(|e| !e.is_gpu_capacity()));
        // On the CPU already, nothing is run again.
        let mut runs = 0;
        let (_, reason) =
            with_cpu_fallback(Backend::Auto, Device::Cpu, Error::is_gpu_capacity, |_| {
                runs += 1;
                Ok::<(), Error>(())
            })
            .unwrap();
        assert_eq!((runs, reason), (1, None));
    }

    #[test]
    fn backends_parse_and_print_their_names() {
        for backend in [Backend::Auto, Backend::Gpu, Backend::Cpu] {
            let parsed: Backend = backend.to_string().parse().unwrap();
            assert_eq!(parsed, backend);
        }
        assert_eq!("GPU".parse::<Backend>().unwrap(), Backend::Gpu);
        let err = "cuda".parse::<Backend>().unwrap_err();
        assert!(
            matches!(&err, Error::UnknownBackend(name) if name == "cuda"),
            "{err}"
        );
        assert!(err.to_string().contains("unknown backend `cuda`"), "{err}");
        assert_eq!(Backend::default(), Backend::Auto);
    }

    /// A GPU failure reaches the facade's error typed: its kind to match
    /// (out of memory, no adapter, ...) and the GPU crate's own error as
    /// its source; the model's own errors pass through unchanged.
    #[test]
    fn gpu_failures_keep_their_kind_and_source() {
        use std::error::Error as _;
        let err = gpu_error("stage 2 on a GPU", GpuError::OutOfMemory("4 EiB".into()));
        let Error::Gpu { kind, .. } = &err else {
            panic!("{err:?}");
        };
        assert_eq!(*kind, GpuFailure::OutOfMemory);
        assert!(
            err.to_string()
                .starts_with("stage 2 on a GPU: the GPU ran out of memory")
        );
        let source = err.source().and_then(|s| s.downcast_ref::<GpuError>());
        assert!(
            matches!(source, Some(GpuError::OutOfMemory(_))),
            "{source:?}"
        );
        for (gpu, expected) in [
            (GpuError::NoAdapter("none".into()), GpuFailure::NoAdapter),
            (GpuError::RequestDevice("no".into()), GpuFailure::NoDevice),
            (GpuError::DeviceLost("gone".into()), GpuFailure::DeviceLost),
            (GpuError::Validation("bad".into()), GpuFailure::Other),
        ] {
            assert!(
                matches!(gpu_error("x", gpu), Error::Gpu { kind, .. } if kind == expected),
                "{expected:?}"
            );
        }
        let model = Error::InvalidModel("no particles".into());
        assert!(matches!(
            gpu_error("x", GpuError::Model(model)),
            Error::InvalidModel(_)
        ));
    }

    /// `sample_on` skipped the surface check `sample` makes: an open surface
    /// got past it to the sampler.
    #[test]
    fn sample_on_refuses_an_open_surface_as_sample_does() {
        let open = SurfaceMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]);
        let params = SamplingParams::with_particles(100);
        let err = sample_on(&Device::Cpu, &open, &params, &mut |_| {}).unwrap_err();
        assert!(err.to_string().contains("open"), "{err}");
    }

    #[test]
    fn the_cpu_is_taken_when_asked_for() {
        let picked = Device::pick(Backend::Cpu).unwrap();
        assert!(matches!(picked.device, Device::Cpu));
        assert_eq!(picked.to_string(), "cpu (asked for)");
    }

    #[test]
    fn auto_takes_a_hardware_gpu_or_says_why_not() {
        let picked = Device::pick(Backend::Auto).unwrap();
        let line = picked.to_string();
        match &picked.device {
            Device::Cpu => assert!(
                line.contains("no GPU adapter")
                    || line.contains("software device")
                    || line.contains("refused a device"),
                "{line}"
            ),
            Device::Gpu { .. } => assert!(line.contains("a hardware GPU"), "{line}"),
        }
    }
}
