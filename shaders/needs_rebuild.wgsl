// Stage 1, the Verlet check: the neighbour rows may miss a pair once some
// particle moved, or its radius grew, by more than half the skin since they
// were built (`built`). Twin of `tissue_cpu::kernels::needs_rebuild`, on the
// new state `next`. The first iteration of a batch that needs a rebuild
// records its slot + 1 in `halt`; the later ones then do nothing.

#import shared/sampling

@group(0) @binding(6) var<storage, read_write> halt: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read> next: array<vec4<f32>>;
@group(0) @binding(12) var<storage, read> built: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn needs_rebuild(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count || atomicLoad(&halt[0]) != 0u) {
        return;
    }
    let drift = length(next[i].xyz - built[i].xyz) + sampling.cutoff * max(next[i].w - built[i].w, 0.0);
    if (drift > sampling.half_skin) {
        atomicMax(&halt[0], sampling.slot + 1u);
    }
}
