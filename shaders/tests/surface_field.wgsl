// Test-only kernel behind `tissue_gpu::sampler::query_field`: the field query
// of `shared/surface_field.wgsl` at given points, the twin of
// `SurfaceField::query`.

#import shared/sampling
#import shared/surface_field

@group(0) @binding(1) var<storage, read> points: array<vec4<f32>>;
// Per point: (side bits, signed distance, triangle bits, 0), nearest point, normal, barycentric.
@group(0) @binding(2) var<storage, read_write> answers: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn field_query_test(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count) {
        return;
    }
    let q = field_query(field_grid(), points[i].xyz);
    let n = q.nearest;
    answers[4u * i] = vec4<f32>(bitcast<f32>(q.side), n.distance, bitcast<f32>(n.triangle), 0.0);
    answers[4u * i + 1u] = vec4<f32>(n.point, 0.0);
    answers[4u * i + 2u] = vec4<f32>(n.normal, 0.0);
    answers[4u * i + 3u] = vec4<f32>(n.barycentric, 0.0);
}
