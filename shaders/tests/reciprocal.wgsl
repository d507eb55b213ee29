// Test-only kernel: runs the grid's `reciprocal` on a list of floats so that
// its rounding can be checked against the CPU's division on the adapter.

#import shared/grid

@group(0) @binding(0) var<storage, read> inputs: array<f32>;
@group(0) @binding(1) var<storage, read_write> outputs: array<f32>;

@compute @workgroup_size(64)
fn reciprocal_test(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x < arrayLength(&inputs)) {
        outputs[id.x] = reciprocal(inputs[id.x]);
    }
}
