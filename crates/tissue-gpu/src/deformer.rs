//! Stage 2 on the GPU: `tissue_solve::Tracker` over [`GpuSolve`], the
//! kernels and buffers of one model.

use std::sync::Arc;

use glam::{Mat3, Vec3};
use tissue_core::{Connections, ParticleModel, SurfaceMesh};
use tissue_solve::coarse::{
    Aggregates, CoarseSpace, CorrectionFor, ElasticCoarse, SharedLaplacian, Smoothing,
    coarse_space_shared, elastic_aggregates, volume_smoother,
};
use tissue_solve::model::Elastic;
use tissue_solve::stage2::Plan;
use tissue_solve::stage2::Spring;
use tissue_solve::{DeformParams, DeformReport, Iteration, PrepareStage, Tracker};

use crate::{DeformState, GpuError, Pipelines};

mod solve_device;

/// Stage 2 on the GPU for one particle model: the CPU path's tracker (the
/// same step `alpha` from `lambda_max`, the same spectral Chebyshev `rho`,
/// the same prediction and stopping rule), with the rotations of
/// `params.rotations`: by the SVD every iteration, or by the polar update
/// warm-started from each particle's last rotation (the SVD's where it does
/// not settle), the stored rotations turned with the surface at a frame
/// boundary as the CPU path turns them. With `params.coarse`, the CPU
/// path's coarse space (the same aggregates and factor, made on the host)
/// corrects the plain step every iteration (`shaders/coarse.wgsl`). The elastic phase's two-level solve is the CPU path's, made on the
/// host where the phase starts, its aggregates grown until their factor
/// fits the GPU's coarse solve (the CPU's cycles above that have no
/// kernels here yet). With the elastic force the GPU
/// computes the targets after the rotations and gathers the force over them. The
/// positions are read back at the end of every solve and uploaded with a
/// new frame's control points (both frame boundaries); the
/// step norms are read back once per [`SLOTS`] iterations, and a batch in
/// which the rule held is replayed up to that iteration (from the positions
/// and, warm-started, the rotations at its start), so the iteration count
/// equals the CPU's.
#[derive(Debug)]
pub struct GpuDeformer {
    tracker: Tracker<GpuSolve>,
}

/// The GPU's stage-2 kernels and buffers for one model: what
/// [`SolveDevice`] asks of a device.
#[derive(Debug)]
pub struct GpuSolve {
    /// The device and queue the solve runs on (handles: clones of the
    /// caller's).
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipelines: Pipelines,
    state: DeformState,
    /// The two-level iteration's contraction, with the coarse space.
    coarse_rho: Option<f32>,
    /// The coarse space uploaded (kept for [`GpuDeformer::shared_laplacian`]).
    coarse: Option<Arc<CoarseSpace>>,
    /// What the host linearises the elastic phase from, with its two-level
    /// solve (the elastic force, `coarse` and `elastic_coarse_max_aggregates` on).
    elastic_host: Option<ElasticHost>,
    /// The elastic phase's correction in hand (its contraction, its step).
    elastic_coarse: Option<Arc<ElasticCoarse>>,
    /// Per particle its body force (the plan's loads; empty without), for
    /// the loads buffer made again with other springs.
    loads: Vec<Vec3>,
    /// `current` at a batch's start, for a replay (a copy target that no
    /// kernel binds: raw).
    backup_current: wgpu::Buffer,
    /// `previous` at a batch's start, likewise.
    backup_previous: wgpu::Buffer,
    /// `rotations` at a batch's start, likewise: a warm-started replay
    /// starts from them.
    backup_rotations: wgpu::Buffer,
    /// `current` where [`SolveDevice::save`] kept it, likewise.
    saved_current: wgpu::Buffer,
    /// `rotations` where [`SolveDevice::save`] kept them, likewise.
    saved_rotations: wgpu::Buffer,
    /// What the iterations of the solve in hand run with.
    iteration: Option<Iteration>,
    /// Iterations of the last batch, whose weights the slots still hold.
    slots: u32,
}

/// The most unknowns one factor of a coarse solve on the GPU takes
/// (aggregates of the two-level solve, or groups of its cycles; three per
/// aggregate of the elastic phase's): each substitution runs in one
/// workgroup, a barrier a row, and on llvmpipe a dispatch of 8,617 rows
/// stopped short (the solve came back half done, and the iteration
/// diverged: the phantom at 100,000 particles), while 6,033 ran whole. A
/// coarse Laplacian of more aggregates is solved by two-grid cycles over
/// at most this many groups (`shaders/multilevel.wgsl`, on both devices:
/// [`GpuDeformer::cpu_twin`]); an elastic coarse matrix of more than a
/// third as many aggregates by block cycles (`shaders/block_multilevel.wgsl`).
pub const GPU_COARSE_UNKNOWNS: usize = 4_096;

/// The rest data the host needs to make the elastic phase's correction.
#[derive(Debug)]
struct ElasticHost {
    rest: Vec<Vec3>,
    connections: Connections,
    elastic: Arc<Elastic>,
    aggregates: Aggregates,
    /// How the volume smoother is made and its iteration's contraction at
    /// rest, where the elastic phase smooths with it (the CPU path's).
    volume_smoother: Option<(Smoothing, f32)>,
    /// Up to how many aggregates the correction is factored, cycled above.
    direct_max: usize,
    /// Per particle its spring towards the observation, part of the
    /// correction's operator (empty without: [`Plan::springs`]).
    springs: Vec<Spring>,
}

impl GpuDeformer {
    /// The parameters under which the CPU path runs the solve the GPU runs
    /// under `params`, its twin: the same, but that the coarse Laplacian
    /// is factored only up to [`GPU_COARSE_UNKNOWNS`] aggregates and the
    /// elastic coarse matrix up to a third as many (three unknowns an
    /// aggregate): the GPU's one-workgroup substitution. Above, both are
    /// solved by two-grid cycles, their groups capped there too, as the
    /// GPU solves them.
    pub fn cpu_twin(params: &DeformParams) -> DeformParams {
        params.clone().with(|p| {
            p.tuning.coarse_direct_max_aggregates = params
                .tuning
                .coarse_direct_max_aggregates
                .min(GPU_COARSE_UNKNOWNS);
            p.tuning.elastic_coarse_direct_max_aggregates = params
                .tuning
                .elastic_coarse_direct_max_aggregates
                .min(GPU_COARSE_UNKNOWNS / 3);
        })
    }

    /// Checks `model` and `params`, estimates the Laplacian's extreme
    /// eigenvalues and builds the coarse space (on the host, by the same
    /// calls as the CPU path), compiles the kernels and uploads the model,
    /// the coarse space and, with the elastic force, the elastic model's
    /// rest data.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &ParticleModel,
        params: DeformParams,
    ) -> Result<Self, GpuError> {
        Self::new_observed(device, queue, model, params, &mut |_| {})
    }

    /// [`GpuDeformer::new`], telling `observe` as each stage of the
    /// preparation starts (the CPU twin's stages, and the upload).
    pub fn new_observed(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &ParticleModel,
        params: DeformParams,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, GpuError> {
        Self::new_shared(device, queue, model, params, None, observe)
    }

    /// [`GpuDeformer::new_observed`], taking what another solver of the
    /// same connections and free particles prepared where it matches
    /// ([`SharedLaplacian`]; [`GpuDeformer::shared_laplacian`] of that
    /// one, or the CPU twin's).
    pub fn new_shared(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &ParticleModel,
        params: DeformParams,
        shared: Option<&SharedLaplacian>,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, GpuError> {
        let tracker =
            Tracker::new_shared(model, params, shared, observe, |plan, params, observe| {
                GpuSolve::prepare(device, queue, model, plan, params, shared, observe)
            })?;
        Ok(Self { tracker })
    }

    /// What this solver prepared that depends only on the connections and
    /// the free particles, for another solver of the same model in another
    /// rest shape ([`GpuDeformer::new_shared`]).
    pub fn shared_laplacian(&self) -> SharedLaplacian {
        self.tracker.shared_laplacian()
    }

    /// The kernels and buffers the solves run on.
    pub fn solve_device(&self) -> &GpuSolve {
        self.tracker.device()
    }

    /// The kernels and buffers, to drive through their
    /// [`tissue_solve::SolveDevice`] calls (tests that compare devices one
    /// call at a time).
    pub fn solve_device_mut(&mut self) -> &mut GpuSolve {
        self.tracker.device_mut()
    }

    /// The device the solve runs on.
    pub fn device(&self) -> &wgpu::Device {
        self.tracker.device().device()
    }

    /// The queue the solve submits to.
    pub fn queue(&self) -> &wgpu::Queue {
        self.tracker.device().queue()
    }

    /// The kernels.
    pub fn pipelines(&self) -> &Pipelines {
        self.tracker.device().pipelines()
    }

    /// The buffers.
    pub fn state(&self) -> &DeformState {
        self.tracker.device().state()
    }

    /// The passes every iteration of the last solve ran, in order (the
    /// CPU path's `CpuSolve::passes`).
    pub fn passes(&self) -> Vec<tissue_solve::stage2::Pass> {
        self.state().passes()
    }

    /// Bytes of every GPU buffer the deformer holds ([`GpuSolve::buffer_bytes`]).
    pub fn buffer_bytes(&self) -> u64 {
        self.tracker.device().buffer_bytes()
    }

    /// The model's size (bounding-box diagonal at rest).
    pub fn size(&self) -> f32 {
        self.tracker.plan().size
    }

    /// Smallest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_min(&self) -> f32 {
        self.tracker.plan().lambda_min
    }

    /// Largest eigenvalue of the connection-graph Laplacian over free particles.
    pub fn lambda_max(&self) -> f32 {
        self.tracker.plan().lambda_max
    }

    /// The parameters of the next solves.
    pub fn params(&self) -> &DeformParams {
        self.tracker.params()
    }

    /// Changes the parameters of the next solves (the tolerance, say); the
    /// state is kept ([`Tracker::set_params`]: what was prepared for the
    /// model cannot change).
    pub fn set_params(&mut self, params: DeformParams) -> Result<(), tissue_core::Error> {
        self.tracker.set_params(params)
    }

    /// Places the control points on `deformed`, the rest surface with moved
    /// vertices, predicts the free particles as the CPU path does (unless
    /// `extrapolate` is off) and uploads them (a frame boundary).
    pub fn set_surface(&mut self, deformed: &SurfaceMesh) -> Result<(), GpuError> {
        self.tracker.set_surface(deformed)
    }

    /// Holds the observation the skin is paired with, or none
    /// (`Tracker::set_observation`).
    pub fn set_observation(
        &mut self,
        field: Option<&tissue_core::field::SurfaceField>,
    ) -> Result<(), GpuError> {
        self.tracker.set_observation(field)
    }

    /// Sets how the elastic iterations pair the skin with the observation
    /// (`Tracker::set_pairing`), or stops pairing.
    pub fn set_pairing(
        &mut self,
        pairing: Option<tissue_solve::stage2::Pairing>,
    ) -> Result<(), GpuError> {
        self.tracker.set_pairing(pairing)
    }

    /// The next solve starts from `positions` (`Tracker::warm_start`).
    pub fn warm_start(&mut self, positions: &[Vec3]) -> Result<(), GpuError> {
        self.tracker.warm_start(positions)
    }

    /// The potential the elastic force descends at the current positions,
    /// measured on the GPU and read back (`SolveDevice::potential`); `None`
    /// for the other forces.
    pub fn potential(&mut self) -> Result<Option<f64>, GpuError> {
        self.tracker.potential()
    }

    /// Rest particle positions.
    pub fn rest(&self) -> &[Vec3] {
        self.tracker.rest()
    }

    /// The positions at the end of the last solve (read back by it), or
    /// after the last `set_surface` or `reset`.
    pub fn host_positions(&self) -> &[Vec3] {
        self.tracker.positions()
    }

    /// Reads the current positions back (a frame boundary).
    pub fn positions(&self) -> Result<Vec<Vec3>, GpuError> {
        self.tracker.device().read_current()
    }

    /// Reads back each particle's rotation (rest offsets onto current
    /// offsets) from the last iteration, as
    /// `tissue_cpu::deformation::Deformer::rotations` has them: what
    /// `Embedding::moved` and `RigidBinding::motion` need. Stalls until the
    /// GPU is done: frame boundaries only.
    pub fn read_rotations(&self) -> Result<Vec<Mat3>, GpuError> {
        self.tracker.device().read_rotations()
    }

    /// Back to the rest shape.
    pub fn reset(&mut self) -> Result<(), GpuError> {
        self.tracker.reset()
    }

    /// Iterates until the stopping rule of `Deformer::solve` holds or the cap
    /// is reached (see the type's doc for what differs).
    pub fn solve(&mut self) -> Result<DeformReport, GpuError> {
        self.solve_observed(&mut |_| {})
    }

    /// [`Deformer::solve`], telling `observe` where it is after every
    /// iteration (as the CPU's twin does, at the same iterations).
    pub fn solve_observed(
        &mut self,
        observe: &mut dyn FnMut(&tissue_solve::SolveStep),
    ) -> Result<DeformReport, GpuError> {
        self.tracker.solve_observed(observe)
    }
}

impl GpuSolve {
    /// The device half of [`GpuDeformer::new_shared`] (what
    /// `Tracker::new_shared` is given to make the device): the kernels
    /// compiled, the model uploaded, the coarse space (from `shared` where
    /// it fits), and the elastic phase's host data, as the
    /// CPU twin prepares them.
    pub fn prepare(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &ParticleModel,
        plan: &Plan,
        params: &DeformParams,
        shared: Option<&SharedLaplacian>,
        observe: &mut dyn FnMut(PrepareStage),
    ) -> Result<Self, GpuError> {
        observe(PrepareStage::Upload);
        let pipelines = Pipelines::new(device)?;
        let mut state = DeformState::new(device, queue, &pipelines, model, &plan.free)?;
        if let Some(elastic) = &plan.elastic {
            state.set_elastic(device, &pipelines, elastic)?;
        }
        if !plan.loads.is_empty() || !plan.springs.is_empty() {
            state.set_loads(device, &pipelines, &plan.loads, &plan.springs)?;
        }
        // The coarse space corrects the symmetric force, an elastic solve's shear phase included
        // (`Iteration::correct`), as on the CPU path.
        // Factored up to what one workgroup substitutes, cycled above
        // (the groups are capped there too), as the CPU twin does.
        if params.tuning.coarse != 0.0 {
            observe(PrepareStage::CoarseSpace);
        }
        let coarse = coarse_space_shared(
            model,
            plan,
            &GpuDeformer::cpu_twin(params),
            shared.map(|shared| (shared, plan.laplacian_key)),
        )
        .filter(|space| {
            let unknowns = space.multilevel().map_or(space.count(), |m| m.groups());
            let fits = unknowns <= GPU_COARSE_UNKNOWNS;
            if !fits {
                log::warn!(
                    "the GPU's coarse solve takes at most {GPU_COARSE_UNKNOWNS} unknowns in \
                     one factor, this coarse space has {unknowns}: the GPU solves without it"
                );
            }
            fits
        });
        if let Some(space) = &coarse {
            state.set_coarse(device, &pipelines, space)?;
        }
        if plan.elastic.is_some() {
            observe(PrepareStage::ElasticCoarse);
        }
        // The elastic correction is factored or cycled as the CPU
        // twin makes it, its groups' factor at most what one
        // workgroup substitutes.
        let twin = GpuDeformer::cpu_twin(params);
        let elastic_aggregates = elastic_aggregates(model, plan, &twin);
        let elastic_host = match (&plan.elastic, elastic_aggregates) {
            (Some(elastic), Some(aggregates)) => {
                state.set_elastic_aggregates(device, &pipelines, &aggregates)?;
                Some(ElasticHost {
                    springs: plan.springs.clone(),
                    rest: model.positions.clone(),
                    connections: model.connections.clone(),
                    elastic: Arc::clone(elastic),
                    volume_smoother: volume_smoother(
                        model,
                        plan,
                        &twin,
                        Some(&aggregates),
                        twin.tuning.elastic_coarse_direct_max_aggregates,
                        shared.and_then(|shared| shared.smoother_for(plan.laplacian_key, &twin)),
                    ),
                    direct_max: twin.tuning.elastic_coarse_direct_max_aggregates,
                    aggregates,
                })
            }
            _ => None,
        };
        let backup = |label, bytes: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: state.len() as u64 * bytes,
                usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        Ok(GpuSolve {
            device: device.clone(),
            queue: queue.clone(),
            backup_current: backup("backup current", 16),
            backup_previous: backup("backup previous", 16),
            backup_rotations: backup(
                "backup rotations",
                std::mem::size_of::<crate::Rotation>() as u64,
            ),
            saved_current: backup("saved current", 16),
            saved_rotations: backup(
                "saved rotations",
                std::mem::size_of::<crate::Rotation>() as u64,
            ),
            pipelines,
            state,
            coarse_rho: coarse.as_deref().map(CoarseSpace::rho),
            coarse,
            elastic_host,
            elastic_coarse: None,
            loads: plan.loads.clone(),
            iteration: None,
            slots: 0,
        })
    }

    /// The device the solve runs on.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The queue the solve submits to.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The kernels.
    pub fn pipelines(&self) -> &Pipelines {
        &self.pipelines
    }

    /// The buffers.
    pub fn state(&self) -> &DeformState {
        &self.state
    }

    /// Bytes of every GPU buffer the solve holds: the state's, the three
    /// backups a batch is replayed from and the two copies of the state an
    /// elastic phase accepted.
    pub fn buffer_bytes(&self) -> u64 {
        self.state.buffer_bytes()
            + self.backup_current.size()
            + self.backup_previous.size()
            + self.backup_rotations.size()
            + self.saved_current.size()
            + self.saved_rotations.size()
    }

    /// Reads the current positions back (a frame boundary).
    pub fn read_current(&self) -> Result<Vec<Vec3>, GpuError> {
        self.state.read_positions(&self.device, &self.queue)
    }

    /// Reads back each particle's rotation (rest offsets onto current
    /// offsets) from the last iteration, as the CPU path has them. Stalls
    /// until the GPU is done: frame boundaries only.
    pub fn read_rotations(&self) -> Result<Vec<Mat3>, GpuError> {
        self.state.read_rotations(&self.device, &self.queue)
    }

    /// Makes the elastic phase's correction at the current positions (read
    /// back) on the host, as the CPU path makes its own, and uploads it; a
    /// failure leaves the phase uncorrected, with a warning.
    fn linearise(&mut self, iteration: Iteration) -> Result<(), GpuError> {
        if self.elastic_host.is_none() {
            return Ok(());
        }
        let device = self.device.clone();
        let current = self.read_positions_unscoped()?;
        let Some(host) = &self.elastic_host else {
            return Ok(());
        };
        self.elastic_coarse = ElasticCoarse::at_phase_start(
            &host.aggregates,
            &host.rest,
            &current,
            &host.connections,
            &host.elastic,
            CorrectionFor {
                contraction: iteration.contraction,
                smoothing: host.volume_smoother.map(|(smoothing, _)| smoothing),
                rho: host.volume_smoother.map(|(_, rho)| rho),
                direct_max_aggregates: host.direct_max,
                envelope: true,
            },
            &host.springs,
            None,
        )
        .map(Arc::new);
        match &self.elastic_coarse {
            Some(coarse) => self
                .state
                .linearise_elastic(&device, &self.pipelines, coarse)?,
            None => self.state.forget_elastic_linearisation(),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::expect_used, reason = "tests fail loudly on purpose")]
    use super::*;
    use tissue_core::SamplingParams;

    /// The library's default factors the coarse Laplacian exactly as far
    /// as the GPU's one-workgroup substitution goes, so both devices solve
    /// every model's coarse space the same way by default, and the CPU
    /// twin of a default solve is that solve.
    #[test]
    fn by_default_both_devices_factor_or_cycle_the_same_coarse_spaces() {
        let defaults = DeformParams::default();
        assert_eq!(
            defaults.tuning.coarse_direct_max_aggregates,
            GPU_COARSE_UNKNOWNS
        );
        assert_eq!(
            defaults.tuning.elastic_coarse_direct_max_aggregates,
            GPU_COARSE_UNKNOWNS / 3
        );
        assert_eq!(GpuDeformer::cpu_twin(&defaults), defaults);
        let larger = defaults.clone().with(|p| {
            p.tuning.coarse_direct_max_aggregates = 10_000;
            p.tuning.elastic_coarse_direct_max_aggregates = 2_000;
        });
        let twin = GpuDeformer::cpu_twin(&larger);
        assert_eq!(
            twin.tuning.coarse_direct_max_aggregates,
            GPU_COARSE_UNKNOWNS
        );
        assert_eq!(twin.tuning.elastic_coarse_direct_max_aggregates, 1_365);
    }

    /// A device of wgpu's no-op backend: its buffers are host memory,
    /// allocated fallibly; its buffer size unlimited (so neither wgpu nor
    /// we refuse a size before the allocation does); its kernels do nothing.
    fn noop_device() -> (wgpu::Device, wgpu::Queue) {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = wgpu::Backends::NOOP;
        descriptor.backend_options.noop.enable = true;
        // Without indirect-call validation, whose u32 offsets would cap
        // buffers at 4 GiB.
        descriptor
            .flags
            .remove(wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL);
        descriptor.backend_options.noop.limits = Some(wgpu::Limits {
            max_buffer_size: u64::MAX,
            ..wgpu::Limits::unlimited()
        });
        let instance = wgpu::Instance::new(descriptor);
        let adapter = pollster::block_on(instance.request_adapter(&Default::default()))
            .expect("the no-op backend has an adapter");
        pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .expect("the no-op adapter opens a device")
    }

    /// A small phantom model and its surface pushed out by 2 %.
    fn model_and_frame() -> (ParticleModel, SurfaceMesh) {
        let breast = tissue_core::phantom::default_breast();
        let sampled =
            tissue_cpu::sample(&breast, &SamplingParams::with_particles(400), &mut |_| {})
                .expect("the phantom samples");
        let mut frame = sampled.model.surface.clone();
        for v in &mut frame.vertices {
            *v *= 1.02;
        }
        (sampled.model, frame)
    }

    fn solve_on_noop(least_staging: u64) -> Result<DeformReport, GpuError> {
        let (device, queue) = noop_device();
        let (model, frame) = model_and_frame();
        let mut deformer = GpuDeformer::new(&device, &queue, &model, DeformParams::default())?;
        deformer.tracker.device_mut().state.readback.least = least_staging;
        deformer.set_surface(&frame)?;
        deformer.solve()
    }

    #[test]
    fn a_solve_on_the_noop_device_runs_to_its_end() {
        // The control for the test below: on this device the whole solve
        // runs (its kernels do nothing, so no step is taken), and only the
        // staging buffer's size differs there.
        let report = solve_on_noop(0).expect("the solve runs on the no-op device");
        assert!(report.iterations >= 1, "{report:?}");
    }

    #[test]
    fn a_buffer_the_device_cannot_allocate_inside_a_solve_is_out_of_memory() {
        // The solve's first read back asks for a 4 EiB staging buffer:
        // within the device's limits, beyond any memory. wgpu raises
        // out-of-memory inside the solve; it must come back typed, not as
        // a panic from wgpu's default error handler.
        match solve_on_noop(1 << 62) {
            Err(GpuError::OutOfMemory(why)) => assert!(why.contains("readback"), "{why}"),
            other => panic!("expected GpuError::OutOfMemory, got {other:?}"),
        }
    }
}
