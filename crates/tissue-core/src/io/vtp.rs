//! The pieces of an ASCII VTK XML PolyData file that the model file is built
//! from: data arrays and cell sections, written and read. The model's layout
//! on top of them is in `model`.

use std::fmt::{Display, Write as _};
use std::io::{self, Write};
use std::str::FromStr;

use glam::Vec3;
use rayon::prelude::*;

use super::space::Space;
use super::xml::Element;

// ---------------------------------------------------------------------------
// Writing

/// How arrays are written: ASCII (exact decimal), or binary (the
/// little-endian values zlib-compressed in blocks, base64 inline, as VTK
/// writes compressed data: [`compressed`]; for large models).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Encoding {
    Ascii,
    Binary,
}

/// Bytes per block before compression, as VTK writes them.
const BLOCK: usize = 32 * 1024;

/// `bytes` compressed as VTK's zlib compressor does: blocks of [`BLOCK`]
/// bytes, each deflated (level 1: these numbers compress about as well at
/// any level), behind the header `[blocks, BLOCK, last block's size (0 when
/// full), each block's compressed size]` in `UInt64` words.
fn compressed(bytes: &[u8]) -> io::Result<(Vec<u8>, Vec<u8>)> {
    let chunks: Vec<&[u8]> = bytes.chunks(BLOCK).collect();
    let mut header: Vec<u64> = vec![
        chunks.len() as u64,
        BLOCK as u64,
        (bytes.len() % BLOCK) as u64,
    ];
    let mut packed = Vec::with_capacity(bytes.len() / 2);
    for chunk in chunks {
        let before = packed.len();
        let mut zlib = flate2::write::ZlibEncoder::new(&mut packed, flate2::Compression::fast());
        zlib.write_all(chunk)?;
        zlib.finish()?;
        header.push((packed.len() - before) as u64);
    }
    Ok((
        header.iter().flat_map(|w| w.to_le_bytes()).collect(),
        packed,
    ))
}

/// A value as the bytes of VTK type `ty` (little-endian). The writers only
/// ask for a type that holds the value (the model is checked first).
pub(super) trait Encode: Display + Copy + Send + Sync {
    fn encode(self, ty: &str, out: &mut Vec<u8>);
}

macro_rules! encode_as {
    ($($t:ty),*) => {$(
        impl Encode for $t {
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss, clippy::cast_possible_wrap, reason = "the writers' values fit their declared types")]
            fn encode(self, ty: &str, out: &mut Vec<u8>) {
                match ty {
                    "Float32" => out.extend((self as f32).to_le_bytes()),
                    "UInt8" => out.push(self as u8),
                    "Int32" => out.extend((self as i32).to_le_bytes()),
                    _ => out.extend((self as i64).to_le_bytes()),
                }
            }
        }
    )*};
}
encode_as!(f32, u8, u32, i64, u64, usize);

/// A cell section of cells with `size` points each (VTK XML offsets are the
/// end of each cell, without a leading zero).
pub(super) fn write_cells<T: Encode>(
    w: &mut dyn Write,
    encoding: Encoding,
    section: &str,
    size: usize,
    connectivity: impl Iterator<Item = T>,
) -> io::Result<()> {
    writeln!(w, "      <{section}>")?;
    let mut cells = 0;
    let counted = connectivity.inspect(|_| cells += 1);
    // One cell a line, except for vertex cells.
    let per_line = if size > 1 { size } else { 12 };
    // Binary cells as Int32, half the bytes: the writers refuse models
    // with more points than that holds.
    let ty = match encoding {
        Encoding::Ascii => "Int64",
        Encoding::Binary => "Int32",
    };
    write_values(w, encoding, ty, "connectivity", 1, per_line, counted)?;
    let cells = cells / size;
    write_array(w, encoding, ty, "offsets", 1, (1..=cells).map(|c| c * size))?;
    writeln!(w, "      </{section}>")
}

/// 3D Slicer's coordinate-system tag, a field-data string array `SPACE`
/// holding `LPS` or `RAS`, as VTK writes a string array in ASCII: each
/// character's code, then 0. Slicer loads a model so tagged in that system
/// without asking or mirroring it.
pub(super) fn write_space_array(w: &mut dyn Write, space: Space) -> io::Result<()> {
    let codes: Vec<String> = space
        .name()
        .bytes()
        .chain([0])
        .map(|b| b.to_string())
        .collect();
    writeln!(
        w,
        r#"      <Array type="String" Name="SPACE" NumberOfTuples="1" format="ascii">{}</Array>"#,
        codes.join(" ")
    )
}

/// One `DataArray`; in ASCII one tuple per line for vectors and a dozen
/// values a line for scalars.
pub(super) fn write_array<T: Encode>(
    w: &mut dyn Write,
    encoding: Encoding,
    ty: &str,
    name: &str,
    components: usize,
    values: impl Iterator<Item = T>,
) -> io::Result<()> {
    let per_line = if components > 1 { components } else { 12 };
    write_values(w, encoding, ty, name, components, per_line, values)
}

/// One `DataArray`, in ASCII with `per_line` values a line. `{}` is Rust's
/// shortest round-trip formatting, so floats read back bit-exactly; binary
/// values are the values' own bits.
fn write_values<T: Encode>(
    w: &mut dyn Write,
    encoding: Encoding,
    ty: &str,
    name: &str,
    components: usize,
    per_line: usize,
    values: impl Iterator<Item = T>,
) -> io::Result<()> {
    use base64::Engine as _;

    write!(w, r#"        <DataArray type="{ty}" Name="{name}""#)?;
    if components > 1 {
        write!(w, r#" NumberOfComponents="{components}""#)?;
    }
    if encoding == Encoding::Binary {
        let mut bytes = Vec::new();
        for value in values {
            value.encode(ty, &mut bytes);
        }
        let (header, blocks) = compressed(&bytes)?;
        let engine = &base64::engine::general_purpose::STANDARD;
        return writeln!(
            w,
            " format=\"binary\">\n          {}{}\n        </DataArray>",
            engine.encode(header),
            engine.encode(blocks)
        );
    }
    write!(w, r#" format="ascii">"#)?;
    // Formatted in blocks of whole lines on every thread (the decimal
    // formatting is most of a large model's writing), then written in
    // order: the same text as one value after the other.
    let values: Vec<T> = values.collect();
    let blocks: Vec<String> = values
        .par_chunks(per_line * LINES_PER_BLOCK)
        .map(|block| {
            let mut text = String::with_capacity(12 * block.len());
            for (k, value) in block.iter().enumerate() {
                let gap = if k % per_line == 0 {
                    "\n          "
                } else {
                    " "
                };
                // Writing into a `String` cannot fail.
                let _ = write!(text, "{gap}{value}");
            }
            text
        })
        .collect();
    for block in blocks {
        w.write_all(block.as_bytes())?;
    }
    writeln!(w, "\n        </DataArray>")
}

/// Lines of an ASCII array formatted together ([`write_values`]).
const LINES_PER_BLOCK: usize = 512;

// ---------------------------------------------------------------------------
// Reading

/// The numbers of an ASCII `DataArray`: exactly `tuples` tuples of
/// `components` values, each parsed as `T`.
pub(super) fn values<T: FromStr>(
    array: &Element,
    what: &str,
    components: usize,
    tuples: usize,
) -> Result<Vec<T>, String> {
    match array.attribute("format") {
        None | Some("ascii") => {}
        Some(other) => {
            return Err(format!(
                "{what} is stored as format=\"{other}\"; tissue reads only ASCII arrays \
                 (to re-save from ParaView, choose Data Mode \"Ascii\")"
            ));
        }
    }
    let declared = array.attribute("NumberOfComponents").unwrap_or("1");
    if declared.trim().parse::<usize>().ok() != Some(components) {
        return Err(format!(
            "{what} has NumberOfComponents=\"{declared}\", expected {components}"
        ));
    }
    let expected = components
        .checked_mul(tuples)
        .ok_or_else(|| format!("{what}: {tuples} tuples is beyond any real file"))?;
    let mut out = Vec::with_capacity(expected.min(1 << 24));
    for (k, token) in array.text.split_ascii_whitespace().enumerate() {
        if k == expected {
            return Err(format!(
                "{what} has more than the {expected} values expected ({tuples} × {components})"
            ));
        }
        let value = token
            .parse()
            .map_err(|_| format!("{what}: value {k} (`{token}`) is not a valid number"))?;
        out.push(value);
    }
    if out.len() != expected {
        return Err(format!(
            "{what} has {} values, expected {expected} ({tuples} × {components})",
            out.len()
        ));
    }
    Ok(out)
}

/// A non-negative count attribute of the piece, if present.
pub(super) fn count_attribute(piece: &Element, key: &str) -> Result<Option<usize>, String> {
    piece
        .attribute(key)
        .map(|s| {
            s.trim()
                .parse()
                .map_err(|_| format!("the piece's {key}=\"{s}\" is not a count"))
        })
        .transpose()
}

/// The points of the piece, `NumberOfPoints` of them.
pub(super) fn piece_points(piece: &Element) -> Result<Vec<Vec3>, String> {
    let n = count_attribute(piece, "NumberOfPoints")?
        .ok_or("the piece's NumberOfPoints attribute is missing")?;
    let array = piece
        .child("Points")
        .and_then(|p| p.child("DataArray"))
        .ok_or("the <Points> array is missing")?;
    let flat: Vec<f32> = values(array, "Points", 3, n)?;
    Ok(flat
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect())
}

/// The piece's `section` element (`Verts`, `Lines`, `Polys`, `Strips`) and
/// its declared count (`NumberOf<section>`, if given); `None` when the
/// piece has no such element and declares none, an error when it declares
/// cells but has no element.
pub(super) fn cell_section<'a>(
    piece: &'a Element,
    section: &str,
) -> Result<Option<(&'a Element, Option<usize>)>, String> {
    let attribute = format!("NumberOf{section}");
    let declared = count_attribute(piece, &attribute)?;
    match piece.child(section) {
        Some(element) => Ok(Some((element, declared))),
        None => match declared {
            Some(d) if d > 0 => Err(format!(
                "{attribute}=\"{d}\" but there is no <{section}> element"
            )),
            _ => Ok(None),
        },
    }
}

/// Cells of `section` (`Verts`, `Lines`, `Polys`), each with exactly `K`
/// points, all indices below `points`.
pub(super) fn piece_cells<const K: usize>(
    piece: &Element,
    section: &str,
    points: usize,
) -> Result<Vec<[u32; K]>, String> {
    let Some((element, declared)) = cell_section(piece, section)? else {
        return Ok(Vec::new());
    };
    let what = |name: &str| format!("{section} {name}");
    let offsets_array = element
        .data_array("offsets")
        .ok_or_else(|| format!("the {} array is missing", what("offsets")))?;
    let cells = match declared {
        Some(d) => d,
        None => offsets_array.text.split_ascii_whitespace().count(),
    };
    let offsets: Vec<i64> = values(offsets_array, &what("offsets"), 1, cells)?;
    let connectivity_array = element
        .data_array("connectivity")
        .ok_or_else(|| format!("the {} array is missing", what("connectivity")))?;
    let corners = cells
        .checked_mul(K)
        .ok_or_else(|| format!("NumberOf{section}=\"{cells}\" is beyond any real file"))?;
    let connectivity: Vec<i64> = values(connectivity_array, &what("connectivity"), 1, corners)?;
    let kind = match section {
        "Verts" => "vertex",
        "Lines" => "line",
        _ => "polygon",
    };
    let mut out = Vec::with_capacity(cells);
    for (c, &offset) in offsets.iter().enumerate() {
        if offset != ((c + 1) * K) as i64 {
            return Err(format!(
                "{kind} cell {c} does not have {K} points (offset {offset}); \
                 a tissue model has only {kind} cells of {K} points"
            ));
        }
        let mut cell = [0_u32; K];
        for (slot, &index) in cell.iter_mut().zip(&connectivity[c * K..(c + 1) * K]) {
            *slot = u32::try_from(index)
                .ok()
                .filter(|&i| (i as usize) < points)
                .ok_or_else(|| format!("{kind} cell {c} refers to point {index} of {points}"))?;
        }
        out.push(cell);
    }
    Ok(out)
}

/// The `FieldData` array `name`, if present.
pub(super) fn field_array<'a>(poly_data: &'a Element, name: &str) -> Option<&'a Element> {
    poly_data.child("FieldData")?.data_array(name)
}

/// The single integer in field-data array `array`.
pub(super) fn field_integer(array: &Element, name: &str) -> Result<i64, String> {
    let value: Vec<i64> = values(array, &format!("`{name}`"), 1, 1)?;
    Ok(value[0])
}

/// The `PointData` array `name`: `n` tuples of `components` values.
pub(super) fn point_array<T: FromStr>(
    point_data: &Element,
    name: &str,
    components: usize,
    n: usize,
) -> Result<Vec<T>, String> {
    let array = point_data
        .data_array(name)
        .ok_or_else(|| format!("the PointData array `{name}` is missing"))?;
    values(array, &format!("`{name}`"), components, n)
}
