// The uniform grid shared by `grid_build.wgsl` and `neighbour_rows.wgsl`.
// Rust mirrors: `tissue_gpu::grid::GridParams`, `tissue_gpu::grid::GridLayout`
// (layout-tested against naga). The CPU twin is `tissue_cpu::grid::Grid`.

#import shared/layout

// The parameters of one grid build or neighbour-row build.
struct GridParams {
    // Number of particles.
    count: u32,
    // Cells the cell buffers hold: `tissue_cpu::grid::max_cells(count)`.
    capacity: u32,
    // The smallest cell edge asked for (grid_build; unused when `rows` is 1).
    cell: f32,
    // 1: the cell is half the neighbour reach, from the largest radius.
    rows: u32,
    // Neighbour rows: j is a neighbour of i when |p_i - p_j| < factor (r_i + r_j) + skin.
    factor: f32,
    skin: f32,
    // 1: rows ascending by particle index.
    sorted: u32,
    // Elements of a prefix-sum level (`scan_blocks`, `scan_add`).
    len: u32,
    // Neighbour rows: entries the `indices` binding holds; entry k >= split
    // is `offsets[count + 1 + k - split]`, after the row starts (rows too
    // long for one binding of the device).
    split: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// The grid the layout kernel chose, read by every later kernel.
struct GridLayout {
    // Corner of cell (0, 0, 0); w the reciprocal of the cell edge, rounded
    // to nearest (`reciprocal`).
    origin: vec4<f32>,
    // Cells along x, y, z; w the number of cells.
    dims: vec4<u32>,
    // Cell edge length.
    cell: f32,
    // Neighbour rows: the largest pair limit, factor 2 r_max + skin.
    reach: f32,
    // Neighbour rows: cells searched on each side of a particle's cell.
    span: u32,
    // 0, or why the grid is unusable (`STATUS_*`); later kernels then do nothing.
    status: u32,
}

// A position or radius is NaN or infinite: there is no grid.
const STATUS_NON_FINITE: u32 = 1u;

// Slots of `bounds`: the lower corner (as inverted keys, so that atomicMax
// finds the minimum and zeroed memory is the empty set), the largest
// radius and the upper corner (keys).
const BOUND_LO: u32 = 0u;
const BOUND_RADIUS: u32 = 3u;
const BOUND_HI: u32 = 4u;

// The builtins of one thread of a grid kernel (every entry point of
// `grid_build.wgsl` and `neighbour_rows.wgsl` but the one-thread
// `grid_layout`); beyond 65,535 workgroups the dispatch is two-dimensional.
struct Invocation {
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
}

// What `grid_particle` gives a thread that has no particle to work on.
const NO_PARTICLE: u32 = 0xffffffffu;

// The particle thread `at` works on, or `NO_PARTICLE` past the `count`
// particles or when the grid is unusable (`status`, the layout's, not 0).
fn grid_particle(at: Invocation, count: u32, status: u32) -> u32 {
    let i = particle_index(at.workgroup, at.groups, at.local);
    return select(NO_PARTICLE, i, i < count && status == 0u);
}

// A key whose unsigned order is the order of the floats: negative floats
// are flipped whole, non-negative ones get the sign bit set.
fn order_key(x: f32) -> u32 {
    let bits = bitcast<u32>(x);
    return select(bits | 0x80000000u, ~bits, (bits & 0x80000000u) != 0u);
}

fn key_value(key: u32) -> f32 {
    return bitcast<f32>(select(~key, key & 0x7fffffffu, (key & 0x80000000u) != 0u));
}

// By the bits, so that no compiler assumption about NaN can remove the test.
fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// 1 / x rounded to nearest, as the CPU's division rounds it, for a positive
// normal x below 2^126 (cell edges; anything else gets `1.0 / x`). WGSL's
// division may be off by 2.5 units in the last place (NVIDIA's is), which
// puts a particle near a cell's face in the next cell over; multiplication
// and subtraction round exactly everywhere. By long division of 2^48 by
// the 24-bit significand m: its 25-bit quotient is the result's 24 bits
// and a rounding bit, the remainder the sticky bit. The quotient is never
// exactly halfway: 2^48 / m is an integer only for a power of two.
fn reciprocal(x: f32) -> f32 {
    let bits = bitcast<u32>(x);
    let e = (bits >> 23u) & 0xffu;
    if ((bits >> 31u) != 0u || e == 0u || e > 252u) {
        return 1.0 / x;
    }
    let m = (bits & 0x7fffffu) | 0x800000u;
    if (m == 0x800000u) {
        return bitcast<f32>((254u - e) << 23u);
    }
    var remainder = 1u;
    var quotient = 0u;
    for (var k = 0u; k < 48u; k++) {
        remainder <<= 1u;
        quotient <<= 1u;
        if (remainder >= m) {
            remainder -= m;
            quotient |= 1u;
        }
    }
    var significand = quotient >> 1u;
    if ((quotient & 1u) != 0u && (remainder != 0u || (significand & 1u) != 0u)) {
        significand += 1u;
    }
    // The significand's leading bit adds one to the exponent field (and a
    // carry out of rounding, another).
    return bitcast<f32>(((252u - e) << 23u) + significand);
}

// `Grid::coords`: the cell holding p, clamped into the grid.
fn cell_coords(grid: GridLayout, p: vec3<f32>) -> vec3<u32> {
    let g = (p - grid.origin.xyz) * grid.origin.w;
    // Clamped before the conversion, which is undefined out of range; the
    // bound is the largest f32 below 2^32.
    let c = vec3<u32>(clamp(g, vec3<f32>(0.0), vec3<f32>(4294967040.0)));
    return min(c, grid.dims.xyz - vec3<u32>(1u));
}

// `Grid::index`: cells in x-fastest order.
fn cell_index(grid: GridLayout, c: vec3<u32>) -> u32 {
    return (c.z * grid.dims.y + c.y) * grid.dims.x + c.x;
}
