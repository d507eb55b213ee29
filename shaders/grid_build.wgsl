// Stage 1: the uniform grid, twin of `tissue_cpu::kernels::grid_build` (and,
// for the one-invocation `grid_layout`, of `tissue_cpu::grid::grid_layout`).
// In dispatch order: bounds (and the largest radius) by order-preserving
// u32 atomics, the layout, each particle's cell and counts, an exclusive
// prefix sum of the counts (`scan_blocks` and `scan_add`, level by level),
// the scatter into cell order and, because atomics arrive in any order,
// each cell's run made ascending by particle index: the CPU's stable scatter.
// The scan also turns neighbour-row lengths into row offsets.

#import shared/grid

@group(0) @binding(0) var<uniform> params: GridParams;
// xyz position, w radius (read only when `params.rows` is 1).
@group(0) @binding(1) var<storage, read> positions: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> bounds: array<atomic<u32>, 8>;
@group(0) @binding(3) var<storage, read_write> grid: GridLayout;
@group(0) @binding(4) var<storage, read_write> cell_of: array<u32>;
// The same buffer as `cell_start`, before the prefix sum.
@group(0) @binding(5) var<storage, read_write> cell_counts: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read> cell_start: array<u32>;
// A particle's place within its cell in the order the atomics served it.
@group(0) @binding(7) var<storage, read_write> arrival: array<u32>;
// Particle indices in cell order, in arrival order within a cell.
@group(0) @binding(8) var<storage, read_write> arrived: array<u32>;
// Particle indices in cell order, ascending within a cell.
@group(0) @binding(9) var<storage, read_write> particles: array<u32>;
// One level of the prefix sum: its values in place, and each block's total.
@group(0) @binding(10) var<storage, read_write> scan_data: array<u32>;
@group(0) @binding(11) var<storage, read_write> scan_sums: array<u32>;

var<workgroup> lower: array<vec4<u32>, WORKGROUP_SIZE>;
var<workgroup> upper: array<vec4<u32>, WORKGROUP_SIZE>;
var<workgroup> partial: array<u32, WORKGROUP_SIZE>;

// Keys are maxed, never floats, so that a NaN cannot vanish in the tree.
@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_bounds(at: Invocation) {
    let local = at.local;
    let i = particle_index(at.workgroup, at.groups, local);
    // No early return: every thread must reach the barriers.
    var lo = vec4<u32>(0u);
    var hi = vec4<u32>(0u);
    if (i < params.count) {
        let p = positions[i];
        lo = vec4<u32>(~order_key(p.x), ~order_key(p.y), ~order_key(p.z), 0u);
        if (params.rows == 1u) {
            lo.w = order_key(p.w);
        }
        hi = vec4<u32>(order_key(p.x), order_key(p.y), order_key(p.z), 0u);
    }
    lower[local] = lo;
    upper[local] = hi;
    workgroupBarrier();
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        if (local < stride) {
            lower[local] = max(lower[local], lower[local + stride]);
            upper[local] = max(upper[local], upper[local + stride]);
        }
        workgroupBarrier();
    }
    if (local == 0u && flat_workgroup(at.workgroup, at.groups) * WORKGROUP_SIZE < params.count) {
        for (var k = 0u; k < 3u; k++) {
            atomicMax(&bounds[BOUND_LO + k], lower[0][k]);
            atomicMax(&bounds[BOUND_HI + k], upper[0][k]);
        }
        atomicMax(&bounds[BOUND_RADIUS], lower[0].w);
    }
}

// Cells of edge `cell` over `extent`: floor(extent reciprocal(cell)) + 1
// per axis.
fn dims_for(extent: vec3<f32>, cell: f32) -> vec3<u32> {
    let d = floor(extent * reciprocal(cell)) + 1.0;
    return vec3<u32>(min(d, vec3<f32>(4294967040.0)));
}

// d.x d.y d.z <= capacity, without overflow: exactly the CPU's f64 test.
fn fits(d: vec3<u32>, capacity: u32) -> bool {
    if (d.x > capacity || d.y > capacity / d.x) {
        return false;
    }
    return d.z <= capacity / (d.x * d.y);
}

// `tissue_cpu::grid::grid_layout`, the same f32 operations in the same order.
@compute @workgroup_size(1)
fn grid_layout() {
    var lo = vec3<f32>(0.0);
    var hi = vec3<f32>(0.0);
    var r_max = 0.0;
    if (params.count > 0u) {
        lo = vec3<f32>(
            key_value(~atomicLoad(&bounds[BOUND_LO])),
            key_value(~atomicLoad(&bounds[BOUND_LO + 1u])),
            key_value(~atomicLoad(&bounds[BOUND_LO + 2u])),
        );
        hi = vec3<f32>(
            key_value(atomicLoad(&bounds[BOUND_HI])),
            key_value(atomicLoad(&bounds[BOUND_HI + 1u])),
            key_value(atomicLoad(&bounds[BOUND_HI + 2u])),
        );
        // `tissue_cpu::kernels::neighbour_rows` folds the radii from 0.
        r_max = key_value(max(atomicLoad(&bounds[BOUND_RADIUS]), order_key(0.0)));
    }
    let reach = params.factor * 2.0 * r_max + params.skin;
    var cell = select(params.cell, 0.5 * reach, params.rows == 1u);
    var finite = is_finite(cell) && is_finite(reach);
    for (var k = 0u; k < 3u; k++) {
        finite = finite && is_finite(lo[k]) && is_finite(hi[k]);
    }
    // f32::MIN_POSITIVE and 1e-6f32 by their bits: a literal would pass
    // through f64 first and might round differently from Rust's. The cell
    // is never below f32::MIN_POSITIVE: a subnormal one (every particle at
    // one point) is flushed to zero on some devices and would never grow.
    let smallest = bitcast<f32>(0x00800000u);
    let extent = max(hi - lo, vec3<f32>(smallest));
    cell = max(max(cell, max(extent.x, max(extent.y, extent.z)) * bitcast<f32>(0x358637bdu)), smallest);
    // Fewer than 200 growths reach any finite extent; the bound only keeps
    // a bad input from spinning.
    var grown = false;
    for (var k = 0u; k < 1024u && finite; k++) {
        if (fits(dims_for(extent, cell), params.capacity)) {
            grown = true;
            break;
        }
        cell *= 1.25;
    }
    if (!grown) {
        grid = GridLayout(vec4<f32>(0.0), vec4<u32>(1u), 1.0, 0.0, 1u, STATUS_NON_FINITE);
        return;
    }
    let d = dims_for(extent, cell);
    grid = GridLayout(
        vec4<f32>(lo, reciprocal(cell)),
        vec4<u32>(d, d.x * d.y * d.z),
        cell,
        reach,
        select(1u, 2u, cell < reach),
        0u,
    );
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cell_count(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    let c = cell_index(grid, cell_coords(grid, positions[i].xyz));
    cell_of[i] = c;
    arrival[i] = atomicAdd(&cell_counts[c], 1u);
}

// One level of an exclusive prefix sum: each workgroup scans its block of
// `scan_data` in place (Hillis-Steele in workgroup memory) and writes the
// block's total to `scan_sums`, which the next level scans.
@compute @workgroup_size(WORKGROUP_SIZE)
fn scan_blocks(at: Invocation) {
    let local = at.local;
    let block = flat_workgroup(at.workgroup, at.groups);
    let i = block * WORKGROUP_SIZE + local;
    var value = 0u;
    if (i < params.len) {
        value = scan_data[i];
    }
    partial[local] = value;
    workgroupBarrier();
    for (var offset = 1u; offset < WORKGROUP_SIZE; offset <<= 1u) {
        var left = 0u;
        if (local >= offset) {
            left = partial[local - offset];
        }
        workgroupBarrier();
        partial[local] += left;
        workgroupBarrier();
    }
    if (i < params.len) {
        scan_data[i] = partial[local] - value;
    }
    // The idle tail of a two-dimensional dispatch writes nothing.
    if (local == WORKGROUP_SIZE - 1u && block * WORKGROUP_SIZE < params.len) {
        scan_sums[block] = partial[local];
    }
}

// Adds each block's offset (the scanned `scan_sums`) to its elements.
@compute @workgroup_size(WORKGROUP_SIZE)
fn scan_add(at: Invocation) {
    let block = flat_workgroup(at.workgroup, at.groups);
    let i = block * WORKGROUP_SIZE + at.local;
    if (i < params.len) {
        scan_data[i] += scan_sums[block];
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cell_scatter(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    arrived[cell_start[cell_of[i]] + arrival[i]] = i;
}

// A particle's place in its cell is the number of its cell mates with a
// smaller index: the order of the CPU's stable scatter. Quadratic in the
// cell's population, which the layout keeps small on average.
@compute @workgroup_size(WORKGROUP_SIZE)
fn cell_sort(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    let c = cell_of[i];
    let first = cell_start[c];
    let end = cell_start[c + 1u];
    var before = 0u;
    for (var k = first; k < end; k++) {
        before += u32(arrived[k] < i);
    }
    particles[first + before] = i;
}
