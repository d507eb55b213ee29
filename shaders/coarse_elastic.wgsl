// The elastic phase's two-level correction, twin of
// `tissue_solve::coarse_elastic::ElasticCoarse::correct`, in six passes
// between `integrate` and `chebyshev`. The elastic operator at the state the
// phase started from, K = L + 1/2 sum_i W_i g_i g_i^T (g_i the gradient of
// J_i, its entry at neighbour j cof(F_i) c_ij = C_i d_ij + S_i (mu_j - mu_i)
// with C_i = cof(F_i) B_i and S_i = a_i cof(F_i) there),
// gives K e' = −s / (c alpha) + K s for the error after the plain step s;
// its projection onto the aggregates' translations (three unknowns each) is
// removed:
// - `elastic_step`, per particle: s_i, 0 outside the aggregates (w = 1 inside);
// - `elastic_change`, per particle: sqrt(W_i) g_i . s, the uploaded
//   `elastic_gradients` being sqrt(W_i) C_i and sqrt(W_i) S_i;
// - `elastic_residual`, per particle: (K s)_j − s_j / (c alpha), or
//   (K s)_j − r_j after the volume smoother (volume_smoother.wgsl), which
//   leaves r_j in `elastic_residual` and s in `elastic_step`;
// - `elastic_restrict`, per aggregate: the sum over its particles, three
//   entries of `elastic_coarse`;
// - `elastic_forward` and `elastic_backward`, one workgroup each: the
//   coarse matrix's Cholesky factor over the 3 n unknowns, forward by
//   columns, backward by rows, the vector in workgroup memory;
// - `elastic_apply`, per particle: q̂_i −= the solution at its aggregate.
// The CPU computes in f64, here in f32.

#import shared/layout

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
    } else {
        elastic_step[i] = vec4<f32>(plain[i].xyz - current[i].xyz, 1.0);
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
    // `smoothed_step` having left r here; after the plain step r = s / (c alpha).
    let r = select(own.xyz / contraction, elastic_residual[j].xyz, params.volume_delta > 0.0);
    elastic_residual[j] = vec4<f32>(k - r, 0.0);
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
// The vector is held in workgroup memory for the solve, so that a step
// waits on a workgroup barrier only, not on the device's memory, and each
// step's diagonal is fetched one step ahead. `HELD_UNKNOWNS` is the
// deformer's `GPU_COARSE_UNKNOWNS`, which `ElasticCoarseBuffers::linearise`
// refuses to exceed.
const HELD_UNKNOWNS: u32 = 4096u;

var<workgroup> held: array<f32, HELD_UNKNOWNS>;

// The diagonal of row j.
fn elastic_diagonal(j: u32) -> f32 {
    return elastic_row_values[elastic_row_starts[j + 1u] - 1u];
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_forward(@builtin(local_invocation_index) local: u32) {
    let n = select(elastic_unknowns(), 0u, params.count == 0u);
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = elastic_coarse[i];
    }
    workgroupBarrier();
    var diagonal = 1.0;
    if (n > 0u) {
        diagonal = elastic_diagonal(0u);
    }
    for (var j = 0u; j < n; j++) {
        let next = elastic_diagonal(min(j + 1u, n - 1u));
        let y = held[j] / diagonal;
        let end = elastic_column_starts[j + 1u];
        for (var k = elastic_column_starts[j] + local; k < end; k += WORKGROUP_SIZE) {
            let i = elastic_column_rows[k];
            held[i] -= elastic_column_values[k] * y;
        }
        workgroupBarrier();
        if (local == 0u) {
            held[j] = y;
        }
        diagonal = next;
    }
    workgroupBarrier();
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        elastic_coarse[i] = held[i];
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_backward(@builtin(local_invocation_index) local: u32) {
    let n = select(elastic_unknowns(), 0u, params.count == 0u);
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        held[i] = elastic_coarse[i];
    }
    workgroupBarrier();
    var diagonal = 1.0;
    if (n > 0u) {
        diagonal = elastic_diagonal(n - 1u);
    }
    for (var step = 0u; step < n; step++) {
        let i = n - 1u - step;
        let next = elastic_diagonal(max(i, 1u) - 1u);
        let start = elastic_row_starts[i];
        let last = elastic_row_starts[i + 1u] - 1u;
        let x = held[i] / diagonal;
        let first = i + start - last;
        for (var k = start + local; k < last; k += WORKGROUP_SIZE) {
            held[first + (k - start)] -= elastic_row_values[k] * x;
        }
        workgroupBarrier();
        if (local == 0u) {
            held[i] = x;
        }
        diagonal = next;
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
