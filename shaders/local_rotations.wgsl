// Stage 2, eqs. (10)-(13): per particle, the rotation that best maps rest
// offsets onto current offsets, the polar rotation of
// M_i = Σ_j (q_j − q_i)(p_j − p_i)ᵀ. Twin: `tissue_cpu::deformation::local_rotations`.

#import shared/layout
#import shared/svd3

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read> indices: array<u32>;
@group(0) @binding(5) var<storage, read_write> rotations: array<Rotation>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn local_rotations(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    var m = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        let d = rest[j].xyz - rest[i].xyz;
        let c = current[j].xyz - current[i].xyz;
        m += mat3x3<f32>(c * d.x, c * d.y, c * d.z);
    }
    let r = rotation_of(m);
    rotations[i] = Rotation(vec4<f32>(r[0], 0.0), vec4<f32>(r[1], 0.0), vec4<f32>(r[2], 0.0));
}
