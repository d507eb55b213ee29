// Stage 2, the elastic model's targets (`tissue_solve::elastic`): per
// particle T_i = R_i − W_i (J_i − 1) cof(F_i) A_i⁻¹, with the corrected
// gradient F_i = M_i A_i⁻¹ and J_i = det F_i; the force kernel gathers the
// symmetric sum over T in place of R. Where W_i = 0 (a flat neighbourhood)
// T_i = R_i. Twin: `tissue_cpu::deformation::elastic_targets`.

#import shared/layout
#import shared/offsets

@group(0) @binding(0) var<uniform> params: Params;
// Bindings 1 to 4 (rest, current, offsets, indices): shared/offsets.
@group(0) @binding(5) var<storage, read> rotations: array<Rotation>;
// Per particle A_i⁻¹ (zero for a flat neighbourhood), as three columns.
@group(0) @binding(6) var<storage, read> inverse_moments: array<Rotation>;
// Per particle the volume term's weight W_i.
@group(0) @binding(7) var<storage, read> weights: array<f32>;
@group(0) @binding(8) var<storage, read_write> targets: array<Rotation>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_targets(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    let w = weights[i];
    if (w == 0.0) {
        targets[i] = rotations[i];
        return;
    }
    let inverse = matrix_of(inverse_moments[i]);
    let f = offsets_product(i) * inverse;
    // cof(F) = det(F) F⁻ᵀ: its columns are cross products of F's, and
    // det F = F_x · (F_y × F_z), glam's order.
    let cofactor = mat3x3<f32>(cross(f[1], f[2]), cross(f[2], f[0]), cross(f[0], f[1]));
    let jacobian = dot(f[0], cofactor[0]);
    targets[i] = stored(matrix_of(rotations[i]) - (w * (jacobian - 1.0)) * cofactor * inverse);
}
