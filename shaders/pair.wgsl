// Stage 2: `pair`, each paired particle's spring set towards the
// observation's plane at its nearest point, first in the elastic force's
// iterations where the state holds an observation and a pairing. Twin of
// `tissue_cpu::kernels::pair` with `tissue_solve::stage2::paired_spring`:
// for a surface the plane across the direction to the nearest point (its
// normal there on the surface), for a point cloud its plane smoothed over
// the points near the particle (or its nearest point's fitted plane); the
// weight faded from half the way to a cloud's edge or the trim,
// no spring beyond.

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
    // No spring farther than this from the observation.
    trim: f32,
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
// Body forces (`count`), then springs (`count`): shared/loads.
@group(0) @binding(24) var<storage, read_write> loads: array<vec4<f32>>;

// `tissue_core::field::SMOOTH_REACH`.
const SMOOTH_REACH: f32 = 3.0;

// The observed point and normal a particle is paired with.
struct Plane {
    point: vec3<f32>,
    normal: vec3<f32>,
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

// `tissue_solve::stage2::pairing_plane`.
fn pairing_plane(p: vec3<f32>) -> Plane {
    if (pairing.cloud != 0u && pairing.smoothing > 0.0) {
        let smoothed = smooth_plane(pairing.grid, p, pairing.smoothing);
        if (smoothed.found) {
            return smoothed.plane;
        }
    }
    let near = field_nearest(pairing.grid, p);
    return Plane(near.point, near.normal);
}

// `taper`: the share of a spring's weight kept `ratio` of the way to a limit.
fn taper(ratio: f32) -> f32 {
    return clamp(2.0 * (1.0 - ratio), 0.0, 1.0);
}

// `paired_spring`: x's spring from its nearest observed point and the
// observation's normal there, faded towards a cloud's edge and the trim.
fn paired_spring(x: vec3<f32>, point: vec3<f32>, normal: vec3<f32>) -> vec4<f32> {
    let offset = x - point;
    var n = normal;
    var distance = 0.0;
    var across = 0.0;
    if (pairing.cloud != 0u) {
        let along = dot(normal, offset);
        let beside = length(offset - along * normal);
        if (beside > pairing.edge) {
            return vec4<f32>(0.0);
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
    let share = taper(across) * taper(distance / pairing.trim);
    if (share <= 0.0) {
        return vec4<f32>(0.0);
    }
    let s = sqrt(max(pairing.weight * share, 0.0)) * n;
    return vec4<f32>(s, dot(s, point));
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
    let plane = pairing_plane(x);
    loads[params.count + i] = paired_spring(x, plane.point, plane.normal);
}
