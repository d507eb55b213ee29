//! `.vtp` surfaces (VTK XML PolyData: 3D Slicer's model format, and what
//! ParaView saves): written and read back, read when compressed, and read
//! in ParaView's default layout (binary data appended after the XML).
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

use std::io::Write;

use tissue_core::io::surface::{load_closed_surface, load_surface, save_surface};
use tissue_core::{Error, SurfaceMesh};

fn octahedron() -> SurfaceMesh {
    let (vertices, triangles) = tissue_testkit::octahedron();
    SurfaceMesh::new(vertices, triangles)
}

#[test]
fn a_vtp_surface_round_trips_and_bounds_a_solid() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("octahedron.vtp");
    let mesh = octahedron();
    save_surface(&mesh, &path).unwrap();
    let text = std::fs::read(&path).unwrap();
    assert!(String::from_utf8_lossy(&text).contains(r#"type="PolyData""#));
    let back = load_surface(&path).unwrap();
    assert_eq!(back.vertices, mesh.vertices);
    assert_eq!(back.triangles, mesh.triangles);
    let closed = load_closed_surface(&path).unwrap();
    assert!((closed.signed_volume() - 4.0 / 3.0).abs() < 1e-6);
}

#[test]
fn a_compressed_vtp_reads_as_the_same_surface() {
    use vtkio::model::{ByteOrder, DataSet, IOBuffer, PolyDataPiece, Version, VertexNumbers, Vtk};
    let mesh = octahedron();
    let vtk = Vtk {
        version: Version::Auto,
        byte_order: ByteOrder::LittleEndian,
        title: String::new(),
        file_path: None,
        data: DataSet::inline(PolyDataPiece {
            points: IOBuffer::F64(
                mesh.vertices
                    .iter()
                    .flat_map(|v| v.to_array().map(f64::from))
                    .collect(),
            ),
            polys: Some(VertexNumbers::XML {
                connectivity: mesh
                    .triangles
                    .iter()
                    .flatten()
                    .map(|&i| u64::from(i))
                    .collect(),
                offsets: vec![3, 6, 9, 12, 15, 18, 21, 24],
            }),
            ..Default::default()
        }),
    };
    let file = vtk
        .try_into_xml_format(vtkio::xml::Compressor::ZLib, 9)
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("compressed.vtp");
    std::fs::write(&path, file.to_string()).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("vtkZLibDataCompressor"), "{text}");
    let back = load_surface(&path).unwrap();
    assert_eq!(back.vertices, mesh.vertices);
    assert_eq!(back.triangles, mesh.triangles);
}

/// How a compressed array's one block is laid out.
#[derive(Debug, Clone, Copy)]
enum Block {
    /// Smaller than the block size (the usual case for small arrays).
    Partial,
    /// Exactly the block size.
    Full,
}

/// The octahedron as ParaView writes a `.vtp` by default: every array
/// `format="appended"`, its bytes after `<AppendedData encoding="raw">_`,
/// each block behind its header; zlib-compressed in one block per array
/// when `compressed` (the header then `[1, 32768, size, compressed size]`:
/// one block, partly full).
fn appended_raw_octahedron(path: &std::path::Path, compressed: Option<Block>) -> SurfaceMesh {
    let mesh = octahedron();
    let points: Vec<u8> = mesh
        .vertices
        .iter()
        .flat_map(|v| v.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let connectivity: Vec<u8> = mesh
        .triangles
        .iter()
        .flatten()
        .flat_map(|&i| i64::from(i).to_le_bytes())
        .collect();
    let offsets: Vec<u8> = (1..=8i64).flat_map(|k| (3 * k).to_le_bytes()).collect();
    let mut blocks = Vec::new();
    let mut starts = Vec::new();
    for block in [&points, &connectivity, &offsets] {
        starts.push(blocks.len());
        if let Some(layout) = compressed {
            let mut zlib =
                flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            zlib.write_all(block).unwrap();
            let packed = zlib.finish().unwrap();
            let (size, last) = match layout {
                // ParaView's blocks hold 32 KiB: one partial block here.
                Block::Partial => (32_768, block.len()),
                // A block exactly full: its partial size is written as 0.
                Block::Full => (block.len(), 0),
            };
            for word in [1, size, last, packed.len()] {
                blocks.extend((word as u32).to_le_bytes());
            }
            blocks.extend_from_slice(&packed);
        } else {
            blocks.extend((block.len() as u32).to_le_bytes());
            blocks.extend_from_slice(block);
        }
    }
    let compressor = if compressed.is_some() {
        r#" compressor="vtkZLibDataCompressor""#
    } else {
        ""
    };
    let mut file = std::fs::File::create(path).unwrap();
    write!(
        file,
        r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt32"{compressor}>
  <PolyData>
    <Piece NumberOfPoints="6" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="8">
      <Points>
        <DataArray type="Float32" Name="Points" NumberOfComponents="3" format="appended" offset="{}"/>
      </Points>
      <Polys>
        <DataArray type="Int64" Name="connectivity" format="appended" offset="{}"/>
        <DataArray type="Int64" Name="offsets" format="appended" offset="{}"/>
      </Polys>
    </Piece>
  </PolyData>
  <AppendedData encoding="raw">
   _"#,
        starts[0], starts[1], starts[2]
    )
    .unwrap();
    file.write_all(&blocks).unwrap();
    write!(file, "\n  </AppendedData>\n</VTKFile>\n").unwrap();
    mesh
}

#[test]
fn a_vtp_with_appended_raw_data_reads_as_the_same_surface() {
    let dir = tempfile::tempdir().unwrap();
    for compressed in [None, Some(Block::Partial), Some(Block::Full)] {
        let path = dir.path().join(format!("appended-{compressed:?}.vtp"));
        let mesh = appended_raw_octahedron(&path, compressed);
        let back = load_surface(&path).unwrap_or_else(|e| panic!("compressed {compressed:?}: {e}"));
        assert_eq!(back.vertices, mesh.vertices, "compressed {compressed:?}");
        assert_eq!(back.triangles, mesh.triangles, "compressed {compressed:?}");
    }
}

#[test]
fn a_vtp_that_is_no_surface_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let garbage = dir.path().join("garbage.vtp");
    std::fs::write(&garbage, "<VTKFile type=\"PolyData\"><oops").unwrap();
    let err = load_surface(&garbage).unwrap_err();
    assert!(matches!(err, Error::Format { .. }), "{err}");
    assert!(err.to_string().contains("garbage.vtp"), "{err}");
    let grid = dir.path().join("grid.vtp");
    std::fs::write(
        &grid,
        r#"<?xml version="1.0"?>
<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">
  <ImageData WholeExtent="0 1 0 1 0 1" Origin="0 0 0" Spacing="1 1 1">
    <Piece Extent="0 1 0 1 0 1"></Piece>
  </ImageData>
</VTKFile>
"#,
    )
    .unwrap();
    let err = load_surface(&grid).unwrap_err();
    assert!(err.to_string().contains("grid.vtp"), "{err}");
    // Raw appended data cut short, or claiming absurd sizes: refused, no panic.
    let whole = dir.path().join("whole.vtp");
    appended_raw_octahedron(&whole, Some(Block::Partial));
    let bytes = std::fs::read(&whole).unwrap();
    let tag = bytes
        .windows(15)
        .position(|w| w == br#"encoding="raw">"#.as_slice())
        .unwrap();
    let marker = tag + bytes[tag..].iter().position(|&b| b == b'_').unwrap() + 1;
    for cut in [marker + 3, marker + 20, bytes.len() - 40] {
        let short = dir.path().join(format!("short-{cut}.vtp"));
        std::fs::write(&short, &bytes[..cut]).unwrap();
        let err = load_surface(&short).unwrap_err();
        assert!(err.to_string().contains("short-"), "{err}");
    }
    let mut absurd = bytes.clone();
    absurd[marker..marker + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    let huge = dir.path().join("huge.vtp");
    std::fs::write(&huge, &absurd).unwrap();
    assert!(load_surface(&huge).is_err());
}

/// A `.vtp` cut anywhere, whatever its encoding, or with well-formed XML
/// around a points array too short for its count, is refused naming the
/// file: never a panic.
#[test]
fn a_vtp_cut_anywhere_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.vtp");
    save_surface(&octahedron(), &whole).unwrap();
    let appended = dir.path().join("appended.vtp");
    appended_raw_octahedron(&appended, Some(Block::Partial));
    for source in [&whole, &appended] {
        let bytes = std::fs::read(source).unwrap();
        for cut in (1..bytes.len()).step_by(7) {
            let short = dir.path().join("short.vtp");
            std::fs::write(&short, &bytes[..cut]).unwrap();
            let outcome = std::panic::catch_unwind(|| load_surface(&short));
            match outcome {
                Ok(Ok(mesh)) => panic!(
                    "{} cut at {cut}: read {} vertices",
                    source.display(),
                    mesh.vertices.len()
                ),
                Ok(Err(err)) => assert!(err.to_string().contains("short.vtp"), "{err}"),
                Err(_) => panic!(
                    "{} cut at {cut} of {}: the reader panicked",
                    source.display(),
                    bytes.len()
                ),
            }
        }
    }
    // The points array of the written file shortened inside its XML.
    let text = std::fs::read_to_string(&whole).unwrap();
    let points = text.find("Name=\"Points\"").unwrap();
    let open = points + text[points..].find('>').unwrap() + 1;
    let close = open + text[open..].find('<').unwrap();
    let payload = text[open..close].trim();
    for keep in [0, 4, payload.len() / 2] {
        let shorter = format!("{}{}{}", &text[..open], &payload[..keep], &text[close..]);
        let short = dir.path().join("short.vtp");
        std::fs::write(&short, shorter).unwrap();
        let outcome = std::panic::catch_unwind(|| load_surface(&short));
        assert!(
            matches!(outcome, Ok(Err(_))),
            "points cut to {keep} characters: {:?}",
            outcome.map(|r| r.map(|m| m.vertices.len()))
        );
    }
}
