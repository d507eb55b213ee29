//! The elastic phase's two-level solve on the GPU: the aggregates (once per
//! model) and, each time the host linearises the elastic operator
//! ([`ElasticCoarse`], the CPU path's, made from positions read back), the
//! per-particle gradients and the factor `shaders/coarse_elastic.wgsl` reads.

use tissue_solve::coarse::{Aggregates, ElasticCoarse};

use crate::buffer::Storage;
use crate::coarse::{factor_of, members_of};
use crate::multilevel::BlockCycleBuffers;
use crate::support::scoped;
use crate::{ElasticGradient, GpuError, Rotation};

/// The buffers; empty (16 bytes each) until uploaded.
#[derive(Debug)]
pub(crate) struct ElasticCoarseBuffers {
    /// Number of aggregates (0: none uploaded).
    pub(crate) aggregates: u32,
    /// Whether a linearisation (gradients and factor) is uploaded.
    pub(crate) linearised: bool,
    /// The volume smoother's `delta` and Jacobi sweeps, where the uploaded
    /// linearisation has one (its iterations then make the smoothed step,
    /// `Pass::SmoothedStep`).
    pub(crate) smoother: Option<(f32, usize)>,
    aggregate: Storage<u32>,
    member_starts: Storage<u32>,
    members: Storage<u32>,
    /// Per particle `s_i` (`vec4`, w 1 inside an aggregate).
    step: Storage<[f32; 4]>,
    /// Per particle `sqrt(W_i) g_i . s`.
    change: Storage<f32>,
    /// Per particle `(K e')_j` (`vec4`).
    residual: Storage<[f32; 4]>,
    /// Per particle `sqrt(W_i) cof(F_i) B_i` and `sqrt(W_i) a_i cof(F_i)`.
    gradients: Storage<ElasticGradient>,
    /// Three entries per aggregate.
    pub(crate) coarse: Storage<f32>,
    row_starts: Storage<u32>,
    row_values: Storage<f32>,
    column_starts: Storage<u32>,
    column_rows: Storage<u32>,
    column_values: Storage<f32>,
    /// Per particle `(t_i, z_i, D_i, 0)`: the volume smoother's changes,
    /// pressures and diagonal (`vec4`).
    pressures: Storage<[f32; 4]>,
    /// Per particle the pressures' force `(H z)_k` (`vec4`).
    pressure_force: Storage<[f32; 4]>,
    /// The coarse matrix's two-grid cycles, where it is too large for one
    /// factor (the groups' factor then in `row_*` and `column_*`).
    pub(crate) cycles: BlockCycleBuffers,
}

impl ElasticCoarseBuffers {
    /// Nothing uploaded.
    pub(crate) fn empty(device: &wgpu::Device) -> Result<Self, GpuError> {
        let what = |name: &str| format!("the elastic {name} buffer (no coarse space)");
        Ok(Self {
            aggregates: 0,
            linearised: false,
            smoother: None,
            aggregate: Storage::init(device, "elastic_aggregate", &[], &what("aggregate"))?,
            member_starts: Storage::init(device, "elastic_member_starts", &[], &what("starts"))?,
            members: Storage::init(device, "elastic_members", &[], &what("members"))?,
            step: Storage::init(device, "elastic_step", &[], &what("step"))?,
            change: Storage::init(device, "elastic_change", &[], &what("change"))?,
            residual: Storage::init(device, "elastic_residual", &[], &what("residual"))?,
            gradients: Storage::init(device, "elastic_gradients", &[], &what("gradients"))?,
            coarse: Storage::init(device, "elastic_coarse", &[], &what("coarse"))?,
            row_starts: Storage::init(device, "elastic_row_starts", &[], &what("rows"))?,
            row_values: Storage::init(device, "elastic_row_values", &[], &what("rows"))?,
            column_starts: Storage::init(device, "elastic_column_starts", &[], &what("columns"))?,
            column_rows: Storage::init(device, "elastic_column_rows", &[], &what("columns"))?,
            column_values: Storage::init(device, "elastic_column_values", &[], &what("columns"))?,
            pressures: Storage::init(device, "pressures", &[], &what("pressures"))?,
            pressure_force: Storage::init(device, "pressure_force", &[], &what("pressure force"))?,
            cycles: BlockCycleBuffers::empty(device)?,
        })
    }

    /// The aggregates of a model of `particles` particles, and the
    /// per-particle scratch buffers; no linearisation yet.
    pub(crate) fn with_aggregates(
        device: &wgpu::Device,
        aggregates: &Aggregates,
        particles: usize,
    ) -> Result<Self, GpuError> {
        if aggregates.aggregate.len() != particles {
            return Err(GpuError::Length {
                what: "elastic aggregates (one per particle)",
                expected: particles,
                got: aggregates.aggregate.len(),
            });
        }
        let count = aggregates.count();
        let (member_starts, members) = members_of(&aggregates.aggregate, count);
        let what = |name: &str| format!("the elastic {name} buffer ({particles} particles)");
        let mut buffers = Self::empty(device)?;
        (
            buffers.aggregate,
            buffers.member_starts,
            buffers.members,
            buffers.step,
            buffers.change,
            buffers.residual,
            buffers.pressures,
            buffers.pressure_force,
        ) = scoped(device, || {
            Ok((
                Storage::init(
                    device,
                    "elastic_aggregate",
                    &aggregates.aggregate,
                    &what("aggregate"),
                )?,
                Storage::init(
                    device,
                    "elastic_member_starts",
                    &member_starts,
                    &what("starts"),
                )?,
                Storage::init(device, "elastic_members", &members, &what("members"))?,
                Storage::zeroed(device, "elastic_step", particles, &what("step"))?,
                Storage::zeroed(device, "elastic_change", particles, &what("change"))?,
                Storage::zeroed(device, "elastic_residual", particles, &what("residual"))?,
                Storage::zeroed(device, "pressures", particles, &what("pressures"))?,
                Storage::zeroed(device, "pressure_force", particles, &what("pressure force"))?,
            ))
        })?;
        buffers.aggregates = u32::try_from(count).map_err(|_| GpuError::LimitExceeded {
            limit: "u32 aggregate index",
            what: "the elastic coarse space's aggregates".into(),
            asked: count as u64,
            allowed: u64::from(u32::MAX),
        })?;
        Ok(buffers)
    }

    /// Uploads `coarse`, the elastic operator linearised at a state: the
    /// gradients scaled by `sqrt(W_i)` and the factor, or the cycles and
    /// their groups' factor, in `f32`.
    pub(crate) fn linearise(
        &mut self,
        device: &wgpu::Device,
        coarse: &ElasticCoarse,
    ) -> Result<(), GpuError> {
        let unknowns = 3 * self.aggregates as usize;
        let groups_factor;
        let (factor, factored, what) = match (coarse.envelope(), coarse.multilevel()) {
            (Some(factor), _) => (
                factor,
                unknowns,
                "elastic coarse unknowns (three an aggregate)",
            ),
            (None, Some(cycles)) => {
                if cycles.len() != self.aggregates as usize {
                    return Err(GpuError::Length {
                        what: "elastic cycles' aggregates",
                        expected: self.aggregates as usize,
                        got: cycles.len(),
                    });
                }
                groups_factor = cycles.groups_envelope().ok_or_else(|| {
                    GpuError::Internal(format!(
                        "the elastic cycles' matrix of {} groups is not positive definite in \
                         its envelope (a rounding failure)",
                        cycles.groups()
                    ))
                })?;
                (
                    &groups_factor,
                    3 * cycles.groups(),
                    "elastic cycles' group unknowns (three a group)",
                )
            }
            (None, None) => {
                return Err(GpuError::Internal(
                    "the elastic correction was made with the host's sparse factor, not in the \
                     envelope form or the cycles the GPU reads"
                        .into(),
                ));
            }
        };
        if factored > crate::GPU_COARSE_UNKNOWNS {
            return Err(GpuError::Internal(format!(
                "{what}: {factored}, more than the {} one workgroup substitutes in its memory",
                crate::GPU_COARSE_UNKNOWNS
            )));
        }
        if factor.len() != factored {
            return Err(GpuError::Length {
                what,
                expected: factored,
                got: factor.len(),
            });
        }
        self.cycles = match coarse.multilevel() {
            Some(cycles) => BlockCycleBuffers::upload(device, cycles)?,
            None => BlockCycleBuffers::empty(device)?,
        };
        let k = coarse.linearisation();
        let gradients: Vec<ElasticGradient> = (0..k.weights.len())
            .map(|i| {
                let root = k.weights[i].sqrt();
                ElasticGradient {
                    correction: Rotation::from((k.corrections[i] * root).as_mat3()),
                    scale: Rotation::from((k.scales[i] * root).as_mat3()),
                }
            })
            .collect();
        let ((row_starts, row_values), (column_starts, column_rows, column_values)) =
            factor_of(factor);
        let what = |name: &str| format!("the elastic {name} buffer ({unknowns} unknowns)");
        (
            self.gradients,
            self.coarse,
            self.row_starts,
            self.row_values,
            self.column_starts,
            self.column_rows,
            self.column_values,
        ) = scoped(device, || {
            Ok((
                Storage::init(device, "elastic_gradients", &gradients, &what("gradients"))?,
                Storage::zeroed(device, "elastic_coarse", unknowns, &what("coarse"))?,
                Storage::init(device, "elastic_row_starts", &row_starts, &what("rows"))?,
                Storage::init(device, "elastic_row_values", &row_values, &what("rows"))?,
                Storage::init(
                    device,
                    "elastic_column_starts",
                    &column_starts,
                    &what("columns"),
                )?,
                Storage::init(
                    device,
                    "elastic_column_rows",
                    &column_rows,
                    &what("columns"),
                )?,
                Storage::init(
                    device,
                    "elastic_column_values",
                    &column_values,
                    &what("columns"),
                )?,
            ))
        })?;
        // The volume smoother's diagonal, where it smooths: the rest of
        // each particle's entry is written by its kernels.
        self.smoother = match coarse.smoother() {
            Some(smoother) => {
                let pressures: Vec<[f32; 4]> = smoother
                    .diagonal()
                    .iter()
                    .map(|&d| [0.0, 0.0, d as f32, 0.0])
                    .collect();
                let particles = pressures.len();
                self.pressures = scoped(device, || {
                    Storage::init(
                        device,
                        "pressures",
                        &pressures,
                        &format!("the pressures buffer ({particles} particles)"),
                    )
                })?;
                Some((smoother.delta() as f32, smoother.sweeps()))
            }
            None => None,
        };
        self.linearised = true;
        Ok(())
    }

    /// The buffers by the names the shaders give them.
    pub(crate) fn named(&self) -> Vec<(&'static str, &wgpu::Buffer)> {
        let mut named = vec![
            ("elastic_aggregate", self.aggregate.buffer()),
            ("elastic_member_starts", self.member_starts.buffer()),
            ("elastic_members", self.members.buffer()),
            ("elastic_step", self.step.buffer()),
            ("elastic_change", self.change.buffer()),
            ("elastic_residual", self.residual.buffer()),
            ("elastic_gradients", self.gradients.buffer()),
            ("elastic_coarse", self.coarse.buffer()),
            ("elastic_row_starts", self.row_starts.buffer()),
            ("elastic_row_values", self.row_values.buffer()),
            ("elastic_column_starts", self.column_starts.buffer()),
            ("elastic_column_rows", self.column_rows.buffer()),
            ("elastic_column_values", self.column_values.buffer()),
            ("pressures", self.pressures.buffer()),
            ("pressure_force", self.pressure_force.buffer()),
        ];
        named.extend(self.cycles.named());
        named
    }
}
