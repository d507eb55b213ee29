//! Surface files in and out, welding, and closed-surface validation: round
//! trips for every format, one handmade mesh per defect, hostile files, and
//! the real meshes in the shared folder.

#![allow(clippy::unwrap_used, reason = "tests")]
#![allow(clippy::expect_used, reason = "tests")]
#![allow(missing_docs, reason = "tests")]

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use tissue_core::io::surface::{
    LoadOptions, RELATIVE_WELD_TOLERANCE, load_closed_surface, load_closed_surface_with,
    load_closed_surface_with_report, load_surface, save_surface, weld,
};
use tissue_core::validate::{ShellsDropped, keep_largest_shell, validate};
use tissue_core::{Error, MeshError, SurfaceMesh, Vec3};

// --- helpers -------------------------------------------------------------

/// The folder of real-world meshes beside the workspace, or `None` (after
/// saying so) when it is absent. Under `CI=true` its absence is a failure:
/// tests that silently skip are not tests.
fn shared_mesh(name: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    if dir.is_dir() {
        return Some(dir.join(name));
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared test meshes are missing (looked for {})",
        dir.display()
    );
    eprintln!(
        "SKIPPED: {} not found, so {name} is not tested (set CI=true to make this a failure)",
        dir.display()
    );
    None
}

/// A tetrahedron wound counter-clockwise seen from outside.
fn tetrahedron() -> SurfaceMesh {
    SurfaceMesh::new(
        vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
}

/// A regular octahedron wound counter-clockwise seen from outside.
fn octahedron() -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::octahedron();
    SurfaceMesh::new(vertices, triangles)
}

/// The octahedron |x| + |y| + |z| = n cut into 8 n^2 triangles on the
/// integer lattice (so seams weld exactly), then pushed onto the unit sphere.
/// Outward, closed, one shell.
fn lattice_sphere(n: i32) -> SurfaceMesh {
    let mut corners = Vec::new();
    for signs in 0..8 {
        let s = Vec3::new(
            if signs & 1 == 0 { 1.0 } else { -1.0 },
            if signs & 2 == 0 { 1.0 } else { -1.0 },
            if signs & 4 == 0 { 1.0 } else { -1.0 },
        );
        let mirrored = s.x * s.y * s.z < 0.0;
        let point = |i: i32, j: i32| s * Vec3::new(i as f32, j as f32, (n - i - j) as f32);
        let mut push = |a: Vec3, b: Vec3, c: Vec3| {
            corners.extend(if mirrored { [a, c, b] } else { [a, b, c] });
        };
        for i in 0..n {
            for j in 0..n - i {
                push(point(i, j), point(i + 1, j), point(i, j + 1));
                if i + j + 2 <= n {
                    push(point(i + 1, j), point(i + 1, j + 1), point(i, j + 1));
                }
            }
        }
    }
    let triangles = (0..corners.len() as u32 / 3)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    let mut mesh = weld(&SurfaceMesh::new(corners, triangles), 0.0);
    for v in &mut mesh.vertices {
        *v = v.normalize();
    }
    mesh
}

/// Asserts that `loaded` is `original` up to the numbering of vertices:
/// the same positions bit for bit, and the same triangles in the same order
/// with the same corner order.
fn assert_same_up_to_numbering(original: &SurfaceMesh, loaded: &SurfaceMesh, what: &str) {
    assert_eq!(
        loaded.vertices.len(),
        original.vertices.len(),
        "{what}: vertex count"
    );
    assert_eq!(
        loaded.triangles.len(),
        original.triangles.len(),
        "{what}: triangle count"
    );
    let key = |v: Vec3| v.to_array().map(f32::to_bits);
    let index: HashMap<_, _> = original
        .vertices
        .iter()
        .enumerate()
        .map(|(i, &v)| (key(v), i as u32))
        .collect();
    let to_original: Vec<u32> = loaded
        .vertices
        .iter()
        .map(|&v| {
            *index
                .get(&key(v))
                .unwrap_or_else(|| panic!("{what}: loaded vertex {v} is not in the original"))
        })
        .collect();
    for (t, (got, want)) in loaded.triangles.iter().zip(&original.triangles).enumerate() {
        let got = got.map(|i| to_original[i as usize]);
        assert_eq!(got, *want, "{what}: triangle {t}");
    }
}

fn write_file(dir: &Path, name: &str, content: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, content).unwrap();
    path
}

fn mesh_error(result: Result<SurfaceMesh, Error>) -> MeshError {
    match result {
        Err(Error::Mesh { source, .. }) => source,
        other => panic!("expected a mesh error, got {other:?}"),
    }
}

/// Triangles grouped into edge-connected pieces, largest first.
fn shells(mesh: &SurfaceMesh) -> Vec<SurfaceMesh> {
    let mut parent: Vec<usize> = (0..mesh.triangles.len()).collect();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut first_at_edge = HashMap::new();
    for (t, &[a, b, c]) in mesh.triangles.iter().enumerate() {
        for (p, q) in [(a, b), (b, c), (c, a)] {
            let other = *first_at_edge.entry((p.min(q), p.max(q))).or_insert(t);
            let (x, y) = (find(&mut parent, other), find(&mut parent, t));
            parent[x] = y;
        }
    }
    let mut groups: HashMap<usize, Vec<[u32; 3]>> = HashMap::new();
    for (t, &triangle) in mesh.triangles.iter().enumerate() {
        groups
            .entry(find(&mut parent, t))
            .or_default()
            .push(triangle);
    }
    let mut pieces: Vec<SurfaceMesh> = groups
        .into_values()
        .map(|triangles| weld(&SurfaceMesh::new(mesh.vertices.clone(), triangles), 0.0))
        .collect();
    pieces.sort_by_key(|p| std::cmp::Reverse(p.triangles.len()));
    pieces
}

// --- round trips -----------------------------------------------------------

/// Coordinates that are awkward to print: thirds, tiny, huge, negative zero.
fn awkward_octahedron() -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::awkward_octahedron();
    SurfaceMesh::new(vertices, triangles)
}

#[test]
fn every_format_round_trips_bit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let meshes = [
        ("tetrahedron", tetrahedron()),
        ("awkward octahedron", awkward_octahedron()),
        ("sphere", lattice_sphere(12)),
    ];
    for (what, mesh) in &meshes {
        for extension in ["obj", "stl", "ply", "vtk", "OBJ", "Stl"] {
            let path = dir.path().join(format!("mesh.{extension}"));
            save_surface(mesh, &path).unwrap();
            let loaded = load_surface(&path).unwrap();
            assert_same_up_to_numbering(mesh, &loaded, &format!("{what} as .{extension}"));
        }
    }
}

#[test]
fn ply_and_vtk_keep_vertex_order() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = awkward_octahedron();
    for name in ["m.ply", "m.vtk"] {
        let path = dir.path().join(name);
        save_surface(&mesh, &path).unwrap();
        assert_eq!(load_surface(&path).unwrap(), mesh, "{name}");
    }
}

#[test]
fn save_rejects_unknown_extension_and_unwritable_path() {
    let dir = tempfile::tempdir().unwrap();
    let err = save_surface(&tetrahedron(), &dir.path().join("t.off")).unwrap_err();
    assert!(matches!(err, Error::UnsupportedFormat { .. }), "{err:?}");
    let err = save_surface(&tetrahedron(), &dir.path().join("missing/t.obj")).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
}

// --- reading each format's variants -----------------------------------------

#[test]
fn ascii_stl_with_bare_solid_line_and_crlf_is_welded() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = tetrahedron();
    let mut text = String::from("solid\r\n");
    for t in 0..mesh.triangles.len() {
        text.push_str("facet normal 0 0 0\r\n outer loop\r\n");
        for v in mesh.corners(t) {
            writeln!(text, "  vertex {} {} {}\r", v.x, v.y, v.z).unwrap();
        }
        text.push_str(" endloop\r\nendfacet\r\n");
    }
    text.push_str("endsolid\r\n");
    let path = write_file(dir.path(), "ascii.stl", text.as_bytes());
    let loaded = load_surface(&path).unwrap();
    assert_same_up_to_numbering(&mesh, &loaded, "ASCII STL");
}

#[test]
fn binary_stl_whose_header_starts_with_solid_is_read_as_binary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.stl");
    save_surface(&tetrahedron(), &path).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[..24].copy_from_slice(b"solid exported by a CAD ");
    std::fs::write(&path, &bytes).unwrap();
    assert_same_up_to_numbering(
        &tetrahedron(),
        &load_surface(&path).unwrap(),
        "solid header",
    );
}

#[test]
fn obj_with_per_corner_indices_polygons_and_two_objects_has_one_vertex_per_position() {
    let dir = tempfile::tempdir().unwrap();
    // A unit cube: six quads in two objects, with texture and normal indices,
    // a negative (relative) index and a duplicated position record.
    let obj = "\
mtllib missing.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
v 0 0 0
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
o bottom_and_sides
f 9/1/1 4/2/1 3/3/1 2/1/1
f 1/1/1 2/2/1 6/3/1 5/1/1
f 2//1 3//1 7//1 6//1
o rest
f 3/1 4/2 8/3 7/1
f 4 1 5 8
f 5/1/1 6/2/1 7/3/1 -2/1/1
";
    let path = write_file(dir.path(), "cube.obj", obj.as_bytes());
    let cube = load_surface(&path).unwrap();
    assert_eq!(cube.vertices.len(), 8);
    assert_eq!(cube.triangles.len(), 12);
    let mut cube = cube;
    let validation = validate(&mut cube).unwrap();
    assert!(!validation.flipped);
    assert!((validation.volume - 1.0).abs() < 1e-9);
}

#[test]
fn ply_ascii_polygons_and_vertex_index_name() {
    let dir = tempfile::tempdir().unwrap();
    let ply = "\
ply
format ascii 1.0
comment a unit cube made of quads
element vertex 8
property double x
property double y
property double z
property uchar red
element face 6
property list uchar uint vertex_index
end_header
0 0 0 1
1 0 0 2
1 1 0 3
0 1 0 4
0 0 1 5
1 0 1 6
1 1 1 7
0 1 1 8
4 0 3 2 1
4 0 1 5 4
4 1 2 6 5
4 2 3 7 6
4 3 0 4 7
4 4 5 6 7
";
    let path = write_file(dir.path(), "cube.ply", ply.as_bytes());
    let mut cube = load_surface(&path).unwrap();
    assert_eq!((cube.vertices.len(), cube.triangles.len()), (8, 12));
    assert!((validate(&mut cube).unwrap().volume - 1.0).abs() < 1e-9);
}

/// The tetrahedron as binary PLY: float coordinates, a `uchar` count and
/// `int` or `uint` indices per face.
fn binary_ply(big_endian: bool, index_type: &str) -> Vec<u8> {
    let mesh = tetrahedron();
    let encoding = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut bytes = format!(
        "ply\nformat {encoding} 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
         property float z\nelement face 4\nproperty list uchar {index_type} vertex_indices\nend_header\n"
    )
    .into_bytes();
    let word = |w: [u8; 4]| {
        if big_endian {
            [w[3], w[2], w[1], w[0]]
        } else {
            w
        }
    };
    for c in mesh.vertices.iter().flat_map(|v| v.to_array()) {
        bytes.extend(word(c.to_le_bytes()));
    }
    for t in &mesh.triangles {
        bytes.push(3);
        for i in t {
            bytes.extend(word(i.to_le_bytes()));
        }
    }
    bytes
}

#[test]
fn ply_binary_both_endiannesses() {
    let dir = tempfile::tempdir().unwrap();
    for big_endian in [false, true] {
        for index_type in ["int", "uint"] {
            let path = write_file(dir.path(), "t.ply", &binary_ply(big_endian, index_type));
            let what = format!("big endian {big_endian}, {index_type}");
            let loaded = load_surface(&path).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!(loaded, tetrahedron(), "{what}");
        }
    }
}

#[test]
fn vtk_ascii_polygons_and_triangle_strips() {
    let dir = tempfile::tempdir().unwrap();
    // The cube again: bottom and top as one quad each, the four sides as a
    // closed strip of eight triangles.
    let vtk = "\
# vtk DataFile Version 3.0
cube
ASCII
DATASET POLYDATA
POINTS 8 float
0 0 0 1 0 0 1 1 0 0 1 0
0 0 1 1 0 1 1 1 1 0 1 1
POLYGONS 2 10
4 0 3 2 1
4 4 5 6 7
TRIANGLE_STRIPS 1 11
10 4 0 5 1 6 2 7 3 4 0
";
    let path = write_file(dir.path(), "cube.vtk", vtk.as_bytes());
    let mut cube = load_surface(&path).unwrap();
    assert_eq!((cube.vertices.len(), cube.triangles.len()), (8, 12));
    let validation = validate(&mut cube).unwrap();
    assert!((validation.volume - 1.0).abs() < 1e-9);
    assert!(!validation.flipped);
}

#[test]
fn vtk_binary_polydata_is_big_endian() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = tetrahedron();
    let mut bytes =
        b"# vtk DataFile Version 3.0\ntetrahedron\nBINARY\nDATASET POLYDATA\nPOINTS 4 float\n"
            .to_vec();
    for c in mesh.vertices.iter().flat_map(|v| v.to_array()) {
        bytes.extend(c.to_be_bytes());
    }
    bytes.extend(b"\nPOLYGONS 4 16\n");
    for t in &mesh.triangles {
        bytes.extend(3u32.to_be_bytes());
        for i in t {
            bytes.extend(i.to_be_bytes());
        }
    }
    bytes.push(b'\n');
    let path = write_file(dir.path(), "t.vtk", &bytes);
    assert_eq!(load_surface(&path).unwrap(), mesh);
}

#[test]
fn vtk_unstructured_grid_of_triangles() {
    let dir = tempfile::tempdir().unwrap();
    let vtk = "\
# vtk DataFile Version 3.0
tetrahedron surface
ASCII
DATASET UNSTRUCTURED_GRID
POINTS 4 float
0 0 0 1 0 0 0 1 0 0 0 1
CELLS 5 18
3 0 2 1
3 0 1 3
3 0 3 2
3 1 2 3
1 0
CELL_TYPES 5
5
5
5
5
1
";
    let path = write_file(dir.path(), "grid.vtk", vtk.as_bytes());
    assert_eq!(load_surface(&path).unwrap(), tetrahedron());
}

// --- files that must be refused, never panic ----------------------------------

#[test]
fn unknown_extension_is_unsupported() {
    let err = load_surface(Path::new("mesh.off")).unwrap_err();
    assert!(
        matches!(err, Error::UnsupportedFormat { expected, .. } if expected.contains("stl")),
        "{err:?}"
    );
}

#[test]
fn missing_file_is_an_io_error_naming_the_path() {
    let err = load_surface(Path::new("/nonexistent/liver.obj")).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("/nonexistent/liver.obj"), "{err}");
}

#[test]
fn empty_files_are_refused_with_the_path() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["e.stl", "e.obj", "e.ply", "e.vtk"] {
        let path = write_file(dir.path(), name, b"");
        let err = load_surface(&path).unwrap_err();
        assert!(
            matches!(
                err,
                Error::Format { .. }
                    | Error::Mesh {
                        source: MeshError::Empty { .. },
                        ..
                    }
            ),
            "{name}: {err:?}"
        );
        assert!(err.to_string().contains(name), "{name}: {err}");
    }
}

#[test]
fn garbage_stl_is_a_format_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut state = 12345u32;
    let noise: Vec<u8> = (0..1000)
        .map(|_| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 24) as u8
        })
        .collect();
    for (name, content) in [
        ("noise.stl", &noise[..]),
        ("short.stl", b"hello" as &[u8]),
        (
            "fake_ascii.stl",
            b"solid x\nfacet normal banana\nendsolid x\n",
        ),
    ] {
        let path = write_file(dir.path(), name, content);
        let err = load_surface(&path).unwrap_err();
        assert!(matches!(err, Error::Format { .. }), "{name}: {err:?}");
    }
}

#[test]
fn face_naming_a_missing_vertex_is_index_out_of_range() {
    let dir = tempfile::tempdir().unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    let path = write_file(dir.path(), "bad.ply", ply.as_bytes());
    assert!(matches!(
        mesh_error(load_surface(&path)),
        MeshError::IndexOutOfRange {
            vertex: 7,
            vertices: 3,
            ..
        }
    ));
}

#[test]
fn huge_announced_counts_are_refused_without_allocating_them() {
    let dir = tempfile::tempdir().unwrap();
    let mut stl = vec![0u8; 84 + 50];
    stl[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let files: [(&str, &[u8]); 4] = [
        ("huge.stl", &stl),
        (
            "huge.vtk",
            b"# vtk DataFile Version 3.0\nx\nBINARY\nDATASET POLYDATA\nPOINTS 4294967295 float\n\0\0\0\0",
        ),
        (
            "huge_ascii.vtk",
            b"# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n0 0 0\nPOLYGONS 4294967295 4294967295\n3 0 0 0\n",
        ),
        (
            "huge.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 4294967295\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0",
        ),
    ];
    for (name, content) in files {
        let path = write_file(dir.path(), name, content);
        let err = load_surface(&path).unwrap_err();
        assert!(matches!(err, Error::Format { .. }), "{name}: {err:?}");
    }
}

// --- one defect each ------------------------------------------------------------

#[test]
fn empty_mesh() {
    let mut mesh = SurfaceMesh::default();
    assert_eq!(
        validate(&mut mesh),
        Err(MeshError::Empty {
            vertices: 0,
            triangles: 0
        })
    );
}

#[test]
fn nan_vertex_is_non_finite() {
    let mut mesh = tetrahedron();
    mesh.vertices[2].y = f32::NAN;
    let err = validate(&mut mesh).unwrap_err();
    assert!(
        matches!(err, MeshError::NonFinite { count: 1, example: 2, value } if value[1].is_nan()),
        "{err:?}"
    );
}

#[test]
fn index_out_of_range() {
    let mut mesh = tetrahedron();
    mesh.triangles[3][1] = 4;
    assert_eq!(
        validate(&mut mesh),
        Err(MeshError::IndexOutOfRange {
            count: 1,
            example: 3,
            vertex: 4,
            vertices: 4
        })
    );
}

#[test]
fn repeated_index_is_degenerate() {
    let mut mesh = tetrahedron();
    mesh.triangles[1] = [0, 1, 1];
    let err = validate(&mut mesh).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::Degenerate {
                count: 1,
                example: 1,
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn collinear_corners_are_degenerate() {
    // A flat "tetrahedron": its apex lies on an edge of the base, so the two
    // triangles beside that edge have no area.
    let mut mesh = tetrahedron();
    mesh.vertices[3] = Vec3::new(0.5, 0.5, 0.0);
    let err = validate(&mut mesh).unwrap_err();
    assert!(matches!(err, MeshError::Degenerate { .. }), "{err:?}");
}

#[test]
fn missing_triangle_is_open() {
    let mut mesh = octahedron();
    mesh.triangles.remove(5);
    let err = validate(&mut mesh).unwrap_err();
    assert!(matches!(err, MeshError::Open { count: 3, .. }), "{err:?}");
}

#[test]
fn triangle_on_an_existing_edge_is_non_manifold() {
    let mut mesh = octahedron();
    // A fin hanging off the edge between vertices 0 and 2.
    mesh.vertices.push(Vec3::new(2.0, 2.0, 0.0));
    mesh.triangles.push([0, 6, 2]);
    let err = validate(&mut mesh).unwrap_err();
    match err {
        MeshError::NonManifold { count, at, to } => {
            assert_eq!(count, 1);
            assert_eq!((at, to), (Vec3::X.to_array(), Vec3::Y.to_array()));
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn one_flipped_triangle_is_inconsistent() {
    let mut mesh = octahedron();
    mesh.triangles[3].swap(0, 1);
    let err = validate(&mut mesh).unwrap_err();
    assert!(
        matches!(err, MeshError::InconsistentOrientation { count: 3, .. }),
        "{err:?}"
    );
}

#[test]
fn two_tetrahedra_are_several_shells() {
    let mut mesh = tetrahedron();
    let other = tetrahedron();
    mesh.vertices
        .extend(other.vertices.iter().map(|&v| v + Vec3::splat(5.0)));
    mesh.triangles
        .extend(other.triangles.iter().map(|t| t.map(|i| i + 4)));
    let err = validate(&mut mesh).unwrap_err();
    match err {
        MeshError::SeveralShells { count, example, at } => {
            assert_eq!((count, example), (2, 4));
            assert!(Vec3::from_array(at).cmpgt(Vec3::splat(4.9)).all(), "{at:?}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn tetrahedra_touching_at_a_vertex_are_several_shells() {
    let mut mesh = tetrahedron();
    mesh.vertices.extend([
        Vec3::new(-1.0, 0.0, 0.0),
        Vec3::new(0.0, -1.0, 0.0),
        Vec3::new(0.0, 0.0, -1.0),
    ]);
    // Mirror image through the origin, sharing vertex 0; mirrored, so wound the other way.
    mesh.triangles
        .extend([[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]);
    let err = validate(&mut mesh).unwrap_err();
    assert!(
        matches!(err, MeshError::SeveralShells { count: 2, .. }),
        "{err:?}"
    );
}

#[test]
fn double_sided_triangle_has_zero_volume() {
    let mut mesh = SurfaceMesh::new(
        vec![Vec3::ZERO, Vec3::X, Vec3::Y],
        vec![[0, 1, 2], [0, 2, 1]],
    );
    let err = validate(&mut mesh).unwrap_err();
    assert!(matches!(err, MeshError::ZeroVolume { .. }), "{err:?}");
}

#[test]
fn inward_tetrahedron_is_flipped_and_reported() {
    let mut mesh = tetrahedron();
    for t in &mut mesh.triangles {
        t.swap(0, 1);
    }
    assert!(mesh.signed_volume() < 0.0);
    let validation = validate(&mut mesh).unwrap();
    assert!(validation.flipped);
    assert!((validation.volume - 1.0 / 6.0).abs() < 1e-12);
    assert!((mesh.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
    // Validating again finds nothing left to do.
    assert!(!validate(&mut mesh).unwrap().flipped);
}

#[test]
fn load_closed_surface_reports_defect_with_path() {
    let dir = tempfile::tempdir().unwrap();
    let mut open = octahedron();
    open.triangles.pop();
    let path = dir.path().join("open.obj");
    save_surface(&open, &path).unwrap();
    let err = load_closed_surface(&path).unwrap_err();
    match &err {
        Error::Mesh { path: p, source } => {
            assert_eq!(p, &path);
            assert!(matches!(source, MeshError::Open { .. }), "{source:?}");
        }
        other => panic!("{other:?}"),
    }
    assert!(err.to_string().contains("open.obj"), "{err}");
    assert!(err.to_string().contains("boundary edges"), "{err}");
}

#[test]
fn load_closed_surface_welds_near_duplicates_from_stl() {
    // Each triangle gets its own copy of its corners, off by one ULP here and
    // there, as some exporters do; exact welding alone leaves it open.
    let dir = tempfile::tempdir().unwrap();
    let mesh = lattice_sphere(6);
    let mut soup = SurfaceMesh::default();
    for (t, triangle) in mesh.triangles.iter().enumerate() {
        for (k, &i) in triangle.iter().enumerate() {
            let v = mesh.vertices[i as usize];
            let nudge = if (t + k) % 3 == 0 {
                Vec3::new(f32::from_bits(v.x.to_bits() + 1), v.y, v.z)
            } else {
                v
            };
            soup.vertices.push(nudge);
        }
        let base = 3 * t as u32;
        soup.triangles.push([base, base + 1, base + 2]);
    }
    let path = dir.path().join("soup.stl");
    save_surface(&soup, &path).unwrap();
    let mut exact = load_surface(&path).unwrap();
    assert!(exact.vertices.len() > mesh.vertices.len());
    assert!(matches!(validate(&mut exact), Err(MeshError::Open { .. })));
    let (welded, report) = load_closed_surface_with_report(&path).unwrap();
    assert_eq!(welded.vertices.len(), mesh.vertices.len());
    assert_eq!(welded.triangles.len(), mesh.triangles.len());
    assert!(!report.flipped);
}

#[test]
fn a_million_triangles_validate_quickly() {
    let mesh = lattice_sphere(354);
    assert_eq!(mesh.triangles.len(), 8 * 354 * 354);
    let started = Instant::now();
    let welded = weld(&mesh, RELATIVE_WELD_TOLERANCE * 2.0 * 3f32.sqrt());
    let weld_time = started.elapsed();
    let mut welded = welded;
    let started = Instant::now();
    let validation = validate(&mut welded).unwrap();
    let validate_time = started.elapsed();
    eprintln!(
        "{} triangles: weld {weld_time:?}, validate {validate_time:?}",
        mesh.triangles.len()
    );
    assert!(!validation.flipped);
    assert!((validation.volume - 4.0 / 3.0 * std::f64::consts::PI).abs() < 1e-3);
    // Generous against slow CI machines; it takes a fraction of this in release.
    assert!(validate_time.as_secs_f64() < 3.0, "{validate_time:?}");
}

// --- keeping the largest shell -------------------------------------------------

/// `mesh` moved by `offset` and scaled by `scale` about the origin.
fn placed(mesh: &SurfaceMesh, scale: f32, offset: Vec3) -> SurfaceMesh {
    SurfaceMesh::new(
        mesh.vertices.iter().map(|&v| scale * v + offset).collect(),
        mesh.triangles.clone(),
    )
}

/// The pieces side by side in one mesh, vertices and triangles in order.
fn joined(pieces: &[SurfaceMesh]) -> SurfaceMesh {
    let mut mesh = SurfaceMesh::default();
    for piece in pieces {
        let base = mesh.vertices.len() as u32;
        mesh.vertices.extend(&piece.vertices);
        mesh.triangles
            .extend(piece.triangles.iter().map(|t| t.map(|i| i + base)));
    }
    mesh
}

const LARGEST_SHELL: LoadOptions = LoadOptions::keeping_largest_shell(true);

#[test]
fn keep_largest_shell_keeps_the_bigger_tetrahedron_and_renumbers() {
    // Two tetrahedra with their vertices and triangles interleaved, and two
    // vertices no triangle uses: the small one on 0, 2, 4, 6, the big one
    // (edge 3) on 1, 3, 5, 7.
    let s = 0.5;
    let b = 3.0;
    let mesh = SurfaceMesh::new(
        vec![
            Vec3::ZERO,
            Vec3::splat(10.0),
            Vec3::new(s, 0.0, 0.0),
            Vec3::new(10.0 + b, 10.0, 10.0),
            Vec3::new(0.0, s, 0.0),
            Vec3::new(10.0, 10.0 + b, 10.0),
            Vec3::new(0.0, 0.0, s),
            Vec3::new(10.0, 10.0, 10.0 + b),
            Vec3::splat(-7.0),
            Vec3::splat(77.0),
        ],
        vec![
            [0, 4, 2],
            [1, 5, 3],
            [1, 3, 7],
            [0, 2, 6],
            [0, 6, 4],
            [1, 7, 5],
            [3, 5, 7],
            [2, 4, 6],
        ],
    );
    let (mut kept, dropped) = keep_largest_shell(&mesh);
    assert_eq!(
        kept.vertices,
        [
            mesh.vertices[1],
            mesh.vertices[3],
            mesh.vertices[5],
            mesh.vertices[7]
        ]
    );
    assert_eq!(kept.triangles, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]);
    assert_eq!((dropped.count, dropped.triangles), (1, 4));
    let small = f64::from(s).powi(3) / 6.0;
    assert!(
        (dropped.largest_other_volume - small).abs() < 1e-6 * small,
        "{dropped:?}"
    );
    let validation = validate(&mut kept).unwrap();
    assert!(!validation.flipped);
    assert!((validation.volume - f64::from(b).powi(3) / 6.0).abs() < 1e-5);
}

#[test]
fn keep_largest_shell_ranks_by_volume_before_triangle_count() {
    // The octahedron has twice the triangles but a thousandth of the volume.
    let mesh = joined(&[
        placed(&octahedron(), 0.1, Vec3::splat(-5.0)),
        tetrahedron(),
        placed(&tetrahedron(), 0.2, Vec3::splat(5.0)),
    ]);
    let (kept, dropped) = keep_largest_shell(&mesh);
    assert_eq!(kept, tetrahedron());
    assert_eq!((dropped.count, dropped.triangles), (2, 12));
    // The larger dropped piece is the small tetrahedron: 0.008 / 6 > 0.004 / 3.
    let tetra = 0.2f64.powi(3) / 6.0;
    assert!(
        (dropped.largest_other_volume - tetra).abs() < 1e-6,
        "{dropped:?}"
    );
}

#[test]
fn keep_largest_shell_breaks_a_tie_by_first_triangle() {
    // A tetrahedron and its point reflection through the bounding-box centre
    // (the origin): the same |volume| to the last bit, one facing inward.
    let outward = placed(&tetrahedron(), 1.0, Vec3::ONE);
    let inward = placed(&outward, -1.0, Vec3::ZERO);
    for (first, second) in [(&outward, &inward), (&inward, &outward)] {
        let (kept, dropped) = keep_largest_shell(&joined(&[first.clone(), second.clone()]));
        assert_eq!(&kept, first);
        assert_eq!((dropped.count, dropped.triangles), (1, 4));
        assert!((dropped.largest_other_volume - 1.0 / 6.0).abs() < 1e-6);
    }
}

#[test]
fn keep_largest_shell_leaves_one_shell_unchanged() {
    let mut mesh = octahedron();
    // Even a vertex no triangle uses stays.
    mesh.vertices.push(Vec3::splat(9.0));
    let (kept, dropped) = keep_largest_shell(&mesh);
    assert_eq!(kept, mesh);
    assert_eq!(dropped, ShellsDropped::default());
    assert_eq!(dropped.count, 0);

    let empty = SurfaceMesh::default();
    assert_eq!(
        keep_largest_shell(&empty),
        (empty, ShellsDropped::default())
    );
}

#[test]
fn keep_largest_shell_leaves_bad_indices_for_validate() {
    let mut mesh = joined(&[tetrahedron(), placed(&tetrahedron(), 2.0, Vec3::splat(5.0))]);
    mesh.triangles[1][2] = 99;
    let (mut kept, dropped) = keep_largest_shell(&mesh);
    assert_eq!((&kept, dropped.count), (&mesh, 0));
    assert!(matches!(
        validate(&mut kept),
        Err(MeshError::IndexOutOfRange { vertex: 99, .. })
    ));
}

#[test]
fn keep_largest_shell_never_keeps_a_shell_with_a_nan_vertex() {
    let mut speck = placed(&tetrahedron(), 0.1, Vec3::splat(5.0));
    speck.vertices[3].x = f32::NAN;
    let (kept, dropped) = keep_largest_shell(&joined(&[speck, tetrahedron()]));
    assert_eq!(kept, tetrahedron());
    assert_eq!((dropped.count, dropped.triangles), (1, 4));
}

#[test]
fn several_shells_error_names_the_largest_shell_option() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.obj");
    let two = joined(&[tetrahedron(), placed(&tetrahedron(), 2.0, Vec3::splat(5.0))]);
    save_surface(&two, &path).unwrap();
    let err = load_closed_surface(&path).unwrap_err();
    assert!(err.to_string().contains("--largest-shell"), "{err}");
    let (kept, validation, dropped) = load_closed_surface_with(&path, &LARGEST_SHELL).unwrap();
    assert_eq!(kept.triangles.len(), 4);
    assert!((validation.volume - 8.0 / 6.0).abs() < 1e-5);
    assert_eq!(dropped.count, 1);
}

#[test]
fn load_options_default_to_one_shell_only() {
    assert_eq!(
        LoadOptions::default(),
        LoadOptions::keeping_largest_shell(false)
    );
}

// --- the shared real-world meshes ---------------------------------------------

#[test]
fn liver_smooth_obj_is_closed_and_outward() {
    let Some(path) = shared_mesh("liver-smooth.obj") else {
        return;
    };
    let (mesh, report) = load_closed_surface_with_report(&path).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (2194, 4384));
    assert!(!report.flipped);
    assert!((report.volume - 39.3).abs() < 0.05, "{}", report.volume);
}

#[test]
fn liver_obj_is_closed() {
    let Some(path) = shared_mesh("liver.obj") else {
        return;
    };
    let (mesh, report) = load_closed_surface_with_report(&path).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (139, 274));
    assert!(!report.flipped);
    assert!((report.volume - 36.57).abs() < 0.01, "{}", report.volume);
}

#[test]
fn liver_vtk_is_an_inward_liver_plus_three_slivers() {
    let Some(path) = shared_mesh("liver.vtk") else {
        return;
    };
    let mesh = load_surface(&path).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (5008, 10000));
    let err = mesh_error(load_closed_surface(&path));
    assert!(
        matches!(
            err,
            MeshError::SeveralShells {
                count: 4,
                example: 347,
                ..
            }
        ),
        "{err:?}"
    );
    // The three extra shells are tiny closed 4-triangle pieces; the liver itself is fine but inward.
    let pieces = shells(&mesh);
    let sizes: Vec<usize> = pieces.iter().map(|p| p.triangles.len()).collect();
    assert_eq!(sizes, [9988, 4, 4, 4]);
    let mut liver = pieces[0].clone();
    let report = validate(&mut liver).unwrap();
    assert!(report.flipped);
    assert!((report.volume - 1.4772e6).abs() < 1e3, "{}", report.volume);
}

/// A real binary file cut short anywhere is refused, not a panic.
#[test]
fn truncated_liver_vtk_and_bunny_stl_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["liver.vtk", "Bunny.stl"] {
        let Some(path) = shared_mesh(name) else {
            return;
        };
        let bytes = std::fs::read(&path).unwrap();
        let cut_path = dir.path().join(name);
        for k in 0..100 {
            let end = k * bytes.len() / 100;
            std::fs::write(&cut_path, &bytes[..end]).unwrap();
            assert!(load_surface(&cut_path).is_err(), "{name} cut at {end}");
        }
    }
}

#[test]
fn armadillo_obj_welds_per_corner_indices() {
    let Some(path) = shared_mesh("Armadillo_verysimplified.obj") else {
        return;
    };
    let (mesh, report) = load_closed_surface_with_report(&path).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (531, 1058));
    assert!(!report.flipped);
}

#[test]
fn bunny_stl_is_closed() {
    let Some(path) = shared_mesh("Bunny.stl") else {
        return;
    };
    let (mesh, report) = load_closed_surface_with_report(&path).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (1366, 2728));
    assert!(!report.flipped);
}

#[test]
fn dragon_stl_is_rejected_as_non_manifold() {
    let Some(path) = shared_mesh("dragon.stl") else {
        return;
    };
    // It is also open and inconsistently wound; non-manifold edges are checked first.
    let err = mesh_error(load_closed_surface(&path));
    assert!(
        matches!(err, MeshError::NonManifold { count: 97, .. }),
        "{err:?}"
    );
}

#[test]
fn liver_vtk_with_largest_shell_is_the_liver_turned_outward() {
    let Some(path) = shared_mesh("liver.vtk") else {
        return;
    };
    let err =
        mesh_error(load_closed_surface_with(&path, &LoadOptions::default()).map(|(mesh, ..)| mesh));
    assert!(
        matches!(err, MeshError::SeveralShells { count: 4, .. }),
        "{err:?}"
    );

    let (mesh, validation, dropped) = load_closed_surface_with(&path, &LARGEST_SHELL).unwrap();
    assert_eq!(mesh.triangles.len(), 9988);
    assert!(validation.flipped);
    assert!(mesh.signed_volume() > 0.0);
    assert!(
        (validation.volume - 1.477e6).abs() < 0.01 * 1.477e6,
        "{}",
        validation.volume
    );
    assert_eq!((dropped.count, dropped.triangles), (3, 12));
    assert!(
        dropped.largest_other_volume < 1e-3 * validation.volume,
        "{dropped:?}"
    );

    // The same shell as an independent grouping of the triangles finds.
    let loaded = load_surface(&path).unwrap();
    let (kept, _) = keep_largest_shell(&loaded);
    assert_eq!(kept, shells(&loaded)[0]);
}

#[test]
fn largest_shell_changes_nothing_for_a_single_shell() {
    let Some(path) = shared_mesh("Bunny.stl") else {
        return;
    };
    let (mesh, validation, dropped) = load_closed_surface_with(&path, &LARGEST_SHELL).unwrap();
    assert_eq!(dropped, ShellsDropped::default());
    assert_eq!(
        (mesh, validation),
        load_closed_surface_with_report(&path).unwrap()
    );
}

#[test]
fn dragon_stl_with_largest_shell_is_still_refused() {
    let Some(path) = shared_mesh("dragon.stl") else {
        return;
    };
    // Its largest piece is itself broken; the option drops pieces, it mends nothing.
    let err = mesh_error(load_closed_surface_with(&path, &LARGEST_SHELL).map(|(mesh, ..)| mesh));
    assert!(matches!(err, MeshError::NonManifold { .. }), "{err:?}");
}
