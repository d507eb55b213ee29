//! Fixtures the tests of several crates share, written once. They are plain
//! `glam` data (no tissue types), so that tissue-core's own unit tests can
//! use them without a second copy of tissue-core in the build.

use std::f32::consts::PI;

use glam::{Mat3, Vec3};

/// A regular octahedron of "radius" 1 around the origin, wound
/// counter-clockwise seen from outside: vertices `±x, ±y, ±z` and eight
/// triangles.
pub fn octahedron() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let vertices = vec![
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ];
    let triangles = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    (vertices, triangles)
}

/// The corner tetrahedron with legs of `edge` along the axes (vertices at
/// the origin, `edge x`, `edge y`, `edge z`), wound counter-clockwise seen
/// from outside.
pub fn tetrahedron(edge: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let vertices = vec![
        Vec3::ZERO,
        Vec3::new(edge, 0.0, 0.0),
        Vec3::new(0.0, edge, 0.0),
        Vec3::new(0.0, 0.0, edge),
    ];
    (vertices, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
}

/// The [`octahedron`] with coordinates that are awkward to print and read
/// back exactly: a third, subnormal-adjacent and huge values, a negative
/// zero, a value near `f32::MAX`.
pub fn awkward_octahedron() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (mut vertices, triangles) = octahedron();
    vertices[0] = Vec3::new(1.0 / 3.0, 1e-30, -0.0);
    vertices[1] = Vec3::new(-123_456.79, 0.1, 2.0 / 7.0);
    vertices[2] = Vec3::new(f32::MIN_POSITIVE, 0.7, 1e-7);
    vertices[4] = Vec3::new(0.3, 0.2, 3.4e38);
    (vertices, triangles)
}

/// A deterministic xorshift stream of numbers in `[-1, 1)`, the same on
/// every platform, from `seed` (any non-zero value).
pub fn xorshift(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed.max(1);
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

/// The hand-picked 3x3 matrices every SVD test starts from: zero, the
/// identity and its negative (a reflection), a diagonal with a negative
/// entry, a rank-one and a rank-two matrix.
pub fn small_svd_cases() -> [Mat3; 6] {
    [
        Mat3::ZERO,
        Mat3::IDENTITY,
        -Mat3::IDENTITY,
        Mat3::from_diagonal(Vec3::new(1.0, -2.0, 3.0)),
        Mat3::from_cols(Vec3::X, Vec3::X, Vec3::X),
        Mat3::from_cols(
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(4.0, 5.0, 6.0),
            Vec3::new(7.0, 8.0, 9.0),
        ),
    ]
}

/// `count` deterministic 3x3 matrices with entries in `[-1, 1)`.
pub fn matrices(count: usize) -> Vec<Mat3> {
    let mut next = xorshift(0x2545_f491_4f6c_dd1d);
    (0..count)
        .map(|_| Mat3::from_cols_array(&[(); 9].map(|_| next())))
        .collect()
}

/// A reproducible cloud of `n` particles in the box `[0, scale)`, with radii
/// in `[0.02, 0.05)`: positions and radii from a xorshift stream seeded by
/// `seed`.
pub fn cloud(n: usize, seed: u64, scale: Vec3) -> (Vec<Vec3>, Vec<f32>) {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    let positions = (0..n)
        .map(|_| Vec3::new(next(), next(), next()) * scale)
        .collect();
    let radii = (0..n).map(|_| 0.02 + 0.03 * next()).collect();
    (positions, radii)
}

/// A path of `n` free particles between two fixed ends: the particle count
/// (`n + 2`), the connected pairs, and which particles are free. Its
/// Laplacian over the free particles has the eigenpairs
/// `2 - 2 cos(k pi / (n + 1))`, `sin(k pi i / (n + 1))`.
pub fn dirichlet_path(n: usize) -> (usize, Vec<(u32, u32)>, Vec<bool>) {
    let total = n + 2;
    let pairs = (0..total as u32 - 1).map(|i| (i, i + 1)).collect();
    let free = (0..total).map(|i| i != 0 && i != total - 1).collect();
    (total, pairs, free)
}

/// An `n x n x n` grid of unit spacing, each point jittered by up to 0.2 in
/// every axis (`xorshift(seed)`), its pairs closer than 1.5 connected, the
/// outer layer fixed: the positions, the pairs, and which points are free.
pub fn jittered_grid(n: usize, seed: u64) -> (Vec<Vec3>, Vec<(u32, u32)>, Vec<bool>) {
    let mut next = xorshift(seed);
    let (mut positions, mut free) = (Vec::new(), Vec::new());
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                let jitter = Vec3::new(next(), next(), next()) * 0.2;
                positions.push(Vec3::new(x as f32, y as f32, z as f32) + jitter);
                let inside = |c: usize| c > 0 && c < n - 1;
                free.push(inside(x) && inside(y) && inside(z));
            }
        }
    }
    let mut pairs = Vec::new();
    for i in 0..positions.len() {
        for j in i + 1..positions.len() {
            if positions[i].distance(positions[j]) < 1.5 {
                pairs.push((i as u32, j as u32));
            }
        }
    }
    (positions, pairs, free)
}

/// A closed circular cylinder along z, radius 1, height 4, base at z = 0:
/// 48 segments, 40 rings, caps of concentric rings (no slivers).
pub fn cylinder() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (segments, rings) = (48u32, 40u32);
    let (radius, height) = (1.0f32, 4.0f32);
    let mut vertices = Vec::new();
    for r in 0..=rings {
        let z = height * r as f32 / rings as f32;
        for s in 0..segments {
            let a = 2.0 * PI * s as f32 / segments as f32;
            vertices.push(Vec3::new(radius * a.cos(), radius * a.sin(), z));
        }
    }
    let ring = |r: u32, s: u32| r * segments + s % segments;
    let mut triangles = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            triangles.push([ring(r, s), ring(r, s + 1), ring(r + 1, s + 1)]);
            triangles.push([ring(r, s), ring(r + 1, s + 1), ring(r + 1, s)]);
        }
    }
    // Caps: concentric rings towards a centre vertex, so cap triangles are not slivers.
    for (z, top) in [(0.0f32, false), (height, true)] {
        let edge_ring = if top { rings } else { 0 };
        let mut outer: Vec<u32> = (0..segments).map(|s| ring(edge_ring, s)).collect();
        for k in 1..8u32 {
            let rr = radius * (1.0 - k as f32 / 8.0);
            let inner: Vec<u32> = (0..segments)
                .map(|s| {
                    let a = 2.0 * PI * s as f32 / segments as f32;
                    vertices.push(Vec3::new(rr * a.cos(), rr * a.sin(), z));
                    (vertices.len() - 1) as u32
                })
                .collect();
            for s in 0..segments as usize {
                let (o0, o1) = (outer[s], outer[(s + 1) % segments as usize]);
                let (i0, i1) = (inner[s], inner[(s + 1) % segments as usize]);
                if top {
                    triangles.push([o0, o1, i1]);
                    triangles.push([o0, i1, i0]);
                } else {
                    triangles.push([o0, i1, o1]);
                    triangles.push([o0, i0, i1]);
                }
            }
            outer = inner;
        }
        vertices.push(Vec3::new(0.0, 0.0, z));
        let centre = (vertices.len() - 1) as u32;
        for s in 0..segments as usize {
            let (o0, o1) = (outer[s], outer[(s + 1) % segments as usize]);
            triangles.push(if top {
                [o0, o1, centre]
            } else {
                [o0, centre, o1]
            });
        }
    }
    (vertices, triangles)
}

/// `tests/fixtures/vtk/NAME`: one closed surface (226 vertices, 448
/// triangles) as VTK itself writes it, made by `make_fixtures.py` there.
pub fn vtk_fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/vtk")
        .join(name)
}

/// The `.vtp` fixtures of the rest surface in `ascii.vtp`'s coordinates,
/// untagged: every layout `vtkXMLPolyDataWriter` writes.
pub const VTK_XML_FIXTURES: [&str; 13] = [
    "ascii.vtp",
    "binary-inline.vtp",
    "appended-raw.vtp",
    "appended-base64.vtp",
    "appended-zlib.vtp",
    "default.vtp",
    "inline-zlib.vtp",
    "appended-lz4.vtp",
    "appended-lzma.vtp",
    "inline-lz4.vtp",
    "inline-lzma.vtp",
    "appended-zlib-uint64.vtp",
    "appended-zlib-smallblocks.vtp",
];

/// The legacy `.vtk` fixtures of the same surface, untagged (ASCII ones
/// hold six significant digits).
pub const VTK_LEGACY_FIXTURES: [&str; 4] = [
    "legacy-ascii.vtk",
    "legacy-binary.vtk",
    "legacy-v42-ascii.vtk",
    "legacy-v42-binary.vtk",
];

/// 3D Slicer's saves of the same surface, tagged: `slicer-ras.vtp` in
/// `ascii.vtp`'s coordinates, the LPS ones mirrored in x and y.
pub const VTK_SLICER_FIXTURES: [&str; 3] = ["slicer-ras.vtp", "slicer-lps.vtp", "slicer-lps.vtk"];

/// The surface of `vertices` and `triangles` with every triangle cut into
/// four at its edges' midpoints: the same surface in another triangulation
/// (the original vertices, then one new vertex per edge).
pub fn cut_in_four(vertices: &[Vec3], triangles: &[[u32; 3]]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut vertices = vertices.to_vec();
    let mut middles = std::collections::HashMap::new();
    let mut middle = |a: u32, b: u32, vertices: &mut Vec<Vec3>| {
        *middles.entry((a.min(b), a.max(b))).or_insert_with(|| {
            vertices.push(0.5 * (vertices[a as usize] + vertices[b as usize]));
            (vertices.len() - 1) as u32
        })
    };
    let mut cut = Vec::with_capacity(4 * triangles.len());
    for &[a, b, c] in triangles {
        let (ab, bc, ca) = (
            middle(a, b, &mut vertices),
            middle(b, c, &mut vertices),
            middle(c, a, &mut vertices),
        );
        cut.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    (vertices, cut)
}

/// A sphere of radius `radius` about the origin: the octahedron cut in
/// four `cuts` times, its vertices put on the sphere.
pub fn sphere(radius: f32, cuts: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (mut vertices, mut triangles) = octahedron();
    for _ in 0..cuts {
        (vertices, triangles) = cut_in_four(&vertices, &triangles);
    }
    (
        vertices.iter().map(|v| radius * v.normalize()).collect(),
        triangles,
    )
}
