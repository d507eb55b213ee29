// Stage 1, eqs. (7)-(8): each balloon inflates when under-compressed and
// deflates when over-compressed; dr is a change of ln r, its ln argument
// clamped to [exp(-x), exp(x)]. Twin of `tissue_cpu::kernels::radius_update`
// (radii: `current.w`; compressions: `forces.w`); writes `next.w`.

#import shared/sampling

@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> forces: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> halt: array<u32>;
@group(0) @binding(7) var<storage, read_write> next: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn radius_update(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count || halt[0] != 0u) {
        return;
    }
    let argument = clamp(
        1.0 + sampling.eta * (forces[i].w - sampling.ideal),
        sampling.radius_bound_inv,
        sampling.radius_bound,
    );
    next[i].w = current[i].w / argument;
}
