// Stage 2, eq. (14): the force on each particle, gathered over its
// connections (no atomics). params.model 0: the paper's one-sided
// F_j = Σ_i [R_i (p_j − p_i) − (q_j − q_i)]; 1: the symmetric
// F_j = Σ_i [(R_i + R_j)(p_j − p_i) − 2 (q_j − q_i)], −½ the energy's gradient.
// (The elastic force has a kernel of its own: elastic_targets.wgsl.)
// Twin: `tissue_cpu::kernels::deformation_force`.

#import shared/layout

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> rotations: array<Rotation>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(0) @binding(5) var<storage, read> indices: array<u32>;
@group(0) @binding(6) var<storage, read_write> force: array<vec4<f32>>;

const PAPER: u32 = 0u;

fn rotation(k: u32) -> mat3x3<f32> {
    return matrix_of(rotations[k]);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn deformation_force(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let j = particle_index(workgroup, groups, local);
    if (j >= params.count) {
        return;
    }
    let r_j = rotation(j);
    var f = vec3<f32>(0.0);
    for (var k = offsets[j]; k < offsets[j + 1u]; k++) {
        let i = indices[k];
        let d = rest[j].xyz - rest[i].xyz;
        let c = current[j].xyz - current[i].xyz;
        if (params.model == PAPER) {
            f += rotation(i) * d - c;
        } else {
            f += (rotation(i) + r_j) * d - 2.0 * c;
        }
    }
    force[j] = vec4<f32>(f, 0.0);
}
