//! The compiled kernels and the step that records them.

use tissue_solve::stage2::{Choices, Pass, RotationMethod};

use crate::multilevel::{BLOCK_CYCLE_KERNELS, CYCLE_KERNELS};
use crate::state::DeformState;
use crate::support::Scopes;
use crate::{GpuError, shaders};

/// One stage-2 kernel (a WGSL entry point bound to the state's buffers).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// `local_rotations.wgsl`: `R_i` from `M_i` through the 3x3 SVD.
    LocalRotations,
    /// `local_rotations.wgsl::local_rotations_warm`: `R_i` by the polar
    /// update warm-started from the stored `R_i`, the SVD's where it does
    /// not settle (`RotationMethod::WarmPolar`; it stands in for
    /// [`Kernel::LocalRotations`] in the `WARM_*` iterations).
    LocalRotationsWarm,
    /// `local_rotations.wgsl::turn_rotations`: every stored rotation
    /// premultiplied by the state's turn (a frame boundary's; in no
    /// iteration, see [`DeformState::write_turn`]).
    TurnRotations,
    /// `elastic_targets.wgsl`: the elastic model's terms (target `T_i` and
    /// stress `U_i`), each particle's rotation the polar rotation of its
    /// gradient by the SVD (only on a state given [`DeformState::set_elastic`]).
    ElasticTargets,
    /// `elastic_targets.wgsl::elastic_targets_warm`: the same with the
    /// rotation warm-started from that of `M_i` (the `WARM_*` iterations).
    ElasticTargetsWarm,
    /// `elastic_targets.wgsl::elastic_force`: the elastic force gathered
    /// over the terms.
    ElasticForce,
    /// `elastic_targets.wgsl::elastic_potential`: each particle's part of
    /// the potential the elastic force descends (in no iteration, see
    /// [`DeformState::potential`]).
    ElasticPotential,
    /// `elastic_targets.wgsl::elastic_potential_work`: the loads' work
    /// taken from each free particle's part (after [`Kernel::ElasticPotential`],
    /// which has no binding left for the loads).
    ElasticPotentialWork,
    /// `deformation_force.wgsl`: the force, paper or symmetric.
    DeformationForce,
    /// `integrate.wgsl::integrate`: `q̂ = q + alpha F` into the plain buffer.
    Integrate,
    /// `step_norms.wgsl`: per-workgroup max and sum of `|q̂ − q|²`.
    StepNorms,
    /// `integrate.wgsl::chebyshev`: the Chebyshev combine; updates current and previous.
    Chebyshev,
    /// `step_norms.wgsl` on the update made, `current` against `previous`
    /// after the combine: the step a corrected solve's stopping rule takes
    /// (the CPU's `step_norms(current, next)`).
    UpdateNorms,
    /// `coarse.wgsl::coarse_residual`: per particle `(L e')_i` from the
    /// plain step, for the two-level solve.
    CoarseResidual,
    /// `coarse.wgsl::coarse_restrict`: per aggregate the sum of its
    /// particles' residuals.
    CoarseRestrict,
    /// `coarse.wgsl::coarse_forward`: one workgroup, the forward
    /// substitution of the coarse Laplacian's Cholesky factor.
    CoarseForward,
    /// `coarse.wgsl::coarse_backward`: one workgroup, the backward one.
    CoarseBackward,
    /// `coarse.wgsl::coarse_apply`: the coarse solution subtracted from
    /// the plain step of every particle of its aggregate.
    CoarseApply,
    /// `coarse_elastic.wgsl::elastic_step_of`: per particle the plain step,
    /// 0 outside the elastic aggregates.
    ElasticStep,
    /// `coarse_elastic.wgsl::elastic_change_of`: per particle the volume
    /// term's linearised change `sqrt(W_i) g_i . s`.
    ElasticChange,
    /// `coarse_elastic.wgsl::elastic_residual_of`: per particle `(K e')_j`.
    ElasticResidual,
    /// `coarse_elastic.wgsl::elastic_restrict`: per elastic aggregate the
    /// sum of its particles' residuals.
    ElasticRestrict,
    /// `coarse_elastic.wgsl::elastic_forward`: one workgroup, the forward
    /// substitution of the elastic coarse matrix's Cholesky factor.
    ElasticForward,
    /// `coarse_elastic.wgsl::elastic_backward`: one workgroup, the backward one.
    ElasticBackward,
    /// `coarse_elastic.wgsl::elastic_apply`: the solution subtracted from
    /// the plain step of every particle of its aggregate.
    ElasticApply,
    /// `volume_smoother.wgsl::smoother_residual`: per particle half the
    /// force, loads included, inside the elastic aggregates.
    SmootherResidual,
    /// `volume_smoother.wgsl::pressure_start`: per particle `h_i . r` and
    /// the pressures' first Jacobi sweep.
    PressureStart,
    /// `volume_smoother.wgsl::pressure_forces`: per particle the
    /// pressures' force `(H z)_k`.
    PressureForces,
    /// `volume_smoother.wgsl::pressure_sweep`: a further Jacobi sweep.
    PressureSweep,
    /// `volume_smoother.wgsl::smoothed_step`: the smoothed step into the
    /// plain buffer, and what the elastic correction takes.
    SmoothedStep,
    /// `multilevel.wgsl::cycle_start`: per aggregate the coarse cycles'
    /// first Jacobi sweep from zero.
    CycleStart,
    /// `multilevel.wgsl::cycle_sweep`: a further sweep, from the first of
    /// `x`'s buffers into the second.
    CycleSweep,
    /// The same sweep from the second buffer into the first.
    CycleSweepBack,
    /// `multilevel.wgsl::cycle_restrict`: per group the sum of its
    /// aggregates' residuals.
    CycleRestrict,
    /// `coarse.wgsl::coarse_forward` on the groups' vector and factor.
    GroupForward,
    /// `coarse.wgsl::coarse_backward` on the groups' vector and factor.
    GroupBackward,
    /// `multilevel.wgsl::cycle_prolong`: the groups' solution added to
    /// every aggregate of its group.
    CycleProlong,
    /// `block_multilevel.wgsl::block_cycle_start`: per elastic aggregate
    /// the elastic cycles' first block Jacobi sweep from zero.
    BlockCycleStart,
    /// `block_multilevel.wgsl::block_cycle_sweep`: a further sweep, from
    /// the first of `x`'s buffers into the second.
    BlockCycleSweep,
    /// The same sweep from the second buffer into the first.
    BlockCycleSweepBack,
    /// `block_multilevel.wgsl::block_cycle_restrict`: per group the sum of
    /// its aggregates' residuals.
    BlockCycleRestrict,
    /// `coarse_elastic.wgsl::elastic_forward` on the groups' vector and factor.
    BlockGroupForward,
    /// `coarse_elastic.wgsl::elastic_backward` on the groups' vector and factor.
    BlockGroupBackward,
    /// `block_multilevel.wgsl::block_cycle_prolong`: the groups' solution
    /// added to every aggregate of its group.
    BlockCycleProlong,
    /// `pair.wgsl`: each paired particle's spring towards the
    /// observation's plane at its nearest point (one thread a paired
    /// particle, its dispatch set with the pairing).
    Pair,
    /// `descent.wgsl::descent_dots`: per particle the conjugate-gradient
    /// phase's residual and its dot products' parts (after an iteration's
    /// passes up to its combine; in no iteration).
    DescentDots,
    /// `descent.wgsl::descent_direction`: per particle the new direction,
    /// and the line search's base.
    DescentDirection,
    /// `descent.wgsl::descent_move`: per particle the base moved along the
    /// direction.
    DescentMove,
}

impl Kernel {
    /// Every kernel, in the order of the state's per-kernel tables.
    pub const ALL: [Kernel; 48] = [
        Kernel::LocalRotations,
        Kernel::LocalRotationsWarm,
        Kernel::TurnRotations,
        Kernel::ElasticTargets,
        Kernel::ElasticTargetsWarm,
        Kernel::ElasticForce,
        Kernel::ElasticPotential,
        Kernel::ElasticPotentialWork,
        Kernel::DeformationForce,
        Kernel::Integrate,
        Kernel::StepNorms,
        Kernel::Chebyshev,
        Kernel::UpdateNorms,
        Kernel::CoarseResidual,
        Kernel::CoarseRestrict,
        Kernel::CoarseForward,
        Kernel::CoarseBackward,
        Kernel::CoarseApply,
        Kernel::ElasticStep,
        Kernel::ElasticChange,
        Kernel::ElasticResidual,
        Kernel::ElasticRestrict,
        Kernel::ElasticForward,
        Kernel::ElasticBackward,
        Kernel::ElasticApply,
        Kernel::SmootherResidual,
        Kernel::PressureStart,
        Kernel::PressureForces,
        Kernel::PressureSweep,
        Kernel::SmoothedStep,
        Kernel::CycleStart,
        Kernel::CycleSweep,
        Kernel::CycleSweepBack,
        Kernel::CycleRestrict,
        Kernel::GroupForward,
        Kernel::GroupBackward,
        Kernel::CycleProlong,
        Kernel::BlockCycleStart,
        Kernel::BlockCycleSweep,
        Kernel::BlockCycleSweepBack,
        Kernel::BlockCycleRestrict,
        Kernel::BlockGroupForward,
        Kernel::BlockGroupBackward,
        Kernel::BlockCycleProlong,
        Kernel::Pair,
        Kernel::DescentDots,
        Kernel::DescentDirection,
        Kernel::DescentMove,
    ];

    /// The kernels that run `pass`, in order, appended to `out`.
    pub fn of_pass(pass: Pass, out: &mut Vec<Kernel>) {
        match pass {
            Pass::Pair => out.push(Kernel::Pair),
            Pass::Rotations(RotationMethod::Svd) => out.push(Kernel::LocalRotations),
            Pass::Rotations(RotationMethod::WarmPolar) => out.push(Kernel::LocalRotationsWarm),
            Pass::ElasticTerms(RotationMethod::Svd) => out.push(Kernel::ElasticTargets),
            Pass::ElasticTerms(RotationMethod::WarmPolar) => {
                out.push(Kernel::ElasticTargetsWarm);
            }
            Pass::Force => out.push(Kernel::DeformationForce),
            Pass::ElasticForce => out.push(Kernel::ElasticForce),
            Pass::PlainStep => out.push(Kernel::Integrate),
            Pass::SmoothedStep { cycled, sweeps } => {
                // The pressures' first Jacobi sweep in `pressure_start`, each
                // further one a `pressure_sweep` after a `pressure_forces`,
                // and a last `pressure_forces` for the step.
                out.extend([Kernel::SmootherResidual, Kernel::PressureStart]);
                for _ in 1..sweeps {
                    out.extend([Kernel::PressureForces, Kernel::PressureSweep]);
                }
                out.extend([Kernel::PressureForces, Kernel::SmoothedStep]);
                Kernel::elastic_correction(cycled, out);
            }
            Pass::CoarseCorrection { cycled } => {
                out.extend([Kernel::CoarseResidual, Kernel::CoarseRestrict]);
                if cycled {
                    out.extend(CYCLE_KERNELS);
                } else {
                    out.extend([Kernel::CoarseForward, Kernel::CoarseBackward]);
                }
                out.push(Kernel::CoarseApply);
            }
            Pass::ElasticCorrection { cycled } => {
                out.push(Kernel::ElasticStep);
                Kernel::elastic_correction(cycled, out);
            }
            Pass::StepNorms => out.push(Kernel::StepNorms),
            Pass::Combine => out.push(Kernel::Chebyshev),
            Pass::UpdateNorms => out.push(Kernel::UpdateNorms),
        }
    }

    /// The elastic correction of the step in the plain buffer: its
    /// linearised change and residual, their sums per aggregate, the
    /// aggregates' system solved (by its factor's two substitutions, or by
    /// cycles), the solution applied.
    fn elastic_correction(cycled: bool, out: &mut Vec<Kernel>) {
        out.extend([
            Kernel::ElasticChange,
            Kernel::ElasticResidual,
            Kernel::ElasticRestrict,
        ]);
        if cycled {
            out.extend(BLOCK_CYCLE_KERNELS);
        } else {
            out.extend([Kernel::ElasticForward, Kernel::ElasticBackward]);
        }
        out.push(Kernel::ElasticApply);
    }

    /// The kernels of an iteration of `passes`, in order.
    pub fn of_passes(passes: &[Pass]) -> Vec<Kernel> {
        let mut out = Vec::new();
        for &pass in passes {
            Kernel::of_pass(pass, &mut out);
        }
        out
    }

    /// The most kernels any iteration runs (what a timestamp query set for
    /// one iteration must hold).
    pub fn longest_iteration() -> usize {
        Choices::all()
            .iter()
            .map(|choices| Kernel::of_passes(&choices.passes()).len())
            .max()
            .unwrap_or(0)
    }

    /// `(shader file, entry point)`.
    pub fn entry(self) -> (&'static str, &'static str) {
        match self {
            Kernel::LocalRotations => ("local_rotations", "local_rotations"),
            Kernel::LocalRotationsWarm => ("local_rotations", "local_rotations_warm"),
            Kernel::TurnRotations => ("local_rotations", "turn_rotations"),
            Kernel::ElasticTargets => ("elastic_targets", "elastic_targets"),
            Kernel::ElasticTargetsWarm => ("elastic_targets", "elastic_targets_warm"),
            Kernel::ElasticForce => ("elastic_targets", "elastic_force"),
            Kernel::ElasticPotential => ("elastic_targets", "elastic_potential"),
            Kernel::ElasticPotentialWork => ("elastic_targets", "elastic_potential_work"),
            Kernel::DeformationForce => ("deformation_force", "deformation_force"),
            Kernel::Integrate => ("integrate", "integrate"),
            Kernel::StepNorms | Kernel::UpdateNorms => ("step_norms", "step_norms"),
            Kernel::Chebyshev => ("integrate", "chebyshev"),
            Kernel::CoarseResidual => ("coarse", "coarse_residual"),
            Kernel::CoarseRestrict => ("coarse", "coarse_restrict"),
            Kernel::CoarseForward => ("coarse", "coarse_forward"),
            Kernel::CoarseBackward => ("coarse", "coarse_backward"),
            Kernel::CoarseApply => ("coarse", "coarse_apply"),
            Kernel::ElasticStep => ("coarse_elastic", "elastic_step_of"),
            Kernel::ElasticChange => ("coarse_elastic", "elastic_change_of"),
            Kernel::ElasticResidual => ("coarse_elastic", "elastic_residual_of"),
            Kernel::ElasticRestrict => ("coarse_elastic", "elastic_restrict"),
            Kernel::ElasticForward => ("coarse_elastic", "elastic_forward"),
            Kernel::ElasticBackward => ("coarse_elastic", "elastic_backward"),
            Kernel::ElasticApply => ("coarse_elastic", "elastic_apply"),
            Kernel::SmootherResidual => ("volume_smoother", "smoother_residual"),
            Kernel::PressureStart => ("volume_smoother", "pressure_start"),
            Kernel::PressureForces => ("volume_smoother", "pressure_forces"),
            Kernel::PressureSweep => ("volume_smoother", "pressure_sweep"),
            Kernel::SmoothedStep => ("volume_smoother", "smoothed_step"),
            Kernel::CycleStart => ("multilevel", "cycle_start"),
            Kernel::CycleSweep | Kernel::CycleSweepBack => ("multilevel", "cycle_sweep"),
            Kernel::CycleRestrict => ("multilevel", "cycle_restrict"),
            Kernel::GroupForward => ("coarse", "coarse_forward"),
            Kernel::GroupBackward => ("coarse", "coarse_backward"),
            Kernel::CycleProlong => ("multilevel", "cycle_prolong"),
            Kernel::BlockCycleStart => ("block_multilevel", "block_cycle_start"),
            Kernel::BlockCycleSweep | Kernel::BlockCycleSweepBack => {
                ("block_multilevel", "block_cycle_sweep")
            }
            Kernel::BlockCycleRestrict => ("block_multilevel", "block_cycle_restrict"),
            Kernel::BlockGroupForward => ("coarse_elastic", "elastic_forward"),
            Kernel::BlockGroupBackward => ("coarse_elastic", "elastic_backward"),
            Kernel::BlockCycleProlong => ("block_multilevel", "block_cycle_prolong"),
            Kernel::Pair => ("pair", "pair"),
            Kernel::DescentDots => ("descent", "descent_dots"),
            Kernel::DescentDirection => ("descent", "descent_direction"),
            Kernel::DescentMove => ("descent", "descent_move"),
        }
    }

    /// A name for reports: the entry point, or what `UpdateNorms` measures.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::UpdateNorms => "step_norms (update)",
            Kernel::CycleSweepBack => "cycle_sweep (back)",
            Kernel::GroupForward => "coarse_forward (groups)",
            Kernel::GroupBackward => "coarse_backward (groups)",
            Kernel::BlockCycleSweepBack => "block_cycle_sweep (back)",
            Kernel::BlockGroupForward => "elastic_forward (groups)",
            Kernel::BlockGroupBackward => "elastic_backward (groups)",
            other => other.entry().1,
        }
    }

    /// Whether it runs one thread a particle. Not so: the pairing runs one
    /// a paired particle, one workgroup sums
    /// the projections over all the others, one runs each substitution of
    /// a coarse solve, and the restrictions and the cycles run per
    /// aggregate or per group (their dispatches set with their coarse
    /// space).
    pub(crate) fn per_particle(self) -> bool {
        !matches!(
            self,
            Kernel::CoarseForward
                | Kernel::CoarseBackward
                | Kernel::CoarseRestrict
                | Kernel::ElasticForward
                | Kernel::ElasticBackward
                | Kernel::ElasticRestrict
                | Kernel::CycleStart
                | Kernel::CycleSweep
                | Kernel::CycleSweepBack
                | Kernel::CycleRestrict
                | Kernel::GroupForward
                | Kernel::GroupBackward
                | Kernel::CycleProlong
                | Kernel::BlockCycleStart
                | Kernel::BlockCycleSweep
                | Kernel::BlockCycleSweepBack
                | Kernel::BlockCycleRestrict
                | Kernel::BlockGroupForward
                | Kernel::BlockGroupBackward
                | Kernel::BlockCycleProlong
                | Kernel::Pair
        )
    }

    /// Position in [`Kernel::ALL`].
    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

/// A compute pipeline with its bind group layout (group 0, from naga's
/// reflection of the module) and its workgroup size (from the module).
#[derive(Debug)]
pub(crate) struct CompiledKernel {
    pub(crate) pipeline: wgpu::ComputePipeline,
    pub(crate) layout: wgpu::BindGroupLayout,
    pub(crate) bindings: Vec<shaders::Binding>,
    pub(crate) workgroup_size: u32,
}

/// A family of kernels: WGSL entry points named by an enum whose
/// declaration order is the order of its per-kernel tables.
pub trait KernelId: Copy + std::fmt::Debug + 'static {
    /// Every kernel of the family, in the order of its tables.
    const KERNELS: &'static [Self];

    /// Whether the family's uniforms are bound with a dynamic offset (one
    /// slot per iteration of a batch).
    const DYNAMIC_UNIFORM: bool = true;

    /// `(shader file, entry point)`.
    fn entry(self) -> (&'static str, &'static str);

    /// Position in [`KernelId::KERNELS`].
    fn index(self) -> usize;
}

/// The compiled kernels of one family, one per kernel, built once per
/// device: stage 2's ([`Pipelines`]), stage 1's
/// ([`crate::SamplingPipelines`]), the grid's ([`crate::GridPipelines`]) and
/// the structures' ([`crate::EmbeddingKernel`]).
#[derive(Debug)]
pub struct KernelSet<K> {
    kernels: Vec<CompiledKernel>,
    family: std::marker::PhantomData<K>,
}

impl<K: KernelId> KernelSet<K> {
    /// Compiles every kernel of the family for `device`; any wgpu error is
    /// returned, not panicked on.
    pub fn new(device: &wgpu::Device) -> Result<Self, GpuError> {
        let scope = Scopes::push(device);
        let built: Result<Vec<CompiledKernel>, GpuError> = K::KERNELS
            .iter()
            .map(|k| {
                let (file, entry) = k.entry();
                crate::support::compile(device, file, entry, K::DYNAMIC_UNIFORM)
            })
            .collect();
        scope.pop()?;
        Ok(Self {
            kernels: built?,
            family: std::marker::PhantomData,
        })
    }

    pub(crate) fn kernel(&self, kernel: K) -> &CompiledKernel {
        &self.kernels[kernel.index()]
    }

    /// Threads per workgroup of `kernel`, as its module declares.
    pub fn workgroup_size(&self, kernel: K) -> u32 {
        self.kernel(kernel).workgroup_size
    }
}

impl KernelId for Kernel {
    const KERNELS: &'static [Self] = &Kernel::ALL;

    fn entry(self) -> (&'static str, &'static str) {
        Kernel::entry(self)
    }

    fn index(self) -> usize {
        Kernel::index(self)
    }
}

/// The compiled stage-2 kernels, built once per device.
pub type Pipelines = KernelSet<Kernel>;

impl Pipelines {
    /// Records one dispatch of `kernel` over every particle, with the
    /// parameters of `slot` (see [`DeformState::write_params`]).
    pub fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
    ) {
        self.dispatch_timed(encoder, state, kernel, slot, None);
    }

    /// [`Pipelines::dispatch`] in a pass of its own that writes `timestamps`
    /// at its start and end (the benchmark's per-kernel timing; the device
    /// must have been opened with `wgpu::Features::TIMESTAMP_QUERY`).
    pub fn dispatch_timed(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 2"),
            timestamp_writes: timestamps,
        });
        self.dispatch_in(&mut pass, state, kernel, slot);
    }

    fn dispatch_in(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        state: &DeformState,
        kernel: Kernel,
        slot: u32,
    ) {
        let compiled = self.kernel(kernel);
        let [x, y] = state.workgroups(kernel);
        pass.set_pipeline(&compiled.pipeline);
        pass.set_bind_group(0, state.bind_group(kernel), &[state.params_offset(slot)]);
        pass.dispatch_workgroups(x, y, 1);
    }

    /// `kernels` in order, each with the parameters of `slot`, in one
    /// compute pass.
    pub fn record_kernels(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        kernels: &[Kernel],
        slot: u32,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 2 kernels"),
            timestamp_writes: None,
        });
        for &kernel in kernels {
            self.dispatch_in(&mut pass, state, kernel, slot);
        }
    }

    /// The step: `iterations` solver iterations (at most [`crate::SLOTS`]),
    /// iteration `k` with the parameters of slot `k`, in one compute pass,
    /// the kernels of [`DeformState::iteration`] (each pass of the
    /// iteration's [`tissue_solve::stage2::Choices::passes`] by its kernels).
    pub fn record_iterations(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        state: &DeformState,
        iterations: u32,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tissue stage 2 iterations"),
            timestamp_writes: None,
        });
        let iteration = state.iteration();
        for slot in 0..iterations.min(crate::SLOTS) {
            for &kernel in &iteration {
                self.dispatch_in(&mut pass, state, kernel, slot);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Kernel, KernelId};
    use crate::grid::GridKernel;
    use crate::multilevel::{BLOCK_CYCLE_KERNELS, CYCLE_KERNELS};
    use crate::sampler::SamplingKernel;
    use crate::structures::EmbeddingMoved;
    use tissue_solve::stage2::RotationMethod;
    use tissue_solve::stage2::{Choices, Correction, Pass};

    fn kernels(pass: Pass) -> Vec<Kernel> {
        Kernel::of_passes(&[pass])
    }

    /// The GPU's smoothed step runs as many Jacobi sweeps on the pressures
    /// as its pass asks (the CPU's smoother, `VolumeSmoother::sweeps`): the
    /// first in `pressure_start`, each further one a `pressure_sweep` after
    /// a `pressure_forces`, and a last `pressure_forces` for the step.
    #[test]
    fn the_smoothed_step_sweeps_as_often_as_its_pass_asks() {
        for sweeps in [1, 2, 5, tissue_solve::coarse::MAX_SMOOTHER_SWEEPS] {
            let smoothed = kernels(Pass::SmoothedStep {
                cycled: false,
                sweeps,
            });
            let count = |kernel| smoothed.iter().filter(|&&k| k == kernel).count();
            assert_eq!(count(Kernel::PressureStart), 1);
            assert_eq!(count(Kernel::PressureSweep), sweeps - 1);
            assert_eq!(count(Kernel::PressureForces), sweeps);
        }
    }

    /// The default iteration (the symmetric force, the two-level solve
    /// factored), kernel by kernel.
    #[test]
    fn the_default_iteration_runs_its_kernels_in_order() {
        let choices = Choices {
            elastic: false,
            rotations: RotationMethod::Svd,
            correction: Correction::Coarse { cycled: false },
            pairs: false,
        };
        assert_eq!(
            Kernel::of_passes(&choices.passes()),
            [
                Kernel::LocalRotations,
                Kernel::DeformationForce,
                Kernel::Integrate,
                Kernel::CoarseResidual,
                Kernel::CoarseRestrict,
                Kernel::CoarseForward,
                Kernel::CoarseBackward,
                Kernel::CoarseApply,
                Kernel::Chebyshev,
                Kernel::UpdateNorms,
            ]
        );
    }

    /// `index` is the declaration order; the per-kernel tables (the
    /// compiled set, bind groups, workgroups) are in `KERNELS` order, so the
    /// two must agree in every family.
    fn assert_indexed<K: KernelId>() {
        for (i, kernel) in K::KERNELS.iter().enumerate() {
            assert_eq!(kernel.index(), i, "{kernel:?}");
        }
    }

    #[test]
    fn the_warm_iterations_differ_from_the_svd_ones_only_in_the_rotations() {
        for svd in Choices::all()
            .into_iter()
            .filter(|c| c.rotations == RotationMethod::Svd)
        {
            let warm = Choices {
                rotations: RotationMethod::WarmPolar,
                ..svd
            };
            let (svd, warm) = (
                Kernel::of_passes(&svd.passes()),
                Kernel::of_passes(&warm.passes()),
            );
            assert_eq!(svd.len(), warm.len());
            for (&s, &w) in svd.iter().zip(&warm) {
                match s {
                    Kernel::LocalRotations => assert_eq!(w, Kernel::LocalRotationsWarm),
                    Kernel::ElasticTargets => assert_eq!(w, Kernel::ElasticTargetsWarm),
                    other => assert_eq!(w, other),
                }
            }
        }
    }

    /// Each cycled pass is its factored one with the cycles in place of
    /// the factor's two substitutions, and nothing else changed.
    #[test]
    fn a_cycled_pass_cycles_where_the_factored_one_substitutes() {
        for (factored, cycled, forward, backward, cycle) in [
            (
                Pass::CoarseCorrection { cycled: false },
                Pass::CoarseCorrection { cycled: true },
                Kernel::CoarseForward,
                Kernel::CoarseBackward,
                CYCLE_KERNELS,
            ),
            (
                Pass::ElasticCorrection { cycled: false },
                Pass::ElasticCorrection { cycled: true },
                Kernel::ElasticForward,
                Kernel::ElasticBackward,
                BLOCK_CYCLE_KERNELS,
            ),
            (
                Pass::SmoothedStep {
                    cycled: false,
                    sweeps: 2,
                },
                Pass::SmoothedStep {
                    cycled: true,
                    sweeps: 2,
                },
                Kernel::ElasticForward,
                Kernel::ElasticBackward,
                BLOCK_CYCLE_KERNELS,
            ),
        ] {
            let mut expected = Vec::new();
            for kernel in kernels(factored) {
                if kernel == forward {
                    expected.extend(cycle);
                } else if kernel != backward {
                    expected.push(kernel);
                }
            }
            assert_eq!(kernels(cycled), expected);
            assert!(Kernel::longest_iteration() >= expected.len());
        }
    }

    /// Each pass starts with a kernel of its own shader, and every stage-2
    /// kernel but the frame boundary's (the turn, the potential's
    /// measure) and the conjugate-gradient phase's (`descent.wgsl`, after
    /// an iteration's passes) runs in some iteration.
    #[test]
    fn every_pass_runs_its_shader_and_every_kernel_runs_in_a_pass() {
        let mut used = std::collections::HashSet::new();
        for choices in Choices::all() {
            for pass in choices.passes() {
                let list = kernels(pass);
                assert_eq!(list[0].entry().0, pass.shader(), "{pass:?}");
                used.extend(list);
            }
        }
        for kernel in Kernel::ALL {
            assert_eq!(
                used.contains(&kernel),
                !matches!(
                    kernel,
                    Kernel::TurnRotations
                        | Kernel::ElasticPotential
                        | Kernel::ElasticPotentialWork
                        | Kernel::DescentDots
                        | Kernel::DescentDirection
                        | Kernel::DescentMove
                ),
                "{kernel:?}"
            );
        }
    }

    #[test]
    fn every_kernel_indexes_its_place_in_its_family() {
        assert_indexed::<Kernel>();
        assert_indexed::<SamplingKernel>();
        assert_indexed::<GridKernel>();
        assert_indexed::<EmbeddingMoved>();
    }
}
