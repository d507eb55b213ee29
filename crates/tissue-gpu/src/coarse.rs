//! The two-level solve's data on the GPU: the CPU path's coarse space
//! ([`CoarseSpace`], made once on the host, the same aggregates, factor and
//! contraction) in the buffers `shaders/coarse.wgsl` reads.

pub(crate) use tissue_solve::coarse::members_of;
use tissue_solve::coarse::{CoarseSpace, Envelope};

use crate::GpuError;
use crate::buffer::Storage;
use crate::multilevel::CycleBuffers;
use crate::support::scoped;

/// The coarse space's buffers; empty (16 bytes each) until
/// [`CoarseBuffers::upload`] fills them.
#[derive(Debug)]
pub(crate) struct CoarseBuffers {
    /// Number of aggregates (0: no coarse space).
    pub(crate) aggregates: u32,
    /// Per particle its aggregate, or [`OUTSIDE`].
    aggregate: Storage<u32>,
    /// Per particle `(L e')_i` (`vec4`).
    residual: Storage<[f32; 4]>,
    /// Per aggregate the start of its particles in `members` (aggregates + 1).
    member_starts: Storage<u32>,
    /// The particles of each aggregate, aggregate by aggregate.
    members: Storage<u32>,
    /// Per aggregate the restricted residual, then (factored) the coarse
    /// solution (`vec4`).
    pub(crate) coarse: Storage<[f32; 4]>,
    /// The coarse Laplacian's factor, where it is factored (else empty).
    factor: FactorBuffers,
    /// Its two-grid cycles, where it is too large to factor (else empty).
    pub(crate) cycles: CycleBuffers,
}

impl CoarseBuffers {
    /// No coarse space: every buffer empty.
    pub(crate) fn empty(device: &wgpu::Device) -> Result<Self, GpuError> {
        let what = |name: &str| format!("the {name} buffer (no coarse space)");
        Ok(Self {
            aggregates: 0,
            aggregate: Storage::init(device, "aggregate", &[], &what("aggregate"))?,
            residual: Storage::init(device, "residual", &[], &what("residual"))?,
            member_starts: Storage::init(device, "member_starts", &[], &what("member_starts"))?,
            members: Storage::init(device, "members", &[], &what("members"))?,
            coarse: Storage::init(device, "coarse", &[], &what("coarse"))?,
            factor: FactorBuffers::empty(device, "no coarse space")?,
            cycles: CycleBuffers::empty(device)?,
        })
    }

    /// `space`'s aggregates, and its factor or its cycles, for a model of
    /// `particles` particles; in `f32`.
    pub(crate) fn upload(
        device: &wgpu::Device,
        space: &CoarseSpace,
        particles: usize,
    ) -> Result<Self, GpuError> {
        let aggregate = space.aggregate();
        if aggregate.len() != particles {
            return Err(GpuError::Length {
                what: "coarse aggregates (one per particle)",
                expected: particles,
                got: aggregate.len(),
            });
        }
        let count = space.count();
        let aggregates = u32::try_from(count).map_err(|_| GpuError::LimitExceeded {
            limit: "u32 aggregate index",
            what: "the coarse space's aggregates".into(),
            asked: count as u64,
            allowed: u64::from(u32::MAX),
        })?;
        let (member_starts, members) = members_of(aggregate, count);
        let what = |name: &str| format!("the {name} buffer ({count} aggregates)");
        let (factor, cycles) = match (space.envelope(), space.multilevel()) {
            (Some(envelope), _) => (
                FactorBuffers::upload(device, &envelope, "the coarse Laplacian")?,
                CycleBuffers::empty(device)?,
            ),
            (None, Some(cycles)) => (
                FactorBuffers::empty(device, "the coarse space is cycled")?,
                CycleBuffers::upload(device, cycles)?,
            ),
            (None, None) => {
                return Err(GpuError::Internal(format!(
                    "the coarse space of {count} aggregates has neither a factor nor cycles"
                )));
            }
        };
        scoped(device, || {
            Ok(Self {
                aggregates,
                aggregate: Storage::init(device, "aggregate", aggregate, &what("aggregate"))?,
                residual: Storage::zeroed(device, "residual", particles, &what("residual"))?,
                member_starts: Storage::init(
                    device,
                    "member_starts",
                    &member_starts,
                    &what("member_starts"),
                )?,
                members: Storage::init(device, "members", &members, &what("members"))?,
                coarse: Storage::zeroed(device, "coarse", count, &what("coarse"))?,
                factor,
                cycles,
            })
        })
    }

    /// The buffers by the names the shaders give them.
    pub(crate) fn named(&self) -> Vec<(&'static str, &wgpu::Buffer)> {
        let mut named = vec![
            ("aggregate", self.aggregate.buffer()),
            ("residual", self.residual.buffer()),
            ("member_starts", self.member_starts.buffer()),
            ("members", self.members.buffer()),
            ("coarse", self.coarse.buffer()),
        ];
        named.extend(self.factor.named());
        named.extend(self.cycles.named());
        named
    }
}

/// A factor's buffers as `coarse.wgsl`'s substitutions read them.
#[derive(Debug)]
pub(crate) struct FactorBuffers {
    /// The factor's rows: where each starts in `row_values` (rows + 1).
    row_starts: Storage<u32>,
    /// Each row's entries from its first column to the diagonal.
    row_values: Storage<f32>,
    /// The factor's strictly lower entries by column: where each starts.
    column_starts: Storage<u32>,
    /// Their rows.
    column_rows: Storage<u32>,
    /// Their values.
    column_values: Storage<f32>,
}

impl FactorBuffers {
    /// No factor (`why` names the case in the buffers' errors).
    pub(crate) fn empty(device: &wgpu::Device, why: &str) -> Result<Self, GpuError> {
        let what = |name: &str| format!("the {name} buffer ({why})");
        Ok(Self {
            row_starts: Storage::init(device, "row_starts", &[], &what("row_starts"))?,
            row_values: Storage::init(device, "row_values", &[], &what("row_values"))?,
            column_starts: Storage::init(device, "column_starts", &[], &what("column_starts"))?,
            column_rows: Storage::init(device, "column_rows", &[], &what("column_rows"))?,
            column_values: Storage::init(device, "column_values", &[], &what("column_values"))?,
        })
    }

    /// `factor` in `f32` (`of` names the matrix in the buffers' errors).
    pub(crate) fn upload(
        device: &wgpu::Device,
        factor: &Envelope,
        of: &str,
    ) -> Result<Self, GpuError> {
        let ((row_starts, row_values), (column_starts, column_rows, column_values)) =
            factor_of(factor);
        let what = |name: &str| format!("the {name} buffer ({of}, {} rows)", factor.len());
        Ok(Self {
            row_starts: Storage::init(device, "row_starts", &row_starts, &what("row_starts"))?,
            row_values: Storage::init(device, "row_values", &row_values, &what("row_values"))?,
            column_starts: Storage::init(
                device,
                "column_starts",
                &column_starts,
                &what("column_starts"),
            )?,
            column_rows: Storage::init(device, "column_rows", &column_rows, &what("column_rows"))?,
            column_values: Storage::init(
                device,
                "column_values",
                &column_values,
                &what("column_values"),
            )?,
        })
    }

    /// The buffers by the names `coarse.wgsl` gives them.
    pub(crate) fn named(&self) -> [(&'static str, &wgpu::Buffer); 5] {
        [
            ("row_starts", self.row_starts.buffer()),
            ("row_values", self.row_values.buffer()),
            ("column_starts", self.column_starts.buffer()),
            ("column_rows", self.column_rows.buffer()),
            ("column_values", self.column_values.buffer()),
        ]
    }

    /// The buffer `coarse.wgsl` names `name`, if it is one of these.
    pub(crate) fn buffer(&self, name: &str) -> Option<&wgpu::Buffer> {
        self.named()
            .into_iter()
            .find(|&(n, _)| n == name)
            .map(|(_, b)| b)
    }
}

/// A factor's rows (where each starts, its entries from its first column
/// to the diagonal) and its strictly lower entries by column (where each
/// starts, their rows, their values), in `f32`.
#[allow(clippy::type_complexity, reason = "the five arrays the shaders read")]
pub(crate) fn factor_of(
    factor: &Envelope,
) -> ((Vec<u32>, Vec<f32>), (Vec<u32>, Vec<u32>, Vec<f32>)) {
    let mut row_starts = Vec::with_capacity(factor.len() + 1);
    let mut row_values = Vec::new();
    row_starts.push(0u32);
    for i in 0..factor.len() {
        let (_, row) = factor.row(i);
        row_values.extend(row.iter().map(|&v| v as f32));
        row_starts.push(row_values.len() as u32);
    }
    let (column_starts, column_rows, column_values) = factor.columns();
    let column_values = column_values.iter().map(|&v| v as f32).collect();
    (
        (row_starts, row_values),
        (column_starts, column_rows, column_values),
    )
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use crate::pipelines::{Kernel, Pipelines};
    use crate::state::DeformState;
    use tissue_solve::coarse::coarse_space;
    use tissue_solve::{DeformParams, Plan};

    /// The one-workgroup substitutions on the largest coarse space the GPU
    /// takes (the phantom at 45,000 particles: 3,900-odd aggregates, under
    /// [`crate::GPU_COARSE_UNKNOWNS`]) give the host's f64 solve to f32
    /// rounding, every row of it: a dispatch that stops short leaves rows
    /// unsolved.
    #[test]
    fn the_gpu_coarse_solve_matches_the_host_solve_at_the_largest_size_it_takes() {
        let Some((device, queue)) = crate::testing::gpu("largest coarse solve") else {
            return;
        };
        let model = crate::testing::phantom(45_000);
        let params = DeformParams::default();
        let plan = Plan::for_params(&model, &params).unwrap();
        let space = coarse_space(&model, &plan, &params).unwrap();
        let m = space.count();
        assert!(
            (3_000..=crate::GPU_COARSE_UNKNOWNS).contains(&m),
            "{m} aggregates: not near the limit"
        );
        let pipelines = Pipelines::new(&device).unwrap();
        let mut state = DeformState::new(&device, &queue, &pipelines, &model, &plan.free).unwrap();
        state.set_coarse(&device, &pipelines, &space).unwrap();
        let b: Vec<[f32; 4]> = (0..m)
            .map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), 0.5, 0.0])
            .collect();
        state.coarse.coarse.write(&queue, 0, &b).unwrap();
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        pipelines.dispatch(&mut encoder, &state, Kernel::CoarseForward, 0);
        pipelines.dispatch(&mut encoder, &state, Kernel::CoarseBackward, 0);
        queue.submit([encoder.finish()]);
        let x = state
            .coarse
            .coarse
            .read(&device, &queue, &state.readback)
            .unwrap();
        for axis in 0..3 {
            let mut want: Vec<f64> = b.iter().map(|v| f64::from(v[axis])).collect();
            space.factor().unwrap().solve_scalar(&mut want);
            let scale = want.iter().fold(0.0f64, |s, w| s.max(w.abs()));
            for (i, w) in want.iter().enumerate() {
                let off = (f64::from(x[i][axis]) - w).abs();
                assert!(
                    off <= 1e-4 * scale,
                    "{m} aggregates, row {i}, axis {axis}: {} against {w}",
                    x[i][axis]
                );
            }
        }
    }
}
