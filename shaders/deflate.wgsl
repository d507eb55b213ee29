// Deflation of the plain step along the Laplacian's lowest modes, twin of
// `tissue_cpu::deformation::LowModes::deflate`, in three passes between
// `integrate` and `chebyshev`: `deflate_project`, each workgroup's share of
// the projections c_k = sum_i (q̂_i − q_i) v_ik; `deflate_gains`, one
// workgroup summing them into g_k = c_k (1 / (c alpha lambda_k) − 1) (the
// factor precomputed per mode in `scales`); `deflate_apply`,
// q̂_i += sum_k g_k v_ik. Sums run in f32 per workgroup, then in f32 over
// workgroups (the CPU: f32 per 1024 particles, then f64), so both agree
// within rounding.

#import shared/layout

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> plain: array<vec4<f32>>;
// Particle-major: vectors[i * params.modes + k] is mode k at particle i.
@group(0) @binding(3) var<storage, read> vectors: array<f32>;
// [workgroup][mode]: each deflate_project workgroup's share of c_k.
@group(0) @binding(4) var<storage, read_write> projections: array<vec4<f32>>;
// Per mode, 1 / (c alpha lambda_k) − 1.
@group(0) @binding(5) var<storage, read> scales: array<f32>;
// Per mode, g_k.
@group(0) @binding(6) var<storage, read_write> gains: array<vec4<f32>>;

var<workgroup> steps: array<vec4<f32>, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn deflate_project(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let group = flat_workgroup(workgroup, groups);
    let first = group * WORKGROUP_SIZE;
    let i = first + local;
    // No early return: every thread must reach the barrier; past the end it adds 0.
    var step = vec3<f32>(0.0);
    if (i < params.count) {
        step = plain[i].xyz - current[i].xyz;
    }
    steps[local] = vec4<f32>(step, 0.0);
    workgroupBarrier();
    // Particles of this workgroup (none in the idle tail of a 2-D dispatch).
    var here = 0u;
    if (first < params.count) {
        here = min(params.count - first, WORKGROUP_SIZE);
    }
    // Thread t sums modes t, t + WORKGROUP_SIZE, ...: neighbouring threads
    // read neighbouring entries of a particle's row.
    for (var k = local; k < params.modes; k += WORKGROUP_SIZE) {
        var sum = vec3<f32>(0.0);
        for (var j = 0u; j < here; j++) {
            sum += steps[j].xyz * vectors[(first + j) * params.modes + k];
        }
        projections[group * params.modes + k] = vec4<f32>(sum, 0.0);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn deflate_gains(@builtin(local_invocation_index) local: u32) {
    for (var k = local; k < params.modes; k += WORKGROUP_SIZE) {
        var sum = vec3<f32>(0.0);
        for (var g = 0u; g < params.mode_groups; g++) {
            sum += projections[g * params.modes + k].xyz;
        }
        gains[k] = vec4<f32>(sum * scales[k], 0.0);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn deflate_apply(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    // v is 0 at control points: they stay where the surface put them.
    let row = i * params.modes;
    var d = vec3<f32>(0.0);
    for (var k = 0u; k < params.modes; k++) {
        d += gains[k].xyz * vectors[row + k];
    }
    plain[i] = vec4<f32>(plain[i].xyz + d, 0.0);
}
