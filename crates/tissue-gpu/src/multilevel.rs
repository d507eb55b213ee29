//! The two-grid cycles of a coarse space too large for one factor
//! ([`Multilevel`], made on the host) in the buffers
//! `shaders/multilevel.wgsl` reads, and the order of their kernels.

use glam::DMat3;
use tissue_solve::coarse::{BlockMultilevel, CYCLES, Multilevel, SWEEPS};

use crate::buffer::Storage;
use crate::coarse::{FactorBuffers, members_of};
use crate::pipelines::Kernel;
use crate::support::scoped;
use crate::{GpuError, Rotation};

/// The kernels one family of cycles is made of: the Laplacian's
/// ([`CYCLE_KERNELS`]) or the elastic blocks' ([`BLOCK_CYCLE_KERNELS`]).
#[derive(Clone, Copy)]
struct CycleSet {
    start: Kernel,
    sweep: Kernel,
    sweep_back: Kernel,
    restrict: Kernel,
    forward: Kernel,
    backward: Kernel,
    prolong: Kernel,
}

/// Dispatches of one coarse solve by the cycles.
pub(crate) const CYCLE_LEN: usize =
    1 + (SWEEPS - 1) + CYCLES * (4 + SWEEPS) + (CYCLES - 1) * SWEEPS;

/// `set`'s kernels in order, between the restriction to the aggregates
/// (which leaves the right-hand side in the coarse vector) and the
/// application of the solution: the first sweep from zero into the first
/// of `x`'s two buffers, then per cycle its sweeps before (one fewer in
/// the first), the restriction over the groups, their substitutions, the
/// prolongation, and its sweeps after; each sweep reads one buffer and
/// writes the other. With an odd [`SWEEPS`] the restriction and
/// prolongation always find `x` in the first buffer and the last sweep
/// leaves it in the second, which the application then reads
/// ([`CycleBuffers::buffer_for`], [`BlockCycleBuffers::buffer_for`]).
const fn cycle_kernels(set: CycleSet) -> [Kernel; CYCLE_LEN] {
    let mut out = [set.start; CYCLE_LEN];
    // Where x is: true in the first buffer.
    let (mut k, mut first) = (1, true);
    let mut cycle = 0;
    while cycle < CYCLES {
        // The sweeps before the correction (one fewer in the first cycle,
        // whose start sweeps), then the correction and the sweeps after.
        let mut half = 0;
        while half < 2 {
            let mut sweep = if cycle == 0 && half == 0 { 1 } else { 0 };
            while sweep < SWEEPS {
                out[k] = if first { set.sweep } else { set.sweep_back };
                first = !first;
                (k, sweep) = (k + 1, sweep + 1);
            }
            if half == 0 {
                assert!(first, "the restriction reads x from the first buffer");
                out[k] = set.restrict;
                out[k + 1] = set.forward;
                out[k + 2] = set.backward;
                out[k + 3] = set.prolong;
                k += 4;
            }
            half += 1;
        }
        cycle += 1;
    }
    assert!(!first, "the application reads x from the second buffer");
    out
}

/// The coarse Laplacian's cycles: `shaders/multilevel.wgsl`, the groups
/// substituted by `coarse.wgsl`'s kernels.
pub(crate) const CYCLE_KERNELS: [Kernel; CYCLE_LEN] = cycle_kernels(CycleSet {
    start: Kernel::CycleStart,
    sweep: Kernel::CycleSweep,
    sweep_back: Kernel::CycleSweepBack,
    restrict: Kernel::CycleRestrict,
    forward: Kernel::GroupForward,
    backward: Kernel::GroupBackward,
    prolong: Kernel::CycleProlong,
});

/// The elastic coarse matrix's cycles: `shaders/block_multilevel.wgsl`,
/// the groups substituted by `coarse_elastic.wgsl`'s kernels.
pub(crate) const BLOCK_CYCLE_KERNELS: [Kernel; CYCLE_LEN] = cycle_kernels(CycleSet {
    start: Kernel::BlockCycleStart,
    sweep: Kernel::BlockCycleSweep,
    sweep_back: Kernel::BlockCycleSweepBack,
    restrict: Kernel::BlockCycleRestrict,
    forward: Kernel::BlockGroupForward,
    backward: Kernel::BlockGroupBackward,
    prolong: Kernel::BlockCycleProlong,
});

/// The cycles' buffers; empty (16 bytes each) where the coarse space is
/// factored.
#[derive(Debug)]
pub(crate) struct CycleBuffers {
    /// Number of groups (0: no cycles).
    pub(crate) groups: u32,
    /// `x`'s two buffers, one `vec4` an aggregate.
    first: Storage<[f32; 4]>,
    pub(crate) second: Storage<[f32; 4]>,
    /// The aggregates' matrix by rows, in `f32`.
    level_starts: Storage<u32>,
    level_columns: Storage<u32>,
    level_values: Storage<f32>,
    /// The Jacobi weight over each diagonal entry.
    level_weights: Storage<f32>,
    /// Per aggregate its group; per group its aggregates.
    group_of: Storage<u32>,
    group_starts: Storage<u32>,
    group_members: Storage<u32>,
    /// Per group the restricted residual, then the solution (`vec4`).
    group_coarse: Storage<[f32; 4]>,
    /// The groups' matrix factored within its envelope.
    factor: FactorBuffers,
}

impl CycleBuffers {
    /// No cycles: every buffer empty.
    pub(crate) fn empty(device: &wgpu::Device) -> Result<Self, GpuError> {
        let what = |name: &str| format!("the {name} buffer (no cycles)");
        Ok(Self {
            groups: 0,
            first: Storage::init(device, "cycle_first", &[], &what("cycle_first"))?,
            second: Storage::init(device, "cycle_second", &[], &what("cycle_second"))?,
            level_starts: Storage::init(device, "level_starts", &[], &what("level_starts"))?,
            level_columns: Storage::init(device, "level_columns", &[], &what("level_columns"))?,
            level_values: Storage::init(device, "level_values", &[], &what("level_values"))?,
            level_weights: Storage::init(device, "level_weights", &[], &what("level_weights"))?,
            group_of: Storage::init(device, "group_of", &[], &what("group_of"))?,
            group_starts: Storage::init(device, "group_starts", &[], &what("group_starts"))?,
            group_members: Storage::init(device, "group_members", &[], &what("group_members"))?,
            group_coarse: Storage::init(device, "group_coarse", &[], &what("group_coarse"))?,
            factor: FactorBuffers::empty(device, "no cycles")?,
        })
    }

    /// `cycles`' matrix, groups and the groups' factor, in `f32`.
    pub(crate) fn upload(device: &wgpu::Device, cycles: &Multilevel) -> Result<Self, GpuError> {
        let count = cycles.len();
        let groups = cycles.groups();
        let envelope = cycles.groups_envelope().ok_or_else(|| {
            GpuError::Internal(format!(
                "the coarse cycles' matrix of {groups} groups is not positive definite in its \
                 envelope (a rounding failure)"
            ))
        })?;
        let (starts, columns, values) = cycles.matrix();
        let level_starts = starts
            .iter()
            .map(|&s| u32_index(s, "the coarse cycles' matrix entries"))
            .collect::<Result<Vec<u32>, _>>()?;
        let level_values: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        let level_weights: Vec<f32> = cycles
            .weighted_inverse_diagonal()
            .iter()
            .map(|&w| w as f32)
            .collect();
        let (group_starts, group_members) = members_of(cycles.group(), groups);
        let what = |name: &str| format!("the {name} buffer ({count} aggregates, {groups} groups)");
        scoped(device, || {
            Ok(Self {
                groups: u32_index(groups, "the coarse cycles' groups")?,
                first: Storage::zeroed(device, "cycle_first", count, &what("cycle_first"))?,
                second: Storage::zeroed(device, "cycle_second", count, &what("cycle_second"))?,
                level_starts: Storage::init(
                    device,
                    "level_starts",
                    &level_starts,
                    &what("level_starts"),
                )?,
                level_columns: Storage::init(
                    device,
                    "level_columns",
                    columns,
                    &what("level_columns"),
                )?,
                level_values: Storage::init(
                    device,
                    "level_values",
                    &level_values,
                    &what("level_values"),
                )?,
                level_weights: Storage::init(
                    device,
                    "level_weights",
                    &level_weights,
                    &what("level_weights"),
                )?,
                group_of: Storage::init(device, "group_of", cycles.group(), &what("group_of"))?,
                group_starts: Storage::init(
                    device,
                    "group_starts",
                    &group_starts,
                    &what("group_starts"),
                )?,
                group_members: Storage::init(
                    device,
                    "group_members",
                    &group_members,
                    &what("group_members"),
                )?,
                group_coarse: Storage::zeroed(
                    device,
                    "group_coarse",
                    groups,
                    &what("group_coarse"),
                )?,
                factor: FactorBuffers::upload(device, &envelope, "the coarse cycles' groups")?,
            })
        })
    }

    /// The buffers by the names `shaders/multilevel.wgsl` gives them, `x`'s
    /// as a forward sweep binds them.
    pub(crate) fn named(&self) -> [(&'static str, &wgpu::Buffer); 10] {
        [
            ("cycle_from", self.first.buffer()),
            ("cycle_to", self.second.buffer()),
            ("level_starts", self.level_starts.buffer()),
            ("level_columns", self.level_columns.buffer()),
            ("level_values", self.level_values.buffer()),
            ("level_weights", self.level_weights.buffer()),
            ("group_of", self.group_of.buffer()),
            ("group_starts", self.group_starts.buffer()),
            ("group_members", self.group_members.buffer()),
            ("group_coarse", self.group_coarse.buffer()),
        ]
    }

    /// Where `kernel` binds `name` otherwise than [`CycleBuffers::named`]
    /// says: the backward sweep swaps `x`'s buffers; the first sweep and
    /// the prolongation write the first; the groups' substitutions run
    /// `coarse.wgsl`'s kernels on the groups' vector and factor; and,
    /// with cycles, `coarse_apply` reads the solution from the second.
    pub(crate) fn buffer_for(&self, kernel: Kernel, name: &str) -> Option<&wgpu::Buffer> {
        match (kernel, name) {
            (Kernel::CycleSweepBack, "cycle_from") => Some(self.second.buffer()),
            (Kernel::CycleSweepBack | Kernel::CycleStart | Kernel::CycleProlong, "cycle_to") => {
                Some(self.first.buffer())
            }
            (Kernel::GroupForward | Kernel::GroupBackward, "coarse") => {
                Some(self.group_coarse.buffer())
            }
            (Kernel::GroupForward | Kernel::GroupBackward, name) => self.factor.buffer(name),
            (Kernel::CoarseApply, "coarse") if self.groups > 0 => Some(self.second.buffer()),
            _ => None,
        }
    }
}

/// The elastic coarse matrix's cycles' buffers, three `f32` entries an
/// aggregate or a group; empty (16 bytes each) where that matrix is
/// factored. The groups' factor itself goes where the factored matrix's
/// would (`ElasticCoarseBuffers`), as the two are never both in use.
#[derive(Debug)]
pub(crate) struct BlockCycleBuffers {
    /// Number of groups (0: no cycles).
    pub(crate) groups: u32,
    /// `x`'s two buffers.
    first: Storage<f32>,
    pub(crate) second: Storage<f32>,
    /// The aggregates' block matrix by rows, in `f32`.
    block_starts: Storage<u32>,
    block_columns: Storage<u32>,
    block_values: Storage<Rotation>,
    /// The weight times each diagonal block's inverse.
    block_weights: Storage<Rotation>,
    /// Per aggregate its group; per group its aggregates.
    group_of: Storage<u32>,
    group_starts: Storage<u32>,
    group_members: Storage<u32>,
    /// Per group the restricted residual, then the solution.
    group_coarse: Storage<f32>,
}

impl BlockCycleBuffers {
    /// No cycles: every buffer empty.
    pub(crate) fn empty(device: &wgpu::Device) -> Result<Self, GpuError> {
        let what = |name: &str| format!("the {name} buffer (no elastic cycles)");
        Ok(Self {
            groups: 0,
            first: Storage::init(device, "block_first", &[], &what("block_first"))?,
            second: Storage::init(device, "block_second", &[], &what("block_second"))?,
            block_starts: Storage::init(device, "block_starts", &[], &what("block_starts"))?,
            block_columns: Storage::init(device, "block_columns", &[], &what("block_columns"))?,
            block_values: Storage::init(device, "block_values", &[], &what("block_values"))?,
            block_weights: Storage::init(device, "block_weights", &[], &what("block_weights"))?,
            group_of: Storage::init(device, "block_group_of", &[], &what("block_group_of"))?,
            group_starts: Storage::init(
                device,
                "block_group_starts",
                &[],
                &what("block_group_starts"),
            )?,
            group_members: Storage::init(
                device,
                "block_group_members",
                &[],
                &what("block_group_members"),
            )?,
            group_coarse: Storage::init(
                device,
                "block_group_coarse",
                &[],
                &what("block_group_coarse"),
            )?,
        })
    }

    /// `cycles`' block matrix, sweeps' weights and groups, in `f32`.
    pub(crate) fn upload(
        device: &wgpu::Device,
        cycles: &BlockMultilevel,
    ) -> Result<Self, GpuError> {
        let count = cycles.len();
        let groups = cycles.groups();
        let (starts, columns, values) = cycles.matrix();
        let block_starts = starts
            .iter()
            .map(|&s| u32_index(s, "the elastic cycles' matrix blocks"))
            .collect::<Result<Vec<u32>, _>>()?;
        let stored = |blocks: &[DMat3]| -> Vec<Rotation> {
            blocks.iter().map(|b| Rotation::from(b.as_mat3())).collect()
        };
        let (block_values, block_weights) =
            (stored(values), stored(cycles.weighted_inverse_diagonal()));
        let (group_starts, group_members) = members_of(cycles.group(), groups);
        let what =
            |name: &str| format!("the {name} buffer ({count} elastic aggregates, {groups} groups)");
        scoped(device, || {
            Ok(Self {
                groups: u32_index(groups, "the elastic cycles' groups")?,
                first: Storage::zeroed(device, "block_first", 3 * count, &what("block_first"))?,
                second: Storage::zeroed(device, "block_second", 3 * count, &what("block_second"))?,
                block_starts: Storage::init(
                    device,
                    "block_starts",
                    &block_starts,
                    &what("block_starts"),
                )?,
                block_columns: Storage::init(
                    device,
                    "block_columns",
                    columns,
                    &what("block_columns"),
                )?,
                block_values: Storage::init(
                    device,
                    "block_values",
                    &block_values,
                    &what("block_values"),
                )?,
                block_weights: Storage::init(
                    device,
                    "block_weights",
                    &block_weights,
                    &what("block_weights"),
                )?,
                group_of: Storage::init(
                    device,
                    "block_group_of",
                    cycles.group(),
                    &what("block_group_of"),
                )?,
                group_starts: Storage::init(
                    device,
                    "block_group_starts",
                    &group_starts,
                    &what("block_group_starts"),
                )?,
                group_members: Storage::init(
                    device,
                    "block_group_members",
                    &group_members,
                    &what("block_group_members"),
                )?,
                group_coarse: Storage::zeroed(
                    device,
                    "block_group_coarse",
                    3 * groups,
                    &what("block_group_coarse"),
                )?,
            })
        })
    }

    /// The buffers by the names `shaders/block_multilevel.wgsl` gives
    /// them, `x`'s as a forward sweep binds them.
    pub(crate) fn named(&self) -> [(&'static str, &wgpu::Buffer); 10] {
        [
            ("block_from", self.first.buffer()),
            ("block_to", self.second.buffer()),
            ("block_starts", self.block_starts.buffer()),
            ("block_columns", self.block_columns.buffer()),
            ("block_values", self.block_values.buffer()),
            ("block_weights", self.block_weights.buffer()),
            ("block_group_of", self.group_of.buffer()),
            ("block_group_starts", self.group_starts.buffer()),
            ("block_group_members", self.group_members.buffer()),
            ("block_group_coarse", self.group_coarse.buffer()),
        ]
    }

    /// Where `kernel` binds `name` otherwise than
    /// [`BlockCycleBuffers::named`] says: as [`CycleBuffers::buffer_for`],
    /// the groups' substitutions being `coarse_elastic.wgsl`'s on the
    /// groups' vector and `elastic_apply` reading the solution from the
    /// second buffer where there are cycles.
    pub(crate) fn buffer_for(&self, kernel: Kernel, name: &str) -> Option<&wgpu::Buffer> {
        match (kernel, name) {
            (Kernel::BlockCycleSweepBack, "block_from") => Some(self.second.buffer()),
            (
                Kernel::BlockCycleSweepBack | Kernel::BlockCycleStart | Kernel::BlockCycleProlong,
                "block_to",
            ) => Some(self.first.buffer()),
            (Kernel::BlockGroupForward | Kernel::BlockGroupBackward, "elastic_coarse") => {
                Some(self.group_coarse.buffer())
            }
            (Kernel::ElasticApply, "elastic_coarse") if self.groups > 0 => {
                Some(self.second.buffer())
            }
            _ => None,
        }
    }
}

/// `v` as a `u32` index, or the limit it exceeds.
fn u32_index(v: usize, what: &'static str) -> Result<u32, GpuError> {
    u32::try_from(v).map_err(|_| GpuError::LimitExceeded {
        limit: "u32 index",
        what: what.into(),
        asked: v as u64,
        allowed: u64::from(u32::MAX),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both families of cycles run as many sweeps, restrictions and
    /// substitutions as the host's `Multilevel::solve` and
    /// `BlockMultilevel::solve`, and the same kernels in the same places.
    #[test]
    fn the_gpu_cycles_sweep_as_often_as_the_host_cycles() {
        for (kernels, start, sweep, back, once_a_cycle) in [
            (
                CYCLE_KERNELS,
                Kernel::CycleStart,
                Kernel::CycleSweep,
                Kernel::CycleSweepBack,
                [
                    Kernel::CycleRestrict,
                    Kernel::GroupForward,
                    Kernel::GroupBackward,
                    Kernel::CycleProlong,
                ],
            ),
            (
                BLOCK_CYCLE_KERNELS,
                Kernel::BlockCycleStart,
                Kernel::BlockCycleSweep,
                Kernel::BlockCycleSweepBack,
                [
                    Kernel::BlockCycleRestrict,
                    Kernel::BlockGroupForward,
                    Kernel::BlockGroupBackward,
                    Kernel::BlockCycleProlong,
                ],
            ),
        ] {
            let count = |kernel| kernels.iter().filter(|&&k| k == kernel).count();
            assert_eq!(count(start), 1);
            assert_eq!(1 + count(sweep) + count(back), CYCLES * 2 * SWEEPS);
            for kernel in once_a_cycle {
                assert_eq!(count(kernel), CYCLES, "{kernel:?}");
            }
            // Sweeps alternate their buffers.
            let directions: Vec<bool> = kernels
                .iter()
                .filter_map(|&k| (k == sweep || k == back).then_some(k == sweep))
                .collect();
            assert!(directions.windows(2).all(|w| w[0] != w[1]));
            assert_eq!(kernels[0], start);
            assert_eq!(
                kernels.len(),
                count(start) + count(sweep) + count(back) + 4 * CYCLES
            );
        }
        // The two families in step, kernel for kernel: the same role
        // (`block_` before the blocks' names, the elastic substitutions
        // where the Laplacian's are).
        let role = |k: Kernel| {
            k.name()
                .trim_start_matches("block_")
                .replace("coarse_", "elastic_")
        };
        for (scalar, block) in CYCLE_KERNELS.iter().zip(BLOCK_CYCLE_KERNELS) {
            assert_eq!(role(*scalar), role(block), "{scalar:?} against {block:?}");
        }
    }

    /// One elastic coarse solve by the block cycles' kernels against the
    /// host's `BlockMultilevel::solve` of the same right-hand side (its
    /// sweeps in `f64`): within `f32` rounding, every aggregate.
    #[test]
    #[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
    fn the_gpu_block_cycles_solve_as_the_host_block_cycles_solve() {
        use crate::pipelines::Pipelines;
        use crate::state::DeformState;
        use glam::DVec3;
        use tissue_solve::coarse::{CorrectionFor, ElasticCoarse, elastic_aggregates};
        use tissue_solve::{DeformParams, ForceModel, Plan};

        let Some((device, queue)) = crate::testing::gpu("block cycles' solve") else {
            return;
        };
        let model = crate::testing::phantom(3_000);
        let params = DeformParams::default().with(|p| {
            p.force = ForceModel::Elastic;
        });
        let plan = Plan::for_params(&model, &params).unwrap();
        let elastic = plan.elastic.as_deref().unwrap();
        let aggregates = elastic_aggregates(&model, &plan, &params).unwrap();
        // The operator at a turned, stretched state (not at rest, where
        // the cofactors are the identity).
        let current: Vec<_> = model
            .positions
            .iter()
            .map(|p| glam::Mat3::from_rotation_z(0.3) * (*p * glam::Vec3::new(1.1, 1.0, 0.95)))
            .collect();
        let coarse = ElasticCoarse::new(
            &aggregates,
            &model.positions,
            &current,
            &model.connections,
            elastic,
            CorrectionFor {
                contraction: 0.1,
                smoothing: None,
                rho: Some(0.5),
                direct_max_aggregates: 30,
                envelope: true,
            },
        )
        .unwrap();
        let cycles = coarse.multilevel().unwrap();
        let m = cycles.len();
        assert!(
            cycles.groups() > 1 && cycles.groups() <= 30 && m > 100,
            "{m}"
        );
        let pipelines = Pipelines::new(&device).unwrap();
        let mut state = DeformState::new(&device, &queue, &pipelines, &model, &plan.free).unwrap();
        state.set_elastic(&device, &pipelines, elastic).unwrap();
        state
            .set_elastic_aggregates(&device, &pipelines, &aggregates)
            .unwrap();
        state
            .linearise_elastic(&device, &pipelines, &coarse)
            .unwrap();
        assert_eq!(state.elastic_groups(), cycles.groups());
        let b: Vec<f32> = (0..3 * m).map(|i| (i as f32 * 0.37).sin()).collect();
        state.elastic_coarse.coarse.write(&queue, 0, &b).unwrap();
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        for kernel in BLOCK_CYCLE_KERNELS {
            pipelines.dispatch(&mut encoder, &state, kernel, 0);
        }
        queue.submit([encoder.finish()]);
        let x = state
            .elastic_coarse
            .cycles
            .second
            .read(&device, &queue, &state.readback)
            .unwrap();
        let mut want: Vec<DVec3> = b
            .chunks(3)
            .map(|v| DVec3::new(v[0].into(), v[1].into(), v[2].into()))
            .collect();
        cycles.solve(&mut want);
        let scale = want
            .iter()
            .fold(0.0f64, |s, w| s.max(w.abs().max_element()));
        for (i, w) in want.iter().enumerate() {
            let got = DVec3::new(x[3 * i].into(), x[3 * i + 1].into(), x[3 * i + 2].into());
            assert!(
                (got - *w).abs().max_element() <= 1e-4 * scale,
                "{m} aggregates, row {i}: {got} against {w}"
            );
        }
        // Not a multiple of b: the cycles did solve something.
        let ratio = want[0].x / f64::from(b[0]);
        assert!(
            want.iter()
                .zip(b.chunks(3))
                .any(|(w, b)| (w.y - ratio * f64::from(b[1])).abs() > 1e-3 * scale)
        );
    }

    /// One coarse solve by the cycles' kernels against the host's
    /// `Multilevel::solve` of the same right-hand side (its sweeps in
    /// `f64`, its groups' factor in `f32`): within `f32` rounding, every
    /// aggregate.
    #[test]
    #[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
    fn the_gpu_cycles_solve_as_the_host_cycles_solve() {
        use crate::pipelines::Pipelines;
        use crate::state::DeformState;
        use glam::DVec3;
        use tissue_solve::coarse::coarse_space;
        use tissue_solve::{DeformParams, Plan};

        let Some((device, queue)) = crate::testing::gpu("cycles' solve") else {
            return;
        };
        let model = crate::testing::phantom(3_000);
        let params = DeformParams::default().with(|p| {
            p.tuning.coarse_direct_max_aggregates = 40;
        });
        let plan = Plan::for_params(&model, &params).unwrap();
        let space = coarse_space(&model, &plan, &params).unwrap();
        let cycles = space.multilevel().unwrap();
        let m = space.count();
        assert!(
            cycles.groups() > 1 && cycles.groups() <= 40 && m > 100,
            "{m}"
        );
        let pipelines = Pipelines::new(&device).unwrap();
        let mut state = DeformState::new(&device, &queue, &pipelines, &model, &plan.free).unwrap();
        state.set_coarse(&device, &pipelines, &space).unwrap();
        let b: Vec<[f32; 4]> = (0..m)
            .map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), 0.5, 0.0])
            .collect();
        state.coarse.coarse.write(&queue, 0, &b).unwrap();
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        for kernel in CYCLE_KERNELS {
            pipelines.dispatch(&mut encoder, &state, kernel, 0);
        }
        queue.submit([encoder.finish()]);
        let x = state
            .coarse
            .cycles
            .second
            .read(&device, &queue, &state.readback)
            .unwrap();
        let mut want: Vec<DVec3> = b
            .iter()
            .map(|v| DVec3::new(v[0].into(), v[1].into(), v[2].into()))
            .collect();
        cycles.solve(&mut want);
        let scale = want
            .iter()
            .fold(0.0f64, |s, w| s.max(w.abs().max_element()));
        for (i, w) in want.iter().enumerate() {
            let got = DVec3::new(x[i][0].into(), x[i][1].into(), x[i][2].into());
            assert!(
                (got - *w).abs().max_element() <= 1e-4 * scale,
                "{m} aggregates, row {i}: {got} against {w}"
            );
        }
        // Not the identity: the cycles did solve something.
        assert!(
            want.iter()
                .zip(&b)
                .any(|(w, b)| (w.x - f64::from(b[0])).abs() > 1e-3 * scale)
        );
    }
}
