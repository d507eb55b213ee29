//! Point files: particle positions or target points as CSV (`x,y,z` rows)
//! or PLY (the `vertex` element), written so that they read back bit for
//! bit.

use std::io::{self, Write};
use std::path::Path;

use glam::Vec3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

use super::{extension, format_error, io_error, read_text, write_file};
use crate::error::Error;

/// Writes particle positions to `path`, in the format its extension names:
/// `.csv` (header `x,y,z`, one row per point) or `.ply` (ASCII, vertices
/// only). Other extensions are [`Error::UnsupportedFormat`]; an empty slice or
/// a non-finite coordinate is refused with [`Error::Format`], since
/// [`load_points`] would not read the file back.
///
/// # Example
///
/// ```
/// use tissue_core::Vec3;
/// use tissue_core::io::points::{load_points, save_points};
///
/// let points = vec![Vec3::new(0.1, 0.2, 0.3), Vec3::new(-1.0, 2.5, 1e-30)];
/// let dir = tempfile::tempdir()?;
/// for name in ["points.csv", "points.ply"] {
///     let path = dir.path().join(name);
///     save_points(&points, &path)?;
///     assert_eq!(load_points(&path)?, points);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn save_points(points: &[Vec3], path: &Path) -> Result<(), Error> {
    let kind = PointFormat::of(path)?;
    check_points(points)
        .map_err(|message| format_error(path, format!("cannot write the points: {message}")))?;
    match kind {
        PointFormat::Csv => write_file(path, |w| write_csv(points, w)),
        PointFormat::Ply => write_file(path, |w| write_ply(points, w)),
    }
}

/// [`save_points`], with one more value per point after its coordinates:
/// a column `name` of the CSV file (header `x,y,z,name`), a `float`
/// property of the PLY file's vertices. [`load_points`] reads the
/// coordinates back and leaves the column.
///
/// # Errors
///
/// Those of [`save_points`]; a column of other than one finite value per
/// point, or a name that is not a plain word.
pub fn save_points_with(
    points: &[Vec3],
    name: &str,
    column: &[f32],
    path: &Path,
) -> Result<(), Error> {
    let kind = PointFormat::of(path)?;
    check_points(points)
        .map_err(|message| format_error(path, format!("cannot write the points: {message}")))?;
    let word = !name.is_empty()
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !["x", "y", "z"].contains(&name);
    if column.len() != points.len() || column.iter().any(|v| !v.is_finite()) || !word {
        return Err(format_error(
            path,
            format!(
                "cannot write the column {name:?}: {} values for {} points (one finite value \
                 each, under a plain name)",
                column.len(),
                points.len()
            ),
        ));
    }
    match kind {
        PointFormat::Csv => write_file(path, |w| {
            writeln!(w, "x,y,z,{name}")?;
            for (p, v) in points.iter().zip(column) {
                writeln!(w, "{},{},{},{v}", p.x, p.y, p.z)?;
            }
            Ok(())
        }),
        PointFormat::Ply => write_file(path, |w| {
            writeln!(w, "ply")?;
            writeln!(w, "format ascii 1.0")?;
            writeln!(w, "comment written by tissue")?;
            writeln!(w, "element vertex {}", points.len())?;
            for axis in ["x", "y", "z", name] {
                writeln!(w, "property float {axis}")?;
            }
            writeln!(w, "end_header")?;
            for (p, v) in points.iter().zip(column) {
                writeln!(w, "{} {} {} {v}", p.x, p.y, p.z)?;
            }
            Ok(())
        }),
    }
}

/// Reads points from a `.csv` or `.ply` file (by extension).
///
/// CSV: three comma-separated numbers per line, optionally after a header
/// line `x,y,z` (more columns after those three, named in the header, are
/// read past, as [`save_points_with`] writes them); blank lines are
/// skipped. A row with the wrong number of
/// columns, a value that is not a number, or a non-finite value is an
/// [`Error::Format`] naming the line. PLY (ASCII or binary): the `x`, `y`, `z`
/// properties of the `vertex` element; other elements are ignored. A file with
/// no points is an error, as is any other extension
/// ([`Error::UnsupportedFormat`]).
///
/// # Example
///
/// ```
/// use tissue_core::Vec3;
/// use tissue_core::io::points::load_points;
///
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("targets.csv");
/// std::fs::write(&path, "x,y,z\n1,2,3\n4.5,-6,0.25\n")?;
/// assert_eq!(
///     load_points(&path)?,
///     vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.5, -6.0, 0.25)]
/// );
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_points(path: &Path) -> Result<Vec<Vec3>, Error> {
    match PointFormat::of(path)? {
        PointFormat::Csv => {
            let text = read_text(path)?;
            parse_csv(&text).map_err(|message| format_error(path, message))
        }
        PointFormat::Ply => {
            let bytes = std::fs::read(path).map_err(|source| io_error(path, source))?;
            parse_ply(&bytes).map_err(|message| format_error(path, message))
        }
    }
}

fn check_points(points: &[Vec3]) -> Result<(), String> {
    if points.is_empty() {
        return Err("there are no points".into());
    }
    match points.iter().position(|&p| !p.is_finite()) {
        Some(i) => Err(format!("point {i} = {} is not finite", points[i])),
        None => Ok(()),
    }
}

#[derive(Debug, Clone, Copy)]
enum PointFormat {
    Csv,
    Ply,
}

impl PointFormat {
    fn of(path: &Path) -> Result<Self, Error> {
        match extension(path).as_deref() {
            Some("csv") => Ok(Self::Csv),
            Some("ply") => Ok(Self::Ply),
            _ => Err(Error::UnsupportedFormat {
                path: path.to_path_buf(),
                expected: ".csv, .ply",
            }),
        }
    }
}

fn write_csv(points: &[Vec3], w: &mut dyn Write) -> io::Result<()> {
    writeln!(w, "x,y,z")?;
    for p in points {
        writeln!(w, "{},{},{}", p.x, p.y, p.z)?;
    }
    Ok(())
}

fn write_ply(points: &[Vec3], w: &mut dyn Write) -> io::Result<()> {
    writeln!(w, "ply")?;
    writeln!(w, "format ascii 1.0")?;
    writeln!(w, "comment written by tissue")?;
    writeln!(w, "element vertex {}", points.len())?;
    for axis in ["x", "y", "z"] {
        writeln!(w, "property float {axis}")?;
    }
    writeln!(w, "end_header")?;
    for p in points {
        writeln!(w, "{} {} {}", p.x, p.y, p.z)?;
    }
    Ok(())
}

/// Three numbers from one CSV line of `columns` values (the first three
/// the coordinates), or why not.
fn csv_row(line: &str, columns: usize) -> Result<Vec3, String> {
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    if fields.len() != columns {
        return Err(if columns == 3 {
            format!(
                "expected 3 comma-separated values (x,y,z), found {}",
                fields.len()
            )
        } else {
            format!(
                "expected {columns} comma-separated values (as the header names), found {}",
                fields.len()
            )
        });
    }
    if let Some(field) = fields[3..].iter().find(|f| f.parse::<f32>().is_err()) {
        return Err(format!("`{field}` is not a number"));
    }
    let mut xyz = [0.0_f32; 3];
    for (slot, field) in xyz.iter_mut().zip(&fields) {
        let value: f32 = field
            .parse()
            .map_err(|_| format!("`{field}` is not a number"))?;
        if !value.is_finite() {
            return Err(format!("`{field}` is not a finite number"));
        }
        *slot = value;
    }
    Ok(Vec3::from_array(xyz))
}

fn parse_csv(text: &str) -> Result<Vec<Vec3>, String> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut points = Vec::new();
    let mut seen_row = false;
    let mut columns = 3;
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let first = !seen_row;
        seen_row = true;
        match csv_row(line, columns) {
            Ok(p) => points.push(p),
            Err(_) if first && csv_header(line).is_some() => {
                columns = csv_header(line).unwrap_or(3);
            }
            Err(message) => return Err(format!("line {}: {message}", k + 1)),
        }
    }
    if points.is_empty() {
        return Err("no points in the file".into());
    }
    Ok(points)
}

/// The column count of a header line `x,y,z` or `x,y,z,name,...` (named
/// columns after the coordinates), `None` for any other line.
fn csv_header(line: &str) -> Option<usize> {
    let fields: Vec<String> = line
        .split(',')
        .map(|f| f.trim().trim_matches('"').to_ascii_lowercase())
        .collect();
    let named = fields[3.min(fields.len())..]
        .iter()
        .all(|f| !f.is_empty() && f.parse::<f64>().is_err());
    (fields.len() >= 3 && fields[..3] == ["x", "y", "z"] && named).then_some(fields.len())
}

fn ply_scalar(property: &Property) -> Option<f32> {
    Some(match *property {
        Property::Float(v) => v,
        Property::Double(v) => v as f32,
        Property::Char(v) => f32::from(v),
        Property::UChar(v) => f32::from(v),
        Property::Short(v) => f32::from(v),
        Property::UShort(v) => f32::from(v),
        Property::Int(v) => v as f32,
        Property::UInt(v) => v as f32,
        _ => return None,
    })
}

fn parse_ply(bytes: &[u8]) -> Result<Vec<Vec3>, String> {
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut &bytes[..])
        .map_err(|e| format!("not a readable PLY file: {e}"))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or("the PLY file has no `vertex` element")?;
    let mut points = Vec::with_capacity(vertices.len());
    for (i, vertex) in vertices.iter().enumerate() {
        let mut xyz = [0.0_f32; 3];
        for (slot, axis) in xyz.iter_mut().zip(["x", "y", "z"]) {
            let property = vertex
                .get(axis)
                .ok_or_else(|| format!("vertex {i} has no `{axis}` property"))?;
            *slot = ply_scalar(property)
                .ok_or_else(|| format!("vertex {i}: `{axis}` is a list, not a number"))?;
        }
        let p = Vec3::from_array(xyz);
        if !p.is_finite() {
            return Err(format!("vertex {i} = {p} is not finite"));
        }
        points.push(p);
    }
    if points.is_empty() {
        return Err("no points in the file".into());
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    /// A column after the coordinates is written under its name and read
    /// past on both formats; a row short of the header's columns, or a
    /// column of the wrong length, is refused.
    #[test]
    fn a_named_column_after_the_coordinates_round_trips() {
        let points = vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(-4.0, 0.5, 6.0)];
        let dir = tempfile::tempdir().unwrap();
        for name in ["p.csv", "p.ply"] {
            let path = dir.path().join(name);
            save_points_with(&points, "uncertainty_95", &[0.5, 1.25], &path).unwrap();
            assert_eq!(load_points(&path).unwrap(), points);
            assert!(
                std::fs::read_to_string(&path)
                    .unwrap()
                    .contains("uncertainty_95")
            );
            assert!(save_points_with(&points, "uncertainty_95", &[0.5], &path).is_err());
        }
        assert_eq!(
            parse_csv("x,y,z,r\n1,2,3,0.5\n-4,0.5,6,1\n").unwrap(),
            points
        );
        let short = parse_csv("x,y,z,r\n1,2,3\n").unwrap_err();
        assert!(short.contains("expected 4"), "{short}");
        assert!(parse_csv("x,y,z,r\n1,2,3,a\n").is_err());
    }

    #[test]
    fn csv_header_is_optional_and_blank_lines_are_skipped() {
        let expected = vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(-4.0, 0.5, 6.0)];
        assert_eq!(parse_csv("x,y,z\n1,2,3\n\n-4, 0.5 ,6\n").unwrap(), expected);
        assert_eq!(parse_csv("1,2,3\r\n-4,0.5,6\r\n").unwrap(), expected);
        assert_eq!(
            parse_csv("\u{feff}\"X\",\"Y\",\"Z\"\n1,2,3\n-4,0.5,6").unwrap(),
            expected
        );
    }

    #[test]
    fn csv_errors_name_the_line() {
        assert_eq!(
            parse_csv("x,y,z\n1,2,3\n1,2\n").unwrap_err(),
            "line 3: expected 3 comma-separated values (x,y,z), found 2"
        );
        assert_eq!(
            parse_csv("x,y,z\n1,2,3\n1,two,3\n").unwrap_err(),
            "line 3: `two` is not a number"
        );
        assert_eq!(
            parse_csv("1,2,3\n1,2,NaN\n").unwrap_err(),
            "line 2: `NaN` is not a finite number"
        );
        assert_eq!(
            parse_csv("a,b,c\n1,2,3\n").unwrap_err(),
            "line 1: `a` is not a number"
        );
        assert_eq!(parse_csv("x,y,z\n").unwrap_err(), "no points in the file");
    }

    #[test]
    fn ply_with_doubles_and_extra_properties_is_read() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\n\
                    property double y\nproperty double z\nproperty uchar red\n\
                    element face 0\nproperty list uchar int vertex_indices\nend_header\n\
                    1 2 3 255\n0.5 -1 0 0\n";
        assert_eq!(
            parse_ply(text.as_bytes()).unwrap(),
            vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.5, -1.0, 0.0)]
        );
    }

    #[test]
    fn ply_without_vertices_is_rejected() {
        let text = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n\
                    property float y\nproperty float z\nend_header\n";
        assert_eq!(
            parse_ply(text.as_bytes()).unwrap_err(),
            "no points in the file"
        );
        let truncated = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
                         property float y\nproperty float z\nend_header\n1 2 3\n";
        assert!(parse_ply(truncated.as_bytes()).is_err());
    }
}
