//! The two-grid cycles of a coarse space too large for one factor
//! ([`Multilevel`], made on the host) in the buffers
//! `shaders/multilevel.wgsl` reads, and the order of their kernels.

use tissue_solve::multilevel::{CYCLES, Multilevel, SWEEPS};

use crate::GpuError;
use crate::buffer::Storage;
use crate::coarse::{FactorBuffers, members_of};
use crate::pipelines::Kernel;
use crate::support::scoped;

/// The cycles' kernels in order, between `coarse_restrict` (which leaves
/// the right-hand side in `coarse`) and `coarse_apply`: the first sweep
/// from zero into the first of `x`'s two buffers, then per cycle its
/// sweeps before (one fewer in the first), the restriction over the
/// groups, their substitutions, the prolongation, and its sweeps after;
/// each sweep reads one buffer and writes the other. With an odd
/// [`SWEEPS`] the restriction and prolongation always find `x` in the
/// first buffer and the last sweep leaves it in the second, which
/// `coarse_apply` then reads ([`CycleBuffers::buffer_for`]).
pub(crate) const CYCLE_KERNELS: [Kernel;
    1 + (SWEEPS - 1) + CYCLES * (4 + SWEEPS) + (CYCLES - 1) * SWEEPS] = {
    let mut out =
        [Kernel::CycleStart; 1 + (SWEEPS - 1) + CYCLES * (4 + SWEEPS) + (CYCLES - 1) * SWEEPS];
    // Where x is: true in the first buffer.
    let (mut k, mut first) = (1, true);
    let mut cycle = 0;
    while cycle < CYCLES {
        let mut sweep = if cycle == 0 { 1 } else { 0 };
        while sweep < SWEEPS {
            out[k] = if first {
                Kernel::CycleSweep
            } else {
                Kernel::CycleSweepBack
            };
            first = !first;
            (k, sweep) = (k + 1, sweep + 1);
        }
        assert!(first, "the restriction reads x from the first buffer");
        out[k] = Kernel::CycleRestrict;
        out[k + 1] = Kernel::GroupForward;
        out[k + 2] = Kernel::GroupBackward;
        out[k + 3] = Kernel::CycleProlong;
        k += 4;
        let mut sweep = 0;
        while sweep < SWEEPS {
            out[k] = if first {
                Kernel::CycleSweep
            } else {
                Kernel::CycleSweepBack
            };
            first = !first;
            (k, sweep) = (k + 1, sweep + 1);
        }
        cycle += 1;
    }
    assert!(!first, "coarse_apply reads x from the second buffer");
    out
};

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
        let index = |v: usize, what: &'static str| {
            u32::try_from(v).map_err(|_| GpuError::LimitExceeded {
                limit: "u32 index",
                what: what.into(),
                asked: v as u64,
                allowed: u64::from(u32::MAX),
            })
        };
        let level_starts = starts
            .iter()
            .map(|&s| index(s, "the coarse cycles' matrix entries"))
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
                groups: index(groups, "the coarse cycles' groups")?,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The cycles run as many sweeps, restrictions and substitutions as
    /// the host's `Multilevel::solve`.
    #[test]
    fn the_gpu_cycles_sweep_as_often_as_the_host_cycles() {
        let count = |kernel| CYCLE_KERNELS.iter().filter(|&&k| k == kernel).count();
        let sweeps = count(Kernel::CycleSweep) + count(Kernel::CycleSweepBack);
        assert_eq!(count(Kernel::CycleStart), 1);
        assert_eq!(1 + sweeps, CYCLES * 2 * SWEEPS);
        for kernel in [
            Kernel::CycleRestrict,
            Kernel::GroupForward,
            Kernel::GroupBackward,
            Kernel::CycleProlong,
        ] {
            assert_eq!(count(kernel), CYCLES, "{kernel:?}");
        }
        // Sweeps alternate their buffers.
        let directions: Vec<bool> = CYCLE_KERNELS
            .iter()
            .filter_map(|&k| match k {
                Kernel::CycleSweep => Some(true),
                Kernel::CycleSweepBack => Some(false),
                _ => None,
            })
            .collect();
        assert!(directions.windows(2).all(|w| w[0] != w[1]));
        assert_eq!(CYCLE_KERNELS[0], Kernel::CycleStart);
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

        let Ok((_, device, queue)) = crate::device_from_env() else {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "no GPU adapter under CI=true"
            );
            eprintln!("SKIPPED: no GPU adapter");
            return;
        };
        let model = tissue_cpu::sample(
            &tissue_core::phantom::default_breast(),
            &tissue_core::SamplingParams::with_particles(3_000),
            &mut |_| {},
        )
        .unwrap()
        .model;
        let params = DeformParams {
            coarse_direct_max_aggregates: 40,
            ..DeformParams::default()
        };
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
