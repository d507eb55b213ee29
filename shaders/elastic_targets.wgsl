// Stage 2, the elastic model (`tissue_solve::elastic`): each particle's
// terms of the force, then the force gathered over them (no atomics).
// - `elastic_targets` (rotation by the SVD) and `elastic_targets_warm`
//   (warm-started from the last iteration's), the elastic phase's
//   rotations pass (no local_rotations there): with M_i = Σ_j e_ij d_ijᵀ and
//   N_i = Σ_j e_ij (μ_j − μ_i)ᵀ, the consistent gradient
//   F_i = M_i B_iᵀ + a_i N_i, R_i its polar rotation,
//   Q_i = a_i (F_i − R_i) + W_i (J_i − 1) cof(F_i), the target
//   T_i = M_i A_i⁻¹ − Q_i B_i and the stress U_i = a_i Q_i. A flat
//   neighbourhood (a_i = 0) keeps the pair term: T_i = R_i (of M_i), U_i = 0.
//   Twin: `tissue_cpu::kernels::elastic_targets::elastic_terms` (`Elastic::terms`).
// - `elastic_force`: f_k = Σ_i [(T_i + T_k) d_ik − (U_i + U_k)(μ_k − μ_i) − 2 e_ik],
//   gathered as Σ_i [T_i d_ik − U_i (μ_k − μ_i) − 2 e_ik] + T_k Σ_i d_ik
//   − U_k Σ_i (μ_k − μ_i) (k's own terms once, not per connection).
//   Twin: `tissue_cpu::kernels::elastic_targets::elastic_force` (`Elastic::force_on`).
// - `elastic_potential`: particle i's part of the potential the force
//   descends, E_i / 2 − b_i · q_i (b_i its body force, free particles only),
//   E_i = Σ_j |e_ij − Fh_i d_ij|² + a_i |F_i − R_i|² + W_i (J_i − 1)², Fh_i =
//   M_i A_i⁻¹, R_i the polar rotation of F_i by the SVD; a flat
//   neighbourhood keeps Σ_j |e_ij − R_i d_ij|², R_i that of M_i.
//   Twin: `tissue_cpu::kernels::elastic_targets::elastic_potential`
//   (`Elastic::particle_energy`).

#import shared/layout
#import shared/loads
#import shared/svd3
#import shared/polar

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read> indices: array<u32>;
// Per particle its rotation: the last iteration's in (the warm start),
// this one's out (of F_i, or of M_i where flat).
@group(0) @binding(5) var<storage, read_write> rotations: array<Rotation>;
@group(0) @binding(6) var<storage, read> elastic_particles: array<ElasticParticle>;
@group(0) @binding(7) var<storage, read_write> elastic_terms: array<ElasticTerms>;
@group(0) @binding(8) var<storage, read_write> force: array<vec4<f32>>;
// Per particle its part of the potential (`elastic_potential`'s output),
// then its held part (`elastic_potential_work`'s).
@group(0) @binding(9) var<storage, read_write> potential: array<f32>;
@group(0) @binding(10) var<storage, read> free: array<u32>;
// With a pairing, each particle's spring where the solve last kept a state
// (two entries each, as `loads` holds them); one zero entry without.
@group(0) @binding(11) var<storage, read> held_springs: array<vec4<f32>>;

// M_i and N_i over particle i's connections.
struct Products {
    offsets: mat3x3<f32>,
    multipliers: mat3x3<f32>,
}

fn products(i: u32) -> Products {
    let zero = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var m = zero;
    var n = zero;
    let mu_i = elastic_particles[i].multiplier.xyz;
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        let d = rest[j].xyz - rest[i].xyz;
        let e = current[j].xyz - current[i].xyz;
        m += mat3x3<f32>(e * d.x, e * d.y, e * d.z);
        let u = elastic_particles[j].multiplier.xyz - mu_i;
        n += mat3x3<f32>(e * u.x, e * u.y, e * u.z);
    }
    return Products(m, n);
}

// The consistent gradient F_i = M_i B_iᵀ + a_i N_i of `particle` with
// products `p`; M_i itself for a flat neighbourhood (a_i = 0), which has no
// gradient.
fn gradient_of(particle: ElasticParticle, p: Products) -> mat3x3<f32> {
    let a = particle.correction.x_axis.w;
    if (a == 0.0) {
        return p.offsets;
    }
    return p.offsets * transpose(matrix_of(particle.correction)) + a * p.multipliers;
}

// Particle i's rotation and terms, the rotation found by `warm` (the warm
// polar update from the last iteration's) or the SVD.
fn terms_of(i: u32, warm: bool) {
    let particle = elastic_particles[i];
    let a = particle.correction.x_axis.w;
    let zero = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    let p = products(i);
    let correction = matrix_of(particle.correction);
    let f = gradient_of(particle, p);
    var r: mat3x3<f32>;
    if (warm) {
        r = warm_rotation(f, matrix_of(rotations[i]));
    } else {
        r = rotation_of(f);
    }
    rotations[i] = stored(r);
    if (a == 0.0) {
        elastic_terms[i] = ElasticTerms(stored(r), stored(zero));
        return;
    }
    let w = particle.inverse.x_axis.w;
    let inverse = matrix_of(particle.inverse);
    // cof(F) = det(F) F⁻ᵀ: its columns are cross products of F's.
    let cofactor = mat3x3<f32>(cross(f[1], f[2]), cross(f[2], f[0]), cross(f[0], f[1]));
    // det F = F_x · (F_y × F_z), glam's order.
    let jacobian = dot(f[0], cofactor[0]);
    let q = a * (f - r) + (w * (jacobian - 1.0)) * cofactor;
    elastic_terms[i] = ElasticTerms(stored(p.offsets * inverse - q * correction), stored(a * q));
}

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
    terms_of(i, false);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_targets_warm(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    terms_of(i, true);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_force(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(workgroup, groups, local);
    if (k >= params.count) {
        return;
    }
    let t_k = matrix_of(elastic_terms[k].rest_term);
    let u_k = matrix_of(elastic_terms[k].multiplier_term);
    let mu_k = elastic_particles[k].multiplier.xyz;
    var f = vec3<f32>(0.0);
    var d_sum = vec3<f32>(0.0);
    var u_sum = vec3<f32>(0.0);
    for (var n = offsets[k]; n < offsets[k + 1u]; n++) {
        let i = indices[n];
        let d = rest[k].xyz - rest[i].xyz;
        let e = current[k].xyz - current[i].xyz;
        let u = mu_k - elastic_particles[i].multiplier.xyz;
        let terms = elastic_terms[i];
        f += matrix_of(terms.rest_term) * d - matrix_of(terms.multiplier_term) * u - 2.0 * e;
        d_sum += d;
        u_sum += u;
    }
    force[k] = vec4<f32>(f + t_k * d_sum - u_k * u_sum, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_potential(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= params.count) {
        return;
    }
    // The row's bounds read first: Mesa's OpenGL compiler (llvmpipe,
    // wgpu's GL backend) reads them wrong for part of the particles where
    // they are read after the products and the rotation, and the pair
    // term then skips their connections.
    let first = offsets[i];
    let last = offsets[i + 1u];
    let particle = elastic_particles[i];
    let a = particle.correction.x_axis.w;
    let p = products(i);
    let f = gradient_of(particle, p);
    // The pair term's map, and the gradient's terms where there is one; a
    // flat neighbourhood's map is the rotation of M_i (its `f`). The
    // rotation by the polar update warm-started from the last iteration's
    // (the energy is stationary in it), which stays as it is.
    let r = warm_rotation(f, matrix_of(rotations[i]));
    var map: mat3x3<f32>;
    var own = 0.0;
    if (a == 0.0) {
        map = r;
    } else {
        map = p.offsets * matrix_of(particle.inverse);
        let shear = f - r;
        let jacobian = determinant(f);
        let w = particle.inverse.x_axis.w;
        own = a * (dot(shear[0], shear[0]) + dot(shear[1], shear[1]) + dot(shear[2], shear[2]))
            + w * (jacobian - 1.0) * (jacobian - 1.0);
    }
    var pair = 0.0;
    for (var k = first; k < last; k++) {
        let j = indices[k];
        let d = rest[j].xyz - rest[i].xyz;
        let e = current[j].xyz - current[i].xyz;
        let miss = e - map * d;
        pair += dot(miss, miss);
    }
    potential[i] = 0.5 * (pair + own);
}

// The loads' work taken from each free particle's part of the potential,
// and its spring's part added (`elastic_potential` binds all a stage may);
// with held springs, its held part after all the parts: the same with its
// held spring's part instead.
// Twin: `tissue_cpu::kernels::elastic_targets::elastic_potential`.
@compute @workgroup_size(WORKGROUP_SIZE)
fn elastic_potential_work(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let n = params.count;
    let i = particle_index(workgroup, groups, local);
    if (i >= n) {
        return;
    }
    var base = potential[i];
    var pull = 0.0;
    var held = 0.0;
    if (free[i] != 0u) {
        let q = current[i].xyz;
        base = base - dot(body_force(i, n), q);
        pull = spring_potential(i, n, q);
        if (arrayLength(&held_springs) == 2u * n) {
            let s = Spring(held_springs[2u * i], held_springs[2u * i + 1u]);
            let miss = q - s.anchor.xyz;
            held = 0.5 * dot(miss, spring_times(s, miss));
        }
    }
    potential[i] = base + pull;
    if (arrayLength(&held_springs) == 2u * n && arrayLength(&potential) >= 2u * n) {
        potential[n + i] = base + held;
    }
}
