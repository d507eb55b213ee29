// Stage 1 convergence: per workgroup, the sum of squared steps of particles
// the wall did not hold (before or after), their count, and the sum of
// (ln r_new / r_old)^2; the host finishes in f64 (RMS step in r0, RMS change
// of ln r). Twin of `tissue_cpu::kernels::sampling_change::change`.

#import shared/sampling

@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> contact: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> next: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> contact_next: array<vec4<f32>>;
// Per slot, per workgroup: (sum of steps², free particles, sum of ln², 0).
@group(0) @binding(11) var<storage, read_write> partials: array<vec4<f32>>;

var<workgroup> sums: array<vec4<f32>, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn change(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    // No early return: every thread must reach the barriers; past the end it adds 0.
    var term = vec4<f32>(0.0);
    if (i < sampling.count) {
        if (contact_next[i].w == 0.0 && contact[i].w == 0.0) {
            // Particles the wall holds slide along it; their steps are not the
            // interior's relaxation.
            let d = next[i].xyz - current[i].xyz;
            term.x = dot(d, d);
            term.y = 1.0;
        }
        let l = log(next[i].w / current[i].w);
        term.z = l * l;
    }
    sums[local] = term;
    workgroupBarrier();
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        if (local < stride) {
            sums[local] += sums[local + stride];
        }
        workgroupBarrier();
    }
    if (local == 0u) {
        partials[sampling.slot * sampling.groups + flat_workgroup(workgroup, groups)] = sums[0];
    }
}
