// Stage 1's surface placement, twin of
// `tissue_solve::sampling::place_surface_particles`: each particle within
// `surface_band` of its radius of the surface (or outside it) moved onto its
// nearest surface point and attached there; the others stay where they are.
// Its output is the connections' input (`neighbour_rows.wgsl`), so the
// placed particles never leave the GPU before the connections are built.

#import shared/sampling
#import shared/surface_field

// xyz position, w radius: the converged state.
@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
// xyz the placed position, w the radius.
@group(0) @binding(13) var<storage, read_write> placed: array<vec4<f32>>;
// x the triangle attached to (`NOT_ATTACHED` for an interior particle),
// yzw the barycentric coordinates' bits.
@group(0) @binding(14) var<storage, read_write> attached: array<vec4<u32>>;

const NOT_ATTACHED: u32 = 0xffffffffu;

@compute @workgroup_size(WORKGROUP_SIZE)
fn place_surface(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count) {
        return;
    }
    let p = current[i].xyz;
    let r = current[i].w;
    let band = sampling.surface_band * r;
    let q = field_query(field_grid(), p);
    var n = q.nearest;
    var attach = false;
    if (q.side == SIDE_DEEP_INSIDE) {
        // A balloon grown beyond the field's margin: ask exactly.
        if (band > sampling.field_margin) {
            n = nearest_of_all(field_grid(), p);
            attach = n.distance > -band;
        }
    } else if (q.side == SIDE_DEEP_OUTSIDE) {
        n = nearest_of_all(field_grid(), p);
        attach = true;
    } else {
        attach = n.distance > -band;
    }
    if (attach) {
        placed[i] = vec4<f32>(n.point, r);
        let b = bitcast<vec3<u32>>(n.barycentric);
        attached[i] = vec4<u32>(n.triangle, b);
    } else {
        placed[i] = vec4<f32>(p, r);
        attached[i] = vec4<u32>(NOT_ATTACHED, 0u, 0u, 0u);
    }
}
