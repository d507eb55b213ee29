// Stage 1: neighbour rows (CSR), twin of `tissue_cpu::kernels::neighbour_rows`:
// j is in row i when j != i and |p_i - p_j| < factor (r_i + r_j) + skin,
// searched in the cells (half the reach wide) within `grid.span` cells of
// p_i's, in the CPU's order. After `grid_build.wgsl` (with `params.rows` 1):
// `reorder`, `count_rows`, the prefix sum of the counts into `offsets`
// (`grid_build.wgsl`'s scan), then `fill_rows` and, when sorted, `sort_rows`.

#import shared/grid

@group(0) @binding(0) var<uniform> params: GridParams;
// xyz position, w radius.
@group(0) @binding(1) var<storage, read> positions: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> grid: GridLayout;
@group(0) @binding(6) var<storage, read> cell_start: array<u32>;
@group(0) @binding(9) var<storage, read> particles: array<u32>;
// `positions` in cell order: the search reads memory in runs.
@group(0) @binding(12) var<storage, read_write> in_cell_order: array<vec4<f32>>;
// Row lengths from `count_rows`; after the prefix sum, row i is entries
// `offsets[i]..offsets[i + 1]`: entry k is `indices[k]` below `params.split`
// and `offsets[count + 1 + k - split]` from there (`row_entry`).
@group(0) @binding(13) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(14) var<storage, read_write> indices: array<u32>;

// Where entry k of the rows lives: below `split` in `indices`, past it in
// `offsets` after the row starts.
fn row_entry(k: u32) -> u32 {
    if (k < params.split) {
        return indices[k];
    }
    return offsets[params.count + 1u + k - params.split];
}

fn set_row_entry(k: u32, value: u32) {
    if (k < params.split) {
        indices[k] = value;
    } else {
        offsets[params.count + 1u + k - params.split] = value;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn reorder(at: Invocation) {
    let slot = grid_particle(at, params.count, grid.status);
    if (slot == NO_PARTICLE) {
        return;
    }
    in_cell_order[slot] = positions[particles[slot]];
}

// The block of cells around p_i's with the pair test (the CPU twin reads
// only the cells of that block p_i's sphere reaches: the same particles in
// the same order): counts row i and, when `fill`, writes it from
// `offsets[i]` (never past `offsets[i + 1]`).
fn search(i: u32, fill: bool) -> u32 {
    let p = positions[i].xyz;
    let base = params.factor * positions[i].w + params.skin;
    let c = cell_coords(grid, p);
    let span = grid.span;
    let last = grid.dims.xyz - vec3<u32>(1u);
    var found = 0u;
    var at = 0u;
    var stop = 0u;
    if (fill) {
        at = offsets[i];
        stop = offsets[i + 1u];
    }
    for (var cz = c.z - min(c.z, span); cz <= min(c.z + span, last.z); cz++) {
        for (var cy = c.y - min(c.y, span); cy <= min(c.y + span, last.y); cy++) {
            let row = cell_index(grid, vec3<u32>(0u, cy, cz));
            let first = cell_start[row + c.x - min(c.x, span)];
            let end = cell_start[row + min(c.x + span, last.x) + 1u];
            for (var slot = first; slot < end; slot++) {
                let q = in_cell_order[slot];
                let limit = base + params.factor * q.w;
                let d = q.xyz - p;
                if (dot(d, d) < limit * limit) {
                    let j = particles[slot];
                    if (j != i) {
                        found += 1u;
                        if (fill && at < stop) {
                            set_row_entry(at, j);
                            at += 1u;
                        }
                    }
                }
            }
        }
    }
    return found;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn count_rows(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    offsets[i] = search(i, false);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn fill_rows(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    search(i, true);
}

// Heapsort of entries `first..first + n` (in place, O(n log n) for any row).
fn sift_down(first: u32, start: u32, n: u32) {
    var root = start;
    loop {
        var child = 2u * root + 1u;
        if (child >= n) {
            break;
        }
        if (child + 1u < n && row_entry(first + child + 1u) > row_entry(first + child)) {
            child += 1u;
        }
        let top = row_entry(first + root);
        let larger = row_entry(first + child);
        if (top >= larger) {
            break;
        }
        set_row_entry(first + root, larger);
        set_row_entry(first + child, top);
        root = child;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn sort_rows(at: Invocation) {
    let i = grid_particle(at, params.count, grid.status);
    if (i == NO_PARTICLE) {
        return;
    }
    let first = offsets[i];
    let n = offsets[i + 1u] - first;
    for (var k = n / 2u; k > 0u; k--) {
        sift_down(first, k - 1u, n);
    }
    for (var end = n; end > 1u; end--) {
        let top = row_entry(first);
        set_row_entry(first, row_entry(first + end - 1u));
        set_row_entry(first + end - 1u, top);
        sift_down(first, 0u, end - 1u);
    }
}
