// The surface field of `tissue_core::field::SurfaceField` on the GPU: the same
// data uploaded as it is, and the same query. Rust builds both buffers in
// `tissue_gpu::sampler` (`FieldBuffers`).
//
// `field_cells` (u32), one after the other: the cell states (`cells`), the CSR
// starts of the candidates (`cells + 1`), the candidate triangles, and the
// candidate distances (f32 bits); `FieldGrid::sections` holds where each begins.
// `field_triangles` (vec4, w unused): per triangle three corners, then the seven
// normals (face, edges ab bc ca, vertices a b c).

// Every query takes the field's grid (stage 1 from its `sampling`
// parameters, stage 2's pairing from its own).

#import shared/field_grid

@group(0) @binding(8) var<storage, read> field_cells: array<u32>;
@group(0) @binding(9) var<storage, read> field_triangles: array<vec4<f32>>;

// `tissue_core::field::CELL_*`.
const CELL_BAND: u32 = 0u;
const CELL_INSIDE: u32 = 1u;
const CELL_OUTSIDE: u32 = 2u;

// `Side`: deep inside, deep outside, or near with the exact nearest point.
const SIDE_DEEP_INSIDE: u32 = 0u;
const SIDE_DEEP_OUTSIDE: u32 = 1u;
const SIDE_NEAR: u32 = 2u;

// Vec4s per triangle in `field_triangles`.
const TRIANGLE_STRIDE: u32 = 10u;

// `tissue_core::field::Nearest`.
struct Nearest {
    distance: f32,
    point: vec3<f32>,
    normal: vec3<f32>,
    triangle: u32,
    barycentric: vec3<f32>,
}

// `tissue_core::field::Side`: `nearest` is meaningful for `SIDE_NEAR` only.
struct Query {
    side: u32,
    nearest: Nearest,
}

// Closest point on a triangle with the feature it lies on, as the index of its
// normal (0 face, 1 + edge, 4 + vertex).
struct Closest {
    point: vec3<f32>,
    barycentric: vec3<f32>,
    feature: u32,
}

// Ericson 5.1.5, as `closest_on_triangle` in field.rs (edges ab = 0, bc = 1, ca = 2).
fn closest_on_triangle(p: vec3<f32>, a: vec3<f32>, b: vec3<f32>, c: vec3<f32>) -> Closest {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        return Closest(a, vec3<f32>(1.0, 0.0, 0.0), 4u);
    }
    let bp = p - b;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
        return Closest(b, vec3<f32>(0.0, 1.0, 0.0), 5u);
    }
    let vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        let v = d1 / (d1 - d3);
        return Closest(a + ab * v, vec3<f32>(1.0 - v, v, 0.0), 1u);
    }
    let cp = p - c;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) {
        return Closest(c, vec3<f32>(0.0, 0.0, 1.0), 6u);
    }
    let vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        let w = d2 / (d2 - d6);
        return Closest(a + ac * w, vec3<f32>(1.0 - w, 0.0, w), 3u);
    }
    let va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return Closest(b + (c - b) * w, vec3<f32>(0.0, 1.0 - w, w), 2u);
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    return Closest(a + ab * v + ac * w, vec3<f32>(1.0 - v - w, v, w), 0u);
}

// The running best of `nearest_among`.
struct Best {
    found: bool,
    d2: f32,
    triangle: u32,
    closest: Closest,
}

fn consider(p: vec3<f32>, t: u32, best: Best) -> Best {
    let base = t * TRIANGLE_STRIDE;
    let closest = closest_on_triangle(
        p,
        field_triangles[base].xyz,
        field_triangles[base + 1u].xyz,
        field_triangles[base + 2u].xyz,
    );
    let offset = p - closest.point;
    let d2 = dot(offset, offset);
    if (!best.found || d2 < best.d2) {
        return Best(true, d2, t, closest);
    }
    return best;
}

fn nearest_of_best(p: vec3<f32>, best: Best) -> Nearest {
    if (!best.found) {
        // An empty candidate list cannot happen for a band cell; "far outside".
        return Nearest(bitcast<f32>(0x7f800000u), p, vec3<f32>(0.0, 0.0, 1.0), 0u, vec3<f32>(1.0, 0.0, 0.0));
    }
    let normal = field_triangles[best.triangle * TRIANGLE_STRIDE + 3u + best.closest.feature].xyz;
    let distance = sqrt(best.d2);
    let sign = select(-1.0, 1.0, dot(p - best.closest.point, normal) > 0.0);
    return Nearest(sign * distance, best.closest.point, normal, best.triangle, best.closest.barycentric);
}

fn cell_centre(grid: FieldGrid, x: u32, y: u32, z: u32) -> vec3<f32> {
    return grid.origin.xyz + (vec3<f32>(f32(x), f32(y), f32(z)) + 0.5) * grid.origin.w;
}

// Exact nearest point in band cell `index`: candidates in order of distance
// from the cell centre, stopping when none further can be closer.
fn nearest_in_band(grid: FieldGrid, p: vec3<f32>, index: u32, centre: vec3<f32>) -> Nearest {
    let sections = grid.sections;
    let starts = sections.x;
    let candidates = sections.y;
    let distances = sections.z;
    let first = field_cells[starts + index];
    let end = field_cells[starts + index + 1u];
    let offset = length(p - centre);
    var best = Best(false, 0.0, 0u, Closest(p, vec3<f32>(1.0, 0.0, 0.0), 0u));
    for (var k = first; k < end; k++) {
        let bound = bitcast<f32>(field_cells[distances + k]) - offset;
        if (best.found && bound > 0.0 && bound * bound > best.d2) {
            break;
        }
        best = consider(p, field_cells[candidates + k], best);
    }
    return nearest_of_best(p, best);
}

// All triangles, without bounds (the rare path for points far outside).
fn nearest_of_all(grid: FieldGrid, p: vec3<f32>) -> Nearest {
    var best = Best(false, 0.0, 0u, Closest(p, vec3<f32>(1.0, 0.0, 0.0), 0u));
    let triangles = grid.dims.w;
    for (var t = 0u; t < triangles; t++) {
        best = consider(p, t, best);
    }
    return nearest_of_best(p, best);
}

// `SurfaceField::query`.
fn field_query(grid: FieldGrid, p: vec3<f32>) -> Query {
    let none = Nearest(0.0, p, vec3<f32>(0.0, 0.0, 1.0), 0u, vec3<f32>(1.0, 0.0, 0.0));
    let g = (p - grid.origin.xyz) / grid.origin.w;
    // NaN compares false: a non-finite point is beyond the grid, as on the CPU.
    if (!(g.x >= 0.0 && g.y >= 0.0 && g.z >= 0.0)) {
        return Query(SIDE_DEEP_OUTSIDE, none);
    }
    let dims = grid.dims.xyz;
    // f32 -> u32 saturates in WGSL as `as u32` does in Rust.
    let x = u32(g.x);
    let y = u32(g.y);
    let z = u32(g.z);
    if (x >= dims.x || y >= dims.y || z >= dims.z) {
        return Query(SIDE_DEEP_OUTSIDE, none);
    }
    let index = (z * dims.y + y) * dims.x + x;
    let state = field_cells[index];
    if (state == CELL_INSIDE) {
        return Query(SIDE_DEEP_INSIDE, none);
    }
    if (state == CELL_OUTSIDE) {
        return Query(SIDE_DEEP_OUTSIDE, none);
    }
    return Query(SIDE_NEAR, nearest_in_band(grid, p, index, cell_centre(grid, x, y, z)));
}

// `SurfaceField::nearest`: exact wherever `p` is.
fn field_nearest(grid: FieldGrid, p: vec3<f32>) -> Nearest {
    let q = field_query(grid, p);
    if (q.side == SIDE_NEAR) {
        return q.nearest;
    }
    return nearest_of_all(grid, p);
}
