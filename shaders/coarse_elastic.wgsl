// The elastic phase's two-level correction, twin of
// `tissue_solve::coarse_elastic::ElasticCoarse::correct`, in six passes
// between `integrate` and `chebyshev`. The elastic operator at the state the
// phase started from, K = L + 1/2 sum_i W_i g_i g_i^T + S (S the springs'
// P / 2 per particle, shared/loads; g_i the gradient of
// J_i, its entry at neighbour j cof(F_i) c_ij = C_i d_ij + S_i (mu_j - mu_i)
// with C_i = cof(F_i) B_i and S_i = a_i cof(F_i) there),
// gives K e' = −s / (c alpha) + K s for the error after the plain step s;
// its projection onto the aggregates' translations (three unknowns each) is
// removed:
// - `elastic_step`, per particle: s_i, 0 outside the aggregates (w = 1 inside),
//   and minus its spring's part of K s (shared/loads) into `elastic_residual`;
// - `elastic_change`, per particle: sqrt(W_i) g_i . s, the uploaded
//   `elastic_gradients` being sqrt(W_i) C_i and sqrt(W_i) S_i;
// - `elastic_residual`, per particle: (K s)_j − s_j / (c alpha), or
//   (K s)_j − r_j after the volume smoother (volume_smoother.wgsl), which
//   leaves r_j (less the spring's part of K s) in `elastic_residual` and s
//   in `elastic_step`;
// - `elastic_restrict`, per aggregate: the sum over its particles, three
//   entries of `elastic_coarse`;
// - `elastic_forward` and `elastic_backward`, one workgroup each: the
//   coarse matrix's Cholesky factor over the 3 n unknowns, forward by
//   columns, backward by rows, the vector in workgroup memory;
// - `elastic_apply`, per particle: q̂_i −= the solution at its aggregate.
// The CPU computes in f64, here in f32.

#import shared/layout
#import shared/loads

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> plain: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(0) @binding(5) var<storage, read> indices: array<u32>;
// Per particle its elastic aggregate, or OUTSIDE.
@group(0) @binding(6) var<storage, read> elastic_aggregate: array<u32>;
// Per particle s_i (w: 1 inside an aggregate, 0 outside).
@group(0) @binding(7) var<storage, read_write> elastic_step: array<vec4<f32>>;
// Per particle sqrt(W_i) C_i and sqrt(W_i) S_i at the phase's start (0: flat).
@group(0) @binding(8) var<storage, read> elastic_gradients: array<ElasticGradient>;
// Per particle sqrt(W_i) g_i . s.
@group(0) @binding(9) var<storage, read_write> elastic_change: array<f32>;
// Per particle (K e')_j.
@group(0) @binding(10) var<storage, read_write> elastic_residual: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read> elastic_member_starts: array<u32>;
@group(0) @binding(12) var<storage, read> elastic_members: array<u32>;
// Three entries per aggregate: the restricted residual, then the solution;
// its length is three times the number of aggregates.
@group(0) @binding(13) var<storage, read_write> elastic_coarse: array<f32>;
@group(0) @binding(14) var<storage, read> elastic_row_starts: array<u32>;
@group(0) @binding(15) var<storage, read> elastic_row_values: array<f32>;
@group(0) @binding(16) var<storage, read> elastic_column_starts: array<u32>;
@group(0) @binding(17) var<storage, read> elastic_column_rows: array<u32>;
@group(0) @binding(18) var<storage, read> elastic_column_values: array<f32>;
// The multipliers mu_i.
@group(0) @binding(19) var<storage, read> elastic_particles: array<ElasticParticle>;

const OUTSIDE: u32 = 0xffffffffu;

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_step_of(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    if (elastic_aggregate[i] == OUTSIDE) {
        elastic_step[i] = vec4<f32>(0.0);
        elastic_residual[i] = vec4<f32>(0.0);
    } else {
        let s = plain[i].xyz - current[i].xyz;
        elastic_step[i] = vec4<f32>(s, 1.0);
        // Minus the spring's part of K s, which `elastic_residual_of` does
        // not make (as `smoothed_step` leaves it after the volume smoother).
        elastic_residual[i] = vec4<f32>(-spring_operator(i, params.count, s), 0.0);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_change_of(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let c = matrix_of(elastic_gradients[i].correction);
    let scale = matrix_of(elastic_gradients[i].scale);
    let p = rest[i].xyz;
    let mu = elastic_particles[i].multiplier.xyz;
    let s = elastic_step[i].xyz;
    var change = 0.0;
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        let entry = c * (rest[j].xyz - p) + scale * (elastic_particles[j].multiplier.xyz - mu);
        change += dot(elastic_step[j].xyz - s, entry);
    }
    elastic_change[i] = change;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_residual_of(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let j = particle_index(workgroup, groups, local);
    if (j >= params.count) {
        return;
    }
    let own = elastic_step[j];
    if (own.w == 0.0) {
        elastic_residual[j] = vec4<f32>(0.0);
        return;
    }
    // c alpha: c = 2 for the elastic (symmetric) force.
    let contraction = select(2.0, 1.0, params.model == 0u) * params.alpha;
    let h_j = elastic_change[j] * matrix_of(elastic_gradients[j].correction);
    let n_j = elastic_change[j] * matrix_of(elastic_gradients[j].scale);
    let p = rest[j].xyz;
    let mu = elastic_particles[j].multiplier.xyz;
    var k = vec3<f32>(0.0);
    for (var n = offsets[j]; n < offsets[j + 1u]; n++) {
        let i = indices[n];
        let d = p - rest[i].xyz;
        let h_i = elastic_change[i] * matrix_of(elastic_gradients[i].correction);
        let n_i = elastic_change[i] * matrix_of(elastic_gradients[i].scale);
        k += (own.xyz - elastic_step[i].xyz)
            + 0.5 * ((h_i + h_j) * d + (n_i + n_j) * (mu - elastic_particles[i].multiplier.xyz));
    }
    // After the volume smoother (volume_smoother.wgsl) K e' = K s − r, its
    // `smoothed_step` having left r − (S s)_j here; after the plain step
    // r = s / (c alpha), `elastic_step_of` having left −(S s)_j (S s the
    // springs' part of K s, shared/loads).
    let r = select(own.xyz / contraction, vec3<f32>(0.0), params.volume_delta > 0.0);
    elastic_residual[j] = vec4<f32>(k - r - elastic_residual[j].xyz, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_restrict(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let a = particle_index(workgroup, groups, local);
    // (`params` read by every pass: the batch binds it at a dynamic offset.)
    if (3u * a >= arrayLength(&elastic_coarse) || params.count == 0u) {
        return;
    }
    var sum = vec3<f32>(0.0);
    for (var k = elastic_member_starts[a]; k < elastic_member_starts[a + 1u]; k++) {
        sum += elastic_residual[elastic_members[k]].xyz;
    }
    elastic_coarse[3u * a] = sum.x;
    elastic_coarse[3u * a + 1u] = sum.y;
    elastic_coarse[3u * a + 2u] = sum.z;
}

// The bound factor's unknowns: one row start each past the first. Not the
// vector's length alone: a buffer holds 16 bytes at least, so the vector of
// one aggregate or group (three unknowns) has a fourth element.
fn elastic_unknowns() -> u32 {
    return min(arrayLength(&elastic_coarse), arrayLength(&elastic_row_starts) - 1u);
}

// L L^T x = b in place in `elastic_coarse`, by one workgroup each way, one
// unknown after another with a barrier between, as
// `coarse.wgsl::coarse_forward` and `coarse_backward` do for one coordinate.
// The vector is held in workgroup memory for the solve, and what a step
// reads of the factor (its diagonal, its range, each thread's first entry)
// is fetched during the step before, the range's end two steps before: a
// step then waits on a workgroup barrier, not on the device's memory. The
// same operations in the same order as one step after another would do.
// `HELD_UNKNOWNS` is the deformer's `GPU_COARSE_UNKNOWNS`, which
// `ElasticCoarseBuffers::linearise` refuses to exceed.
const HELD_UNKNOWNS: u32 = 4096u;

var<workgroup> held: array<f32, HELD_UNKNOWNS>;

// Forward, L y = b by columns: y_j = b_j / L_jj, then b_i −= L_ij y_j for
// the rows below that reach column j.
@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_forward(@builtin(local_invocation_index) local: u32) {
    let n = select(elastic_unknowns(), 0u, params.count == 0u);
    if (n == 0u) {
        return;
    }
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = elastic_coarse[i];
    }
    workgroupBarrier();
    // Column j: entries begin..end; this thread's first (row, value).
    var diagonal = elastic_row_values[elastic_row_starts[1u] - 1u];
    var begin = elastic_column_starts[0u];
    var end = elastic_column_starts[1u];
    var row = 0u;
    var value = 0.0;
    if (begin + local < end) {
        row = elastic_column_rows[begin + local];
        value = elastic_column_values[begin + local];
    }
    var end_next = elastic_column_starts[min(2u, n)];
    for (var j = 0u; j < n; j++) {
        // Column j + 1's, fetched ahead (nothing past the last column).
        let diagonal_next = elastic_row_values[elastic_row_starts[min(j + 2u, n)] - 1u];
        var row_next = 0u;
        var value_next = 0.0;
        if (end + local < end_next) {
            row_next = elastic_column_rows[end + local];
            value_next = elastic_column_values[end + local];
        }
        let end_after = elastic_column_starts[min(j + 3u, n)];
        let y = held[j] / diagonal;
        if (begin + local < end) {
            held[row] -= value * y;
        }
        for (var k = begin + local + WORKGROUP_SIZE; k < end; k += WORKGROUP_SIZE) {
            held[elastic_column_rows[k]] -= elastic_column_values[k] * y;
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
        elastic_coarse[i] = held[i];
    }
}

// Backward, L^T x = y by rows: x_i = y_i / L_ii, then y_j −= L_ij x_i for
// the columns of row i (its envelope: entries start..last, `last` the
// diagonal's).
@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_backward(@builtin(local_invocation_index) local: u32) {
    let n = select(elastic_unknowns(), 0u, params.count == 0u);
    if (n == 0u) {
        return;
    }
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = elastic_coarse[i];
    }
    workgroupBarrier();
    var start = elastic_row_starts[n - 1u];
    var last = elastic_row_starts[n] - 1u;
    var diagonal = elastic_row_values[last];
    var value = 0.0;
    if (start + local < last) {
        value = elastic_row_values[start + local];
    }
    var start_next = elastic_row_starts[max(n, 2u) - 2u];
    for (var step = 0u; step < n; step++) {
        let i = n - 1u - step;
        // Row i - 1's, fetched ahead: its diagonal ends where row i starts
        // (nothing before row 0).
        let last_next = max(start, 1u) - 1u;
        let diagonal_next = elastic_row_values[last_next];
        var value_next = 0.0;
        if (i > 0u && start_next + local < last_next) {
            value_next = elastic_row_values[start_next + local];
        }
        let start_after = elastic_row_starts[max(i, 2u) - 2u];
        let x = held[i] / diagonal;
        let first = i + start - last;
        if (start + local < last) {
            held[first + local] -= value * x;
        }
        for (var k = start + local + WORKGROUP_SIZE; k < last; k += WORKGROUP_SIZE) {
            held[first + (k - start)] -= elastic_row_values[k] * x;
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
        elastic_coarse[i] = held[i];
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_apply(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let a = elastic_aggregate[i];
    if (a != OUTSIDE) {
        let x = vec3<f32>(elastic_coarse[3u * a], elastic_coarse[3u * a + 1u], elastic_coarse[3u * a + 2u]);
        plain[i] = vec4<f32>(plain[i].xyz - x, 0.0);
    }
}
