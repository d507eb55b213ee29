//! Legacy VTK: PolyData (`POLYGONS`, `TRIANGLE_STRIPS`) or the surface
//! cells of an UnstructuredGrid, ASCII or binary, read through `vtkio`;
//! written as legacy ASCII PolyData. VTK XML PolyData (`.vtp`): read and
//! written through `vtkio`.

use std::io::{Cursor, Write};

use glam::Vec3;

use super::fan;
use crate::mesh::SurfaceMesh;

pub(super) fn read_vtk(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    let vtk = guarded(|| {
        vtkio::Vtk::parse_legacy_be(Cursor::new(bytes))
            .map_err(|e| format!("cannot parse legacy VTK: {e}"))
    })?;
    surface_of(vtk.data)
}

/// Runs a `vtkio` parse, turning a panic inside it into an error: it
/// unwraps on some damaged files (a data array shorter than its count).
fn guarded<T>(parse: impl FnOnce() -> Result<T, String>) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(parse)).unwrap_or_else(|_| {
        Err(
            "the VTK reader failed on this file: it is damaged, or an array is shorter \
             than its count"
                .into(),
        )
    })
}

/// VTK XML PolyData (`.vtp`, 3D Slicer's model format and ParaView's):
/// inline ASCII or base64 binary, appended, compressed or not, read through
/// `vtkio`; the polygons and strips of every piece.
pub(super) fn read_vtp(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    let converted = raw_appended_as_base64(bytes)?;
    let bytes = converted.as_deref().unwrap_or(bytes);
    let vtk = guarded(|| {
        vtkio::Vtk::parse_xml(Cursor::new(bytes)).map_err(|e| format!("cannot parse VTK XML: {e}"))
    })?;
    match vtk.data {
        vtkio::model::DataSet::PolyData { .. } => surface_of(vtk.data),
        _ => Err("a VTK XML file but not PolyData (.vtp holds a surface as PolyData)".into()),
    }
}

/// A VTK XML file whose appended data is raw binary (ParaView's default
/// when it saves "binary" data), rewritten with that data base64-encoded,
/// the one appended encoding `vtkio` reads; `None` when it has no raw
/// appended data. Each array's block is encoded as VTK encodes it: header
/// and data together when uncompressed; the header, then the data, when
/// compressed (`compressor` set on `<VTKFile>`).
pub(crate) fn raw_appended_as_base64(bytes: &[u8]) -> Result<Option<Vec<u8>>, String> {
    use base64::Engine as _;
    use base64::engine::general_purpose::STANDARD;

    const TAG: &[u8] = b"<AppendedData";
    let Some(tag) = find(bytes, TAG, 0) else {
        return Ok(None);
    };
    let tag_end = find(bytes, b">", tag).ok_or("an unterminated <AppendedData> tag")?;
    let attributes = String::from_utf8_lossy(&bytes[tag..tag_end]);
    if !attributes.contains(r#"encoding="raw""#) {
        return Ok(None);
    }
    let underscore = find(bytes, b"_", tag_end).ok_or("raw appended data without its `_` mark")?;
    let raw = &bytes[underscore + 1..];
    let xml = String::from_utf8_lossy(&bytes[..tag]).into_owned();
    let file_tag = xml
        .find("<VTKFile")
        .map(|start| &xml[start..start + xml[start..].find('>').unwrap_or(0)])
        .ok_or("no <VTKFile> element")?;
    let header_bytes = if file_tag.contains(r#"header_type="UInt64""#) {
        8
    } else {
        4
    };
    let big_endian = file_tag.contains(r#"byte_order="BigEndian""#);
    let compressed = file_tag.contains("compressor=");
    let number = |at: usize| -> Result<usize, String> {
        let word = raw
            .get(at..at + header_bytes)
            .ok_or("raw appended data ends inside a block header")?;
        let mut eight = [0u8; 8];
        if big_endian {
            eight[8 - header_bytes..].copy_from_slice(word);
            Ok(u64::from_be_bytes(eight) as usize)
        } else {
            eight[..header_bytes].copy_from_slice(word);
            Ok(u64::from_le_bytes(eight) as usize)
        }
    };
    // Every array's offset, in the order they come.
    let mut offsets: Vec<usize> = Vec::new();
    let mut at = 0;
    while let Some(found) = xml[at..].find(r#"offset=""#) {
        let start = at + found + r#"offset=""#.len();
        let end = start + xml[start..].find('"').ok_or("an unterminated offset")?;
        offsets.push(
            xml[start..end]
                .parse()
                .map_err(|_| "an offset that is not a number")?,
        );
        at = end;
    }
    let mut sorted = offsets.clone();
    sorted.sort_unstable();
    sorted.dedup();
    let mut encoded = String::new();
    let mut moved = std::collections::HashMap::new();
    let mut raw_end = 0;
    let beyond = || "raw appended data ends inside a block".to_string();
    for &offset in &sorted {
        if offset > raw.len() {
            return Err(format!(
                "an appended offset of {offset} bytes, past the {} bytes of data",
                raw.len()
            ));
        }
        moved.insert(offset, encoded.len());
        if compressed {
            let blocks = number(offset)?;
            if blocks > raw.len() / header_bytes {
                return Err(beyond());
            }
            let header = header_bytes * (3 + blocks);
            let mut data = 0usize;
            for b in 0..blocks {
                data = data
                    .checked_add(number(offset + header_bytes * (3 + b))?)
                    .ok_or_else(beyond)?;
            }
            let end = offset
                .checked_add(header)
                .and_then(|e| e.checked_add(data))
                .ok_or_else(beyond)?;
            let block = raw.get(offset..end).ok_or_else(beyond)?;
            // A full last block is written as a partial size of 0, which
            // vtkio reads as an empty one: give its full size instead.
            let mut head = block[..header].to_vec();
            if blocks > 0 && number(offset + 2 * header_bytes)? == 0 {
                let full = head[header_bytes..2 * header_bytes].to_vec();
                head[2 * header_bytes..3 * header_bytes].copy_from_slice(&full);
            }
            encoded.push_str(&STANDARD.encode(&head));
            encoded.push_str(&STANDARD.encode(&block[header..]));
            raw_end = raw_end.max(end);
        } else {
            let end = (offset + header_bytes)
                .checked_add(number(offset)?)
                .ok_or_else(beyond)?;
            let block = raw.get(offset..end).ok_or_else(beyond)?;
            encoded.push_str(&STANDARD.encode(block));
            raw_end = raw_end.max(end);
        }
    }
    let mut out = String::with_capacity(xml.len() + encoded.len() + 64);
    let mut at = 0;
    for (found, _) in xml.match_indices(r#"offset=""#) {
        let start = found + r#"offset=""#.len();
        let end = start + xml[start..].find('"').unwrap_or(0);
        let old: usize = xml[start..end].parse().unwrap_or(0);
        out.push_str(&xml[at..start]);
        out.push_str(&moved.get(&old).copied().unwrap_or(old).to_string());
        at = end;
    }
    out.push_str(&xml[at..]);
    out.push_str(&attributes.replace(r#"encoding="raw""#, r#"encoding="base64""#));
    out.push_str(">\n_");
    out.push_str(&encoded);
    let mut rewritten = out.into_bytes();
    rewritten.extend_from_slice(&raw[raw_end.min(raw.len())..]);
    Ok(Some(rewritten))
}

/// Where `needle` first occurs in `bytes` at or after `from`.
fn find(bytes: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    bytes
        .get(from..)?
        .windows(needle.len())
        .position(|w| w == needle)
        .map(|p| from + p)
}

/// Writes `mesh` as VTK XML PolyData through `vtkio` (binary, as vtkio
/// writes it; ParaView and 3D Slicer read it).
pub(super) fn write_vtp(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
    use vtkio::model::{ByteOrder, DataSet, IOBuffer, PolyDataPiece, Version, VertexNumbers, Vtk};
    let points: Vec<f32> = mesh.vertices.iter().flat_map(|v| v.to_array()).collect();
    let connectivity: Vec<u64> = mesh
        .triangles
        .iter()
        .flat_map(|t| t.map(u64::from))
        .collect();
    let offsets: Vec<u64> = (1..=mesh.triangles.len() as u64).map(|k| 3 * k).collect();
    let vtk = Vtk {
        version: Version::Auto,
        byte_order: ByteOrder::LittleEndian,
        title: String::new(),
        file_path: None,
        data: DataSet::inline(PolyDataPiece {
            points: IOBuffer::F32(points),
            polys: Some(VertexNumbers::XML {
                connectivity,
                offsets,
            }),
            ..Default::default()
        }),
    };
    vtk.write_xml(&mut *out)
        .map_err(|e| std::io::Error::other(e.to_string()))
}

/// The triangles of a VTK dataset: the polygons (fanned) and strips of
/// PolyData, or the surface cells of an UnstructuredGrid.
fn surface_of(data: vtkio::model::DataSet) -> Result<SurfaceMesh, String> {
    use vtkio::model::{DataSet, Piece};

    let mut mesh = SurfaceMesh::default();
    match data {
        DataSet::PolyData { pieces, .. } => {
            for piece in pieces {
                let Piece::Inline(piece) = piece else {
                    return Err("VTK pieces stored in other files are not supported".into());
                };
                let offset = append_points(&mut mesh, &piece.points)?;
                if let Some(polygons) = piece.polys {
                    for cell in cells(polygons)? {
                        fan_with_offset(&cell, offset, &mut mesh.triangles)?;
                    }
                }
                if let Some(strips) = piece.strips {
                    for cell in cells(strips)? {
                        strip(&cell, offset, &mut mesh.triangles);
                    }
                }
            }
        }
        DataSet::UnstructuredGrid { pieces, .. } => {
            for piece in pieces {
                let Piece::Inline(piece) = piece else {
                    return Err("VTK pieces stored in other files are not supported".into());
                };
                let offset = append_points(&mut mesh, &piece.points)?;
                let types = piece.cells.types;
                let cells = cells(piece.cells.cell_verts)?;
                if cells.len() != types.len() {
                    return Err(format!(
                        "VTK grid has {} cells but {} cell types",
                        cells.len(),
                        types.len()
                    ));
                }
                append_grid_surface(&cells, &types, offset, &mut mesh.triangles)?;
            }
        }
        _ => {
            return Err(
                "VTK dataset is neither POLYDATA nor UNSTRUCTURED_GRID, so it has no surface"
                    .into(),
            );
        }
    }
    Ok(mesh)
}

/// Appends a VTK point buffer; returns the index of its first point.
fn append_points(mesh: &mut SurfaceMesh, points: &vtkio::model::IOBuffer) -> Result<u32, String> {
    let offset = mesh.vertices.len() as u32;
    let coordinates = points
        .cast_into::<f64>()
        .ok_or("VTK points are not numbers")?;
    if coordinates.len() % 3 != 0 {
        return Err(format!(
            "VTK points: {} coordinates is not a multiple of 3",
            coordinates.len()
        ));
    }
    mesh.vertices.extend(
        coordinates
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)),
    );
    Ok(offset)
}

/// The point lists of VTK cells, from either the legacy `n i1 .. in` layout
/// or offsets + connectivity (legacy files of version 5 and later).
fn cells(numbers: vtkio::model::VertexNumbers) -> Result<Vec<Vec<u32>>, String> {
    use vtkio::model::VertexNumbers;

    let too_short = || "VTK cell list ends in the middle of a cell".to_string();
    match numbers {
        VertexNumbers::Legacy {
            num_cells,
            vertices,
        } => {
            let mut cells = Vec::new();
            let mut rest = &vertices[..];
            for _ in 0..num_cells {
                let (&n, tail) = rest.split_first().ok_or_else(too_short)?;
                let n = n as usize;
                if tail.len() < n {
                    return Err(too_short());
                }
                cells.push(tail[..n].to_vec());
                rest = &tail[n..];
            }
            Ok(cells)
        }
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            let ends = match offsets.split_first() {
                Some((0, ends)) => ends,
                _ => &offsets[..],
            };
            let mut start = 0usize;
            let mut cells = Vec::with_capacity(ends.len());
            for &end in ends {
                let end = usize::try_from(end).map_err(|_| too_short())?;
                let cell = connectivity.get(start..end).ok_or_else(too_short)?;
                let cell = cell
                    .iter()
                    .map(|&i| u32::try_from(i))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|_| "VTK point index does not fit 32 bits".to_string())?;
                cells.push(cell);
                start = end;
            }
            Ok(cells)
        }
    }
}

/// Surface cells of an unstructured grid as triangles; volume, line and
/// point cells are skipped.
fn append_grid_surface(
    cells: &[Vec<u32>],
    types: &[vtkio::model::CellType],
    offset: u32,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<(), String> {
    use vtkio::model::CellType;

    let mut skipped = 0usize;
    for (cell, kind) in cells.iter().zip(types) {
        match kind {
            CellType::Triangle | CellType::Polygon | CellType::Quad => {
                fan_with_offset(cell, offset, triangles)?;
            }
            // A pixel's corners go in lexicographic order, not around it.
            CellType::Pixel => match cell[..] {
                [a, b, c, d] => fan_with_offset(&[a, b, d, c], offset, triangles)?,
                _ => return Err("VTK pixel cell without 4 points".into()),
            },
            CellType::TriangleStrip => strip(cell, offset, triangles),
            _ => skipped += 1,
        }
    }
    if skipped > 0 {
        if triangles.is_empty() {
            return Err(format!(
                "VTK grid has {skipped} cells but none is a triangle, polygon or strip"
            ));
        }
        log::warn!("skipped {skipped} VTK cells that are not surface cells");
    }
    Ok(())
}

fn fan_with_offset(cell: &[u32], offset: u32, triangles: &mut Vec<[u32; 3]>) -> Result<(), String> {
    let shifted: Vec<u32> = cell.iter().map(|&i| i.saturating_add(offset)).collect();
    fan(&shifted, triangles).map_err(|n| format!("VTK polygon with only {n} points"))
}

/// A triangle strip as triangles, every second one reversed so that all
/// share the orientation of the first (VTK's convention).
fn strip(points: &[u32], offset: u32, triangles: &mut Vec<[u32; 3]>) {
    let at = |i: u32| i.saturating_add(offset);
    triangles.extend(points.windows(3).enumerate().map(|(k, w)| {
        if k % 2 == 0 {
            [at(w[0]), at(w[1]), at(w[2])]
        } else {
            [at(w[1]), at(w[0]), at(w[2])]
        }
    }));
}

pub(super) fn write_vtk(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
    writeln!(out, "# vtk DataFile Version 3.0")?;
    writeln!(out, "tissue surface")?;
    writeln!(out, "ASCII")?;
    writeln!(out, "DATASET POLYDATA")?;
    writeln!(out, "POINTS {} float", mesh.vertices.len())?;
    for v in &mesh.vertices {
        writeln!(out, "{} {} {}", v.x, v.y, v.z)?;
    }
    let n = mesh.triangles.len();
    writeln!(out, "POLYGONS {n} {}", 4 * n)?;
    for [a, b, c] in &mesh.triangles {
        writeln!(out, "3 {a} {b} {c}")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]

    use super::*;

    #[test]
    fn strip_keeps_the_orientation_of_its_first_triangle() {
        let mut triangles = Vec::new();
        strip(&[0, 1, 2, 3, 4], 10, &mut triangles);
        assert_eq!(triangles, [[10, 11, 12], [12, 11, 13], [12, 13, 14]]);
    }
}
