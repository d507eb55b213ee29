// The elastic phase's coarse matrix solved by two-grid cycles where it is
// too large for one factor, twin of
// `tissue_solve::multilevel::BlockMultilevel::solve`: multilevel.wgsl's
// cycles with a 3x3 block per pair of aggregates (a translation each).
// `elastic_restrict` leaves the right-hand side b in `elastic_coarse` (three
// entries an aggregate); then, with x in two buffers taken in turn (a sweep
// reads one and writes the other), three entries an aggregate:
// - `block_cycle_start`: the first weighted block Jacobi sweep from zero,
//   x = W b (W the weight times each diagonal block's inverse);
// - `block_cycle_sweep`: a further sweep, x' = x + W (b - A x);
// - `block_cycle_restrict`, one workgroup a group: the sum of b - A x over
//   the group's aggregates, three entries a group;
// - the groups' factor solved by `coarse_elastic.wgsl`'s `elastic_forward`
//   and `elastic_backward`, bound to the groups' vector (the factor's
//   buffers hold the groups' factor while the cycles run);
// - `block_cycle_prolong`: x += the solution at the aggregate's group.
// `elastic_apply` then reads x where the last sweep left it. The CPU sweeps
// in f64 and solves the groups in f32, here all in f32.

#import shared/layout
#import shared/tree_sum

@group(0) @binding(0) var<uniform> params: Params;
// Per aggregate the right-hand side b, three entries.
@group(0) @binding(1) var<storage, read> elastic_coarse: array<f32>;
// The sweep's x and what it writes (two buffers, swapped sweep by sweep).
@group(0) @binding(2) var<storage, read> block_from: array<f32>;
@group(0) @binding(3) var<storage, read_write> block_to: array<f32>;
// The aggregates' block matrix A by rows: row a is block_starts[a] ..
// block_starts[a + 1] of block_columns and block_values.
@group(0) @binding(4) var<storage, read> block_starts: array<u32>;
@group(0) @binding(5) var<storage, read> block_columns: array<u32>;
@group(0) @binding(6) var<storage, read> block_values: array<Rotation>;
// Per aggregate W, the weight times its diagonal block's inverse.
@group(0) @binding(7) var<storage, read> block_weights: array<Rotation>;
// Per aggregate its group; per group the start of its aggregates in
// block_group_members (groups + 1), and the list.
@group(0) @binding(8) var<storage, read> block_group_of: array<u32>;
@group(0) @binding(9) var<storage, read> block_group_starts: array<u32>;
@group(0) @binding(10) var<storage, read> block_group_members: array<u32>;
// Per group the restricted residual, then the groups' solution.
@group(0) @binding(11) var<storage, read_write> block_group_coarse: array<f32>;

// Aggregate a's three entries of b, of x read, of x written.
fn rhs(a: u32) -> vec3<f32> {
    return vec3<f32>(elastic_coarse[3u * a], elastic_coarse[3u * a + 1u], elastic_coarse[3u * a + 2u]);
}

fn read_from(a: u32) -> vec3<f32> {
    return vec3<f32>(block_from[3u * a], block_from[3u * a + 1u], block_from[3u * a + 2u]);
}

fn read_to(a: u32) -> vec3<f32> {
    return vec3<f32>(block_to[3u * a], block_to[3u * a + 1u], block_to[3u * a + 2u]);
}

fn write_to(a: u32, x: vec3<f32>) {
    block_to[3u * a] = x.x;
    block_to[3u * a + 1u] = x.y;
    block_to[3u * a + 2u] = x.z;
}

// Row a of b - A x, x read from `block_from`.
fn block_residual(a: u32) -> vec3<f32> {
    var r = rhs(a);
    for (var k = block_starts[a]; k < block_starts[a + 1u]; k++) {
        r -= matrix_of(block_values[k]) * read_from(block_columns[k]);
    }
    return r;
}

// The aggregate this thread sweeps, or none (params read by every pass:
// the batch binds it at a dynamic offset).
fn swept(workgroup: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    let a = particle_index(workgroup, groups, local);
    return select(a, 0xffffffffu, a >= arrayLength(&block_to) / 3u || params.count == 0u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn block_cycle_start(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = swept(workgroup, groups, local);
    if (a == 0xffffffffu) {
        return;
    }
    write_to(a, matrix_of(block_weights[a]) * rhs(a));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn block_cycle_sweep(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = swept(workgroup, groups, local);
    if (a == 0xffffffffu) {
        return;
    }
    let x = read_from(a);
    write_to(a, x + matrix_of(block_weights[a]) * block_residual(a));
}

// One workgroup a group: each thread sums the residuals of every
// WORKGROUP_SIZE-th aggregate of the group, then the workgroup adds the
// threads' sums in a tree. (One thread a group left most of a large GPU
// idle: a thousand-odd threads, each through some 60 aggregates' rows.)
@compute @workgroup_size(WORKGROUP_SIZE)
fn block_cycle_restrict(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_workgroup(workgroup, groups);
    // The same for the whole workgroup: all of it returns, or none.
    if (g >= arrayLength(&block_group_coarse) / 3u || params.count == 0u) {
        return;
    }
    var sum = vec3<f32>(0.0);
    for (var k = block_group_starts[g] + local; k < block_group_starts[g + 1u]; k += WORKGROUP_SIZE) {
        sum += block_residual(block_group_members[k]);
    }
    let total = workgroup_sum(local, sum);
    if (local == 0u) {
        block_group_coarse[3u * g] = total.x;
        block_group_coarse[3u * g + 1u] = total.y;
        block_group_coarse[3u * g + 2u] = total.z;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn block_cycle_prolong(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = swept(workgroup, groups, local);
    if (a == 0xffffffffu) {
        return;
    }
    let g = block_group_of[a];
    let solution = vec3<f32>(
        block_group_coarse[3u * g],
        block_group_coarse[3u * g + 1u],
        block_group_coarse[3u * g + 2u],
    );
    // The prolongation reads and writes the same buffer (the first).
    write_to(a, read_to(a) + solution);
}
