//! 3D Slicer markups files (`.mrk.json`, schema
//! `markups-schema-v1.0.3.json`) as landmark points: read for their control
//! points and labels, written back with the points moved and every other
//! field as it was.
//!
//! Coordinates: each markup names its `coordinateSystem` (`LPS`, the
//! schema's default, or `RAS`); positions are converted on reading to the
//! space the caller's surfaces are in, and back on writing, so a file keeps
//! its coordinate system. docs/FORMATS.md, "Landmarks: 3D Slicer markups".

use std::path::Path;

use glam::Vec3;
use serde_json::{Map, Value};

use super::space::Space;
use super::{format_error, read_text, write_file};
use crate::error::Error;

/// The schema written into a file that did not name one.
pub const SCHEMA: &str = "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#";

/// Markup types whose control points are not landmarks (a plane's or a
/// box's points define a shape that moving them one by one would break).
const SHAPES: [&str; 2] = ["Plane", "ROI"];

/// A markups file, read: its landmark points and labels, and the whole
/// document, so that [`save_markups`] carries every other field over.
#[derive(Debug, Clone, PartialEq)]
pub struct Markups {
    document: Value,
    /// Per landmark, `(markup, control point)` indices in the document.
    slots: Vec<(usize, usize)>,
    /// Each markup's coordinate system (LPS when the file gives none).
    systems: Vec<Space>,
    /// The space [`Markups::points`] are in.
    space: Space,
    points: Vec<Vec3>,
    labels: Vec<String>,
}

impl Markups {
    /// The landmarks, every markup's defined control points in file order,
    /// in the space given to [`load_markups`].
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Each landmark's `label` (empty when the file gives none).
    pub fn labels(&self) -> &[String] {
        &self.labels
    }

    /// The space the points are in.
    pub fn space(&self) -> Space {
        self.space
    }

    /// Each landmark's coordinate system in the file.
    pub fn systems(&self) -> Vec<Space> {
        self.slots.iter().map(|&(m, _)| self.systems[m]).collect()
    }
}

/// Whether `path` names a markups file: `.mrk.json`, or any `.json`.
pub fn is_markups(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// Reads a 3D Slicer markups file, its positions converted to `space`.
///
/// Every control point of every markup is a landmark, in file order,
/// except those whose `positionStatus` is `undefined` (placed in Slicer's
/// list but not yet in space), which are kept for writing but not carried.
///
/// # Errors
///
/// [`Error::Format`] naming the file and the defect: not JSON, no
/// `markups` list, a Plane or ROI markup, a `coordinateSystem` other than
/// LPS or RAS, units other than millimetres, a control point without a
/// position, a position that is not 3 numbers or not finite in single
/// precision, no control point with a position at all.
pub fn load_markups(path: &Path, space: Space) -> Result<Markups, Error> {
    let text = read_text(path)?;
    parse_markups(&text, space).map_err(|message| format_error(path, message))
}

/// Writes `markups` with its landmarks moved to `points` (in
/// [`Markups::space`], converted back to each markup's coordinate system).
/// Labels, ids, orientations, display properties and every field the file
/// had are written as they were read; `measurements` (lengths, angles and
/// the like of the rest positions) are left out, for Slicer to compute
/// again.
///
/// # Errors
///
/// [`Error::Format`] when `points` are not as many as the landmarks or one
/// is not finite; [`Error::Io`] when the file cannot be written.
pub fn save_markups(markups: &Markups, points: &[Vec3], path: &Path) -> Result<(), Error> {
    let json = markups_json(markups, points)
        .map_err(|message| format_error(path, format!("cannot write the markups: {message}")))?;
    write_file(path, |w| writeln!(w, "{json}"))
}

/// The document of `markups` with `points` in place, as pretty JSON.
fn markups_json(markups: &Markups, points: &[Vec3]) -> Result<String, String> {
    if points.len() != markups.points.len() {
        return Err(format!(
            "{} points for {} control points",
            points.len(),
            markups.points.len()
        ));
    }
    let mut document = markups.document.clone();
    let Some(root) = document.as_object_mut() else {
        return Err("the document is not a JSON object".into());
    };
    if !root.contains_key("@schema") {
        root.insert("@schema".into(), Value::String(SCHEMA.into()));
    }
    let Some(list) = root.get_mut("markups").and_then(Value::as_array_mut) else {
        return Err("the document has no `markups` list".into());
    };
    for (k, (&(m, c), &p)) in markups.slots.iter().zip(points).enumerate() {
        if !p.is_finite() {
            return Err(format!("point {k} = {p} is not finite"));
        }
        let position = markups.space.convert(markups.systems[m], p);
        let point = list
            .get_mut(m)
            .and_then(|markup| markup.get_mut("controlPoints"))
            .and_then(|points| points.get_mut(c))
            .and_then(Value::as_object_mut)
            .ok_or_else(|| format!("control point {c} of markup {m} is gone"))?;
        point.insert(
            "position".into(),
            Value::Array(position.to_array().map(shortest).to_vec()),
        );
    }
    for markup in list.iter_mut().filter_map(Value::as_object_mut) {
        markup.remove("measurements");
    }
    serde_json::to_string_pretty(&document).map_err(|e| e.to_string())
}

/// `x` as the JSON number with the fewest digits that reads back as `x`.
fn shortest(x: f32) -> Value {
    format!("{x}")
        .parse::<f64>()
        .ok()
        .and_then(serde_json::Number::from_f64)
        .map_or(Value::Null, Value::Number)
}

/// Reads the text of a markups file (see [`load_markups`]).
pub(crate) fn parse_markups(text: &str, space: Space) -> Result<Markups, String> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let document: Value =
        serde_json::from_str(text).map_err(|e| format!("not a JSON file: {e}"))?;
    let list = document
        .get("markups")
        .and_then(Value::as_array)
        .ok_or("not a 3D Slicer markups file: no `markups` list")?;
    let mut systems = Vec::with_capacity(list.len());
    let mut slots = Vec::new();
    let mut points = Vec::new();
    let mut labels = Vec::new();
    for (m, markup) in list.iter().enumerate() {
        let markup = markup
            .as_object()
            .ok_or_else(|| format!("markups[{m}] is not a JSON object"))?;
        let name = markup.get("name").and_then(Value::as_str).unwrap_or("");
        let what = if name.is_empty() {
            format!("markups[{m}]")
        } else {
            format!("markups[{m}] (`{name}`)")
        };
        if let Some(kind) = markup.get("type").and_then(Value::as_str)
            && SHAPES.contains(&kind)
        {
            return Err(format!(
                "{what} is a {kind}: its control points define a shape, not landmarks \
                 (use a point list, line or curve)"
            ));
        }
        let system = coordinate_system(markup).map_err(|e| format!("{what}: {e}"))?;
        units(markup).map_err(|e| format!("{what}: {e}"))?;
        systems.push(system);
        let Some(control_points) = markup.get("controlPoints") else {
            continue;
        };
        let control_points = control_points
            .as_array()
            .ok_or_else(|| format!("{what}: `controlPoints` is not a list"))?;
        for (c, point) in control_points.iter().enumerate() {
            let at = format!("markups[{m}].controlPoints[{c}]");
            let point = point
                .as_object()
                .ok_or_else(|| format!("{at} is not a JSON object"))?;
            let label = point.get("label").and_then(Value::as_str).unwrap_or("");
            let at = if label.is_empty() {
                at
            } else {
                format!("{at} (label `{label}`)")
            };
            if point.get("positionStatus").and_then(Value::as_str) == Some("undefined") {
                continue;
            }
            let position = point
                .get("position")
                .ok_or_else(|| format!("{at} has no position"))?;
            let p = position_of(position).map_err(|e| format!("{at}: {e}"))?;
            slots.push((m, c));
            points.push(system.convert(space, p));
            labels.push(label.to_owned());
        }
    }
    if points.is_empty() {
        return Err(format!(
            "no control points with a position (in {} markups)",
            list.len()
        ));
    }
    Ok(Markups {
        document,
        slots,
        systems,
        space,
        points,
        labels,
    })
}

/// A markup's `coordinateSystem`: LPS (the schema's default) when absent.
fn coordinate_system(markup: &Map<String, Value>) -> Result<Space, String> {
    match markup.get("coordinateSystem") {
        None => Ok(Space::Lps),
        Some(Value::String(name)) => name
            .parse()
            .map_err(|_| format!("unknown coordinateSystem `{name}` (expected LPS or RAS)")),
        Some(other) => Err(format!(
            "coordinateSystem {other} is not a name (expected \"LPS\" or \"RAS\")"
        )),
    }
}

/// Refuses `coordinateUnits` other than millimetres, the unit of Slicer's
/// models and so of the surfaces the landmarks go with.
fn units(markup: &Map<String, Value>) -> Result<(), String> {
    let unit = match markup.get("coordinateUnits") {
        None => return Ok(()),
        Some(Value::String(unit)) => Some(unit.as_str()),
        Some(Value::Array(code)) => code.first().and_then(Value::as_str),
        Some(_) => None,
    };
    match unit {
        Some("mm") => Ok(()),
        Some(unit) => Err(format!(
            "coordinateUnits `{unit}`: only millimetres (mm) are read, the unit of 3D \
             Slicer's models"
        )),
        None => Err("coordinateUnits is neither a unit nor a unit code".into()),
    }
}

/// Three finite numbers.
fn position_of(position: &Value) -> Result<Vec3, String> {
    let numbers: Option<Vec<f64>> = position
        .as_array()
        .map(|items| items.iter().map(Value::as_f64).collect())
        .and_then(|all: Option<Vec<f64>>| all);
    match numbers.as_deref() {
        Some(&[x, y, z]) => {
            let p = Vec3::new(x as f32, y as f32, z as f32);
            if p.is_finite() {
                Ok(p)
            } else {
                Err(format!("position {position} is not finite"))
            }
        }
        _ => Err(format!("position {position} is not 3 numbers")),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    fn one_point(fields: &str) -> String {
        format!(
            r#"{{"@schema": "{SCHEMA}", "markups": [{{"type": "Fiducial", {fields}
               "controlPoints": [{{"label": "F-1", "position": [1.0, 2.0, 3.0]}}]}}]}}"#
        )
    }

    #[test]
    fn the_coordinate_system_defaults_to_lps_and_converts_to_the_surface_space() {
        let lps = parse_markups(&one_point(""), Space::Lps).unwrap();
        assert_eq!(lps.points(), [Vec3::new(1.0, 2.0, 3.0)]);
        assert_eq!(lps.systems(), [Space::Lps]);
        let ras = parse_markups(&one_point(r#""coordinateSystem": "RAS","#), Space::Lps).unwrap();
        assert_eq!(ras.points(), [Vec3::new(-1.0, -2.0, 3.0)]);
        assert_eq!(ras.labels(), ["F-1"]);
        let to_ras = parse_markups(&one_point(""), Space::Ras).unwrap();
        assert_eq!(to_ras.points(), [Vec3::new(-1.0, -2.0, 3.0)]);
    }

    #[test]
    fn bad_markups_name_the_defect() {
        let cases = [
            ("{\"markups\": [", "not a JSON file"),
            ("[1, 2, 3]", "no `markups` list"),
            (
                "{\"markups\": []}",
                "no control points with a position (in 0 markups)",
            ),
            (
                &one_point(r#""coordinateSystem": "IJK","#),
                "markups[0]: unknown coordinateSystem `IJK` (expected LPS or RAS)",
            ),
            (
                &one_point(r#""coordinateUnits": "um","#),
                "coordinateUnits `um`",
            ),
            (
                r#"{"markups": [{"type": "ROI", "name": "R", "controlPoints": []}]}"#,
                "markups[0] (`R`) is a ROI",
            ),
            (
                r#"{"markups": [{"controlPoints": [{"label": "A", "position": [1, 2]}]}]}"#,
                "markups[0].controlPoints[0] (label `A`): position [1,2] is not 3 numbers",
            ),
            (
                r#"{"markups": [{"controlPoints": [{"position": [1, "2", 3]}]}]}"#,
                "markups[0].controlPoints[0]: position [1,\"2\",3] is not 3 numbers",
            ),
            (
                r#"{"markups": [{"controlPoints": [{"position": [1, NaN, 3]}]}]}"#,
                "not a JSON file",
            ),
            (
                r#"{"markups": [{"controlPoints": [{"position": [1, 1e300, 3]}]}]}"#,
                "is not finite",
            ),
            (
                r#"{"markups": [{"controlPoints": [{"label": "B"}]}]}"#,
                "markups[0].controlPoints[0] (label `B`) has no position",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_markups(text, Space::Lps).unwrap_err();
            assert!(err.contains(expected), "{text}: `{err}` lacks `{expected}`");
        }
    }

    #[test]
    fn undefined_points_are_not_carried_but_are_written_back() {
        let text = r#"{"markups": [{"type": "Fiducial", "controlPoints": [
            {"label": "a", "position": [0, 0, 0], "positionStatus": "undefined"},
            {"label": "b", "position": [4, 5, 6], "positionStatus": "defined"}]}]}"#;
        let markups = parse_markups(text, Space::Lps).unwrap();
        assert_eq!(markups.labels(), ["b"]);
        let json = markups_json(&markups, &[Vec3::new(7.0, 8.0, 9.5)]).unwrap();
        let back: Value = serde_json::from_str(&json).unwrap();
        let points = &back["markups"][0]["controlPoints"];
        assert_eq!(points[0]["position"], serde_json::json!([0, 0, 0]));
        assert_eq!(points[1]["position"], serde_json::json!([7.0, 8.0, 9.5]));
        assert_eq!(back["@schema"], SCHEMA);
        assert!(
            markups_json(&markups, &[])
                .unwrap_err()
                .contains("0 points")
        );
    }

    #[test]
    fn positions_are_written_with_the_fewest_digits_that_read_back() {
        assert_eq!(shortest(0.1), serde_json::json!(0.1));
        assert_eq!(shortest(-12.345_678), serde_json::json!(-12.345678));
        for x in [0.1_f32, 1e-30, 3.402_823e38, -7.25] {
            assert_eq!(shortest(x).as_f64().unwrap() as f32, x);
        }
    }
}
