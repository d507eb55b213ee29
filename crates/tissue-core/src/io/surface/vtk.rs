//! Legacy VTK: PolyData (`POLYGONS`, `TRIANGLE_STRIPS`) or the surface
//! cells of an UnstructuredGrid, ASCII or binary, read through `vtkio`;
//! written as legacy ASCII PolyData. VTK XML PolyData (`.vtp`): read with
//! the model reader's XML tree and block decoder, written through `vtkio`.

use std::io::{Cursor, Write};

use glam::Vec3;

use super::fan;
use crate::io::space::Space;
use crate::mesh::SurfaceMesh;

pub(super) fn read_vtk(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    legacy_header(bytes)?;
    let vtk = guarded(|| {
        vtkio::Vtk::parse_legacy_be(Cursor::new(bytes)).map_err(|e| {
            // vtkio's parser says only where its grammar failed ("Parse
            // error: Digit"); say what in the file does not add up.
            match legacy_counts(bytes) {
                Some(defect) => format!("cannot read legacy VTK: {defect}"),
                None => format!(
                    "cannot read legacy VTK ({e}): a section's data does not match its \
                     header (a count larger than the values that follow, a value that is \
                     not a number, or a file cut short)"
                ),
            }
        })
    })?;
    surface_of(vtk.data)
}

/// The first lines of a legacy VTK file checked, each defect named: the
/// `# vtk DataFile Version` line, the title, `ASCII` or `BINARY`, and a
/// `DATASET` that can hold a surface.
fn legacy_header(bytes: &[u8]) -> Result<(), String> {
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(4096)]);
    let mut lines = head.lines();
    let first = lines.next().unwrap_or_default().trim();
    if !first.starts_with("# vtk DataFile Version") {
        return Err(format!(
            "not a legacy VTK file: its first line is `{}`, not `# vtk DataFile Version N.N`",
            first.chars().take(60).collect::<String>()
        ));
    }
    let _title = lines.next();
    let format = lines.next().unwrap_or_default().trim();
    if !format.eq_ignore_ascii_case("ASCII") && !format.eq_ignore_ascii_case("BINARY") {
        return Err(format!(
            "the third line of a legacy VTK file says ASCII or BINARY, not `{}`",
            format.chars().take(60).collect::<String>()
        ));
    }
    let dataset = lines
        .map(str::trim)
        .find(|l| !l.is_empty())
        .unwrap_or_default();
    let kind = dataset.strip_prefix("DATASET").map(str::trim);
    match kind {
        Some(k)
            if k.eq_ignore_ascii_case("POLYDATA")
                || k.eq_ignore_ascii_case("UNSTRUCTURED_GRID") =>
        {
            Ok(())
        }
        Some(k) => Err(format!(
            "a legacy VTK DATASET {k}, which holds no surface (POLYDATA or UNSTRUCTURED_GRID do)"
        )),
        None => Err(format!(
            "the line after ASCII or BINARY is `{}`, not `DATASET POLYDATA`",
            dataset.chars().take(60).collect::<String>()
        )),
    }
}

/// For an ASCII legacy file that vtkio could not parse: the first section
/// (`POINTS`, `POLYGONS`, `TRIANGLE_STRIPS`, `CELLS`) whose values are fewer
/// than its header announces, or one that is not a number; `None` when
/// the counts add up (or the file is binary).
fn legacy_counts(bytes: &[u8]) -> Option<String> {
    let text = std::str::from_utf8(bytes).ok()?;
    let mut lines = text.lines().skip(2);
    if !lines.next()?.trim().eq_ignore_ascii_case("ASCII") {
        return None;
    }
    let tokens: Vec<&str> = lines.flat_map(str::split_ascii_whitespace).collect();
    for (k, token) in tokens.iter().enumerate() {
        let (expected, what) = match token.to_ascii_uppercase().as_str() {
            "POINTS" => {
                let n: usize = tokens.get(k + 1)?.parse().ok()?;
                let values = n.checked_mul(3)?;
                (
                    values,
                    format!("POINTS announces {n} points ({values} values)"),
                )
            }
            "POLYGONS" | "TRIANGLE_STRIPS" | "CELLS" | "VERTICES" | "LINES" => {
                let size: usize = tokens.get(k + 2)?.parse().ok()?;
                // Version 5 files follow with OFFSETS and CONNECTIVITY.
                if tokens
                    .get(k + 3)
                    .is_some_and(|t| t.eq_ignore_ascii_case("OFFSETS"))
                {
                    continue;
                }
                (size, format!("{token} announces {size} values"))
            }
            _ => continue,
        };
        // After the keyword and its two numbers (`POINTS n type`,
        // `POLYGONS n size`).
        let values = &tokens[(k + 3).min(tokens.len())..];
        let mut found = 0;
        for value in values.iter().take(expected) {
            if value.parse::<f64>().is_err() {
                // The next section's keyword: the values ran out.
                if value.chars().all(|c| c.is_ascii_uppercase() || c == '_') {
                    return Some(format!("{what}, but only {found} follow before `{value}`"));
                }
                return Some(format!(
                    "{what}, but value {} of them is `{value}`, not a number",
                    found + 1
                ));
            }
            found += 1;
        }
        if found < expected {
            return Some(format!(
                "{what}, but only {found} follow: the file is cut short"
            ));
        }
    }
    None
}

/// Runs a `vtkio` parse, turning a panic inside it into an error: it
/// unwraps on some damaged files (a data array shorter than its count).
/// The panic is silent ([`crate::io::catch_quietly`]): no `panicked at`
/// line (or backtrace) reaches the user beside the error that says what is
/// wrong.
fn guarded<T>(parse: impl FnOnce() -> Result<T, String>) -> Result<T, String> {
    crate::io::catch_quietly(parse).unwrap_or_else(|_| {
        Err(
            "the VTK reader failed on this file: it is damaged, or an array is shorter \
             than its count"
                .into(),
        )
    })
}

/// VTK XML PolyData (`.vtp`, 3D Slicer's model format, VTK's, pyvista's
/// and ParaView's): inline ASCII or base64 binary, appended raw or base64,
/// uncompressed or zlib, LZ4 or LZMA in blocks; the polygons (fanned) and
/// triangle strips of every piece. Read through the model reader's XML tree
/// and block decoder (`io::vtk_binary`), which reads every layout VTK
/// writes, the empty compressed arrays of its empty `Verts`, `Lines` and
/// `Strips` included.
pub(super) fn read_vtp(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    use crate::io::vtp::piece_points;

    let converted = raw_appended_as_base64(bytes)?;
    let bytes = converted.as_deref().unwrap_or(bytes);
    let text = std::str::from_utf8(bytes).map_err(|e| {
        format!(
            "not a VTK XML file: invalid UTF-8 at byte {}",
            e.valid_up_to()
        )
    })?;
    if text.trim().is_empty() {
        return Err("the file is empty".into());
    }
    let mut root = crate::io::xml::parse_xml(text)?;
    if root.name != "VTKFile" {
        return Err(format!(
            "not a VTK XML file: its root element is <{}>, not <VTKFile>",
            root.name
        ));
    }
    match root.attribute("type") {
        Some("PolyData") => {}
        other => {
            return Err(format!(
                "a VTK XML file of type \"{}\", not PolyData (.vtp holds a surface as PolyData)",
                other.unwrap_or("")
            ));
        }
    }
    crate::io::vtk_binary::to_ascii(&mut root)?;
    let poly_data = root
        .child("PolyData")
        .ok_or("the <PolyData> element is missing")?;
    let mut mesh = SurfaceMesh::default();
    for (k, piece) in poly_data.children_named("Piece").enumerate() {
        let in_piece = |e: String| format!("piece {k}: {e}");
        let offset =
            u32::try_from(mesh.vertices.len()).map_err(|_| "more than 2^32 points".to_string())?;
        let points = piece_points(piece).map_err(in_piece)?;
        let count = points.len();
        mesh.vertices.extend(points);
        for cell in xml_cells(piece, "Polys", count).map_err(in_piece)? {
            fan_with_offset(&cell, offset, &mut mesh.triangles).map_err(in_piece)?;
        }
        for cell in xml_cells(piece, "Strips", count).map_err(in_piece)? {
            strip(&cell, offset, &mut mesh.triangles);
        }
    }
    Ok(mesh)
}

/// The cells of a piece's `section` (`Polys`, `Strips`) as point lists, from
/// its `offsets` (each cell's end) and `connectivity`, every index below
/// `points`; none when the section is absent or declared empty.
fn xml_cells(
    piece: &crate::io::xml::Element,
    section: &str,
    points: usize,
) -> Result<Vec<Vec<u32>>, String> {
    use crate::io::vtp::{cell_section, values};

    let Some((element, declared)) = cell_section(piece, section)? else {
        return Ok(Vec::new());
    };
    if declared == Some(0) {
        return Ok(Vec::new());
    }
    let offsets_array = element
        .data_array("offsets")
        .ok_or_else(|| format!("the {section} offsets array is missing"))?;
    let cells = match declared {
        Some(d) => d,
        None => offsets_array.text.split_ascii_whitespace().count(),
    };
    let ends: Vec<i64> = values(offsets_array, &format!("{section} offsets"), 1, cells)?;
    let total = ends.last().copied().unwrap_or(0);
    let total = usize::try_from(total)
        .map_err(|_| format!("{section} offsets end at {total}, not a count"))?;
    let connectivity_array = element
        .data_array("connectivity")
        .ok_or_else(|| format!("the {section} connectivity array is missing"))?;
    let connectivity: Vec<i64> = values(
        connectivity_array,
        &format!("{section} connectivity"),
        1,
        total,
    )?;
    let mut out = Vec::with_capacity(cells);
    let mut start = 0usize;
    for (c, &end) in ends.iter().enumerate() {
        let end = usize::try_from(end)
            .ok()
            .filter(|&e| e >= start && e <= total)
            .ok_or_else(|| {
                format!("{section} cell {c} ends at offset {end}, before its start {start}")
            })?;
        let cell = connectivity[start..end]
            .iter()
            .map(|&i| {
                u32::try_from(i)
                    .ok()
                    .filter(|&i| (i as usize) < points)
                    .ok_or_else(|| format!("{section} cell {c} names point {i} of {points}"))
            })
            .collect::<Result<Vec<u32>, String>>()?;
        out.push(cell);
        start = end;
    }
    Ok(out)
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

/// Writes `mesh` as VTK XML PolyData: the points as `Float32` and the
/// triangles as `Polys`, zlib-compressed in blocks (base64 inline, as the
/// model file's binary arrays: `io::vtp`); with `tag`, the `SPACE`
/// field-data string 3D Slicer tags its models with (`LPS` or `RAS`).
pub(super) fn write_vtp(
    mesh: &SurfaceMesh,
    tag: Option<Space>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    use crate::io::vtp::{Encoding, write_array, write_cells, write_space_array};

    // Binary cells are Int32 (`write_cells`).
    if i32::try_from(mesh.vertices.len()).is_err() {
        return Err(std::io::Error::other(format!(
            "{} vertices are more than a .vtp surface's Int32 cells can name",
            mesh.vertices.len()
        )));
    }
    let w: &mut dyn Write = out;
    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(
        w,
        r#"<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64" compressor="vtkZLibDataCompressor">"#
    )?;
    writeln!(w, "  <PolyData>")?;
    if let Some(space) = tag {
        writeln!(w, "    <FieldData>")?;
        write_space_array(w, space)?;
        writeln!(w, "    </FieldData>")?;
    }
    writeln!(
        w,
        r#"    <Piece NumberOfPoints="{}" NumberOfPolys="{}">"#,
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    writeln!(w, "      <Points>")?;
    let points = mesh.vertices.iter().flat_map(|p| p.to_array());
    write_array(w, Encoding::Binary, "Float32", "Points", 3, points)?;
    writeln!(w, "      </Points>")?;
    let corners = mesh.triangles.iter().flatten().map(|&c| u64::from(c));
    write_cells(w, Encoding::Binary, "Polys", 3, corners)?;
    writeln!(w, "    </Piece>")?;
    writeln!(w, "  </PolyData>")?;
    writeln!(w, "</VTKFile>")
}

/// The coordinate system a `.vtp` names in its `SPACE` field-data string
/// (3D Slicer's tag), `None` when it has none or cannot be read.
pub(super) fn vtp_space(bytes: &[u8]) -> Option<Space> {
    let converted = raw_appended_as_base64(bytes).ok()?;
    let text = std::str::from_utf8(converted.as_deref().unwrap_or(bytes)).ok()?;
    let mut root = crate::io::xml::parse_xml(text).ok()?;
    crate::io::vtk_binary::to_ascii(&mut root).ok()?;
    let array = root
        .child("PolyData")?
        .child("FieldData")?
        .children_named("Array")
        .find(|a| a.attribute("Name") == Some("SPACE"))?;
    let codes: Vec<u8> = array
        .text
        .split_ascii_whitespace()
        .map_while(|t| t.parse().ok())
        .take_while(|&b| b != 0)
        .collect();
    match std::str::from_utf8(&codes).ok()? {
        value if value.contains("RAS") => Some(Space::Ras),
        value if value.contains("LPS") => Some(Space::Lps),
        _ => None,
    }
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

/// Legacy ASCII PolyData; with `tag`, the title line (the second) says
/// `SPACE=LPS` or `SPACE=RAS`, where 3D Slicer writes and reads it.
pub(super) fn write_vtk(
    mesh: &SurfaceMesh,
    tag: Option<Space>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    writeln!(out, "# vtk DataFile Version 3.0")?;
    match tag {
        Some(space) => writeln!(out, "tissue surface SPACE={space}")?,
        None => writeln!(out, "tissue surface")?,
    }
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
