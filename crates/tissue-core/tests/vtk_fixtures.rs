//! Surfaces written by VTK itself (`tests/fixtures/vtk`, made by
//! `make_fixtures.py` with the `vtk` Python package): every encoding
//! `vtkXMLPolyDataWriter` and `vtkPolyDataWriter` write, 3D Slicer's model
//! saves among them (appended, base64, zlib, with empty compressed `Verts`,
//! `Lines` and `Strips` arrays of zero blocks), each read as the same
//! surface; and the coordinate-system tag Slicer writes, read back from
//! Slicer's files and from ours.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

use tissue_core::io::space::Space;
use tissue_core::io::surface::{
    coordinate_tag, load_closed_surface, load_surface, save_surface, save_surface_in,
};
use tissue_core::{Error, SurfaceMesh};
use tissue_testkit::{
    VTK_LEGACY_FIXTURES, VTK_SLICER_FIXTURES, VTK_XML_FIXTURES, vtk_fixture as fixture,
};

/// Every fixture of the rest surface: VTK's layouts, its legacy files and
/// 3D Slicer's saves.
fn every_fixture() -> impl Iterator<Item = &'static str> {
    VTK_XML_FIXTURES
        .into_iter()
        .chain(VTK_LEGACY_FIXTURES)
        .chain(VTK_SLICER_FIXTURES)
}

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
    for name in every_fixture() {
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

/// Legacy VTK files that vtkio's parser refuses with only its grammar's
/// word (`Parse error: Digit`) are refused naming what does not add up.
#[test]
fn a_damaged_legacy_vtk_file_is_named_in_the_error() {
    let dir = tempfile::tempdir().unwrap();
    let header = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\n";
    let cases = [
        (
            format!("{header}POINTS 4 float\n0 0 0 1 0 0\nPOLYGONS 1 4\n3 0 1 2\n"),
            "POINTS announces 4 points (12 values), but only 6 follow before `POLYGONS`",
        ),
        (
            format!(
                "{header}POINTS 4 float\n0 0 0 1 0 0 0 1 0 0 0 1\nPOLYGONS 2 8\n3 0 2 1\n3 0 1 x\n"
            ),
            "POLYGONS announces 8 values, but value 8 of them is `x`, not a number",
        ),
        (
            format!("{header}POINTS 4 float\n0 0 0 1 0 0 0 1 0 0 0 1\nPOLYGONS 2 8\n3 0 2 1\n"),
            "POLYGONS announces 8 values, but only 4 follow: the file is cut short",
        ),
        (
            "hello\n".to_owned(),
            "not a legacy VTK file: its first line is `hello`",
        ),
        (
            "# vtk DataFile Version 3.0\nt\nASCI\n".to_owned(),
            "says ASCII or BINARY, not `ASCI`",
        ),
        (
            "# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\n".to_owned(),
            "DATASET STRUCTURED_POINTS, which holds no surface",
        ),
    ];
    for (k, (text, expected)) in cases.into_iter().enumerate() {
        let path = dir.path().join(format!("bad-{k}.vtk"));
        std::fs::write(&path, text).unwrap();
        let message = load_surface(&path).unwrap_err().to_string();
        assert!(message.contains(&format!("bad-{k}.vtk")), "{message}");
        assert!(message.contains(expected), "{message}");
        assert!(!message.contains("Parse error"), "{message}");
    }
}

/// A compressed block whose header claims more bytes than zlib can make of
/// it (a "zlib bomb", or a damaged header) is refused before it is
/// inflated, naming the array; the file is VTK's own with the `Points`
/// block's header changed to say 2e9 bytes.
#[test]
fn a_block_claiming_more_than_its_compressor_can_make_is_refused() {
    use base64::Engine as _;
    let engine = base64::engine::general_purpose::STANDARD;
    let text = std::fs::read_to_string(fixture("inline-zlib.vtp")).unwrap();
    let tag = text.find(r#"Name="Points""#).unwrap();
    let start = tag + text[tag..].find('>').unwrap() + 1;
    // Where the array's base64 text begins (a suffix of the file).
    let start = text.len() - text[start..].trim_start().len();
    // One block, UInt32 words: [blocks, block size, last size, compressed].
    let header = engine.decode(&text[start..start + 24]).unwrap();
    let word = |k: usize| u32::from_le_bytes(header[4 * k..4 * k + 4].try_into().unwrap());
    assert_eq!(word(0), 1, "one block");
    let mut bomb = header.clone();
    bomb[8..12].copy_from_slice(&2_000_000_000u32.to_le_bytes());
    let edited = format!(
        "{}{}{}",
        &text[..start],
        engine.encode(&bomb),
        &text[start + 24..]
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bomb.vtp");
    std::fs::write(&path, edited).unwrap();
    let message = load_surface(&path).unwrap_err().to_string();
    for expected in [
        "bomb.vtp",
        "`Points`",
        "more than the compressor can make of it",
    ] {
        assert!(message.contains(expected), "{message}");
    }
}
