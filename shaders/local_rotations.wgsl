// Stage 2, eqs. (10)-(13): per particle, the rotation that best maps rest
// offsets onto current offsets, the polar rotation of
// M_i = Σ_j (q_j − q_i)(p_j − p_i)ᵀ. Twin: `tissue_cpu::deformation::local_rotations`.

#import shared/layout
#import shared/offsets
#import shared/svd3

@group(0) @binding(0) var<uniform> params: Params;
// Bindings 1 to 4 (rest, current, offsets, indices): shared/offsets.
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
    rotations[i] = stored(rotation_of(offsets_product(i)));
}
