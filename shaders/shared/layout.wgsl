// Structs and indexing shared by every stage-2 kernel. Rust mirrors:
// `tissue_gpu::Params`, `tissue_gpu::Rotation` (layout-tested against naga).

// Threads per workgroup of every stage-2 kernel; Rust reads it from the module.
const WORKGROUP_SIZE: u32 = 64u;

// Per-iteration parameters (one slot per iteration of a batch, dynamic offset).
struct Params {
    // Number of particles.
    count: u32,
    // Force model: 0 the paper's, 1 symmetric, 2 elastic (whose iterations
    // run elastic_targets.wgsl's kernels; the model sets c in c alpha).
    model: u32,
    // Step alpha = sigma / m.
    alpha: f32,
    // Chebyshev weight of this iteration; exactly 1 means a plain step.
    omega: f32,
    // Which row of `partials` step_norms writes.
    slot: u32,
    // Workgroups per dispatch (x times y), the length of a `partials` row.
    groups: u32,
    // The volume smoother's delta in a smoothed elastic iteration
    // (volume_smoother.wgsl); 0 in every other, whose elastic correction
    // takes the plain step's residual.
    volume_delta: f32,
    // The relaxation of its Jacobi sweeps on the pressures.
    volume_relaxation: f32,
    // The fraction of the smoothed two-level step taken: the residual is
    // scaled by it (1 but where a failed smoothed phase is run again).
    volume_damping: f32,
}

// A particle's rotation as three columns (no bare vec3 in storage).
struct Rotation {
    x_axis: vec4<f32>,
    y_axis: vec4<f32>,
    z_axis: vec4<f32>,
}

// A stored 3x3 matrix (a rotation, a target, an inverse moment) as a matrix.
fn matrix_of(r: Rotation) -> mat3x3<f32> {
    return mat3x3<f32>(r.x_axis.xyz, r.y_axis.xyz, r.z_axis.xyz);
}

// A 3x3 matrix in its stored layout.
fn stored(m: mat3x3<f32>) -> Rotation {
    return Rotation(vec4<f32>(m[0], 0.0), vec4<f32>(m[1], 0.0), vec4<f32>(m[2], 0.0));
}

// Beyond 65,535 workgroups the dispatch is two-dimensional, row by row.
fn flat_workgroup(workgroup: vec3<u32>, groups: vec3<u32>) -> u32 {
    return workgroup.x + workgroup.y * groups.x;
}

fn particle_index(workgroup: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    return flat_workgroup(workgroup, groups) * WORKGROUP_SIZE + local;
}

// The elastic model's rest data of a particle (`tissue_solve::elastic`):
// A_i⁻¹ with W_i in its x_axis.w, B_i with a_i in its x_axis.w, and μ_i.
// Rust mirror: `tissue_gpu::ElasticParticle`.
struct ElasticParticle {
    inverse: Rotation,
    correction: Rotation,
    multiplier: vec4<f32>,
}

// What a particle puts into its neighbours' elastic force: its target T_i
// (the rest offsets' term; `target` is a reserved word) and its stress U_i
// (the multipliers'). Rust mirror: `tissue_gpu::ElasticTerms`.
struct ElasticTerms {
    rest_term: Rotation,
    multiplier_term: Rotation,
}

// The volume term's gradient at a linearisation, scaled by sqrt(W_i):
// cof(F_i) B_i and a_i cof(F_i). Rust mirror: `tissue_gpu::ElasticGradient`.
struct ElasticGradient {
    correction: Rotation,
    scale: Rotation,
}
