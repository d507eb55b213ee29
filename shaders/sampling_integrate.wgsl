// Stage 1, eq. (1): dp = F r0 / m~, the step capped at max_step r0; in
// projection mode a particle that ends outside is moved back onto the surface
// by its penetration depth, the wall's reaction (outward normal, depth m~ / r0)
// in `contact_next`. Twin of `tissue_cpu::kernels::sampling_integrate::integrate`; writes
// `next.xyz` (radius_update wrote `next.w`).

#import shared/sampling
#import shared/surface_field

@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> contact: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> forces: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> halt: array<u32>;
@group(0) @binding(7) var<storage, read_write> next: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> contact_next: array<vec4<f32>>;

// glam's `clamp_length_max`.
fn clamp_length_max(v: vec3<f32>, max_length: f32) -> vec3<f32> {
    let length_sq = dot(v, v);
    if (length_sq > max_length * max_length) {
        return max_length * (v / sqrt(length_sq));
    }
    return v;
}

// What the projection takes away is the wall's reaction, in force units.
fn held(n: Nearest) -> array<vec4<f32>, 2> {
    let reaction = n.distance * sampling.mass / sampling.r0;
    return array<vec4<f32>, 2>(vec4<f32>(n.point, 0.0), vec4<f32>(n.normal, reaction));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn integrate(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count || halt[0] != 0u) {
        return;
    }
    let step = clamp_length_max(forces[i].xyz * sampling.step_scale, sampling.max_step);
    let moved = current[i].xyz + step;
    var out = array<vec4<f32>, 2>(vec4<f32>(moved, 0.0), vec4<f32>(0.0));
    if (sampling.surface_mode == 0u) {
        let q = field_query(field_grid(), moved);
        if (q.side == SIDE_DEEP_OUTSIDE) {
            out = held(nearest_of_all(field_grid(), moved));
        } else if (q.side == SIDE_NEAR && q.nearest.distance > 0.0) {
            out = held(q.nearest);
        }
    }
    next[i] = vec4<f32>(out[0].xyz, next[i].w);
    contact_next[i] = out[1];
}
