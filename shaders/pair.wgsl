// Stage 2: `pair`, each paired particle's spring set towards the
// observation at its nearest point, first in the elastic force's
// iterations where the state holds an observation and a pairing. Twin of
// `tissue_cpu::kernels::pair` with `tissue_solve::stage2::paired_spring`:
// the curvature of half the squared distance there: for a point cloud the
// plane smoothed over the points near the particle (or its nearest
// point's fitted plane), for a surface the plane across the direction to
// the nearest point (its normal there on the surface) on a face, the
// line along an edge, the point at a vertex; the weight faded from half
// the way to a cloud's edge, no spring beyond; farther from the
// observation than the robust scale, Huber's spring (the point moved past
// the observation, the weight lowered: a force of the weight times the
// scale).

#import shared/layout
#import shared/surface_field

// Rust mirror: `tissue_gpu::state::PairingParams` (layout-tested against naga).
struct Pairing {
    // The observation's field.
    grid: FieldGrid,
    // Particles paired (the length of `skin` that is read).
    skin_count: u32,
    // 1 for a point cloud, 0 for a surface.
    cloud: u32,
    // The springs' weight.
    weight: f32,
    // A cloud's edge: no spring farther than this along its plane.
    edge: f32,
    // The robust scale: farther than this, the force it has here.
    robust: f32,
    // A cloud's smoothing radius `h`: its plane from the points within
    // `SMOOTH_REACH h`; 0 for the nearest point's own plane.
    smoothing: f32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> pairing: Pairing;
// The paired particles' indices.
@group(0) @binding(3) var<storage, read> skin: array<u32>;
// Body forces (`count`), then springs (two entries each): shared/loads.
@group(0) @binding(24) var<storage, read_write> loads: array<vec4<f32>>;

// `tissue_core::field::SMOOTH_REACH`.
const SMOOTH_REACH: f32 = 3.0;

// The observed point and normal a particle is paired with.
struct Plane {
    point: vec3<f32>,
    normal: vec3<f32>,
}

// `tissue_solve::stage2::Spring`, as shared/loads reads it: (c, a) and
// (u, b).
struct Spring {
    anchor: vec4<f32>,
    axis: vec4<f32>,
}

// `tissue_solve::stage2::Feature`: where the nearest point lies.
const FEATURE_FACE: u32 = 0u;
const FEATURE_EDGE: u32 = 1u;
const FEATURE_VERTEX: u32 = 2u;

// `tissue_solve::stage2::Paired`: the plane, the feature and, on an edge,
// its unit direction.
struct Paired {
    plane: Plane,
    feature: u32,
    tangent: vec3<f32>,
}

// `SurfaceField::smooth_plane`: the cloud's points within `SMOOTH_REACH h`
// of `p` and their normals, weighted by `exp(-r^2 / h^2)` in the order its
// band cell lists them; `found` false outside the band or with none near.
struct Smoothed {
    found: bool,
    plane: Plane,
}

fn smooth_plane(grid: FieldGrid, p: vec3<f32>, h: f32) -> Smoothed {
    let none = Smoothed(false, Plane(p, vec3<f32>(0.0, 0.0, 1.0)));
    let g = (p - grid.origin.xyz) / grid.origin.w;
    if (!(g.x >= 0.0 && g.y >= 0.0 && g.z >= 0.0)) {
        return none;
    }
    let dims = grid.dims.xyz;
    let x = u32(g.x);
    let y = u32(g.y);
    let z = u32(g.z);
    if (x >= dims.x || y >= dims.y || z >= dims.z) {
        return none;
    }
    let index = (z * dims.y + y) * dims.x + x;
    if (field_cells[index] != CELL_BAND) {
        return none;
    }
    let starts = grid.sections.x;
    let candidates = grid.sections.y;
    let first = field_cells[starts + index];
    let end = field_cells[starts + index + 1u];
    let reach2 = SMOOTH_REACH * SMOOTH_REACH;
    var weight = 0.0;
    var point = vec3<f32>(0.0);
    var normal = vec3<f32>(0.0);
    for (var k = first; k < end; k++) {
        let t = field_cells[candidates + k];
        let q = field_triangles[t * TRIANGLE_STRIDE].xyz;
        let offset = p - q;
        let r2 = dot(offset, offset) / (h * h);
        if (r2 < reach2) {
            let w = exp(-r2);
            weight += w;
            point += w * q;
            normal += w * field_triangles[t * TRIANGLE_STRIDE + 3u].xyz;
        }
    }
    if (!(weight > 0.0 && dot(normal, normal) > 0.0)) {
        return none;
    }
    return Smoothed(true, Plane(point / weight, normalize(normal)));
}

// `tissue_solve::stage2::feature_of`: two zero coordinates a vertex, one
// an edge (the one opposite the corner whose coordinate is zero), none the
// face.
fn feature_of(near: Nearest) -> Paired {
    let plane = Plane(near.point, near.normal);
    let b = near.barycentric;
    let zero = vec3<u32>(select(0u, 1u, b.x == 0.0), select(0u, 1u, b.y == 0.0), select(0u, 1u, b.z == 0.0));
    let zeros = zero.x + zero.y + zero.z;
    if (zeros == 0u) {
        return Paired(plane, FEATURE_FACE, vec3<f32>(0.0));
    }
    if (zeros == 1u) {
        let k = select(select(2u, 1u, zero.y == 1u), 0u, zero.x == 1u);
        let base = near.triangle * TRIANGLE_STRIDE;
        let edge = field_triangles[base + (k + 2u) % 3u].xyz - field_triangles[base + (k + 1u) % 3u].xyz;
        let l = length(edge);
        if (l > 0.0) {
            return Paired(plane, FEATURE_EDGE, edge / l);
        }
    }
    return Paired(plane, FEATURE_VERTEX, vec3<f32>(0.0));
}

// `tissue_solve::stage2::paired_point`.
fn paired_point(p: vec3<f32>) -> Paired {
    if (pairing.cloud != 0u && pairing.smoothing > 0.0) {
        let smoothed = smooth_plane(pairing.grid, p, pairing.smoothing);
        if (smoothed.found) {
            return Paired(smoothed.plane, FEATURE_FACE, vec3<f32>(0.0));
        }
    }
    let near = field_nearest(pairing.grid, p);
    if (pairing.cloud != 0u) {
        return Paired(Plane(near.point, near.normal), FEATURE_FACE, vec3<f32>(0.0));
    }
    return feature_of(near);
}

// `taper`: the share of a spring's weight kept `ratio` of the way to a limit.
fn taper(ratio: f32) -> f32 {
    return clamp(2.0 * (1.0 - ratio), 0.0, 1.0);
}

// `paired_spring`: x's spring from its paired point, faded towards a
// cloud's edge, Huber's beyond the robust scale: (c, a) and (u, b) as
// shared/loads holds them.
fn paired_spring(x: vec3<f32>, paired: Paired) -> Spring {
    let none = Spring(vec4<f32>(0.0), vec4<f32>(0.0));
    var point = paired.plane.point;
    let normal = paired.plane.normal;
    let offset = x - point;
    var n = normal;
    var distance = 0.0;
    var across = 0.0;
    if (pairing.cloud != 0u) {
        let along = dot(normal, offset);
        let beside = length(offset - along * normal);
        if (beside > pairing.edge) {
            return none;
        }
        distance = abs(along);
        across = beside / pairing.edge;
    } else {
        let gap = length(offset);
        let extent = max(max(abs(x.x), abs(x.y)), abs(x.z));
        if (gap > 1e-6 * (1.0 + extent)) {
            n = offset / gap;
        }
        distance = gap;
    }
    var share = taper(across);
    if (share <= 0.0) {
        return none;
    }
    if (distance > pairing.robust) {
        var towards = n;
        if (pairing.cloud != 0u) {
            towards = normal * sign(dot(normal, offset));
        }
        point += towards * (pairing.robust - distance);
        share *= pairing.robust / (2.0 * distance - pairing.robust);
    }
    let weight = max(pairing.weight * share, 0.0);
    if (paired.feature == FEATURE_EDGE) {
        return Spring(vec4<f32>(point, weight), vec4<f32>(paired.tangent, -weight));
    }
    if (paired.feature == FEATURE_VERTEX) {
        return Spring(vec4<f32>(point, weight), vec4<f32>(0.0));
    }
    return Spring(vec4<f32>(point, 0.0), vec4<f32>(n, weight));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pair(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(workgroup, groups, local);
    if (k >= pairing.skin_count) {
        return;
    }
    let i = skin[k];
    let x = current[i].xyz;
    let spring = paired_spring(x, paired_point(x));
    loads[params.count + 2u * i] = spring.anchor;
    loads[params.count + 2u * i + 1u] = spring.axis;
}
