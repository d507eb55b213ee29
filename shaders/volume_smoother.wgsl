// The elastic phase's smoother with the volume term taken implicitly, twin
// of `tissue_solve::volume_smoother::VolumeSmoother::smooth` (its CPU twin
// computes in f64, here in f32). With the volume term's Gauss-Newton part
// H H^T (column i: h_i = sqrt(W_i / 2) g_i, g_i the gradient of J_i at the
// phase's start, its entry at neighbour j
// cof(F_i) c_ij = C_i (p_j − p_i) + S_i (mu_j − mu_i); the uploaded
// `elastic_gradients` hold sqrt(W_i) C_i and sqrt(W_i) S_i, so h_ij is
// theirs over sqrt(2)), the smoothed step for the residual r is
// s = (r − H z) / delta, z from two Jacobi sweeps on
// (delta I + H^T H) z = H^T r relaxed by theta, D_i its diagonal; with
// springs towards the observation delta I is delta I + P / 2 on each
// particle (P = a I + b u u^T, shared/loads), which turns every field H^T
// reads and the step by Phi = delta (delta I + P / 2)^-1
// (`tissue_solve::coarse::VolumeSmoother`):
// - `smoother_residual`, per particle: r_i = d (F_i + b_i + p_i) / 2 (p_i
//   the spring's pull, shared/loads) inside the
//   elastic aggregates (w = 1), 0 outside, into `elastic_step`, with the
//   damping d (1, but where a failed smoothed phase is run again: the
//   two-level step is linear in r, so this takes that fraction of it);
// - `pressure_start`, per particle: t_i = h_i . r, z_i = theta t_i / D_i;
// - `pressure_forces`, per particle: (H z)_k, 0 outside;
// - `pressure_sweep`, per particle: z_i += theta (t_i − delta z_i − h_i . (H z)) / D_i;
// - `pressure_forces` again, then `smoothed_step`, per particle:
//   s_k = (r_k − (H z)_k) / delta, q̂_k = q_k + s_k, s_k into `elastic_step`
//   and r_k − (S s)_k into `elastic_residual` (S s the springs' part of
//   K s), where `coarse_elastic.wgsl`'s correction takes them
//   (K e' = K s − r).
// delta, theta and d come in `params` (volume_delta, volume_relaxation,
// volume_damping).

#import shared/layout
#import shared/loads

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> plain: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(0) @binding(5) var<storage, read> indices: array<u32>;
@group(0) @binding(6) var<storage, read> force: array<vec4<f32>>;
// Per particle its elastic aggregate, or OUTSIDE.
@group(0) @binding(8) var<storage, read> elastic_aggregate: array<u32>;
// Per particle r_i, then s_i (w: 1 inside an aggregate, 0 outside).
@group(0) @binding(9) var<storage, read_write> elastic_step: array<vec4<f32>>;
// Per particle sqrt(W_i) C_i and sqrt(W_i) S_i at the phase's start.
@group(0) @binding(10) var<storage, read> elastic_gradients: array<ElasticGradient>;
// The multipliers mu_i.
@group(0) @binding(11) var<storage, read> elastic_particles: array<ElasticParticle>;
// Per particle (t_i, z_i, D_i, 0); D_i uploaded with the linearisation.
@group(0) @binding(12) var<storage, read_write> pressures: array<vec4<f32>>;
// Per particle (H z)_k.
@group(0) @binding(13) var<storage, read_write> pressure_force: array<vec4<f32>>;
// Per particle r_k for the correction's K e' = K s − r.
@group(0) @binding(14) var<storage, read_write> elastic_residual: array<vec4<f32>>;

const OUTSIDE: u32 = 0xffffffffu;
const SQRT_HALF: f32 = 0.70710678;

// h_i's entry at its neighbour j.
fn entry(i: u32, j: u32) -> vec3<f32> {
    let c = matrix_of(elastic_gradients[i].correction);
    let scale = matrix_of(elastic_gradients[i].scale);
    let d = rest[j].xyz - rest[i].xyz;
    let dmu = elastic_particles[j].multiplier.xyz - elastic_particles[i].multiplier.xyz;
    return SQRT_HALF * (c * d + scale * dmu);
}

// Phi at particle j applied to x with its spring (shared/loads), x
// without: delta M_0^-1, M_0 = delta I + P / 2 = alpha I + beta u u^T
// (alpha = delta + a / 2, beta = b / 2), so
// (delta / alpha) (x − u (u . x) beta / (alpha + beta |u|^2)).
fn phi(j: u32, x: vec3<f32>) -> vec3<f32> {
    let s = spring_of(j, params.count);
    let u = s.axis.xyz;
    let alpha = params.volume_delta + 0.5 * s.anchor.w;
    let beta = 0.5 * s.axis.w;
    let along = beta / (alpha + beta * dot(u, u));
    return (params.volume_delta / alpha) * (x - u * (dot(u, x) * along));
}

// h_i . Phi r, r in `elastic_step` (each field its own function: a kernel
// binds only the buffers it reads).
fn residual_change(i: u32) -> f32 {
    let own = phi(i, elastic_step[i].xyz);
    var change = 0.0;
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        change += dot(phi(j, elastic_step[j].xyz) - own, entry(i, j));
    }
    return change;
}

// h_i . Phi H z, H z in `pressure_force`.
fn force_change(i: u32) -> f32 {
    let own = phi(i, pressure_force[i].xyz);
    var change = 0.0;
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        change += dot(phi(j, pressure_force[j].xyz) - own, entry(i, j));
    }
    return change;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn smoother_residual(
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
        return;
    }
    let f = force[i].xyz + body_force(i, params.count) + spring_pull(i, params.count, current[i].xyz);
    elastic_step[i] = vec4<f32>(0.5 * params.volume_damping * f, 1.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pressure_start(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let t = residual_change(i);
    let d = pressures[i].z;
    pressures[i] = vec4<f32>(t, params.volume_relaxation * t / d, d, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pressure_forces(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(workgroup, groups, local);
    if (k >= params.count) {
        return;
    }
    if (elastic_step[k].w == 0.0) {
        pressure_force[k] = vec4<f32>(0.0);
        return;
    }
    let z_k = pressures[k].y;
    var f = vec3<f32>(0.0);
    for (var n = offsets[k]; n < offsets[k + 1u]; n++) {
        let i = indices[n];
        f += pressures[i].y * entry(i, k) - z_k * entry(k, i);
    }
    pressure_force[k] = vec4<f32>(f, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pressure_sweep(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let p = pressures[i];
    let s_z = params.volume_delta * p.y + force_change(i);
    let z = p.y + params.volume_relaxation * (p.x - s_z) / p.z;
    pressures[i] = vec4<f32>(p.x, z, p.z, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn smoothed_step(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(workgroup, groups, local);
    if (k >= params.count) {
        return;
    }
    let q = current[k].xyz;
    let r = elastic_step[k];
    if (r.w == 0.0) {
        plain[k] = vec4<f32>(q, 0.0);
        elastic_residual[k] = vec4<f32>(0.0);
        return;
    }
    let s = phi(k, r.xyz - pressure_force[k].xyz) / params.volume_delta;
    plain[k] = vec4<f32>(q + s, 0.0);
    elastic_step[k] = vec4<f32>(s, 1.0);
    // The spring's part of K s, which `elastic_residual_of` does not make.
    elastic_residual[k] = vec4<f32>(r.xyz - spring_operator(k, params.count, s), 0.0);
}
