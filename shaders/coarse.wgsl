// The two-level solve's coarse correction, twin of
// `tissue_solve::coarse::CoarseSpace::correct`, in four passes between
// `integrate` and `chebyshev`. For fixed rotations the plain step is
// s = −c alpha L e, so the error after it, e' = e + s, has
// L e' = −s / (c alpha) + L s, known without e; the correction removes
// e's L-orthogonal projection onto the aggregates' constants:
// - `coarse_residual`, per particle: (L e')_i over the free particles
//   (those in an aggregate; the others read as 0);
// - `coarse_restrict`, per aggregate: the sum over its particles;
// - `coarse_forward` and `coarse_backward`, one workgroup each: the coarse
//   Laplacian's Cholesky factor, forward by columns, backward by rows;
// - `coarse_apply`, per particle: q̂_i −= the solution at its aggregate.
// The CPU sums and solves in f64, here in f32: both agree within rounding.

#import shared/layout

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> plain: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read> indices: array<u32>;
// Per particle its aggregate, or OUTSIDE (a control point, a held particle).
@group(0) @binding(5) var<storage, read> aggregate: array<u32>;
// Per particle (L e')_i.
@group(0) @binding(6) var<storage, read_write> residual: array<vec4<f32>>;
// Per aggregate the start of its particles in `members` (aggregates + 1).
@group(0) @binding(7) var<storage, read> member_starts: array<u32>;
@group(0) @binding(8) var<storage, read> members: array<u32>;
// Per aggregate: the restricted residual, then the coarse solution; its
// length is the number of aggregates.
@group(0) @binding(9) var<storage, read_write> coarse: array<vec4<f32>>;
// The factor by rows: row i holds columns i + 1 − length .. i, the diagonal last.
@group(0) @binding(10) var<storage, read> row_starts: array<u32>;
@group(0) @binding(11) var<storage, read> row_values: array<f32>;
// Its strictly lower entries by columns: rows and values of column j.
@group(0) @binding(12) var<storage, read> column_starts: array<u32>;
@group(0) @binding(13) var<storage, read> column_rows: array<u32>;
@group(0) @binding(14) var<storage, read> column_values: array<f32>;

const OUTSIDE: u32 = 0xffffffffu;

// The step of particle j, 0 where it is in no aggregate.
fn step_of(j: u32) -> vec3<f32> {
    if (aggregate[j] == OUTSIDE) {
        return vec3<f32>(0.0);
    }
    return plain[j].xyz - current[j].xyz;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_residual(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    if (aggregate[i] == OUTSIDE) {
        residual[i] = vec4<f32>(0.0);
        return;
    }
    // c alpha: c = 1 for the paper's force, 2 for the symmetric one.
    let contraction = select(2.0, 1.0, params.model == 0u) * params.alpha;
    let first = offsets[i];
    let last = offsets[i + 1u];
    var r = step_of(i) * (f32(last - first) - 1.0 / contraction);
    for (var k = first; k < last; k++) {
        r -= step_of(indices[k]);
    }
    residual[i] = vec4<f32>(r, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_restrict(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = particle_index(workgroup, groups, local);
    // (`params` read by every pass: the batch binds it at a dynamic offset.)
    if (a >= arrayLength(&coarse) || params.count == 0u) {
        return;
    }
    var sum = vec3<f32>(0.0);
    for (var k = member_starts[a]; k < member_starts[a + 1u]; k++) {
        sum += residual[members[k]].xyz;
    }
    coarse[a] = vec4<f32>(sum, 0.0);
}

// L L^T x = b in place in `coarse`, by one workgroup each way (two
// dispatches: one long one stopped short on llvmpipe past about 10,000
// steps): each step's updates are spread over the threads, a barrier
// between steps. Up to `HELD_AGGREGATES` aggregates (wgpu's default 16 KiB
// of workgroup memory) the vector is held in workgroup memory, and what a
// step reads of the factor (its diagonal, its range, each thread's first
// entry) is fetched during the step before, the range's end two steps
// before, as `coarse_elastic.wgsl` does: a step then waits on a workgroup
// barrier, not on the device's memory. Above, the vector is substituted
// where it lies. The same operations in the same order either way.
const HELD_AGGREGATES: u32 = 1024u;

var<workgroup> held: array<vec3<f32>, HELD_AGGREGATES>;

// Forward, L y = b by columns: y_j = b_j / L_jj, then b_i −= L_ij y_j for
// the rows below that reach column j.
@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_forward(@builtin(local_invocation_index) local: u32) {
    let n = select(arrayLength(&coarse), 0u, params.count == 0u);
    if (n > HELD_AGGREGATES) {
        forward_in_place(local, n);
        return;
    }
    if (n == 0u) {
        return;
    }
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = coarse[i].xyz;
    }
    workgroupBarrier();
    var diagonal = row_values[row_starts[1u] - 1u];
    var begin = column_starts[0u];
    var end = column_starts[1u];
    var row = 0u;
    var value = 0.0;
    if (begin + local < end) {
        row = column_rows[begin + local];
        value = column_values[begin + local];
    }
    var end_next = column_starts[min(2u, n)];
    for (var j = 0u; j < n; j++) {
        let diagonal_next = row_values[row_starts[min(j + 2u, n)] - 1u];
        var row_next = 0u;
        var value_next = 0.0;
        if (end + local < end_next) {
            row_next = column_rows[end + local];
            value_next = column_values[end + local];
        }
        let end_after = column_starts[min(j + 3u, n)];
        let y = held[j] / diagonal;
        if (begin + local < end) {
            held[row] -= value * y;
        }
        for (var k = begin + local + WORKGROUP_SIZE; k < end; k += WORKGROUP_SIZE) {
            held[column_rows[k]] -= column_values[k] * y;
        }
        workgroupBarrier();
        if (local == 0u) {
            held[j] = y;
        }
        diagonal = diagonal_next;
        begin = end;
        end = end_next;
        end_next = end_after;
        row = row_next;
        value = value_next;
    }
    workgroupBarrier();
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        coarse[i] = vec4<f32>(held[i], 0.0);
    }
}

// Backward, L^T x = y by rows: x_i = y_i / L_ii, then y_j −= L_ij x_i for
// the columns of row i (entries start..last, `last` the diagonal's).
@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_backward(@builtin(local_invocation_index) local: u32) {
    let n = select(arrayLength(&coarse), 0u, params.count == 0u);
    if (n > HELD_AGGREGATES) {
        backward_in_place(local, n);
        return;
    }
    if (n == 0u) {
        return;
    }
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = coarse[i].xyz;
    }
    workgroupBarrier();
    var start = row_starts[n - 1u];
    var last = row_starts[n] - 1u;
    var diagonal = row_values[last];
    var value = 0.0;
    if (start + local < last) {
        value = row_values[start + local];
    }
    var start_next = row_starts[max(n, 2u) - 2u];
    for (var step = 0u; step < n; step++) {
        let i = n - 1u - step;
        let last_next = max(start, 1u) - 1u;
        let diagonal_next = row_values[last_next];
        var value_next = 0.0;
        if (i > 0u && start_next + local < last_next) {
            value_next = row_values[start_next + local];
        }
        let start_after = row_starts[max(i, 2u) - 2u];
        let x = held[i] / diagonal;
        let first = i + start - last;
        if (start + local < last) {
            held[first + local] -= value * x;
        }
        for (var k = start + local + WORKGROUP_SIZE; k < last; k += WORKGROUP_SIZE) {
            held[first + (k - start)] -= row_values[k] * x;
        }
        workgroupBarrier();
        if (local == 0u) {
            held[i] = x;
        }
        diagonal = diagonal_next;
        last = last_next;
        start = start_next;
        start_next = start_after;
        value = value_next;
    }
    workgroupBarrier();
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        coarse[i] = vec4<f32>(held[i], 0.0);
    }
}

fn forward_in_place(local: u32, n: u32) {
    for (var j = 0u; j < n; j++) {
        let y = coarse[j].xyz / row_values[row_starts[j + 1u] - 1u];
        for (var k = column_starts[j] + local; k < column_starts[j + 1u]; k += WORKGROUP_SIZE) {
            let i = column_rows[k];
            coarse[i] = vec4<f32>(coarse[i].xyz - column_values[k] * y, 0.0);
        }
        storageBarrier();
        workgroupBarrier();
        if (local == 0u) {
            coarse[j] = vec4<f32>(y, 0.0);
        }
    }
}

fn backward_in_place(local: u32, n: u32) {
    for (var step = 0u; step < n; step++) {
        let i = n - 1u - step;
        let start = row_starts[i];
        let diagonal = row_starts[i + 1u] - 1u;
        let x = coarse[i].xyz / row_values[diagonal];
        let first = i + start - diagonal;
        for (var k = start + local; k < diagonal; k += WORKGROUP_SIZE) {
            let j = first + (k - start);
            coarse[j] = vec4<f32>(coarse[j].xyz - row_values[k] * x, 0.0);
        }
        storageBarrier();
        workgroupBarrier();
        if (local == 0u) {
            coarse[i] = vec4<f32>(x, 0.0);
        }
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_apply(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let a = aggregate[i];
    if (a != OUTSIDE) {
        plain[i] = vec4<f32>(plain[i].xyz - coarse[a].xyz, 0.0);
    }
}
