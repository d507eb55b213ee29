//! STL: binary and ASCII read, binary written. Binary STL gives every
//! triangle its own three corners; [`super::load_surface`] welds them.

use std::io::{Cursor, Write};

use glam::Vec3;

use crate::io::space::Space;
use crate::mesh::SurfaceMesh;

/// Binary STL: 80-byte header, `u32` triangle count, then per triangle a
/// normal, three corners (12 little-endian `f32`) and a 2-byte attribute.
const STL_HEADER: usize = 84;
const STL_RECORD: usize = 50;

pub(super) fn read_stl(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    let announced = bytes
        .get(80..STL_HEADER)
        .and_then(|b| b.try_into().ok())
        .map(|b: [u8; 4]| u32::from_le_bytes(b) as usize);
    let binary_size = announced.map(|n| STL_HEADER.saturating_add(n.saturating_mul(STL_RECORD)));
    let text = bytes.trim_ascii_start();
    let looks_ascii = text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"solid");
    // Binary files whose header happens to start with "solid" are common, so
    // a size that matches the binary layout exactly wins.
    match (announced, binary_size) {
        (Some(n), Some(size)) if size == bytes.len() => Ok(read_binary_stl(bytes, n)),
        _ if looks_ascii => read_ascii_stl(text),
        (Some(n), Some(size)) if size < bytes.len() => {
            log::warn!(
                "binary STL has {} bytes after its {n} triangles; ignored",
                bytes.len() - size
            );
            Ok(read_binary_stl(bytes, n))
        }
        (Some(n), Some(size)) => Err(format!(
            "not an ASCII STL (does not start with `solid`) and not a binary STL: the header \
             announces {n} triangles ({size} bytes) but the file has {} bytes",
            bytes.len()
        )),
        _ => Err(format!(
            "not an ASCII STL (does not start with `solid`) and too short for a binary STL \
             ({} bytes, the header alone is {STL_HEADER})",
            bytes.len()
        )),
    }
}

/// Reads `triangles` records; the caller has checked the length.
fn read_binary_stl(bytes: &[u8], triangles: usize) -> SurfaceMesh {
    let corners = bytes[STL_HEADER..]
        .chunks_exact(STL_RECORD)
        .take(triangles)
        .flat_map(|record| {
            let float = |i: usize| {
                let at = 12 + 4 * i;
                f32::from_le_bytes([record[at], record[at + 1], record[at + 2], record[at + 3]])
            };
            (0..3).map(move |c| Vec3::new(float(3 * c), float(3 * c + 1), float(3 * c + 2)))
        });
    triangle_soup(corners)
}

fn read_ascii_stl(text: &[u8]) -> Result<SurfaceMesh, String> {
    // stl_io wants "solid " with a space; a bare "solid" line is also valid STL.
    let mut input = b"solid ".to_vec();
    input.extend_from_slice(&text[5..]);
    let indexed = stl_io::read_stl(&mut Cursor::new(input))
        .map_err(|e| format!("cannot parse ASCII STL: {e}"))?;
    let vertices: Vec<Vec3> = indexed
        .vertices
        .iter()
        .map(|v| Vec3::from_array(v.0))
        .collect();
    let triangles = indexed
        .faces
        .iter()
        .map(|f| f.vertices.map(|i| i as u32))
        .collect();
    Ok(SurfaceMesh::new(vertices, triangles))
}

/// A mesh with three fresh vertices per triangle, to be welded.
fn triangle_soup(corners: impl Iterator<Item = Vec3>) -> SurfaceMesh {
    let vertices: Vec<Vec3> = corners.collect();
    let triangles = (0..vertices.len() as u32 / 3)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    SurfaceMesh::new(vertices, triangles)
}

/// Binary STL; the caller has checked that the triangle count fits a `u32`.
/// The 80-byte header names the writer and, with `tag`, the coordinate
/// system as 3D Slicer writes it there (`SPACE=LPS`); it never starts with
/// `solid`, which readers take for ASCII.
pub(super) fn write_stl(
    mesh: &SurfaceMesh,
    tag: Option<Space>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    let mut header = [b' '; 80];
    let title = match tag {
        Some(space) => format!("tissue surface SPACE={space}"),
        None => "tissue surface".to_owned(),
    };
    header[..title.len()].copy_from_slice(title.as_bytes());
    out.write_all(&header)?;
    out.write_all(&(mesh.triangles.len() as u32).to_le_bytes())?;
    let mut record = Vec::with_capacity(50);
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(t);
        record.clear();
        let normal = (b - a).cross(c - a).normalize_or_zero();
        for v in [normal, a, b, c] {
            for x in v.to_array() {
                record.extend_from_slice(&x.to_le_bytes());
            }
        }
        record.extend_from_slice(&0u16.to_le_bytes());
        out.write_all(&record)?;
    }
    Ok(())
}
