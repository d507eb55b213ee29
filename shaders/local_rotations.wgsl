// Stage 2, eqs. (10)-(13): per particle, the rotation that best maps rest
// offsets onto current offsets, the polar rotation of
// M_i = Σ_j (q_j − q_i)(p_j − p_i)ᵀ: by the SVD (`local_rotations`, twin
// `tissue_cpu::deformation::local_rotations`) or by the polar update
// warm-started from the particle's stored rotation (`local_rotations_warm`,
// twin `tissue_cpu::kernels::local_rotations::local_rotations_warm`). `turn_rotations`
// premultiplies every stored rotation by `turn` at a frame boundary (the
// CPU device's `write_positions` with a turn).

#import shared/layout
#import shared/offsets
#import shared/svd3
#import shared/polar

@group(0) @binding(0) var<uniform> params: Params;
// Bindings 1 to 4 (rest, current, offsets, indices): shared/offsets.
@group(0) @binding(5) var<storage, read_write> rotations: array<Rotation>;
// The turn `turn_rotations` applies (one matrix).
@group(0) @binding(6) var<storage, read> turn: array<Rotation>;

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

@compute @workgroup_size(WORKGROUP_SIZE)
fn local_rotations_warm(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    rotations[i] = stored(warm_rotation(offsets_product(i), matrix_of(rotations[i])));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn turn_rotations(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    rotations[i] = stored(matrix_of(turn[0]) * matrix_of(rotations[i]));
}
