// Stage 2, eq. (1): `integrate`, q̂ = q + alpha (F + b + p) for free
// particles, b the particle's body force where the state has loads and, in
// the elastic force's iterations, p its spring's pull where the state has
// springs (shared/loads; control points stay where the surface put them), twin of
// `tissue_cpu::deformation::integrate`; and `chebyshev`, Wang 2015's
// q_{k+1} = omega (q̂_{k+1} − q_{k−1}) + q_{k−1}, the combine in
// `tissue_cpu::deformation::Deformer::solve` (omega exactly 1: the plain q̂).

#import shared/layout
#import shared/loads

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> force: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> free: array<u32>;
@group(0) @binding(4) var<storage, read_write> plain: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> previous: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn integrate(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let q = current[i].xyz;
    var f = force[i].xyz + body_force(i, params.count);
    if (params.model == 2u) {
        f += spring_pull(i, params.count, q);
    }
    plain[i] = vec4<f32>(select(q, q + params.alpha * f, free[i] != 0u), 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn chebyshev(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let q_hat = plain[i].xyz;
    let q_old = previous[i].xyz;
    let next = select(params.omega * (q_hat - q_old) + q_old, q_hat, params.omega == 1.0);
    previous[i] = current[i];
    current[i] = vec4<f32>(next, 0.0);
}
