// The coarse Laplacian solved by two-grid cycles where it is too large for
// one factor, twin of `tissue_solve::multilevel::Multilevel::solve`. The
// two-level solve's `coarse_restrict` leaves the right-hand side `b` (one
// vec4 an aggregate) in `coarse`; then, with `x` in two buffers taken in
// turn (a sweep reads one and writes the other):
// - `cycle_start`: the first weighted Jacobi sweep from zero, x = w D^-1 b;
// - `cycle_sweep`: a further sweep, x' = x + w D^-1 (b - A x);
// - `cycle_restrict`, one workgroup a group: the sum of b - A x over the
//   group's aggregates;
// - the groups' factor solved by `coarse.wgsl`'s `coarse_forward` and
//   `coarse_backward`, bound to the groups' vector and factor;
// - `cycle_prolong`: x += the solution at the aggregate's group.
// `coarse_apply` then reads x where the last sweep left it. The CPU sweeps
// in f64 and solves the groups in f32, here all in f32.

#import shared/layout
#import shared/tree_sum

@group(0) @binding(0) var<uniform> params: Params;
// Per aggregate the right-hand side b. (Every loop is bounded by a vec4
// array's length, which the buffers' sizes give exactly.)
@group(0) @binding(1) var<storage, read> coarse: array<vec4<f32>>;
// The sweep's x and what it writes (two buffers, swapped sweep by sweep).
@group(0) @binding(2) var<storage, read> cycle_from: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> cycle_to: array<vec4<f32>>;
// The aggregates' matrix A by rows: row a is level_starts[a] ..
// level_starts[a + 1] of level_columns and level_values.
@group(0) @binding(4) var<storage, read> level_starts: array<u32>;
@group(0) @binding(5) var<storage, read> level_columns: array<u32>;
@group(0) @binding(6) var<storage, read> level_values: array<f32>;
// Per aggregate the Jacobi weight over its diagonal entry.
@group(0) @binding(7) var<storage, read> level_weights: array<f32>;
// Per aggregate its group; per group the start of its aggregates in
// group_members (groups + 1), and the list.
@group(0) @binding(8) var<storage, read> group_of: array<u32>;
@group(0) @binding(9) var<storage, read> group_starts: array<u32>;
@group(0) @binding(10) var<storage, read> group_members: array<u32>;
// Per group the restricted residual, then the groups' solution.
@group(0) @binding(11) var<storage, read_write> group_coarse: array<vec4<f32>>;

// (`particle_index` numbers the aggregates or the groups here: one thread each.)

// Row a of b - A x, x read from `cycle_from`.
fn row_residual(a: u32) -> vec3<f32> {
    var r = coarse[a].xyz;
    for (var k = level_starts[a]; k < level_starts[a + 1u]; k++) {
        r -= level_values[k] * cycle_from[level_columns[k]].xyz;
    }
    return r;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cycle_start(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = particle_index(workgroup, groups, local);
    // (`params` read by every pass: the batch binds it at a dynamic offset.)
    if (a >= arrayLength(&cycle_to) || params.count == 0u) {
        return;
    }
    cycle_to[a] = vec4<f32>(level_weights[a] * coarse[a].xyz, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cycle_sweep(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = particle_index(workgroup, groups, local);
    if (a >= arrayLength(&cycle_to) || params.count == 0u) {
        return;
    }
    cycle_to[a] = vec4<f32>(cycle_from[a].xyz + level_weights[a] * row_residual(a), 0.0);
}

// One workgroup a group, as `block_multilevel.wgsl`'s restriction: each
// thread sums every WORKGROUP_SIZE-th aggregate's residual, the workgroup
// adds the threads' sums in a tree.
@compute @workgroup_size(WORKGROUP_SIZE)
fn cycle_restrict(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_workgroup(workgroup, groups);
    // The same for the whole workgroup: all of it returns, or none.
    if (g >= arrayLength(&group_coarse) || params.count == 0u) {
        return;
    }
    var sum = vec3<f32>(0.0);
    for (var k = group_starts[g] + local; k < group_starts[g + 1u]; k += WORKGROUP_SIZE) {
        sum += row_residual(group_members[k]);
    }
    let total = workgroup_sum(local, sum);
    if (local == 0u) {
        group_coarse[g] = vec4<f32>(total, 0.0);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cycle_prolong(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = particle_index(workgroup, groups, local);
    if (a >= arrayLength(&cycle_to) || params.count == 0u) {
        return;
    }
    cycle_to[a] = vec4<f32>(cycle_to[a].xyz + group_coarse[group_of[a]].xyz, 0.0);
}
