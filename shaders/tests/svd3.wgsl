// Test-only kernel: runs `svd3` on a list of matrices so the invariant tests
// can check the WGSL port on the adapter.

#import shared/svd3

// A 3x3 matrix as three vec4 columns (w unused).
struct Matrix {
    x_axis: vec4<f32>,
    y_axis: vec4<f32>,
    z_axis: vec4<f32>,
}

struct Decomposition {
    u: Matrix,
    sigma: vec4<f32>,
    v: Matrix,
}

@group(0) @binding(0) var<storage, read> matrices: array<Matrix>;
@group(0) @binding(1) var<storage, read_write> decompositions: array<Decomposition>;

fn from_columns(m: mat3x3<f32>) -> Matrix {
    return Matrix(vec4<f32>(m[0], 0.0), vec4<f32>(m[1], 0.0), vec4<f32>(m[2], 0.0));
}

@compute @workgroup_size(64)
fn svd3_test(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = id.x + id.y * groups.x * 64u;
    if (i >= arrayLength(&matrices)) {
        return;
    }
    let m = matrices[i];
    let svd = svd3(mat3x3<f32>(m.x_axis.xyz, m.y_axis.xyz, m.z_axis.xyz));
    decompositions[i] = Decomposition(from_columns(svd.u), vec4<f32>(svd.sigma, 0.0), from_columns(svd.v));
}
