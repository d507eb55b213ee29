// The sum of one vec3 per thread over a workgroup, added in a tree in
// workgroup memory. Call it from every thread of the workgroup (in uniform
// control flow: it holds barriers); every thread gets the sum.

#import shared/layout

var<workgroup> tree_sums: array<vec3<f32>, WORKGROUP_SIZE>;

fn workgroup_sum(local: u32, value: vec3<f32>) -> vec3<f32> {
    tree_sums[local] = value;
    workgroupBarrier();
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        if (local < stride) {
            tree_sums[local] += tree_sums[local + stride];
        }
        workgroupBarrier();
    }
    return tree_sums[0];
}
