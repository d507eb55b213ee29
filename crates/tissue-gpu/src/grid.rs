//! Stage 1's uniform grid and neighbour rows on the GPU: twins of
//! `tissue_solve::stage1::grid_build` (`shaders/grid_build.wgsl`) and
//! `tissue_solve::stage1::neighbour_rows` (`shaders/neighbour_rows.wgsl`).
//!
//! - [`GridPipelines`]: the compiled kernels, built once from a `&Device`.
//! - [`GridPipelines::grid_build`]: particles sorted into cells, [`GpuGrid`].
//! - [`GridPipelines::neighbour_rows`]: the CSR rows, [`GpuRows`].
//!
//! Particles are `array<vec4<f32>>` on the GPU: xyz the position, w the radius.
//!
//! **The layout never leaves the GPU.** The bounds (and the largest radius)
//! are reduced by `atomicMax` on order-preserving u32 keys (exact, so the
//! same as the CPU's fold), and one invocation, `grid_layout`, applies
//! `tissue_solve::stage1::grid_layout`'s rule with the same f32 operations in
//! the same order, writing [`GridLayout`] into a storage buffer that later
//! kernels read. The cell buffers are sized for the most cells the rule
//! allows ([`tissue_solve::stage1::max_cells`]: 8 per particle, at least 64),
//! and the prefix sum runs over all of them (cells past the grid's are
//! empty), so a grid build needs no readback at all. Bit-equal grids rely on
//! the device rounding `/` correctly, as lavapipe does; WGSL allows 2.5 ULP,
//! which on other hardware can move a particle lying within an ULP of a
//! cell face into the next cell (a different grid, but the same rows up to
//! pairs at their limit).
//!
//! **The prefix sum** is a multi-level exclusive scan: each level scans
//! blocks of one workgroup and scans the blocks' totals at the next level,
//! until one block remains; any length, up to the storage binding limit.
//!
//! **Stable order.** Counting uses `atomicAdd`, which serves particles in
//! any order; `cell_sort` then places each particle by the number of its
//! cell mates with a smaller index, which is the CPU's stable scatter.
//!
//! **One readback per neighbour-row build**: the total entry count (and the
//! layout's status word), to size the index buffer. Rebuilds are rare.
//! A non-finite position or radius sets that status word; every later
//! kernel then does nothing, and the host returns an error when it reads
//! the count ([`GpuGrid::read`] likewise).

use std::mem::offset_of;

use bytemuck::{Pod, Zeroable};
use tissue_core::SamplingError;
use tissue_solve::stage1::Grid;
use wgpu::util::DeviceExt;

use crate::GpuError;
use crate::buffer::{Storage, xyz};
use crate::pipelines::{CompiledKernel, KernelId, KernelSet};
use crate::readback::{Readback, read_buffer};
use crate::state::workgroups;
use crate::support::{Scopes, bind_group};

/// Mirror of WGSL `GridParams` (`shaders/shared/grid.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GridParams {
    /// Number of particles.
    pub count: u32,
    /// Cells the cell buffers hold.
    pub capacity: u32,
    /// The smallest cell edge asked for (a grid build).
    pub cell: f32,
    /// 1: the cell is half the neighbour reach, from the largest radius.
    pub rows: u32,
    /// Neighbour rows: the factor on `r_i + r_j`.
    pub factor: f32,
    /// Neighbour rows: the skin added to the limit.
    pub skin: f32,
    /// 1: rows ascending.
    pub sorted: u32,
    /// Elements of one prefix-sum level.
    pub len: u32,
    /// Neighbour rows: entries the `indices` binding holds ([`row_split`]);
    /// the rest follow the row starts in `offsets`.
    pub split: u32,
    /// Padding.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

/// Entries of neighbour rows one storage binding of a device with `limits`
/// holds. Rows with more entries keep the rest in the offsets buffer, after
/// the `count + 1` row starts ([`GpuRows`]), so rows up to about twice one
/// binding fit: stage 1's rows at 1,000,000 particles are 217 MB, over the
/// 128 MiB of lavapipe's binding and of wgpu's default limits.
pub fn row_split(limits: &wgpu::Limits) -> u32 {
    u32::try_from(limits.max_storage_buffer_binding_size / 4).unwrap_or(u32::MAX)
}

/// Mirror of WGSL `GridLayout` (`shaders/shared/grid.wgsl`): the grid the
/// `grid_layout` kernel chose.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GridLayout {
    /// Corner of cell `(0, 0, 0)`; w the reciprocal of the cell edge,
    /// rounded to nearest (the CPU's `1.0 / cell`).
    pub origin: [f32; 4],
    /// Cells along x, y, z; w the number of cells.
    pub dims: [u32; 4],
    /// Cell edge length.
    pub cell: f32,
    /// Neighbour rows: the largest pair limit.
    pub reach: f32,
    /// Neighbour rows: cells searched on each side.
    pub span: u32,
    /// 0, or why the grid is unusable (1: a non-finite position or radius).
    pub status: u32,
}

/// A kernel of the grid and neighbour rows (a WGSL entry point of
/// `grid_build.wgsl` or `neighbour_rows.wgsl`; its own bind group layout
/// holds only the bindings the entry point uses).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridKernel {
    /// Bounds of the particles, by u32 atomics.
    GridBounds,
    /// The grid's origin, cell and dimensions, in one invocation.
    GridLayout,
    /// Particles per cell.
    CellCount,
    /// One level of the prefix sum: each block's sums.
    ScanBlocks,
    /// One level of the prefix sum: the blocks' offsets added back.
    ScanAdd,
    /// Particles into their cells.
    CellScatter,
    /// Each cell's run made ascending.
    CellSort,
    /// Particles in grid-cell order.
    Reorder,
    /// Entries per neighbour row.
    CountRows,
    /// The rows' entries.
    FillRows,
    /// Each row made ascending.
    SortRows,
}

impl GridKernel {
    /// Every grid kernel, in the order of the compiled set.
    pub const ALL: [GridKernel; 11] = [
        GridKernel::GridBounds,
        GridKernel::GridLayout,
        GridKernel::CellCount,
        GridKernel::ScanBlocks,
        GridKernel::ScanAdd,
        GridKernel::CellScatter,
        GridKernel::CellSort,
        GridKernel::Reorder,
        GridKernel::CountRows,
        GridKernel::FillRows,
        GridKernel::SortRows,
    ];
}

impl KernelId for GridKernel {
    const KERNELS: &'static [Self] = &GridKernel::ALL;
    const DYNAMIC_UNIFORM: bool = false;

    fn entry(self) -> (&'static str, &'static str) {
        let entry = match self {
            GridKernel::GridBounds => "grid_bounds",
            GridKernel::GridLayout => "grid_layout",
            GridKernel::CellCount => "cell_count",
            GridKernel::ScanBlocks => "scan_blocks",
            GridKernel::ScanAdd => "scan_add",
            GridKernel::CellScatter => "cell_scatter",
            GridKernel::CellSort => "cell_sort",
            GridKernel::Reorder => "reorder",
            GridKernel::CountRows => "count_rows",
            GridKernel::FillRows => "fill_rows",
            GridKernel::SortRows => "sort_rows",
        };
        let file = match self {
            GridKernel::Reorder
            | GridKernel::CountRows
            | GridKernel::FillRows
            | GridKernel::SortRows => "neighbour_rows",
            _ => "grid_build",
        };
        (file, entry)
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// The compiled grid and neighbour-row kernels, built once per device.
pub type GridPipelines = KernelSet<GridKernel>;

/// A grid on the GPU. Valid once the queue has run the build (the buffers
/// are used in submission order); the layout is only on the GPU. The
/// buffers are raw, for a caller to bind in its own kernels.
#[derive(Debug)]
pub struct GpuGrid {
    /// One [`GridLayout`].
    pub layout: wgpu::Buffer,
    /// `capacity + 1` u32: cell `c` holds `particles[cell_start[c]..cell_start[c + 1]]`.
    pub cell_start: wgpu::Buffer,
    /// `count` u32: particle indices in cell order, ascending within a cell.
    pub particles: wgpu::Buffer,
    /// Number of particles.
    pub count: u32,
    /// Cells the buffers hold (the grid uses the first `layout.dims.w`).
    pub capacity: u32,
}

/// Neighbour rows on the GPU: row `i` is entries `offsets[i]..offsets[i + 1]`,
/// entry `k` being `indices[k]` below `split` and
/// `offsets[count + 1 + k - split]` from there (rows longer than one
/// binding holds, [`row_split`]). The buffers are raw, for a caller to bind
/// in its own kernels.
#[derive(Debug)]
pub struct GpuRows {
    /// `count + 1` u32, then the entries from `split` on, if any.
    pub offsets: wgpu::Buffer,
    /// `min(entries, split)` u32 (at least one slot, so that it can be bound).
    pub indices: wgpu::Buffer,
    /// Number of particles.
    pub count: u32,
    /// Entries over all rows.
    pub entries: u32,
    /// Entries `indices` holds at most: [`row_split`] of the device.
    pub split: u32,
}

/// Buffers of one dispatch, by the WGSL variable's name.
type Named<'a> = [(&'a str, &'a wgpu::Buffer)];

/// One recorded dispatch: kernel, its bind group, workgroups `[x, y]`.
type Step<'a> = (&'a CompiledKernel, wgpu::BindGroup, [u32; 2]);

impl GridPipelines {
    /// Levels of the prefix sum over `len` elements (one workgroup's block
    /// per element of the next level, until one block remains).
    pub fn scan_levels(&self, len: u32) -> u32 {
        scan_lengths(len, self.workgroup_size(GridKernel::ScanBlocks)).len() as u32
    }

    /// Sorts the first `count` particles of `positions` (`vec4`: xyz
    /// position, w unused here) into a grid with cells of at least `cell`:
    /// `tissue_solve::stage1::grid_build`. Submits the work and returns without
    /// waiting.
    pub fn grid_build(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        positions: &wgpu::Buffer,
        count: u32,
        cell: f32,
    ) -> Result<GpuGrid, GpuError> {
        if !cell.is_finite() {
            return Err(invalid(SamplingError::NonFiniteSize {
                what: "the grid cell",
                value: cell.to_string(),
            }));
        }
        let empty = placeholder_for(device, positions);
        let positions = empty.as_ref().unwrap_or(positions);
        let params = GridParams {
            cell,
            ..GridParams::default()
        };
        let scopes = Scopes::push(device);
        let built = (|| {
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("grid_build"),
            });
            let grid = self.record_grid(device, &mut encoder, positions, count, params)?;
            queue.submit([encoder.finish()]);
            Ok(grid)
        })();
        scopes.pop()?;
        built
    }

    /// Neighbour rows of the first `count` particles of `positions` (`vec4`:
    /// xyz position, w radius): `j != i` with
    /// `|p_i - p_j| < factor (r_i + r_j) + skin`, each row in grid order or
    /// ascending when `sorted`; `tissue_solve::stage1::neighbour_rows`. Waits
    /// once, for the number of entries; the fill is submitted, not awaited.
    ///
    /// Errors: a non-finite position, radius, factor or skin is
    /// [`GpuError::Model`]; buffers or dispatches beyond the device's limits
    /// are [`GpuError::LimitExceeded`]; a short `positions` buffer is
    /// [`GpuError::Length`].
    #[allow(
        clippy::too_many_arguments,
        reason = "the CPU twin's inputs in its order, plus device, queue and count"
    )]
    pub fn neighbour_rows(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        positions: &wgpu::Buffer,
        count: u32,
        factor: f32,
        skin: f32,
        sorted: bool,
    ) -> Result<GpuRows, GpuError> {
        if !factor.is_finite() || !skin.is_finite() {
            return Err(invalid(SamplingError::NonFiniteSize {
                what: "the neighbour limit's factor and skin",
                value: format!("{factor} and {skin}"),
            }));
        }
        let empty = placeholder_for(device, positions);
        let positions = empty.as_ref().unwrap_or(positions);
        let params = GridParams {
            rows: 1,
            factor,
            skin,
            sorted: u32::from(sorted),
            ..GridParams::default()
        };
        let limits = device.limits();
        let scopes = Scopes::push(device);
        let counted = (|| {
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("neighbour_rows count"),
            });
            let grid = self.record_grid(device, &mut encoder, positions, count, params)?;
            let params = GridParams {
                capacity: grid.capacity,
                count,
                ..params
            };
            let uniform = uniform(device, &params);
            let in_cell_order = storage::<[f32; 4]>(device, "in_cell_order", count)?;
            let offsets = storage::<u32>(device, "offsets", count + 1)?;
            // The total entry count, then the layout's status.
            let summary = storage::<u32>(device, "neighbour_rows summary", 2)?;
            // `count_rows` and `fill_rows` share one search, which names
            // `indices`; counting never writes it, so a placeholder binds.
            let placeholder = storage::<u32>(device, "indices placeholder", 1)?;
            let named: &Named = &[
                ("params", &uniform),
                ("positions", positions),
                ("grid", &grid.layout),
                ("cell_start", &grid.cell_start),
                ("particles", &grid.particles),
                ("in_cell_order", in_cell_order.buffer()),
                ("offsets", offsets.buffer()),
                ("indices", placeholder.buffer()),
            ];
            let mut steps = Vec::new();
            for kernel in [GridKernel::Reorder, GridKernel::CountRows] {
                steps.push(self.step(device, kernel, named, count, &limits)?);
            }
            let scan = self.scan_steps(device, &offsets, count + 1, &limits)?;
            encoder.clear_buffer(offsets.buffer(), 0, None);
            record(
                &mut encoder,
                "neighbour_rows count",
                steps.into_iter().chain(scan),
            );
            // The total is the last offset; the status tells whether there was a grid.
            let word = size_of::<u32>() as u64;
            let last = u64::from(count) * word;
            let status = offset_of!(GridLayout, status) as u64;
            encoder.copy_buffer_to_buffer(offsets.buffer(), last, summary.buffer(), 0, word);
            encoder.copy_buffer_to_buffer(&grid.layout, status, summary.buffer(), word, word);
            queue.submit([encoder.finish()]);
            Ok::<_, GpuError>((grid, params, in_cell_order, offsets, summary))
        })();
        scopes.pop()?;
        let (grid, params, in_cell_order, offsets, summary) = counted?;
        let (entries, status) = match summary.read(device, queue, &Readback::default())?[..] {
            [entries, status] => (entries, status),
            _ => return Err(GpuError::Map("the rows' summary came back short".into())),
        };
        check_status(status)?;

        let split = row_split(&limits);
        let low = entries.min(split);
        let scopes = Scopes::push(device);
        let filled = (|| {
            let indices = storage::<u32>(device, "indices", low)?;
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("neighbour_rows fill"),
            });
            // Entries past one binding follow the row starts.
            let offsets = if entries > split {
                let words = u64::from(count) + 1 + u64::from(entries - split);
                let overflow = Storage::<u32>::zeroed(
                    device,
                    "offsets and overflow",
                    words as usize,
                    &format!(
                        "the neighbour rows' starts and their entries past one binding \
                         ({entries} entries, {split} in one binding)"
                    ),
                )?;
                let starts = (u64::from(count) + 1) * size_of::<u32>() as u64;
                encoder.copy_buffer_to_buffer(offsets.buffer(), 0, overflow.buffer(), 0, starts);
                overflow
            } else {
                offsets
            };
            let uniform = uniform(device, &GridParams { split, ..params });
            let named: &Named = &[
                ("params", &uniform),
                ("positions", positions),
                ("grid", &grid.layout),
                ("cell_start", &grid.cell_start),
                ("particles", &grid.particles),
                ("in_cell_order", in_cell_order.buffer()),
                ("offsets", offsets.buffer()),
                ("indices", indices.buffer()),
            ];
            let mut steps = vec![self.step(device, GridKernel::FillRows, named, count, &limits)?];
            if sorted {
                steps.push(self.step(device, GridKernel::SortRows, named, count, &limits)?);
            }
            record(&mut encoder, "neighbour_rows fill", steps);
            queue.submit([encoder.finish()]);
            Ok::<_, GpuError>((offsets, indices))
        })();
        scopes.pop()?;
        let (offsets, indices) = filled?;
        Ok(GpuRows {
            offsets: offsets.into_buffer(),
            indices: indices.into_buffer(),
            count,
            entries,
            split,
        })
    }

    /// The exclusive prefix sum of `values` on the GPU, read back: the scan
    /// the grid and the rows use, for tests and tools.
    pub fn exclusive_scan(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        values: &[u32],
    ) -> Result<Vec<u32>, GpuError> {
        let len = u32::try_from(values.len()).map_err(|_| GpuError::LimitExceeded {
            limit: "u32 index",
            what: "a prefix sum".into(),
            asked: values.len() as u64,
            allowed: u64::from(u32::MAX),
        })?;
        let limits = device.limits();
        let scopes = Scopes::push(device);
        let built = (|| {
            let data = storage::<u32>(device, "scan", len)?;
            data.write(queue, 0, values)?;
            let steps = self.scan_steps(device, &data, len, &limits)?;
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("exclusive_scan"),
            });
            record(&mut encoder, "exclusive_scan", steps);
            queue.submit([encoder.finish()]);
            Ok::<_, GpuError>(data)
        })();
        scopes.pop()?;
        built?.read(device, queue, &Readback::default())
    }

    /// Records the grid build of `positions` into `encoder`.
    fn record_grid(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        positions: &wgpu::Buffer,
        count: u32,
        params: GridParams,
    ) -> Result<GpuGrid, GpuError> {
        let limits = device.limits();
        let needed = u64::from(count) * 16;
        if positions.size() < needed {
            return Err(GpuError::Length {
                what: "bytes of the particle buffer (16 per particle)",
                expected: needed as usize,
                got: positions.size() as usize,
            });
        }
        if positions.size() > limits.max_storage_buffer_binding_size {
            return Err(GpuError::LimitExceeded {
                limit: "max_storage_buffer_binding_size",
                what: "the particle buffer".into(),
                asked: positions.size(),
                allowed: limits.max_storage_buffer_binding_size,
            });
        }
        let capacity = tissue_solve::stage1::max_cells(count as usize);
        let starts = u32::try_from(capacity + 1).map_err(|_| GpuError::LimitExceeded {
            limit: "u32 cell index",
            what: format!("the grid of {count} particles"),
            asked: capacity + 1,
            allowed: u64::from(u32::MAX),
        })?;
        let params = GridParams {
            count,
            capacity: starts - 1,
            ..params
        };
        let uniform = uniform(device, &params);
        // Order-preserving keys of the bounds' corners and the largest radius.
        let bounds = storage::<u32>(device, "bounds", 8)?;
        let layout = storage::<GridLayout>(device, "grid", 1)?;
        let cell_of = storage::<u32>(device, "cell_of", count)?;
        let cell_start = storage::<u32>(device, "cell_start", starts)?;
        let arrival = storage::<u32>(device, "arrival", count)?;
        let arrived = storage::<u32>(device, "arrived", count)?;
        let particles = storage::<u32>(device, "particles", count)?;
        let named: &Named = &[
            ("params", &uniform),
            ("positions", positions),
            ("bounds", bounds.buffer()),
            ("grid", layout.buffer()),
            ("cell_of", cell_of.buffer()),
            ("cell_counts", cell_start.buffer()),
            ("cell_start", cell_start.buffer()),
            ("arrival", arrival.buffer()),
            ("arrived", arrived.buffer()),
            ("particles", particles.buffer()),
        ];
        let mut steps = vec![
            self.step(device, GridKernel::GridBounds, named, count, &limits)?,
            self.step(device, GridKernel::GridLayout, named, 1, &limits)?,
            self.step(device, GridKernel::CellCount, named, count, &limits)?,
        ];
        steps.extend(self.scan_steps(device, &cell_start, starts, &limits)?);
        steps.push(self.step(device, GridKernel::CellScatter, named, count, &limits)?);
        steps.push(self.step(device, GridKernel::CellSort, named, count, &limits)?);
        encoder.clear_buffer(bounds.buffer(), 0, None);
        encoder.clear_buffer(cell_start.buffer(), 0, None);
        record(encoder, "grid_build", steps);
        Ok(GpuGrid {
            layout: layout.into_buffer(),
            cell_start: cell_start.into_buffer(),
            particles: particles.into_buffer(),
            count,
            capacity: starts - 1,
        })
    }

    /// The dispatches of an in-place exclusive prefix sum of `data[..len]`:
    /// every level's blocks upwards, then the offsets added downwards.
    fn scan_steps(
        &self,
        device: &wgpu::Device,
        data: &Storage<u32>,
        len: u32,
        limits: &wgpu::Limits,
    ) -> Result<Vec<Step<'_>>, GpuError> {
        let lengths = scan_lengths(len, self.workgroup_size(GridKernel::ScanBlocks));
        // Level k's data is level k - 1's block totals; the last level's
        // single total goes to a spare word.
        let mut levels = vec![data.clone()];
        for &n in &lengths[1..] {
            levels.push(storage(device, "scan level", n)?);
        }
        levels.push(storage(device, "scan total", 1)?);
        let uniforms: Vec<wgpu::Buffer> = lengths
            .iter()
            .map(|&len| {
                uniform(
                    device,
                    &GridParams {
                        len,
                        ..GridParams::default()
                    },
                )
            })
            .collect();
        let mut steps = Vec::new();
        for (k, &n) in lengths.iter().enumerate() {
            let named: &Named = &[
                ("params", &uniforms[k]),
                ("scan_data", levels[k].buffer()),
                ("scan_sums", levels[k + 1].buffer()),
            ];
            steps.push(self.step(device, GridKernel::ScanBlocks, named, n, limits)?);
        }
        for (k, &n) in lengths.iter().enumerate().rev().skip(1) {
            let named: &Named = &[
                ("params", &uniforms[k]),
                ("scan_data", levels[k].buffer()),
                ("scan_sums", levels[k + 1].buffer()),
            ];
            steps.push(self.step(device, GridKernel::ScanAdd, named, n, limits)?);
        }
        Ok(steps)
    }

    /// One dispatch of `kernel` over `threads` threads, bound by name.
    fn step(
        &self,
        device: &wgpu::Device,
        kernel: GridKernel,
        named: &Named,
        threads: u32,
        limits: &wgpu::Limits,
    ) -> Result<Step<'_>, GpuError> {
        let compiled = self.kernel(kernel);
        let (_, entry) = kernel.entry();
        let group = bind_group(
            device,
            compiled,
            (entry, entry),
            |name| {
                named
                    .iter()
                    .find(|(n, _)| *n == name)
                    .map(|&(_, buffer)| buffer)
            },
            None,
            "was given no buffer",
        )?;
        let dispatch = workgroups(
            threads,
            compiled.workgroup_size,
            limits.max_compute_workgroups_per_dimension,
        )?;
        Ok((compiled, group, dispatch))
    }
}

impl GpuGrid {
    /// Reads the grid back as the CPU's [`Grid`] (waits for the GPU). A
    /// non-finite position gives an error.
    pub fn read(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Grid, GpuError> {
        let layout: GridLayout = read_buffer(device, queue, &self.layout, 1)?
            .pop()
            .ok_or_else(|| GpuError::Map("the grid's layout came back empty".into()))?;
        check_status(layout.status)?;
        let cells = layout.dims[3].min(self.capacity) as usize;
        Ok(Grid {
            origin: xyz(layout.origin),
            cell: layout.cell,
            dims: [layout.dims[0], layout.dims[1], layout.dims[2]],
            cell_start: read_buffer(device, queue, &self.cell_start, cells + 1)?,
            particles: read_buffer(device, queue, &self.particles, self.count as usize)?,
        })
    }
}

impl GpuRows {
    /// Reads the rows back as `(offsets, indices)`, the CPU twin's result
    /// (waits for the GPU).
    pub fn read(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
        let starts = self.count as usize + 1;
        let high = self.entries.saturating_sub(self.split) as usize;
        let mut offsets = read_buffer(device, queue, &self.offsets, starts + high)?;
        let mut indices = read_buffer(
            device,
            queue,
            &self.indices,
            self.entries.min(self.split) as usize,
        )?;
        indices.extend(offsets.drain(starts..));
        Ok((offsets, indices))
    }
}

/// Lengths of the prefix-sum levels over `len` elements in blocks of `block`.
fn scan_lengths(len: u32, block: u32) -> Vec<u32> {
    let mut lengths = vec![len.max(1)];
    while let Some(&last) = lengths.last().filter(|&&n| n > block.max(2)) {
        lengths.push(last.div_ceil(block.max(2)));
    }
    lengths
}

fn record<'a>(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    steps: impl IntoIterator<Item = Step<'a>>,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    for (kernel, group, [x, y]) in steps {
        pass.set_pipeline(&kernel.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
}

fn check_status(status: u32) -> Result<(), GpuError> {
    match status {
        0 => Ok(()),
        _ => Err(invalid(SamplingError::NonFiniteParticle)),
    }
}

fn invalid(error: SamplingError) -> GpuError {
    GpuError::Model(error.into())
}

fn uniform(device: &wgpu::Device, params: &GridParams) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("grid params"),
        contents: bytemuck::bytes_of(params),
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// A zero-sized buffer (no particles) cannot be bound: a placeholder for one.
fn placeholder_for(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Option<wgpu::Buffer> {
    (buffer.size() == 0).then(|| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("no particles"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        })
    })
}

/// A storage buffer of `len` zeroed elements, refused beyond the device's limits.
fn storage<T: Pod>(
    device: &wgpu::Device,
    label: &'static str,
    len: u32,
) -> Result<Storage<T>, GpuError> {
    Storage::zeroed(device, label, len as usize, &format!("the {label} buffer"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::support::assert_mirror;

    #[test]
    fn grid_params_matches_the_wgsl_layout() {
        assert_mirror!(
            "grid_build",
            "GridParams",
            GridParams {
                count,
                capacity,
                cell,
                rows,
                factor,
                skin,
                sorted,
                len,
                split,
                pad0,
                pad1,
                pad2,
            }
        );
    }

    #[test]
    fn grid_layout_matches_the_wgsl_layout() {
        assert_mirror!(
            "grid_build",
            "GridLayout",
            GridLayout {
                origin,
                dims,
                cell,
                reach,
                span,
                status,
            }
        );
    }

    #[test]
    fn scan_levels_shrink_by_a_block_until_one_remains() {
        assert_eq!(scan_lengths(1, 64), vec![1]);
        assert_eq!(scan_lengths(64, 64), vec![64]);
        assert_eq!(scan_lengths(65, 64), vec![65, 2]);
        assert_eq!(scan_lengths(100_003, 64), vec![100_003, 1_563, 25]);
        assert_eq!(scan_lengths(8_000_001, 64).len(), 4);
    }
}
