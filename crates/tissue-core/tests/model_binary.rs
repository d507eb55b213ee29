//! A model `.vtp` re-saved with binary arrays, as ParaView saves by
//! default (appended raw bytes, zlib-compressed in blocks), and in every
//! other layout VTK writes (inline base64, appended base64, LZ4, UInt32 or
//! UInt64 headers), reads back as the same model. The files are made here
//! from the ASCII one by an encoder written from VTK's description of the
//! format, apart from the reader's decoder.

#![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

use std::io::Write;
use std::path::Path;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use tissue_core::io::model::{load_model, save_model};
use tissue_core::{Attachment, Connections, ParticleModel, SurfaceMesh, Vec3};

/// A tetrahedron with interior and surface particles, connected, with
/// values that do not survive a careless conversion.
fn model() -> ParticleModel {
    let (vertices, triangles) = tissue_testkit::tetrahedron(3.0);
    let surface = SurfaceMesh::new(vertices, triangles);
    let mut positions = Vec::new();
    let mut attachments = Vec::new();
    for k in 0..40 {
        let t = k as f32 / 40.0;
        positions.push(Vec3::new(0.3 + 0.4 * t, 0.2 + t / 3.0, 0.1 + 0.7 * t * t));
        attachments.push(None);
    }
    for k in 0..12 {
        let u = (k as f32 + 0.5) / 13.0;
        let barycentric = [u, (1.0 - u) / 3.0, 1.0 - u - (1.0 - u) / 3.0];
        let triangle = k % 4;
        let [a, b, c] = surface.triangles[triangle as usize].map(|i| surface.vertices[i as usize]);
        positions.push(a * barycentric[0] + b * barycentric[1] + c * barycentric[2]);
        attachments.push(Some(Attachment {
            triangle,
            barycentric,
        }));
    }
    let n = positions.len() as u32;
    ParticleModel {
        radii: (0..n).map(|k| 0.1 + 1.0 / (k as f32 + 7.0)).collect(),
        connections: Connections::from_pairs(
            n as usize,
            (0..n - 1).flat_map(|i| {
                [(i, i + 1), (i, (i * 7 + 3) % n)]
                    .into_iter()
                    .filter(|(a, b)| a != b)
            }),
        ),
        positions,
        attachments,
        surface,
    }
}

/// How the test's encoder lays a file out.
#[derive(Debug, Clone, Copy)]
struct Layout {
    appended: Option<Encoding>,
    compressor: Option<Compressor>,
    header64: bool,
}

#[derive(Debug, Clone, Copy)]
enum Encoding {
    Raw,
    Base64,
}

#[derive(Debug, Clone, Copy)]
enum Compressor {
    Zlib,
    Lz4,
}

/// Bytes of one array's values, little-endian, as VTK type `ty`.
fn bytes_of(text: &str, ty: &str) -> Vec<u8> {
    let mut out = Vec::new();
    for token in text.split_whitespace() {
        match ty {
            "Float32" => out.extend(token.parse::<f32>().unwrap().to_le_bytes()),
            "Int32" => out.extend(token.parse::<i32>().unwrap().to_le_bytes()),
            "Int64" => out.extend(token.parse::<i64>().unwrap().to_le_bytes()),
            "UInt8" => out.push(token.parse::<u8>().unwrap()),
            other => panic!("no encoder for {other}"),
        }
    }
    out
}

/// One header word.
fn word(value: usize, header64: bool) -> Vec<u8> {
    if header64 {
        (value as u64).to_le_bytes().to_vec()
    } else {
        (value as u32).to_le_bytes().to_vec()
    }
}

/// One array's block: its header and its (compressed) bytes. Compressed
/// blocks hold 64 bytes before compression, so that arrays span several.
fn block(data: &[u8], layout: Layout) -> (Vec<u8>, Vec<u8>) {
    let Some(compressor) = layout.compressor else {
        return (word(data.len(), layout.header64), data.to_vec());
    };
    const SIZE: usize = 64;
    let chunks: Vec<&[u8]> = data.chunks(SIZE).collect();
    let packed: Vec<Vec<u8>> = chunks
        .iter()
        .map(|chunk| match compressor {
            Compressor::Zlib => {
                let mut z =
                    flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
                z.write_all(chunk).unwrap();
                z.finish().unwrap()
            }
            Compressor::Lz4 => lz4_flex::block::compress(chunk),
        })
        .collect();
    let mut header = word(chunks.len(), layout.header64);
    header.extend(word(SIZE, layout.header64));
    header.extend(word(data.len() % SIZE, layout.header64));
    for p in &packed {
        header.extend(word(p.len(), layout.header64));
    }
    (header, packed.concat())
}

/// Base64 as VTK writes a block: one stream uncompressed, header and data
/// as two streams compressed.
fn encoded(header: &[u8], data: &[u8], compressed: bool) -> String {
    if compressed {
        STANDARD.encode(header) + &STANDARD.encode(data)
    } else {
        STANDARD.encode([header, data].concat())
    }
}

/// The ASCII model file `ascii` with every DataArray re-encoded per `layout`.
fn reencoded(ascii: &str, layout: Layout) -> Vec<u8> {
    let compressed = layout.compressor.is_some();
    let mut xml = String::new();
    let mut appended: Vec<u8> = Vec::new();
    let mut rest = ascii;
    while let Some(start) = rest.find("<DataArray ") {
        let open_end = start + rest[start..].find('>').unwrap();
        let close = open_end + rest[open_end..].find("</DataArray>").unwrap();
        let attributes = &rest[start + "<DataArray ".len()..open_end];
        let ty = attributes
            .split("type=\"")
            .nth(1)
            .and_then(|t| t.split('"').next())
            .unwrap();
        let (header, data) = block(&bytes_of(&rest[open_end + 1..close], ty), layout);
        xml.push_str(&rest[..start]);
        match layout.appended {
            Some(encoding) => {
                let offset = appended.len();
                match encoding {
                    Encoding::Raw => {
                        appended.extend(&header);
                        appended.extend(&data);
                    }
                    Encoding::Base64 => {
                        appended.extend(encoded(&header, &data, compressed).into_bytes());
                    }
                }
                let attributes = attributes.replace(
                    r#"format="ascii""#,
                    &format!(r#"format="appended" offset="{offset}""#),
                );
                xml.push_str(&format!("<DataArray {attributes}/>"));
            }
            None => {
                let attributes = attributes.replace(r#"format="ascii""#, r#"format="binary""#);
                xml.push_str(&format!(
                    "<DataArray {attributes}>\n          {}\n        </DataArray>",
                    encoded(&header, &data, compressed)
                ));
            }
        }
        rest = &rest[close + "</DataArray>".len()..];
    }
    xml.push_str(rest);
    let mut file_tag = String::from(r#"header_type="UInt64""#);
    if !layout.header64 {
        file_tag = r#"header_type="UInt32""#.into();
    }
    match layout.compressor {
        Some(Compressor::Zlib) => file_tag.push_str(r#" compressor="vtkZLibDataCompressor""#),
        Some(Compressor::Lz4) => file_tag.push_str(r#" compressor="vtkLZ4DataCompressor""#),
        None => {}
    }
    let xml = xml.replace(r#"header_type="UInt64""#, &file_tag);
    let Some(encoding) = layout.appended else {
        return xml.into_bytes();
    };
    let end = xml.rfind("</VTKFile>").unwrap();
    let name = match encoding {
        Encoding::Raw => "raw",
        Encoding::Base64 => "base64",
    };
    let mut out = xml.as_bytes()[..end].to_vec();
    out.extend(format!("  <AppendedData encoding=\"{name}\">\n   _").into_bytes());
    out.extend(appended);
    out.extend(b"\n  </AppendedData>\n</VTKFile>\n");
    out
}

fn assert_same(a: &ParticleModel, b: &ParticleModel, what: &str) {
    assert_eq!(a.positions, b.positions, "{what}");
    assert_eq!(a.radii, b.radii, "{what}");
    assert_eq!(a.attachments, b.attachments, "{what}");
    assert_eq!(
        a.connections.pair_list(),
        b.connections.pair_list(),
        "{what}"
    );
    assert_eq!(a.surface.vertices, b.surface.vertices, "{what}");
    assert_eq!(a.surface.triangles, b.surface.triangles, "{what}");
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn a_model_resaved_with_binary_arrays_reads_as_the_same_model() {
    let model = model();
    let dir = tempfile::tempdir().unwrap();
    let ascii_path = dir.path().join("model.vtp");
    save_model(&model, &ascii_path).unwrap();
    let ascii = std::fs::read_to_string(&ascii_path).unwrap();
    let mut layouts = Vec::new();
    for appended in [None, Some(Encoding::Raw), Some(Encoding::Base64)] {
        for compressor in [None, Some(Compressor::Zlib), Some(Compressor::Lz4)] {
            for header64 in [false, true] {
                layouts.push(Layout {
                    appended,
                    compressor,
                    header64,
                });
            }
        }
    }
    for layout in layouts {
        let what = format!("{layout:?}");
        let path = dir.path().join("binary.vtp");
        let bytes = reencoded(&ascii, layout);
        assert!(
            !String::from_utf8_lossy(&bytes).contains(r#"format="ascii""#),
            "{what}: every array re-encoded"
        );
        write(&path, &bytes);
        let back = load_model(&path).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_same(&model, &back, &what);
    }
}

#[test]
fn a_damaged_binary_model_is_refused_naming_the_array() {
    let model = model();
    let dir = tempfile::tempdir().unwrap();
    let ascii_path = dir.path().join("model.vtp");
    save_model(&model, &ascii_path).unwrap();
    let ascii = std::fs::read_to_string(&ascii_path).unwrap();
    let layout = Layout {
        appended: Some(Encoding::Raw),
        compressor: Some(Compressor::Zlib),
        header64: false,
    };
    let bytes = reencoded(&ascii, layout);
    let path = dir.path().join("damaged.vtp");
    // Cut the file inside its appended data: the arrays there end early.
    let cut = bytes.len() - 200;
    let mut damaged = bytes[..cut].to_vec();
    damaged.extend(b"\n  </AppendedData>\n</VTKFile>\n");
    write(&path, &damaged);
    let err = load_model(&path).unwrap_err().to_string();
    assert!(err.contains("damaged.vtp"), "{err}");
    assert!(
        err.contains("appended data") || err.contains("the array `"),
        "{err}"
    );
    // A zlib block whose bytes were flipped.
    let mut flipped = bytes.clone();
    let start = flipped.windows(4).position(|w| w == b"   _").unwrap() + 4;
    for b in &mut flipped[start + 40..start + 60] {
        *b ^= 0x5a;
    }
    write(&path, &flipped);
    let err = load_model(&path).unwrap_err().to_string();
    assert!(err.contains("damaged.vtp"), "{err}");
}

/// Past `BINARY_FROM_PARTICLES` the model is written with binary arrays,
/// and reads back bit-identical; below it, ASCII.
#[test]
fn a_large_model_is_written_binary_and_reads_back_exactly() {
    use tissue_core::io::model::BINARY_FROM_PARTICLES;
    let small = model();
    let n = BINARY_FROM_PARTICLES + 1;
    let positions: Vec<Vec3> = (0..n)
        .map(|k| {
            let t = k as f32 / n as f32;
            Vec3::new(
                0.2 + 0.5 * t,
                0.3 + (7.0 * t).sin().abs() * 0.5,
                0.1 + t / 3.0,
            )
        })
        .collect();
    let large = ParticleModel {
        radii: (0..n).map(|k| 0.01 + 1.0 / (k as f32 + 3.0)).collect(),
        connections: Connections::from_pairs(n, (0..n as u32 - 1).map(|i| (i, i + 1))),
        attachments: vec![None; n],
        positions,
        surface: small.surface.clone(),
    };
    let dir = tempfile::tempdir().unwrap();
    for (model, binary) in [(&small, false), (&large, true)] {
        let path = dir.path().join("model.vtp");
        save_model(model, &path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let points = if binary {
            r#"Name="Points" NumberOfComponents="3" format="binary""#
        } else {
            r#"Name="Points" NumberOfComponents="3" format="ascii""#
        };
        assert!(text.contains(points), "{points}");
        let back = load_model(&path).unwrap();
        assert_same(model, &back, if binary { "binary" } else { "ascii" });
    }
}
