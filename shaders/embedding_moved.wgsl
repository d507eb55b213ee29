// Structures and landmarks: where each embedded point goes, twin of
// `tissue_cpu::kernels::embedding_moved`:
// x' = sum_k w_k (q_k + R_k (x - p_k)) over the point's carriers (weights
// summing to one; unused carrier slots have weight 0).

#import shared/layout

// Carrier slots per point; Rust reads it from the module and pads to it.
const CARRIERS: u32 = 8u;

struct Carrier {
    particle: u32,
    weight: f32,
}

struct EmbeddingParams {
    // Number of points.
    count: u32,
    // Particles in the model (a carrier index at or beyond it is skipped).
    particles: u32,
    carriers: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> embedding: EmbeddingParams;
@group(0) @binding(1) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> carriers: array<Carrier>;
@group(0) @binding(3) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> rotations: array<Rotation>;
@group(0) @binding(6) var<storage, read_write> moved: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn embedding_moved(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= embedding.count) {
        return;
    }
    let x = points[i].xyz;
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < CARRIERS; k++) {
        let carrier = carriers[i * CARRIERS + k];
        if (carrier.weight == 0.0 || carrier.particle >= embedding.particles) {
            continue;
        }
        let j = carrier.particle;
        let r = rotations[j];
        let turned = matrix_of(r) * (x - rest[j].xyz);
        sum += carrier.weight * (current[j].xyz + turned);
    }
    moved[i] = vec4<f32>(sum, 0.0);
}
