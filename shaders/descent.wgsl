// The conjugate-gradient elastic phase's per-particle work, twin of
// `tissue_cpu::kernels::descent` (`tissue_solve::stage2::SolveDevice`'s
// `descent_residual`, `descent_direction` and `descent_move`), after an
// iteration's passes up to its combine left the two-level step's positions
// q̂ = q + z in `plain`:
// - `descent_dots`, per particle: r_i = (F_i + b_i + p_i) / 2 inside the
//   elastic aggregates, 0 outside (the residual the volume smoother reads,
//   undamped), z_i = q̂_i − q_i, and (r . z, z . r', r . d', |z|) into
//   `dot_parts` (the host sums them in f64), r' the residual kept in
//   `last_residual` by the last call and d' the direction; r' is then r;
// - `descent_direction`, per particle: d_i = z_i + beta d_i, and the
//   positions kept in `line_base`;
// - `descent_move`, per particle: q_i = base_i + t d_i.
// beta and t come in `params.omega`.

#import shared/layout
#import shared/loads

const OUTSIDE: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> plain: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> force: array<vec4<f32>>;
// Per particle its elastic aggregate, or OUTSIDE.
@group(0) @binding(4) var<storage, read> elastic_aggregate: array<u32>;
@group(0) @binding(5) var<storage, read_write> last_residual: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> direction: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> line_base: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> dot_parts: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn descent_dots(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let q = current[i].xyz;
    var r = vec3<f32>(0.0);
    if (elastic_aggregate[i] != OUTSIDE) {
        r = 0.5 * (force[i].xyz + body_force(i, params.count) + spring_pull(i, params.count, q));
    }
    let z = plain[i].xyz - q;
    let last = last_residual[i].xyz;
    dot_parts[i] = vec4<f32>(dot(z, r), dot(z, last), dot(r, direction[i].xyz), length(z));
    last_residual[i] = vec4<f32>(r, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn descent_direction(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let q = current[i].xyz;
    let z = plain[i].xyz - q;
    direction[i] = vec4<f32>(z + params.omega * direction[i].xyz, 0.0);
    line_base[i] = vec4<f32>(q, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn descent_move(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    current[i] = vec4<f32>(line_base[i].xyz + params.omega * direction[i].xyz, 0.0);
}
