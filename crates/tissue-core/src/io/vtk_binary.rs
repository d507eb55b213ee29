//! VTK XML's binary data arrays, decoded for the model reader: a file
//! re-saved by ParaView with its default settings stores every array as
//! `format="appended"` (raw bytes after `<AppendedData>`, often compressed)
//! or `format="binary"` (base64 inside the element). [`to_ascii`] rewrites
//! each such array of a parsed file as the ASCII numbers it holds, so that
//! the reader's layout checks (`vtp`, `model`) see one form.
//!
//! The encoding, as VTK's `vtkXMLWriter` writes it and its file-format
//! documentation describes it: each array is a block that starts with a
//! header of `header_type` words (`UInt32` unless the file says `UInt64`),
//! in the file's `byte_order`. Uncompressed, the header is one word, the
//! byte count, followed by the bytes; base64 encodes header and bytes as
//! one stream. Compressed (`compressor` on `<VTKFile>`), the header is the
//! number of blocks, the block size before compression, the size of the
//! last block before compression (0 when it is full) and each block's
//! compressed size, then the blocks; base64 encodes the header and the
//! blocks as two streams, each padded. Raw appended data is turned into
//! base64 before parsing ([`super::surface::raw_appended_as_base64`]), so
//! here every block is base64 text.

use std::io::Read;

use base64::Engine as _;
use base64::engine::{GeneralPurpose, GeneralPurposeConfig};

use super::xml::Element;

/// Base64 as VTK writes it: padded, and tolerant of the trailing bits some
/// writers leave.
const BASE64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_allow_trailing_bits(true),
);

/// The compressors VTK writes with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Compressor {
    Zlib,
    Lz4,
    Lzma,
}

/// How the file's blocks are laid out (attributes of `<VTKFile>`).
#[derive(Debug, Clone, Copy)]
struct Layout {
    /// Bytes in a header word: 4 or 8.
    word: usize,
    big_endian: bool,
    compressor: Option<Compressor>,
}

impl Layout {
    fn of(root: &Element) -> Result<Self, String> {
        let word = match root.attribute("header_type") {
            None | Some("UInt32") => 4,
            Some("UInt64") => 8,
            Some(other) => return Err(format!("header_type=\"{other}\" is not UInt32 or UInt64")),
        };
        let big_endian = match root.attribute("byte_order") {
            None | Some("LittleEndian") => false,
            Some("BigEndian") => true,
            Some(other) => return Err(format!("byte_order=\"{other}\" is not known")),
        };
        let compressor = match root.attribute("compressor") {
            None | Some("") => None,
            Some("vtkZLibDataCompressor") => Some(Compressor::Zlib),
            Some("vtkLZ4DataCompressor") => Some(Compressor::Lz4),
            Some("vtkLZMADataCompressor") => Some(Compressor::Lzma),
            Some(other) => return Err(format!("compressor=\"{other}\" is not one VTK writes")),
        };
        Ok(Self {
            word,
            big_endian,
            compressor,
        })
    }

    /// Header word `k` of `bytes`.
    fn number(&self, bytes: &[u8], k: usize) -> Result<usize, String> {
        let at = k * self.word;
        let word = bytes
            .get(at..at + self.word)
            .ok_or("the data ends inside a block header")?;
        let mut eight = [0u8; 8];
        let value = if self.big_endian {
            eight[8 - self.word..].copy_from_slice(word);
            u64::from_be_bytes(eight)
        } else {
            eight[..self.word].copy_from_slice(word);
            u64::from_le_bytes(eight)
        };
        usize::try_from(value).map_err(|_| format!("a block size of {value} bytes"))
    }
}

/// Base64 characters that encode `bytes` bytes, padding included.
fn encoded_len(bytes: usize) -> usize {
    bytes.div_ceil(3) * 4
}

fn decode(text: &str) -> Result<Vec<u8>, String> {
    BASE64
        .decode(text)
        .map_err(|e| format!("its base64 data is not valid ({e})"))
}

/// The first `chars` characters of `text`, or an error saying it is shorter.
fn prefix(text: &str, chars: usize) -> Result<&str, String> {
    text.get(..chars).ok_or_else(|| {
        format!(
            "its data ends early ({} base64 characters, {chars} expected)",
            text.len()
        )
    })
}

/// The bytes of the block at the start of `text` (base64), decompressed.
fn block(text: &str, layout: &Layout) -> Result<Vec<u8>, String> {
    let word = layout.word;
    let first = decode(prefix(text, encoded_len(word).min(text.len()))?)?;
    let count = layout.number(&first, 0)?;
    let Some(compressor) = layout.compressor else {
        let total = word
            .checked_add(count)
            .filter(|&t| encoded_len(t) <= text.len())
            .ok_or_else(|| format!("it says {count} bytes, more than its data holds"))?;
        let bytes = match decode(prefix(text, encoded_len(total))?) {
            Ok(stream) => stream.get(word..total).map(<[u8]>::to_vec),
            // Header and bytes encoded as two streams, as some writers do.
            Err(_) => {
                let rest = text.get(encoded_len(word)..).unwrap_or_default();
                let data = decode(prefix(rest, encoded_len(count))?)?;
                data.get(..count).map(<[u8]>::to_vec)
            }
        };
        return bytes.ok_or_else(|| format!("its data holds fewer than the {count} bytes it says"));
    };
    let blocks = count;
    let header_bytes = blocks
        .checked_add(3)
        .and_then(|w| w.checked_mul(word))
        .filter(|&h| encoded_len(h) <= text.len())
        .ok_or_else(|| format!("it says {blocks} compressed blocks, more than its data holds"))?;
    let header_chars = encoded_len(header_bytes);
    let header = decode(prefix(text, header_chars)?)?;
    let full = layout.number(&header, 1)?;
    let last = match layout.number(&header, 2)? {
        0 => full,
        partial => partial,
    };
    let mut sizes = Vec::with_capacity(blocks);
    for b in 0..blocks {
        sizes.push(layout.number(&header, 3 + b)?);
    }
    let compressed: usize = sizes.iter().sum();
    let data = decode(prefix(&text[header_chars..], encoded_len(compressed))?)?;
    let mut out = Vec::with_capacity(full.saturating_mul(blocks).min(1032 * compressed + 64));
    let mut at = 0;
    for (b, &size) in sizes.iter().enumerate() {
        let expected = if b + 1 == blocks { last } else { full };
        let input = data
            .get(at..at + size)
            .ok_or("its compressed blocks end early")?;
        at += size;
        // No compressor makes more than this of a byte (zlib's deflate at
        // most 1032, LZ4 255): a header that says more describes no block
        // VTK wrote, and is refused before it is inflated.
        let most = match compressor {
            Compressor::Zlib => 1032,
            Compressor::Lz4 => 255,
            Compressor::Lzma => 8192,
        };
        if expected > most * size + 64 {
            return Err(format!(
                "compressed block {b} is {size} bytes but its header says it holds {expected}, \
                 more than the compressor can make of it"
            ));
        }
        let before = out.len();
        match compressor {
            Compressor::Zlib => {
                flate2::read::ZlibDecoder::new(input)
                    .take(expected as u64)
                    .read_to_end(&mut out)
                    .map_err(|e| format!("compressed block {b} does not inflate ({e})"))?;
            }
            Compressor::Lz4 => out.extend(
                lz4_flex::block::decompress(input, expected)
                    .map_err(|e| format!("LZ4 block {b} does not decompress ({e})"))?,
            ),
            Compressor::Lzma => {
                // VTK's LZMA blocks are .xz streams; decoded into a writer
                // that takes no more than the header says.
                let mut bounded = Bounded {
                    out: &mut out,
                    left: expected,
                };
                lzma_rs::xz_decompress(&mut std::io::BufReader::new(input), &mut bounded)
                    .map_err(|e| format!("LZMA block {b} does not decompress ({e})"))?;
            }
        }
        if out.len() - before != expected {
            return Err(format!(
                "compressed block {b} holds {} bytes, its header says {expected}",
                out.len() - before
            ));
        }
    }
    Ok(out)
}

/// A writer onto `out` that takes at most `left` more bytes: a block that
/// decompresses to more than its header says fails instead of growing.
struct Bounded<'a> {
    out: &'a mut Vec<u8>,
    left: usize,
}

impl std::io::Write for Bounded<'_> {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        if bytes.len() > self.left {
            return Err(std::io::Error::other(
                "it holds more bytes than its header says",
            ));
        }
        self.left -= bytes.len();
        self.out.extend_from_slice(bytes);
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// `bytes` as the ASCII numbers of VTK type `ty`, space-separated.
fn numbers(bytes: &[u8], ty: &str, big_endian: bool) -> Result<String, String> {
    macro_rules! each {
        ($t:ty) => {{
            const SIZE: usize = std::mem::size_of::<$t>();
            if !bytes.len().is_multiple_of(SIZE) {
                return Err(format!(
                    "{} bytes is not a whole number of {ty} values",
                    bytes.len()
                ));
            }
            let mut text = String::with_capacity(bytes.len() * 3);
            for chunk in bytes.chunks_exact(SIZE) {
                let mut raw = [0u8; SIZE];
                raw.copy_from_slice(chunk);
                let value = if big_endian {
                    <$t>::from_be_bytes(raw)
                } else {
                    <$t>::from_le_bytes(raw)
                };
                text.push_str(&value.to_string());
                text.push(' ');
            }
            text
        }};
    }
    Ok(match ty {
        "Int8" => each!(i8),
        "UInt8" | "String" => each!(u8),
        "Int16" => each!(i16),
        "UInt16" => each!(u16),
        "Int32" => each!(i32),
        "UInt32" => each!(u32),
        "Int64" => each!(i64),
        "UInt64" => each!(u64),
        "Float32" => each!(f32),
        "Float64" => each!(f64),
        other => return Err(format!("type=\"{other}\" is not a VTK number type")),
    })
}

/// Rewrites every binary or appended `DataArray` under `root` (a
/// `<VTKFile>`) as ASCII; a file without any is left as it is. Errors name
/// the array.
pub(super) fn to_ascii(root: &mut Element) -> Result<(), String> {
    let layout = Layout::of(root)?;
    let appended: Option<String> = root.child("AppendedData").map(|data| {
        let text = data.text.trim();
        text.strip_prefix('_').unwrap_or(text).trim_end().to_owned()
    });
    if let Some(encoding) = root
        .child("AppendedData")
        .and_then(|d| d.attribute("encoding"))
        .filter(|&e| e != "base64")
    {
        return Err(format!(
            "its <AppendedData> is encoded as \"{encoding}\"; VTK writes raw or base64"
        ));
    }
    root.visit_mut(&mut |element| {
        // `Array` holds strings (3D Slicer's `SPACE` tag): decoded as the
        // bytes' codes, as VTK writes a string array in ASCII.
        if element.name != "DataArray" && element.name != "Array" {
            return Ok(());
        }
        let name = element.attribute("Name").unwrap_or("").to_owned();
        let what = |problem: String| format!("the array `{name}`: {problem}");
        let bytes = match element.attribute("format") {
            None | Some("ascii") => return Ok(()),
            Some("binary") => {
                let text: String = element
                    .text
                    .chars()
                    .filter(|c| !c.is_ascii_whitespace())
                    .collect();
                block(&text, &layout).map_err(what)?
            }
            Some("appended") => {
                let data = appended.as_deref().ok_or_else(|| {
                    what("it is appended, but the file has no <AppendedData>".into())
                })?;
                let offset: usize = element
                    .attribute("offset")
                    .and_then(|o| o.trim().parse().ok())
                    .ok_or_else(|| what("it is appended without a valid offset".into()))?;
                let text = data.get(offset..).ok_or_else(|| {
                    what(format!("its offset {offset} is past the appended data"))
                })?;
                block(text, &layout).map_err(what)?
            }
            Some(other) => {
                return Err(what(format!(
                    "format=\"{other}\" is not ascii, binary or appended"
                )));
            }
        };
        let ty = element.attribute("type").unwrap_or("").to_owned();
        element.text = numbers(&bytes, &ty, layout.big_endian).map_err(what)?;
        element.set_attribute("format", "ascii");
        Ok(())
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests")]
mod tests {
    use super::*;
    use crate::io::xml::parse_xml;

    /// One array of three Float32, base64 inline, uncompressed, UInt32
    /// header: 12 bytes of data after a header saying 12.
    #[test]
    fn an_inline_binary_array_reads_as_its_numbers() {
        let mut bytes = 12u32.to_le_bytes().to_vec();
        for v in [1.5f32, -2.0, 0.1] {
            bytes.extend(v.to_le_bytes());
        }
        let text = format!(
            r#"<VTKFile type="PolyData" byte_order="LittleEndian"><DataArray type="Float32" Name="x" format="binary">{}</DataArray></VTKFile>"#,
            BASE64.encode(&bytes)
        );
        let mut root = parse_xml(&text).unwrap();
        to_ascii(&mut root).unwrap();
        let array = root.child("DataArray").unwrap();
        assert_eq!(array.attribute("format"), Some("ascii"));
        let values: Vec<f32> = array
            .text
            .split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(values, [1.5, -2.0, 0.1]);
    }

    /// A header that claims more bytes than there are, and base64 that is
    /// not, are refused naming the array.
    #[test]
    fn damaged_blocks_are_refused_naming_the_array() {
        let claims = |count: u32| {
            let mut bytes = count.to_le_bytes().to_vec();
            bytes.extend(1.0f32.to_le_bytes());
            format!(
                r#"<VTKFile><DataArray type="Float32" Name="radius" format="binary">{}</DataArray></VTKFile>"#,
                BASE64.encode(&bytes)
            )
        };
        for (text, expected) in [
            (claims(400), "more than its data holds"),
            (claims(3), "not a whole number of Float32"),
            (
                r#"<VTKFile><DataArray type="Float32" Name="radius" format="binary">0.5 0.5</DataArray></VTKFile>"#
                    .to_owned(),
                "base64",
            ),
            (
                r#"<VTKFile><DataArray type="Float32" Name="radius" format="appended" offset="0"/></VTKFile>"#
                    .to_owned(),
                "no <AppendedData>",
            ),
        ] {
            let mut root = parse_xml(&text).unwrap();
            let err = to_ascii(&mut root).unwrap_err();
            assert!(
                err.contains("`radius`") && err.contains(expected),
                "{err}"
            );
        }
    }
}
