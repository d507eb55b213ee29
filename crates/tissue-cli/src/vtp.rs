//! `particles.vtp`: the moved particles and the deformed surface as one VTK
//! XML PolyData file (ASCII) that ParaView opens as it is. The layout, in
//! `docs/FORMATS.md`, mirrors the model file's: particles first, then the
//! surface's vertices; but the points are where stage 2 moved them and each
//! carries its `displacement` from rest.

use std::fmt::Display;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use tissue::{ParticleModel, SurfaceMesh};

/// `surface` value of a surface vertex (particles are 0 or 1), as in the model file.
const SURFACE_VERTEX: u8 = 2;

/// Writes the particles of `model` at `current` and the `deformed` surface to `path`.
pub fn save_moved_particles(
    path: &Path,
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
) -> Result<()> {
    if current.len() != model.len() || deformed.vertices.len() != model.surface.vertices.len() {
        bail!(
            "{}: {} moved particles and {} surface vertices for a model of {} and {}",
            path.display(),
            current.len(),
            deformed.vertices.len(),
            model.len(),
            model.surface.vertices.len()
        );
    }
    if let Some(i) = current.iter().position(|p| !p.is_finite()) {
        bail!(
            "{}: particle {i} is at {} (the solve diverged)",
            path.display(),
            current[i]
        );
    }
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = BufWriter::new(file);
    write_moved(&mut w, model, current, deformed)
        .and_then(|()| w.flush())
        .with_context(|| format!("writing {}", path.display()))
}

fn write_moved(
    w: &mut dyn Write,
    model: &ParticleModel,
    current: &[Vec3],
    deformed: &SurfaceMesh,
) -> io::Result<()> {
    let n = model.len();
    let v = deformed.vertices.len();
    let pairs = model.connections.pair_list();
    let first_vertex = n as u64;

    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(
        w,
        "<!-- tissue moved particles, then deformed-surface vertices; see docs/FORMATS.md -->"
    )?;
    writeln!(
        w,
        r#"<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#
    )?;
    writeln!(w, "  <PolyData>")?;
    writeln!(w, "    <FieldData>")?;
    writeln!(
        w,
        r#"      <DataArray type="Int64" Name="tissue_particles" NumberOfTuples="1" format="ascii">{n}</DataArray>"#
    )?;
    writeln!(w, "    </FieldData>")?;
    writeln!(
        w,
        r#"    <Piece NumberOfPoints="{}" NumberOfVerts="{n}" NumberOfLines="{}" NumberOfStrips="0" NumberOfPolys="{}">"#,
        n + v,
        pairs.len(),
        deformed.triangles.len()
    )?;

    writeln!(
        w,
        r#"      <PointData Scalars="surface" Vectors="displacement">"#
    )?;
    let particle_moves = current.iter().zip(&model.positions).map(|(q, p)| *q - *p);
    let vertex_moves = deformed
        .vertices
        .iter()
        .zip(&model.surface.vertices)
        .map(|(q, p)| *q - *p);
    write_array(
        w,
        "Float32",
        "displacement",
        3,
        particle_moves
            .chain(vertex_moves)
            .flat_map(|d| d.to_array()),
    )?;
    let flags = model.attachments.iter().map(|a| u8::from(a.is_some()));
    write_array(
        w,
        "UInt8",
        "surface",
        1,
        flags.chain(std::iter::repeat_n(SURFACE_VERTEX, v)),
    )?;
    let radius = model.radii.iter().copied();
    write_array(
        w,
        "Float32",
        "radius",
        1,
        radius.chain(std::iter::repeat_n(0.0_f32, v)),
    )?;
    writeln!(w, "      </PointData>")?;

    writeln!(w, "      <Points>")?;
    let points = current.iter().chain(&deformed.vertices);
    write_array(w, "Float32", "Points", 3, points.flat_map(|p| p.to_array()))?;
    writeln!(w, "      </Points>")?;

    write_cells(w, "Verts", 1, 0..first_vertex)?;
    if !pairs.is_empty() {
        write_cells(w, "Lines", 2, pairs.iter().flat_map(|&(i, j)| [i, j]))?;
    }
    if !deformed.triangles.is_empty() {
        let corners = deformed.triangles.iter().flatten();
        write_cells(w, "Polys", 3, corners.map(|&c| first_vertex + u64::from(c)))?;
    }
    writeln!(w, "    </Piece>")?;
    writeln!(w, "  </PolyData>")?;
    writeln!(w, "</VTKFile>")
}

/// A cell section of cells with `size` points each (VTK XML offsets are the
/// end of each cell, without a leading zero).
fn write_cells<T: Display>(
    w: &mut dyn Write,
    section: &str,
    size: usize,
    connectivity: impl Iterator<Item = T>,
) -> io::Result<()> {
    writeln!(w, "      <{section}>")?;
    let mut cells = 0;
    let counted = connectivity.inspect(|_| cells += 1);
    let per_line = if size > 1 { size } else { 12 };
    write_values(w, "Int64", "connectivity", 1, per_line, counted)?;
    let cells = cells / size;
    write_array(w, "Int64", "offsets", 1, (1..=cells).map(|c| c * size))?;
    writeln!(w, "      </{section}>")
}

/// One ASCII `DataArray`, one tuple a line for vectors, a dozen values a line for scalars.
fn write_array<T: Display>(
    w: &mut dyn Write,
    ty: &str,
    name: &str,
    components: usize,
    values: impl Iterator<Item = T>,
) -> io::Result<()> {
    let per_line = if components > 1 { components } else { 12 };
    write_values(w, ty, name, components, per_line, values)
}

/// One ASCII `DataArray`; `{}` is Rust's shortest round-trip formatting.
fn write_values<T: Display>(
    w: &mut dyn Write,
    ty: &str,
    name: &str,
    components: usize,
    per_line: usize,
    values: impl Iterator<Item = T>,
) -> io::Result<()> {
    write!(w, r#"        <DataArray type="{ty}" Name="{name}""#)?;
    if components > 1 {
        write!(w, r#" NumberOfComponents="{components}""#)?;
    }
    write!(w, r#" format="ascii">"#)?;
    for (k, value) in values.enumerate() {
        if k % per_line == 0 {
            write!(w, "\n          {value}")?;
        } else {
            write!(w, " {value}")?;
        }
    }
    writeln!(w, "\n        </DataArray>")
}
