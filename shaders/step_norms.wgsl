// The plain step's size for the stopping rule: per workgroup, the largest
// |q̂ − q|² and the sum of |q̂ − q|² over its particles; the host finishes
// (max over workgroups, then sqrt; sum in f64, then RMS). Twin of `tissue_cpu::kernels::step_norms`
// in `tissue_cpu::deformation`.

#import shared/layout

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> plain: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<vec2<f32>>;

var<workgroup> maxima: array<f32, WORKGROUP_SIZE>;
var<workgroup> sums: array<f32, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn step_norms(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    // No early return: every thread must reach the barriers; past the end it adds 0.
    var square = 0.0;
    if (i < params.count) {
        let d = plain[i].xyz - current[i].xyz;
        square = dot(d, d);
    }
    maxima[local] = square;
    sums[local] = square;
    workgroupBarrier();
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        if (local < stride) {
            maxima[local] = max(maxima[local], maxima[local + stride]);
            sums[local] += sums[local + stride];
        }
        workgroupBarrier();
    }
    if (local == 0u) {
        partials[params.slot * params.groups + flat_workgroup(workgroup, groups)] = vec2<f32>(maxima[0], sums[0]);
    }
}
