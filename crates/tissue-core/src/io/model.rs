//! Particle model files (VTK XML PolyData).
//!
//! A model is written as a `.vtp` that ParaView opens directly: one piece
//! whose points are the particles followed by the rest surface's vertices,
//! with a vertex cell per particle, a line per connection and the surface's
//! triangles. Every number is ASCII in Rust's shortest round-trip formatting,
//! so what [`load_model`] reads back is bit-identical to what [`save_model`]
//! wrote. The layout is described in `docs/FORMATS.md`.

use std::io::{self, Write};
use std::path::Path;

use glam::Vec3;
use parry3d::query::PointQuery;
use parry3d::shape::{TriMesh, TriMeshFlags};
use rayon::prelude::*;

use super::vtp::{
    Encoding, count_attribute, field_array, field_integer, piece_cells, piece_points, point_array,
    write_array, write_cells, write_space_array,
};
use super::xml::{Element, parse_xml};
use super::{extension, format_error, io_error, write_file};
use crate::error::Error;
use crate::io::space::Space;
use crate::mesh::SurfaceMesh;
use crate::model::{Attachment, Connections, ParticleModel};

// Point files were first here; their old path keeps working.
pub use super::points::{load_points, save_points};

/// Name of the field-data array that marks a `.vtp` as a tissue model and
/// carries its format version.
pub const MODEL_VERSION_ARRAY: &str = "tissue_model_version";

/// The model format version this build writes and reads.
pub const MODEL_VERSION: i64 = 1;

/// Name of the field-data array holding the number of particles: the first
/// that many points are particles, the rest are rest-surface vertices.
pub const PARTICLES_ARRAY: &str = "tissue_particles";

/// Writes `model` to `path` as a VTK XML PolyData file (`.vtp`).
///
/// The model is checked first with [`ParticleModel::validate`] (lengths
/// agree, values finite, radii positive, indices in range, connections
/// symmetric) so that everything written can be read back by [`load_model`];
/// an inconsistent model is refused with [`Error::Format`] and nothing is
/// written. The extension is not checked;
/// use `.vtp` so that ParaView recognises the file.
///
/// # Example
///
/// ```
/// use tissue_core::io::model::{load_model, save_model};
/// use tissue_core::{Connections, ParticleModel, SurfaceMesh, Vec3};
///
/// let model = ParticleModel {
///     positions: vec![Vec3::ZERO, Vec3::X],
///     radii: vec![0.5, 0.5],
///     attachments: vec![None, None],
///     connections: Connections::from_pairs(2, [(0, 1)]),
///     surface: SurfaceMesh::default(),
/// };
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("model.vtp");
/// save_model(&model, &path)?;
/// assert_eq!(load_model(&path)?, model);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn save_model(model: &ParticleModel, path: &Path) -> Result<(), Error> {
    check_writable(model)
        .map_err(|message| format_error(path, format!("cannot write the model: {message}")))?;
    write_file(path, |w| write_model(model, w))
}

/// Reads a model written by [`save_model`].
///
/// The connections are rebuilt from the line cells with
/// [`Connections::from_pairs`]. A file that is not a tissue model, or that is
/// truncated or inconsistent (array lengths, indices out of range, non-finite
/// values, non-positive radii: what [`ParticleModel::validate`] refuses), is
/// an [`Error::Format`] naming the problem.
///
/// # Example
///
/// ```
/// use tissue_core::io::model::{load_model, save_model};
/// use tissue_core::{Attachment, Connections, ParticleModel, SurfaceMesh, Vec3};
///
/// let surface = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// );
/// let model = ParticleModel {
///     positions: vec![Vec3::splat(0.2), Vec3::new(0.25, 0.25, 0.0)],
///     radii: vec![0.1, 0.1],
///     attachments: vec![
///         None,
///         Some(Attachment { triangle: 0, barycentric: [0.5, 0.25, 0.25] }),
///     ],
///     connections: Connections::from_pairs(2, [(0, 1)]),
///     surface,
/// };
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("model.vtp");
/// save_model(&model, &path)?;
/// let loaded = load_model(&path)?;
/// assert_eq!(loaded.connections.of(1), &[0]);
/// assert!(loaded.is_surface(1));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_model(path: &Path) -> Result<ParticleModel, Error> {
    let bytes = std::fs::read(path).map_err(|source| io_error(path, source))?;
    // ParaView's "binary" save: raw bytes after <AppendedData>, re-encoded
    // as base64 so that the file is text.
    let bytes = crate::io::surface::raw_appended_as_base64(&bytes)
        .map_err(|message| format_error(path, message))?
        .unwrap_or(bytes);
    let text = String::from_utf8(bytes).map_err(|e| {
        format_error(
            path,
            format!(
                "not a text file (invalid UTF-8 at byte {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })?;
    parse_model(&text).map_err(|message| format_error(path, message))
}

/// Checks that a model's particles are where its rest surface says they
/// are, before it is deformed: each attached particle within half a mean
/// connection length of its attachment point, each free one inside the
/// surface or within half a mean connection length of it (sampling leaves
/// them within 1 % of a spacing). A hand-edited or corrupted model fails
/// here, naming a particle. ([`load_model`] reads any consistent model,
/// so that files round-trip; `tissue deform` and `track` call this.)
///
/// # Errors
///
/// [`Error::InvalidModel`] naming the first misplaced particle.
pub fn check_placement(model: &ParticleModel) -> Result<(), Error> {
    placement(model).map_err(Error::InvalidModel)
}

fn placement(model: &ParticleModel) -> Result<(), String> {
    let spacing = match model.mean_connection_length() {
        s if s > 0.0 => s,
        _ => 2.0 * model.radii.iter().copied().fold(0.0, f32::max),
    };
    let tolerance = 0.5 * spacing;
    let mut free = Vec::new();
    for (i, (&p, a)) in model.positions.iter().zip(&model.attachments).enumerate() {
        let Some(a) = a else {
            free.push(i);
            continue;
        };
        let on = model.surface.point_on(a.triangle as usize, a.barycentric);
        let off = p.distance(on);
        if off > tolerance {
            return Err(format!(
                "surface particle {i} at {p} is {off} from its attachment point {on} on triangle {} \
                 (more than half a particle spacing, {tolerance}): the model was edited or damaged",
                a.triangle
            ));
        }
    }
    if free.is_empty() {
        return Ok(());
    }
    // A point query against the surface's bounding-volume tree per particle:
    // a distance field over the whole surface would cost more to build than
    // the check takes (0.4 s at 10,000 particles on the phantom).
    let mesh = TriMesh::with_flags(
        model.surface.vertices.clone(),
        model.surface.triangles.clone(),
        TriMeshFlags::ORIENTED,
    )
    .map_err(|e| format!("the model's rest surface: {e}"))?;
    let outside = free.par_iter().find_map_first(|&i| {
        let p = model.positions[i];
        let projection = mesh.project_local_point(p, false);
        let off = if projection.is_inside {
            0.0
        } else {
            p.distance(projection.point)
        };
        // The nearest triangle's side can be wrong where the surface
        // crosses itself; the winding number says whether it wraps `p`.
        (off > tolerance && model.surface.winding_number(p) <= 0.5).then_some((i, p, off))
    });
    if let Some((i, p, outside)) = outside {
        return Err(format!(
            "particle {i} at {p} is {outside} outside the model's rest surface \
             (more than half a particle spacing, {tolerance}): the model was edited or damaged"
        ));
    }
    Ok(())
}

/// Writes a model in the format the extension of `path` names: `.vtp` is the
/// full model ([`save_model`]); `.csv` and `.ply` are the particle positions
/// alone ([`save_points`]), for tools that only want a point cloud. Any other
/// extension is [`Error::UnsupportedFormat`].
pub fn export_model(model: &ParticleModel, path: &Path) -> Result<(), Error> {
    match extension(path).as_deref() {
        Some("vtp") => save_model(model, path),
        Some("csv" | "ply") => save_points(&model.positions, path),
        _ => Err(Error::UnsupportedFormat {
            path: path.to_path_buf(),
            expected: ".vtp (model), .csv, .ply (positions)",
        }),
    }
}

/// Writes a stage-2 result: the particles of `model` where stage 2 moved them
/// (`current`) and the `deformed` surface, laid out like the model file, with
/// a `displacement` array (from rest, per particle and per surface vertex).
/// It carries no model marker: `load_model` refuses it, since it is a
/// result, not a rest state to deform again.
///
/// # Errors
///
/// [`Error::Format`] when `current` or `deformed` do not match `model`, or a
/// position is not finite; [`Error::Io`] when the file cannot be written.
///
/// # Examples
///
/// ```
/// use tissue_core::io::model::{load_model, save_moved_particles};
/// use tissue_core::{Connections, ParticleModel, SurfaceMesh, Vec3};
///
/// let surface = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// );
/// let model = ParticleModel {
///     positions: vec![Vec3::splat(0.1), Vec3::splat(0.2)],
///     radii: vec![0.05; 2],
///     attachments: vec![None; 2],
///     connections: Connections::from_pairs(2, [(0, 1)]),
///     surface: surface.clone(),
/// };
/// let moved = [Vec3::splat(0.15), Vec3::splat(0.25)];
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("particles.vtp");
/// save_moved_particles(&model, &moved, &surface, &path)?;
/// assert!(std::fs::read_to_string(&path)?.contains(r#"Name="displacement""#));
/// assert!(load_model(&path).is_err(), "a result is not a model");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn save_moved_particles(
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
    path: &Path,
) -> Result<(), Error> {
    moved_particles(model, current, deformed, None, &[], path)
}

/// [`save_moved_particles`], with the file tagged as 3D Slicer tags its
/// models (a `SPACE` field-data string, `LPS` or `RAS`), so that Slicer
/// loads it in `space` without asking or mirroring it.
///
/// # Errors
///
/// Those of [`save_moved_particles`].
pub fn save_moved_particles_in(
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
    space: Space,
    path: &Path,
) -> Result<(), Error> {
    moved_particles(model, current, deformed, Some(space), &[], path)
}

/// [`save_moved_particles_in`], with more point data: each `(name,
/// values)` of `arrays` one `Float32` value per particle (a particle's
/// uncertainty, say), zero on the surface vertices after them.
///
/// # Errors
///
/// Those of [`save_moved_particles`]; an array of other than one value
/// per particle, or named as one the file already has.
pub fn save_moved_particles_with(
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
    space: Space,
    arrays: &[(&str, &[f32])],
    path: &Path,
) -> Result<(), Error> {
    moved_particles(model, current, deformed, Some(space), arrays, path)
}

/// The point-data arrays every moved-particles file has.
const MOVED_ARRAYS: [&str; 4] = ["displacement", "radius", "surface", "triangle"];

fn moved_particles(
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
    tag: Option<Space>,
    arrays: &[(&str, &[f32])],
    path: &Path,
) -> Result<(), Error> {
    for (name, values) in arrays {
        if values.len() != model.len() || MOVED_ARRAYS.contains(name) {
            return Err(format_error(
                path,
                format!(
                    "point data {name:?}: {} values for {} particles (one each, under a name of \
                     its own)",
                    values.len(),
                    model.len()
                ),
            ));
        }
    }
    if current.len() != model.len() || deformed.vertices.len() != model.surface.vertices.len() {
        return Err(format_error(
            path,
            format!(
                "{} moved particles and {} surface vertices for a model of {} and {}",
                current.len(),
                deformed.vertices.len(),
                model.len(),
                model.surface.vertices.len()
            ),
        ));
    }
    if let Some(i) = current.iter().position(|p| !p.is_finite()) {
        return Err(format_error(
            path,
            format!("particle {i} is at {} (the solve diverged)", current[i]),
        ));
    }
    let moved = ParticleModel {
        positions: current.to_vec(),
        surface: deformed.clone(),
        ..model.clone()
    };
    check_writable(&moved).map_err(|message| format_error(path, message))?;
    let displacement: Vec<Vec3> = current
        .iter()
        .zip(&model.positions)
        .chain(deformed.vertices.iter().zip(&model.surface.vertices))
        .map(|(now, rest)| *now - *rest)
        .collect();
    write_file(path, |w| {
        write_poly_data(&moved, Some(&displacement), arrays, tag, w)
    })
}

// ---------------------------------------------------------------------------
// Model consistency: what save refuses and load rejects

/// What [`save_model`] and [`save_moved_particles`] refuse: a model that
/// [`ParticleModel::validate`] refuses, or one with more triangles than the
/// file's `Int32` `triangle` array can name.
fn check_writable(model: &ParticleModel) -> Result<(), String> {
    model.validate().map_err(validation_message)?;
    if model.surface.triangles.len() > i32::MAX as usize {
        return Err(format!(
            "the surface has {} triangles; the `triangle` array holds at most {}",
            model.surface.triangles.len(),
            i32::MAX
        ));
    }
    Ok(())
}

/// The problem [`ParticleModel::validate`] found, to report as the file's.
fn validation_message(error: Error) -> String {
    match error {
        Error::InvalidModel(message) => message,
        other => other.to_string(),
    }
}

// ---------------------------------------------------------------------------
// Writing the .vtp

/// Models with more particles than this are written with binary arrays
/// (zlib-compressed, base64: `format="binary"`), a fraction of the ASCII
/// file's size (docs/FORMATS.md). Smaller ones stay ASCII, readable as text.
pub const BINARY_FROM_PARTICLES: usize = 100_000;

/// Value of the `surface` array at rest-surface vertices, so that colouring
/// by `surface` tells the rest surface apart from both kinds of particle.
const REST_SURFACE_FLAG: u8 = 2;

/// One piece holding particles and rest surface together. Two pieces would be
/// the natural layout, but VTK 9's XML reader builds a cell array that first
/// appears in a later piece without offsetting its point ids, so ParaView
/// would draw the surface's triangles between particles.
fn write_model(model: &ParticleModel, w: &mut dyn Write) -> io::Result<()> {
    write_poly_data(model, None, &[], None, w)
}

/// The model file's layout; with `displacement` (one per particle, then one
/// per surface vertex) the file is a stage-2 result instead: it gets a
/// `displacement` array and no model marker, so `load_model` refuses it.
/// With `tag`, the field data has 3D Slicer's `SPACE` string.
fn write_poly_data(
    model: &ParticleModel,
    displacement: Option<&[Vec3]>,
    arrays: &[(&str, &[f32])],
    tag: Option<Space>,
    w: &mut dyn Write,
) -> io::Result<()> {
    let n = model.len();
    let pairs = model.connections.pair_list();
    let surface = &model.surface;
    let v = surface.vertices.len();
    let first_vertex = n as u64;
    let encoding = if n > BINARY_FROM_PARTICLES {
        Encoding::Binary
    } else {
        Encoding::Ascii
    };

    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    let what = if displacement.is_some() {
        "tissue stage-2 result: moved particles, then deformed-surface vertices"
    } else {
        "tissue particle model: particles, then rest-surface vertices"
    };
    writeln!(w, "<!-- {what}; see docs/FORMATS.md -->")?;
    let compressor = match encoding {
        Encoding::Ascii => "",
        Encoding::Binary => {
            // Int32 cells (`vtp::write_cells`).
            let largest = (n + v)
                .max(2 * pairs.len())
                .max(3 * surface.triangles.len());
            if i32::try_from(largest).is_err() {
                return Err(io::Error::other(format!(
                    "{largest} points or cell corners are more than a binary model file holds"
                )));
            }
            r#" compressor="vtkZLibDataCompressor""#
        }
    };
    writeln!(
        w,
        r#"<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64"{compressor}>"#
    )?;
    writeln!(w, "  <PolyData>")?;
    writeln!(w, "    <FieldData>")?;
    if displacement.is_none() {
        writeln!(
            w,
            r#"      <DataArray type="Int32" Name="{MODEL_VERSION_ARRAY}" NumberOfTuples="1" format="ascii">{MODEL_VERSION}</DataArray>"#
        )?;
    }
    writeln!(
        w,
        r#"      <DataArray type="Int64" Name="{PARTICLES_ARRAY}" NumberOfTuples="1" format="ascii">{n}</DataArray>"#
    )?;
    if let Some(space) = tag {
        write_space_array(w, space)?;
    }
    writeln!(w, "    </FieldData>")?;
    writeln!(
        w,
        r#"    <Piece NumberOfPoints="{}" NumberOfVerts="{n}" NumberOfLines="{}" NumberOfStrips="0" NumberOfPolys="{}">"#,
        n + v,
        pairs.len(),
        surface.triangles.len()
    )?;

    writeln!(w, r#"      <PointData Scalars="surface">"#)?;
    if let Some(displacement) = displacement {
        let values = displacement.iter().flat_map(|d| d.to_array());
        write_array(w, encoding, "Float32", "displacement", 3, values)?;
    }
    for (name, values) in arrays {
        let values = values
            .iter()
            .copied()
            .chain(std::iter::repeat_n(0.0_f32, v));
        write_array(w, encoding, "Float32", name, 1, values)?;
    }
    let radius = model.radii.iter().copied();
    write_array(
        w,
        encoding,
        "Float32",
        "radius",
        1,
        radius.chain(std::iter::repeat_n(0.0_f32, v)),
    )?;
    let flags = model.attachments.iter().map(|a| u8::from(a.is_some()));
    write_array(
        w,
        encoding,
        "UInt8",
        "surface",
        1,
        flags.chain(std::iter::repeat_n(REST_SURFACE_FLAG, v)),
    )?;
    let triangle = model
        .attachments
        .iter()
        .map(|a| a.map_or(-1, |a| i64::from(a.triangle)));
    write_array(
        w,
        encoding,
        "Int32",
        "triangle",
        1,
        triangle.chain(std::iter::repeat_n(-1, v)),
    )?;
    let barycentric = model
        .attachments
        .iter()
        .flat_map(|a| a.map_or([0.0; 3], |a| a.barycentric));
    write_array(
        w,
        encoding,
        "Float32",
        "barycentric",
        3,
        barycentric.chain(std::iter::repeat_n(0.0_f32, 3 * v)),
    )?;
    writeln!(w, "      </PointData>")?;

    writeln!(w, "      <Points>")?;
    let points = model.positions.iter().chain(&surface.vertices);
    write_array(
        w,
        encoding,
        "Float32",
        "Points",
        3,
        points.flat_map(|p| p.to_array()),
    )?;
    writeln!(w, "      </Points>")?;

    write_cells(w, encoding, "Verts", 1, 0..first_vertex)?;
    if !pairs.is_empty() {
        let ends = pairs.iter().flat_map(|&(i, j)| [i, j]);
        write_cells(w, encoding, "Lines", 2, ends)?;
    }
    if !surface.triangles.is_empty() {
        let corners = surface.triangles.iter().flatten();
        write_cells(
            w,
            encoding,
            "Polys",
            3,
            corners.map(|&c| first_vertex + u64::from(c)),
        )?;
    }
    writeln!(w, "    </Piece>")?;
    writeln!(w, "  </PolyData>")?;
    writeln!(w, "</VTKFile>")
}

// ---------------------------------------------------------------------------
// Reading the .vtp

fn parse_model(text: &str) -> Result<ParticleModel, String> {
    if text.trim().is_empty() {
        return Err("the file is empty; expected a tissue model (.vtp)".into());
    }
    let mut root = parse_xml(text)?;
    if root.name != "VTKFile" || root.attribute("type") != Some("PolyData") {
        return Err(format!(
            "not a VTK PolyData file (root element <{}> of type {:?}); expected a tissue model (.vtp)",
            root.name,
            root.attribute("type").unwrap_or("")
        ));
    }
    // Binary and appended arrays (a file re-saved by ParaView) as ASCII.
    super::vtk_binary::to_ascii(&mut root)?;
    let root = root;
    let poly_data = root
        .child("PolyData")
        .ok_or("the <PolyData> element is missing")?;

    let version = field_array(poly_data, MODEL_VERSION_ARRAY).ok_or_else(|| {
        format!(
            "a VTK PolyData file but not a tissue model: the field data array \
             `{MODEL_VERSION_ARRAY}` is missing"
        )
    })?;
    let version = field_integer(version, MODEL_VERSION_ARRAY)?;
    if version != MODEL_VERSION {
        return Err(format!(
            "tissue model version {version} is not supported; this build reads version {MODEL_VERSION}"
        ));
    }

    let pieces: Vec<&Element> = poly_data.children_named("Piece").collect();
    let [piece] = pieces[..] else {
        return Err(format!("expected one <Piece>, found {}", pieces.len()));
    };
    let mut positions = piece_points(piece)?;
    let total = positions.len();
    let particles = field_array(poly_data, PARTICLES_ARRAY)
        .ok_or_else(|| format!("the field data array `{PARTICLES_ARRAY}` is missing"))?;
    let particles = field_integer(particles, PARTICLES_ARRAY)?;
    let n = usize::try_from(particles)
        .ok()
        .filter(|&n| n <= total)
        .ok_or_else(|| {
            format!(
                "`{PARTICLES_ARRAY}` is {particles}, expected 0..={total} (the number of points)"
            )
        })?;
    let vertices = positions.split_off(n);

    piece_cells::<1>(piece, "Verts", total)?;
    let lines = piece_cells::<2>(piece, "Lines", total)?;
    if let Some((c, &[i, j])) = lines
        .iter()
        .enumerate()
        .find(|(_, l)| l.iter().any(|&p| p as usize >= n))
    {
        return Err(format!(
            "line cell {c} connects points {i} and {j}, but only the first {n} points are particles"
        ));
    }
    if let Some(&[i, _]) = lines.iter().find(|[i, j]| i == j) {
        return Err(format!("particle {i} is connected to itself"));
    }
    let polys = piece_cells::<3>(piece, "Polys", total)?;
    let mut triangles = Vec::with_capacity(polys.len());
    for (c, corners) in polys.iter().enumerate() {
        if let Some(&p) = corners.iter().find(|&&p| (p as usize) < n) {
            return Err(format!(
                "polygon cell {c} uses point {p}, a particle; triangles must use rest-surface vertices (points {n} onwards)"
            ));
        }
        triangles.push(corners.map(|p| p - n as u32));
    }
    let strips = piece
        .child("Strips")
        .and_then(|s| s.data_array("offsets"))
        .is_some_and(|a| !a.text.trim().is_empty());
    if strips || count_attribute(piece, "NumberOfStrips")?.unwrap_or(0) > 0 {
        return Err("the piece has triangle strips, which a tissue model does not use".into());
    }
    let surface = SurfaceMesh::new(vertices, triangles);

    let point_data = piece
        .child("PointData")
        .ok_or("the <PointData> element is missing")?;
    let radii: Vec<f32> = point_array(point_data, "radius", 1, total)?;
    let flags: Vec<u8> = point_array(point_data, "surface", 1, total)?;
    let triangle: Vec<i64> = point_array(point_data, "triangle", 1, total)?;
    let barycentric: Vec<f32> = point_array(point_data, "barycentric", 3, total)?;
    if let Some(k) = barycentric.iter().position(|b| !b.is_finite()) {
        return Err(format!("point {}: `barycentric` is not finite", k / 3));
    }
    if let Some(v) = flags[n..].iter().position(|&f| f != REST_SURFACE_FLAG) {
        return Err(format!(
            "point {} is a rest-surface vertex (after the {n} particles) but has `surface` {}, expected {REST_SURFACE_FLAG}",
            n + v,
            flags[n + v]
        ));
    }

    let mut attachments = Vec::with_capacity(n);
    for i in 0..n {
        let t = triangle[i];
        let attachment = match flags[i] {
            0 if t == -1 => None,
            0 => {
                return Err(format!(
                    "particle {i} is interior (`surface` 0) but has `triangle` {t}, expected -1"
                ));
            }
            1 => {
                let triangle = u32::try_from(t)
                    .ok()
                    .filter(|&t| (t as usize) < surface.triangles.len())
                    .ok_or_else(|| {
                        format!(
                            "particle {i} is a surface particle but `triangle` is {t}, \
                             expected 0..{} (the rest surface's triangles)",
                            surface.triangles.len()
                        )
                    })?;
                Some(Attachment {
                    triangle,
                    barycentric: [
                        barycentric[3 * i],
                        barycentric[3 * i + 1],
                        barycentric[3 * i + 2],
                    ],
                })
            }
            f => {
                return Err(format!(
                    "particle {i} has `surface` {f}, expected 0 (interior) or 1 (surface)"
                ));
            }
        };
        attachments.push(attachment);
    }

    let model = ParticleModel {
        positions,
        radii: radii[..n].to_vec(),
        attachments,
        connections: Connections::from_pairs(n, lines.iter().map(|&[i, j]| (i, j))),
        surface,
    };
    model.validate().map_err(validation_message)?;
    Ok(model)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;
    use crate::model::tests::small_model;

    fn model_text(model: &ParticleModel) -> String {
        let mut bytes = Vec::new();
        write_model(model, &mut bytes).unwrap();
        String::from_utf8(bytes).unwrap()
    }

    /// Parses `text` after replacing the first `from` with `to`, expecting an
    /// error that contains `needle`.
    fn rejects(from: &str, to: &str, needle: &str) {
        let text = model_text(&small_model());
        assert!(text.contains(from), "fixture lacks {from:?}");
        let edited = text.replacen(from, to, 1);
        let err = parse_model(&edited).unwrap_err();
        assert!(
            err.contains(needle),
            "error {err:?} does not mention {needle:?}"
        );
    }

    #[test]
    fn written_text_parses_back_to_the_same_model() {
        let model = small_model();
        assert_eq!(parse_model(&model_text(&model)).unwrap(), model);
    }

    #[test]
    fn newer_version_is_rejected() {
        rejects(
            r#"NumberOfTuples="1" format="ascii">1<"#,
            r#"NumberOfTuples="1" format="ascii">2<"#,
            "version 2 is not supported",
        );
    }

    #[test]
    fn line_to_a_missing_particle_is_rejected() {
        rejects(
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          0 1",
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          0 9",
            "line cell 0 refers to point 9 of 8",
        );
    }

    #[test]
    fn connection_to_itself_is_rejected() {
        rejects(
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          0 1",
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          1 1",
            "particle 1 is connected to itself",
        );
    }

    #[test]
    fn attachment_to_a_missing_triangle_is_rejected() {
        rejects(
            "Name=\"triangle\" format=\"ascii\">\n          -1 -1 0 1",
            "Name=\"triangle\" format=\"ascii\">\n          -1 -1 0 4",
            "particle 3 is a surface particle but `triangle` is 4",
        );
    }

    #[test]
    fn interior_particle_with_a_triangle_is_rejected() {
        rejects(
            "Name=\"triangle\" format=\"ascii\">\n          -1 -1 0 1",
            "Name=\"triangle\" format=\"ascii\">\n          -1 0 0 1",
            "particle 1 is interior",
        );
    }

    #[test]
    fn non_positive_radius_is_rejected() {
        rejects(
            "Name=\"radius\" format=\"ascii\">\n          0.1 0.1",
            "Name=\"radius\" format=\"ascii\">\n          0.1 -0.1",
            "particle 1: radius -0.1",
        );
    }

    #[test]
    fn short_array_is_rejected() {
        rejects(
            "Name=\"radius\" format=\"ascii\">\n          0.1 0.1 0.05 0.05",
            "Name=\"radius\" format=\"ascii\">\n          0.1 0.1 0.05",
            "`radius` has 7 values, expected 8",
        );
    }

    #[test]
    fn triangle_with_a_missing_vertex_is_rejected() {
        rejects(
            "<Polys>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          4 6 5",
            "<Polys>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          4 6 11",
            "polygon cell 0 refers to point 11 of 8",
        );
    }

    #[test]
    fn triangle_on_a_particle_is_rejected() {
        rejects(
            "<Polys>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          4 6 5",
            "<Polys>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          4 6 2",
            "polygon cell 0 uses point 2, a particle",
        );
    }

    #[test]
    fn connection_to_a_surface_vertex_is_rejected() {
        rejects(
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          0 1",
            "<Lines>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n          0 5",
            "line cell 0 connects points 0 and 5, but only the first 4 points are particles",
        );
    }

    #[test]
    fn particle_count_beyond_the_points_is_rejected() {
        rejects(
            r#"Name="tissue_particles" NumberOfTuples="1" format="ascii">4<"#,
            r#"Name="tissue_particles" NumberOfTuples="1" format="ascii">9<"#,
            "`tissue_particles` is 9, expected 0..=8",
        );
    }

    #[test]
    fn wrong_particle_count_is_rejected() {
        rejects(
            r#"Name="tissue_particles" NumberOfTuples="1" format="ascii">4<"#,
            r#"Name="tissue_particles" NumberOfTuples="1" format="ascii">3<"#,
            "only the first 3 points are particles",
        );
    }

    #[test]
    fn rest_surface_vertex_flagged_as_a_particle_is_rejected() {
        rejects(
            "0 0 1 1 2 2 2 2",
            "0 0 1 1 2 0 2 2",
            "point 5 is a rest-surface vertex (after the 4 particles) but has `surface` 0",
        );
    }

    #[test]
    fn quad_is_rejected() {
        rejects(
            "Name=\"offsets\" format=\"ascii\">\n          3 6 9 12",
            "Name=\"offsets\" format=\"ascii\">\n          4 6 9 12",
            "polygon cell 0 does not have 3 points",
        );
    }

    #[test]
    fn absurd_counts_are_rejected_without_overflow() {
        rejects(
            r#"<Piece NumberOfPoints="8""#,
            r#"<Piece NumberOfPoints="18446744073709551615""#,
            "Points: 18446744073709551615 tuples is beyond any real file",
        );
        rejects(
            r#"NumberOfPolys="4""#,
            r#"NumberOfPolys="6148914691236517206""#,
            "Polys offsets has 4 values",
        );
        rejects(
            r#"NumberOfLines="4""#,
            r#"NumberOfLines="-4""#,
            r#"NumberOfLines="-4" is not a count"#,
        );
    }

    #[test]
    fn a_binary_array_that_is_not_base64_is_refused_naming_it() {
        rejects(
            "Name=\"radius\" format=\"ascii\"",
            "Name=\"radius\" format=\"binary\"",
            "the array `radius`: its base64 data is not valid",
        );
        rejects(
            "Name=\"radius\" format=\"ascii\"",
            "Name=\"radius\" format=\"hex\"",
            "format=\"hex\" is not ascii, binary or appended",
        );
    }

    #[test]
    fn random_corruptions_never_panic() {
        // A fixed linear congruential generator: the same edits every run.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move |bound: usize| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) as usize % bound
        };
        let text = model_text(&small_model());
        let alphabet = b"0129-. \n<>/=\"aeE+";
        for _ in 0..3000 {
            let mut bytes = text.clone().into_bytes();
            for _ in 0..=next(3) {
                let at = next(bytes.len());
                match next(3) {
                    0 => bytes[at] = alphabet[next(alphabet.len())],
                    1 => {
                        let end = (at + next(40)).min(bytes.len());
                        bytes.drain(at..end);
                    }
                    _ => {
                        let end = (at + next(40)).min(bytes.len());
                        let copy = bytes[at..end].to_vec();
                        let to = next(bytes.len());
                        bytes.splice(to..to, copy);
                    }
                }
                if bytes.is_empty() {
                    break;
                }
            }
            // Only ASCII bytes are inserted, so the text stays UTF-8.
            let edited = String::from_utf8(bytes).unwrap();
            if let Ok(model) = parse_model(&edited) {
                model.validate().unwrap();
            }
        }
    }
}
