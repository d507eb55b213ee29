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
//   Laplacian's Cholesky factor, forward by columns, backward by rows, in place;
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
// between steps.

// Forward, L y = b by columns: y_j = b_j / L_jj, then b_i −= L_ij y_j for
// the rows below that reach column j.
@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_forward(@builtin(local_invocation_index) local: u32) {
    let n = select(arrayLength(&coarse), 0u, params.count == 0u);
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

// Backward, L^T x = y by rows: x_i = y_i / L_ii, then y_j −= L_ij x_i for
// the columns of row i.
@compute @workgroup_size(WORKGROUP_SIZE)
fn coarse_backward(@builtin(local_invocation_index) local: u32) {
    let n = select(arrayLength(&coarse), 0u, params.count == 0u);
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
