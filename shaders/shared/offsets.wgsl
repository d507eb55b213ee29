// M_i = Σ_j (q_j − q_i)(p_j − p_i)ᵀ over particle i's connections: the
// matrix whose polar rotation maps its rest offsets onto its current ones,
// and which A_i⁻¹ turns into its gradient, with the four bindings it reads
// (the importing shader's bindings 1 to 4).
// Twin: `tissue_solve::elastic::offsets_product`.

@group(0) @binding(1) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read> indices: array<u32>;

fn offsets_product(i: u32) -> mat3x3<f32> {
    var m = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let j = indices[k];
        let d = rest[j].xyz - rest[i].xyz;
        let c = current[j].xyz - current[i].xyz;
        m += mat3x3<f32>(c * d.x, c * d.y, c * d.z);
    }
    return m;
}
