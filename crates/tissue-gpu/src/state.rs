//! The buffers of one particle model on the GPU.

use glam::{Mat3, Vec3};
use tissue_core::ParticleModel;
use tissue_solve::coarse::{Aggregates, CoarseSpace, ElasticCoarse, RELAXATION};
use tissue_solve::model::Elastic;
use tissue_solve::stage2::Spring;
use tissue_solve::stage2::{Choices, Correction, Holds, Pass};
use tissue_solve::{ForceModel, RotationMethod};

use crate::buffer::{Storage, vec4};
use crate::coarse::CoarseBuffers;
use crate::coarse_elastic::ElasticCoarseBuffers;
use crate::pipelines::{Kernel, Pipelines};
use crate::readback::Readback;
use crate::support::{Scopes, bind_group, scoped};
use crate::{ElasticParticle, ElasticTerms, GpuError, Params, Rotation};

mod pairing;
mod transfer;

use pairing::PairingBuffers;
pub use pairing::{FieldGridParams, PairingParams};

/// Iterations one command buffer records: one uniform slot and one row of
/// step-norm partials each; the host reads the partials back once per batch.
pub const SLOTS: u32 = 8;

/// Stage-2 buffers for one model. Positions are `vec4<f32>` (w unused,
/// `Storage<[f32; 4]>`), rotations three `vec4` columns
/// (`Storage<Rotation>`); the elastic model's buffers are empty (16 bytes
/// each) until [`DeformState::set_elastic`] fills them.
#[derive(Debug)]
pub struct DeformState {
    pub(crate) count: u32,
    params_stride: u64,
    /// Workgroups `[x, y]` of each kernel's dispatch, in [`Kernel::ALL`] order.
    workgroups: [[u32; 2]; Kernel::ALL.len()],
    /// `x * y` of the step_norms dispatch: the length of a partials row.
    pub(crate) step_groups: u32,
    /// The elastic model's data is uploaded ([`DeformState::set_elastic`]).
    elastic: bool,
    /// The force of the phase the next iterations run
    /// ([`DeformState::set_phase`]; the elastic force's terms run on an
    /// elastic state only).
    phase_force: ForceModel,
    /// Whether the next iterations correct their step.
    correct_phase: bool,
    /// How the next iterations find the rotations
    /// ([`DeformState::set_rotations`]).
    rotation_method: RotationMethod,
    /// [`SLOTS`] [`Params`], `params_stride` bytes apart: a uniform buffer,
    /// raw, as its slots sit at the dynamic offset alignment.
    pub(crate) params: wgpu::Buffer,
    /// The rest positions.
    pub(crate) rest: Storage<[f32; 4]>,
    /// The current positions.
    pub(crate) current: Storage<[f32; 4]>,
    /// The positions one iteration back (the Chebyshev weights need them).
    pub(crate) previous: Storage<[f32; 4]>,
    /// The last plain step `q̂`.
    pub(crate) plain: Storage<[f32; 4]>,
    /// Per particle its rotation.
    pub(crate) rotations: Storage<Rotation>,
    /// The turn [`Kernel::TurnRotations`] premultiplies the rotations by
    /// (one matrix, [`DeformState::write_turn`]).
    pub(crate) turn: Storage<Rotation>,
    /// Per particle its force.
    pub(crate) force: Storage<[f32; 4]>,
    /// Per particle 1 when the solve moves it.
    pub(crate) free: Storage<u32>,
    /// Per particle its body force (one zero entry without loads,
    /// [`DeformState::set_loads`]).
    pub(crate) loads: Storage<[f32; 4]>,
    /// The connections' row starts (CSR, `count + 1`).
    pub(crate) offsets: Storage<u32>,
    /// The connections' entries (CSR).
    pub(crate) indices: Storage<u32>,
    /// Per slot, per step_norms workgroup, `(max |q̂ − q|², sum |q̂ − q|²)`.
    pub(crate) partials: Storage<[f32; 2]>,
    /// Per particle the elastic model's rest data (empty without it).
    pub(crate) elastic_particles: Storage<ElasticParticle>,
    /// Per particle its terms of the elastic force (empty without it).
    pub(crate) elastic_terms: Storage<ElasticTerms>,
    /// Per particle its part of the potential the elastic force descends
    /// ([`Kernel::ElasticPotential`]; empty without the elastic model),
    /// then per particle its held part (with a pairing:
    /// [`DeformState::read_potential`]).
    pub(crate) potential: Storage<f32>,
    /// The conjugate-gradient elastic phase's vectors
    /// (`descent.wgsl`; empty until [`DeformState::ensure_descent`]).
    pub(crate) descent: DescentBuffers,
    /// The two-level solve's coarse space (empty until
    /// [`DeformState::set_coarse`]).
    pub(crate) coarse: CoarseBuffers,
    /// The elastic phase's (empty until [`DeformState::set_elastic_aggregates`]).
    pub(crate) elastic_coarse: ElasticCoarseBuffers,
    /// The observation the skin is paired with, and how
    /// ([`DeformState::set_observation`], [`DeformState::set_pairing`]).
    pub(crate) pairing: PairingBuffers,
    /// One per kernel, in [`Kernel::ALL`] order.
    bind_groups: Vec<wgpu::BindGroup>,
    /// The particle of each control point, in particle order.
    controls: Vec<u32>,
    /// Runs of consecutive control particles: `(first particle, first control, length)`.
    control_runs: Vec<(u32, usize, usize)>,
    /// The staging buffer of every read back.
    pub(crate) readback: Readback,
}

/// The conjugate-gradient elastic phase's vectors, one `vec4` per
/// particle each (`shaders/descent.wgsl`).
#[derive(Debug)]
pub(crate) struct DescentBuffers {
    /// The residual the last `descent_dots` kept.
    pub(crate) last_residual: Storage<[f32; 4]>,
    /// The direction.
    pub(crate) direction: Storage<[f32; 4]>,
    /// The positions the line search moves from.
    pub(crate) line_base: Storage<[f32; 4]>,
    /// Per particle the dot products' parts, read back.
    pub(crate) dot_parts: Storage<[f32; 4]>,
}

impl DescentBuffers {
    /// Empty buffers (16 bytes each), for a state whose elastic phase has
    /// not descended by the conjugate gradient.
    fn empty(device: &wgpu::Device, what: &dyn Fn(&str) -> String) -> Result<Self, GpuError> {
        Ok(Self {
            last_residual: Storage::init(device, "last_residual", &[], &what("last_residual"))?,
            direction: Storage::init(device, "direction", &[], &what("direction"))?,
            line_base: Storage::init(device, "line_base", &[], &what("line_base"))?,
            dot_parts: Storage::init(device, "dot_parts", &[], &what("dot_parts"))?,
        })
    }

    /// Zeroed buffers of `n` particles.
    fn zeroed(
        device: &wgpu::Device,
        n: usize,
        what: &dyn Fn(&str) -> String,
    ) -> Result<Self, GpuError> {
        Ok(Self {
            last_residual: Storage::zeroed(device, "last_residual", n, &what("last_residual"))?,
            direction: Storage::zeroed(device, "direction", n, &what("direction"))?,
            line_base: Storage::zeroed(device, "line_base", n, &what("line_base"))?,
            dot_parts: Storage::zeroed(device, "dot_parts", n, &what("dot_parts"))?,
        })
    }
}

/// Workgroups `[x, y]` covering `count` threads in groups of `size`; beyond
/// `per_dimension` workgroups the dispatch is two-dimensional.
pub fn workgroups(count: u32, size: u32, per_dimension: u32) -> Result<[u32; 2], GpuError> {
    let groups = count.div_ceil(size.max(1)).max(1);
    let x = groups.min(per_dimension.max(1));
    let y = groups.div_ceil(x);
    if y > per_dimension {
        return Err(GpuError::LimitExceeded {
            limit: "max_compute_workgroups_per_dimension",
            what: format!("a dispatch over {count} particles ({groups} workgroups of {size})"),
            asked: u64::from(y),
            allowed: u64::from(per_dimension),
        });
    }
    Ok([x, y])
}

impl DeformState {
    /// Bytes of every GPU buffer this state holds, as allocated.
    pub fn buffer_bytes(&self) -> u64 {
        self.named().iter().map(|(_, b)| b.size()).sum()
    }

    /// Uploads `model` (rest = current = previous = the rest positions,
    /// identity rotations), with `free` marking the particles the solve moves
    /// (`tissue_solve::Plan::free`), and binds it to `pipelines`' kernels.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &Pipelines,
        model: &ParticleModel,
        free: &[bool],
    ) -> Result<Self, GpuError> {
        let n = model.len();
        if free.len() != n {
            return Err(GpuError::Length {
                what: "free flags (one per particle)",
                expected: n,
                got: free.len(),
            });
        }
        if n == 0 || model.connections.particles() != n {
            return Err(GpuError::Length {
                what: "connection rows (one per particle, at least one particle)",
                expected: n.max(1),
                got: model.connections.particles(),
            });
        }
        let limits = device.limits();
        let count = u32::try_from(n).map_err(|_| GpuError::LimitExceeded {
            limit: "u32 particle index",
            what: "the particle count".into(),
            asked: n as u64,
            allowed: u64::from(u32::MAX),
        })?;
        let mut workgroups_of = [[1u32; 2]; Kernel::ALL.len()];
        for kernel in Kernel::ALL {
            if kernel.per_particle() {
                workgroups_of[kernel.index()] = workgroups(
                    count,
                    pipelines.workgroup_size(kernel),
                    limits.max_compute_workgroups_per_dimension,
                )?;
            }
        }
        let groups_of = |kernel: Kernel| {
            let [x, y] = workgroups_of[kernel.index()];
            x * y
        };
        let step_groups = groups_of(Kernel::StepNorms);
        let params_stride = u64::from(limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<Params>() as u64);

        let controls: Vec<u32> = (0..count)
            .filter(|&i| model.attachments[i as usize].is_some())
            .collect();
        let mut control_runs: Vec<(u32, usize, usize)> = Vec::new();
        for (k, &i) in controls.iter().enumerate() {
            match control_runs.last_mut() {
                Some((first, _, len)) if *first + *len as u32 == i => *len += 1,
                _ => control_runs.push((i, k, 1)),
            }
        }
        let what = |label: &str| format!("the {label} buffer ({n} particles)");
        let rest: Vec<[f32; 4]> = model.positions.iter().map(|&p| vec4(p, 0.0)).collect();
        let identity = vec![Rotation::from(Mat3::IDENTITY); n];
        let free: Vec<u32> = free.iter().map(|&f| u32::from(f)).collect();
        let (offsets, indices) = (&model.connections.offsets, &model.connections.indices);
        let mut state = scoped(device, || {
            Ok(Self {
                count,
                params_stride,
                workgroups: workgroups_of,
                step_groups,
                elastic: false,
                phase_force: ForceModel::Symmetric,
                correct_phase: true,
                rotation_method: RotationMethod::Svd,
                params: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("params"),
                    size: params_stride * u64::from(SLOTS),
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                rest: Storage::init(device, "rest", &rest, &what("rest"))?,
                current: Storage::init(device, "current", &rest, &what("current"))?,
                previous: Storage::init(device, "previous", &rest, &what("previous"))?,
                plain: Storage::init(device, "plain", &rest, &what("plain"))?,
                rotations: Storage::init(device, "rotations", &identity, &what("rotations"))?,
                turn: Storage::init(
                    device,
                    "turn",
                    &identity[..1],
                    "the turn buffer (one matrix)",
                )?,
                force: Storage::zeroed(device, "force", n, &what("force"))?,
                free: Storage::init(device, "free", &free, &what("free"))?,
                loads: Storage::zeroed(device, "loads", 1, "the loads buffer (none)")?,
                offsets: Storage::init(device, "offsets", offsets, &what("offsets"))?,
                indices: Storage::init(device, "indices", indices, &what("indices"))?,
                partials: Storage::zeroed(
                    device,
                    "partials",
                    (SLOTS * step_groups) as usize,
                    &what("partials"),
                )?,
                elastic_particles: Storage::init(
                    device,
                    "elastic_particles",
                    &[],
                    &what("elastic_particles"),
                )?,
                elastic_terms: Storage::init(device, "elastic_terms", &[], &what("elastic_terms"))?,
                potential: Storage::init(device, "potential", &[], &what("potential"))?,
                descent: DescentBuffers::empty(device, &what)?,
                coarse: CoarseBuffers::empty(device)?,
                elastic_coarse: ElasticCoarseBuffers::empty(device)?,
                pairing: PairingBuffers::empty(device)?,
                bind_groups: Vec::new(),
                controls,
                control_runs,
                readback: Readback::default(),
            })
        })?;
        state.bind_groups = state.bind_all(device, pipelines)?;
        for slot in 0..SLOTS {
            state.write_params(
                queue,
                slot,
                state.params(ForceModel::Symmetric, 0.0, 1.0, slot),
            );
        }
        Ok(state)
    }

    /// Uploads the elastic model's rest data (`tissue_solve::Plan::elastic`)
    /// for the elastic force: from now on the elastic phase's iterations
    /// compute every particle's terms after the rotations and gather the
    /// elastic force over them ([`Pass::ElasticTerms`]).
    pub fn set_elastic(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        elastic: &Elastic,
    ) -> Result<(), GpuError> {
        let c = &elastic.consistency;
        for (what, len) in [
            (
                "inverse moments (one per particle)",
                elastic.inverse_moments.len(),
            ),
            ("volume weights (one per particle)", elastic.weights.len()),
            ("stress weights (one per particle)", c.scales.len()),
            ("multipliers (one per particle)", c.multipliers.len()),
            ("corrected moments (one per particle)", c.corrections.len()),
        ] {
            self.check_len(what, len)?;
        }
        let n = self.len();
        let what = |buffer: &str| format!("the {buffer} buffer ({n} particles)");
        let particles: Vec<ElasticParticle> =
            (0..n).map(|i| ElasticParticle::of(elastic, i)).collect();
        (self.elastic_particles, self.elastic_terms, self.potential) = scoped(device, || {
            Ok((
                Storage::init(
                    device,
                    "elastic_particles",
                    &particles,
                    &what("elastic_particles"),
                )?,
                Storage::zeroed(device, "elastic_terms", n, &what("elastic_terms"))?,
                // Each particle's part, then (with a pairing) its held
                // part (`elastic_potential_work`).
                Storage::zeroed(device, "potential", 2 * n, &what("potential"))?,
            ))
        })?;
        self.elastic = true;
        self.phase_force = ForceModel::Elastic;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Makes the conjugate-gradient elastic phase's buffers where they are
    /// empty (zeroed; the first phase that descends by it asks for them,
    /// so a state that never does holds none).
    pub fn ensure_descent(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
    ) -> Result<(), GpuError> {
        let n = self.len();
        if self.descent.last_residual.len() == n {
            return Ok(());
        }
        let what = |buffer: &str| format!("the {buffer} buffer ({n} particles)");
        self.descent = scoped(device, || DescentBuffers::zeroed(device, n, &what))?;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Uploads every particle's body force (the plan's loads, one per
    /// particle, or none) and its spring towards the observation (the
    /// plan's springs, one per particle, or none): from now on the plain
    /// step adds the body force to the force, and the elastic force's
    /// iterations the springs' pulls. The buffer holds the body forces
    /// (zero without loads) and, with springs, the springs after them, two
    /// entries each (`shared/loads.wgsl`).
    pub fn set_loads(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        loads: &[Vec3],
        springs: &[Spring],
    ) -> Result<(), GpuError> {
        if !loads.is_empty() {
            self.check_len("loads (one per particle)", loads.len())?;
        }
        if !springs.is_empty() {
            self.check_len("springs (one per particle)", springs.len())?;
        }
        let n = self.len();
        let body = (0..n).map(|i| loads.get(i).map_or([0.0; 4], |&b| vec4(b, 0.0)));
        let springs = springs
            .iter()
            .flat_map(|s| [s.anchor.to_array(), s.axis.to_array()]);
        let packed: Vec<[f32; 4]> = body.chain(springs).collect();
        self.loads = scoped(device, || {
            Storage::init(
                device,
                "loads",
                &packed,
                &format!("the loads buffer ({n} particles)"),
            )
        })?;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Sets every particle's body force (one per particle, or none for
    /// zero), the springs kept: written into the loads buffer where it
    /// holds a body force per particle, a buffer of body forces alone made
    /// where it holds none (no loads and no springs before).
    pub fn write_loads(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &Pipelines,
        loads: &[Vec3],
    ) -> Result<(), GpuError> {
        let n = self.len();
        if !loads.is_empty() {
            self.check_len("loads (one per particle)", loads.len())?;
        }
        if self.loads.len() < n {
            return self.set_loads(device, pipelines, loads, &[]);
        }
        let body: Vec<[f32; 4]> = (0..n)
            .map(|i| loads.get(i).map_or([0.0; 4], |&b| vec4(b, 0.0)))
            .collect();
        self.loads.write(queue, 0, &body)
    }

    /// Sets what the next iterations run: the elastic force (an elastic
    /// state's targets after the rotations, the force gathered over them)
    /// or the state's symmetric or paper force; `correct`, whether the
    /// iterations apply the state's correction (its coarse space, or the
    /// elastic one).
    pub fn set_phase(&mut self, force: ForceModel, correct: bool) {
        self.phase_force = force;
        self.correct_phase = correct;
    }

    /// Uploads the two-level solve's coarse space (the CPU path's, made on
    /// the host): the next iterations that correct run
    /// [`Pass::CoarseCorrection`].
    pub fn set_coarse(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        space: &CoarseSpace,
    ) -> Result<(), GpuError> {
        let coarse = CoarseBuffers::upload(device, space, self.len())?;
        let most = device.limits().max_compute_workgroups_per_dimension;
        // The restriction and the cycles' sweeps run per aggregate, the
        // cycles' restriction per group; the substitutions in one
        // workgroup each.
        for kernel in [
            Kernel::CoarseRestrict,
            Kernel::CycleStart,
            Kernel::CycleSweep,
            Kernel::CycleSweepBack,
            Kernel::CycleProlong,
        ] {
            self.workgroups[kernel.index()] =
                workgroups(coarse.aggregates, pipelines.workgroup_size(kernel), most)?;
        }
        // The restriction runs a workgroup a group.
        self.workgroups[Kernel::CycleRestrict.index()] =
            workgroups(coarse.cycles.groups.max(1), 1, most)?;
        self.coarse = coarse;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Uploads the elastic phase's aggregates; its corrected iterations run
    /// once [`DeformState::linearise_elastic`] gave a linearisation.
    pub fn set_elastic_aggregates(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        aggregates: &Aggregates,
    ) -> Result<(), GpuError> {
        let buffers = ElasticCoarseBuffers::with_aggregates(device, aggregates, self.len())?;
        // The restriction and the cycles' sweeps run per aggregate.
        for kernel in [
            Kernel::ElasticRestrict,
            Kernel::BlockCycleStart,
            Kernel::BlockCycleSweep,
            Kernel::BlockCycleSweepBack,
            Kernel::BlockCycleProlong,
        ] {
            self.workgroups[kernel.index()] = workgroups(
                buffers.aggregates,
                pipelines.workgroup_size(kernel),
                device.limits().max_compute_workgroups_per_dimension,
            )?;
        }
        self.elastic_coarse = buffers;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Uploads the elastic operator linearised at a state (the host's
    /// [`ElasticCoarse`] over the aggregates given before).
    pub fn linearise_elastic(
        &mut self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
        coarse: &ElasticCoarse,
    ) -> Result<(), GpuError> {
        self.elastic_coarse.linearise(device, coarse)?;
        // The cycles' restriction runs a workgroup a group.
        self.workgroups[Kernel::BlockCycleRestrict.index()] = workgroups(
            self.elastic_coarse.cycles.groups.max(1),
            1,
            device.limits().max_compute_workgroups_per_dimension,
        )?;
        self.bind_groups = self.bind_all(device, pipelines)?;
        Ok(())
    }

    /// Runs the elastic phase uncorrected until the next
    /// [`DeformState::linearise_elastic`] (the host could not make one).
    pub fn forget_elastic_linearisation(&mut self) {
        self.elastic_coarse.linearised = false;
        self.elastic_coarse.smoother = None;
    }

    /// Number of aggregates of the uploaded coarse space (0: none).
    pub fn aggregates(&self) -> usize {
        self.coarse.aggregates as usize
    }

    /// Number of groups of the elastic coarse matrix's two-grid cycles in
    /// the uploaded linearisation (0: none, or factored).
    pub fn elastic_groups(&self) -> usize {
        self.elastic_coarse.cycles.groups as usize
    }

    /// Sets how the next iterations find the rotations: by the SVD, or by
    /// the polar update warm-started from the stored rotations (the `WARM_*`
    /// iterations of [`DeformState::iteration`]).
    pub fn set_rotations(&mut self, rotations: RotationMethod) {
        self.rotation_method = rotations;
    }

    /// Whether [`DeformState::set_elastic`] gave the elastic model's data.
    pub fn elastic(&self) -> bool {
        self.elastic
    }

    /// What this state holds for its iterations, for the rule that picks
    /// their passes ([`Choices::of`]).
    fn holds(&self) -> Holds {
        let elastic = &self.elastic_coarse;
        Holds {
            elastic: self.elastic,
            coarse: (self.coarse.aggregates > 0).then_some(self.coarse.cycles.groups > 0),
            elastic_correction: elastic.linearised.then_some((
                elastic.cycles.groups > 0,
                elastic.smoother.map(|(_, sweeps)| sweeps),
            )),
            pairs: self.pairing.pairs(),
        }
    }

    /// The choices of the next iterations: the phase's force and
    /// correction ([`DeformState::set_phase`]), the rotations
    /// ([`DeformState::set_rotations`]), and what the state holds.
    pub fn choices(&self) -> Choices {
        Choices::of(
            self.phase_force,
            self.rotation_method,
            self.correct_phase,
            self.holds(),
        )
    }

    /// The passes of one iteration, in order ([`Choices::passes`]).
    pub fn passes(&self) -> Vec<Pass> {
        self.choices().passes()
    }

    /// The kernels of one iteration, in order: each pass of
    /// [`DeformState::passes`] by its kernels ([`Kernel::of_pass`]).
    pub fn iteration(&self) -> Vec<Kernel> {
        Kernel::of_passes(&self.passes())
    }

    /// A bind group per kernel, in [`Kernel::ALL`] order. `UpdateNorms`
    /// is `step_norms` with `previous` (the old current, after the combine)
    /// bound as its `plain`.
    fn bind_all(
        &self,
        device: &wgpu::Device,
        pipelines: &Pipelines,
    ) -> Result<Vec<wgpu::BindGroup>, GpuError> {
        let scope = Scopes::push(device);
        let groups: Result<Vec<wgpu::BindGroup>, GpuError> = Kernel::ALL
            .into_iter()
            .map(|kernel| {
                let update = kernel == Kernel::UpdateNorms;
                bind_group(
                    device,
                    pipelines.kernel(kernel),
                    (kernel.entry().0, kernel.name()),
                    |name| match name {
                        "plain" if update => Some(self.previous.buffer()),
                        _ => self
                            .coarse
                            .cycles
                            .buffer_for(kernel, name)
                            .or_else(|| self.elastic_coarse.cycles.buffer_for(kernel, name))
                            .or_else(|| self.buffer(name)),
                    },
                    Some(std::mem::size_of::<Params>() as u64),
                    "names no stage-2 buffer",
                )
            })
            .collect();
        scope.pop()?;
        groups
    }

    /// Every buffer, by the WGSL variable's name the kernels bind it to.
    fn named(&self) -> Vec<(&'static str, &wgpu::Buffer)> {
        let mut named = vec![
            ("params", &self.params),
            ("rest", self.rest.buffer()),
            ("current", self.current.buffer()),
            ("previous", self.previous.buffer()),
            ("plain", self.plain.buffer()),
            ("rotations", self.rotations.buffer()),
            ("turn", self.turn.buffer()),
            ("force", self.force.buffer()),
            ("free", self.free.buffer()),
            ("loads", self.loads.buffer()),
            ("offsets", self.offsets.buffer()),
            ("indices", self.indices.buffer()),
            ("partials", self.partials.buffer()),
            ("elastic_particles", self.elastic_particles.buffer()),
            ("elastic_terms", self.elastic_terms.buffer()),
            ("potential", self.potential.buffer()),
            ("last_residual", self.descent.last_residual.buffer()),
            ("direction", self.descent.direction.buffer()),
            ("line_base", self.descent.line_base.buffer()),
            ("dot_parts", self.descent.dot_parts.buffer()),
        ];
        named.extend(self.coarse.named());
        named.extend(self.elastic_coarse.named());
        named.extend(self.pairing.named());
        named
    }

    /// The buffer bound to the WGSL variable `name`, if any.
    fn buffer(&self, name: &str) -> Option<&wgpu::Buffer> {
        self.named()
            .into_iter()
            .find(|&(n, _)| n == name)
            .map(|(_, b)| b)
    }

    pub(crate) fn bind_group(&self, kernel: Kernel) -> &wgpu::BindGroup {
        &self.bind_groups[kernel.index()]
    }

    pub(crate) fn workgroups(&self, kernel: Kernel) -> [u32; 2] {
        self.workgroups[kernel.index()]
    }

    pub(crate) fn params_offset(&self, slot: u32) -> u32 {
        // Bounded by SLOTS * min_uniform_buffer_offset_alignment.
        (u64::from(slot.min(SLOTS - 1)) * self.params_stride) as u32
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// Always false: a state holds at least one particle.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Number of control points (surface particles).
    pub fn control_count(&self) -> usize {
        self.controls.len()
    }

    /// The parameters of one iteration in `slot`, for this model. The
    /// elastic force (`model` 2) needs [`DeformState::set_elastic`], whose
    /// iterations run its own kernels.
    pub fn params(&self, model: ForceModel, alpha: f32, omega: f32, slot: u32) -> Params {
        Params {
            count: self.count,
            model: match model {
                ForceModel::Paper => 0,
                ForceModel::Symmetric => 1,
                ForceModel::Elastic => 2,
            },
            alpha,
            omega,
            slot: slot.min(SLOTS - 1),
            groups: self.step_groups,
            volume_delta: self.smoothed_delta(),
            volume_relaxation: RELAXATION as f32,
            volume_damping: 1.0,
        }
    }

    /// The volume smoother's `delta` where the next iterations make the
    /// smoothed step ([`Pass::SmoothedStep`]), else 0.
    fn smoothed_delta(&self) -> f32 {
        let smoothed = matches!(
            self.choices().correction,
            Correction::Elastic {
                smoothed: Some(_),
                ..
            }
        );
        match self.elastic_coarse.smoother {
            Some((delta, _)) if smoothed => delta,
            _ => 0.0,
        }
    }

    /// Writes the parameters of `slot` (taking effect at the next submit).
    pub fn write_params(&self, queue: &wgpu::Queue, slot: u32, params: Params) {
        queue.write_buffer(
            &self.params,
            u64::from(self.params_offset(slot)),
            bytemuck::bytes_of(&params),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatches_beyond_the_per_dimension_limit_become_two_dimensional() {
        assert_eq!(workgroups(3_001, 64, 65_535).ok(), Some([47, 1]));
        assert_eq!(workgroups(1, 64, 65_535).ok(), Some([1, 1]));
        // 100 workgroups with at most 30 per dimension: 30 x 4 (the last row partly idle).
        assert_eq!(workgroups(6_400, 64, 30).ok(), Some([30, 4]));
        assert!(matches!(
            workgroups(64 * 1_000, 64, 30),
            Err(GpuError::LimitExceeded { .. })
        ));
    }
}
