//! Surfaces written by VTK itself (`tests/fixtures/vtk`, made by
//! `make_fixtures.py` with the `vtk` Python package): every encoding
//! `vtkXMLPolyDataWriter` and `vtkPolyDataWriter` write, 3D Slicer's model
//! saves among them (appended, base64, zlib, with empty compressed `Verts`,
//! `Lines` and `Strips` arrays of zero blocks), each read as the same
//! surface; and the coordinate-system tag Slicer writes, read back from
//! Slicer's files and from ours.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

use std::path::PathBuf;

use tissue_core::io::space::Space;
use tissue_core::io::surface::{
    coordinate_tag, load_closed_surface, load_surface, save_surface, save_surface_in,
};
use tissue_core::{Error, SurfaceMesh};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/vtk")
        .join(name)
}

/// Every `.vtp` the fixtures hold of the rest surface (the same points,
/// bit for bit, as `ascii.vtp`).
const XML: [&str; 15] = [
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
    "slicer-ras.vtp",
    "slicer-lps.vtp",
];

/// The legacy files: ASCII ones hold six significant digits.
const LEGACY: [&str; 5] = [
    "legacy-ascii.vtk",
    "legacy-binary.vtk",
    "legacy-v42-ascii.vtk",
    "legacy-v42-binary.vtk",
    "slicer-lps.vtk",
];

/// `mesh` with x and y negated (what Slicer writes for an LPS save of a
/// RAS model).
fn mirrored(mesh: &SurfaceMesh) -> SurfaceMesh {
    SurfaceMesh::new(
        mesh.vertices
            .iter()
            .map(|v| Space::Ras.convert(Space::Lps, *v))
            .collect(),
        mesh.triangles.clone(),
    )
}

#[test]
fn every_surface_vtk_writes_reads_as_the_same_closed_surface() {
    let reference = load_surface(&fixture("ascii.vtp")).unwrap();
    assert_eq!(reference.vertices.len(), 226);
    assert_eq!(reference.triangles.len(), 448);
    let volume = load_closed_surface(&fixture("ascii.vtp"))
        .unwrap()
        .signed_volume();
    assert!((volume - 60_560.3).abs() < 1.0, "volume {volume}");
    for name in XML.iter().chain(&LEGACY) {
        let path = fixture(name);
        let mesh = load_surface(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let expected = if name.starts_with("slicer-lps") {
            mirrored(&reference)
        } else {
            reference.clone()
        };
        assert_eq!(mesh.triangles, expected.triangles, "{name}");
        let tolerance = if name.ends_with(".vtk") { 1e-4 } else { 0.0 };
        let worst = mesh
            .vertices
            .iter()
            .zip(&expected.vertices)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f32::max);
        assert_eq!(mesh.vertices.len(), expected.vertices.len(), "{name}");
        assert!(worst <= tolerance, "{name}: a vertex {worst} mm off");
        let closed = load_closed_surface(&path).unwrap();
        assert!(
            (closed.signed_volume() - volume).abs() < 2.0,
            "{name}: volume {}",
            closed.signed_volume()
        );
    }
}

#[test]
fn the_moved_fixture_has_the_rest_fixtures_vertices_and_triangles() {
    let rest = load_surface(&fixture("appended-zlib.vtp")).unwrap();
    let moved = load_surface(&fixture("moved-appended-zlib.vtp")).unwrap();
    assert_eq!(moved.triangles, rest.triangles);
    let largest = moved
        .vertices
        .iter()
        .zip(&rest.vertices)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max);
    assert!((1.0..1.3).contains(&largest), "moved {largest} mm");
}

#[test]
fn slicers_coordinate_tag_is_read_from_its_files() {
    assert_eq!(coordinate_tag(&fixture("slicer-ras.vtp")), Some(Space::Ras));
    assert_eq!(coordinate_tag(&fixture("slicer-lps.vtp")), Some(Space::Lps));
    assert_eq!(coordinate_tag(&fixture("slicer-lps.vtk")), Some(Space::Lps));
    for name in ["appended-zlib.vtp", "ascii.vtp", "legacy-binary.vtk"] {
        assert_eq!(coordinate_tag(&fixture(name)), None, "{name}");
    }
}

#[test]
fn a_surface_saved_in_a_space_is_tagged_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_surface(&fixture("ascii.vtp")).unwrap();
    for extension in ["vtp", "vtk", "obj", "stl", "ply"] {
        for space in [Space::Lps, Space::Ras] {
            let path = dir.path().join(format!("{space}.{extension}"));
            save_surface_in(&mesh, space, &path).unwrap();
            assert_eq!(coordinate_tag(&path), Some(space), "{}", path.display());
            let back = load_surface(&path).unwrap();
            assert_eq!(back.triangles.len(), mesh.triangles.len(), "{extension}");
            let worst = back
                .vertices
                .iter()
                .zip(&mesh.vertices)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0, f32::max);
            assert!(worst < 1e-4, "{extension}: {worst}");
        }
        let untagged = dir.path().join(format!("plain.{extension}"));
        save_surface(&mesh, &untagged).unwrap();
        assert_eq!(coordinate_tag(&untagged), None, "{extension}");
    }
}

/// What the decoder's internals used to leak (`Base64Decode`,
/// `InvalidDataFormat`) now reads as the defect, naming the file.
#[test]
fn a_damaged_vtk_header_is_named_in_the_error() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(fixture("appended-base64.vtp")).unwrap();
    let zlib = std::fs::read_to_string(fixture("inline-zlib.vtp")).unwrap();
    let cases = [
        (
            text.replacen(r#"header_type="UInt32""#, r#"header_type="""#, 1),
            r#"header_type="" is not UInt32 or UInt64"#,
        ),
        (
            zlib.replacen("vtkZLibDataCompressor", "vtkSnappyCompressor", 1),
            r#"compressor="vtkSnappyCompressor" is not one VTK writes"#,
        ),
        (
            text.replacen(r#"byte_order="LittleEndian""#, r#"byte_order="Middle""#, 1),
            r#"byte_order="Middle" is not known"#,
        ),
        (
            text.replacen(r#"type="PolyData""#, r#"type="ImageData""#, 1),
            "not PolyData",
        ),
    ];
    for (k, (bad, expected)) in cases.into_iter().enumerate() {
        let path = dir.path().join(format!("bad-{k}.vtp"));
        std::fs::write(&path, bad).unwrap();
        let err = load_surface(&path).unwrap_err();
        assert!(matches!(err, Error::Format { .. }), "{err}");
        let message = err.to_string();
        assert!(message.contains(&format!("bad-{k}.vtp")), "{message}");
        assert!(message.contains(expected), "{message}");
        assert!(!message.contains("Base64Decode"), "{message}");
    }
}
