//! Legacy VTK: PolyData (`POLYGONS`, `TRIANGLE_STRIPS`) or the surface
//! cells of an UnstructuredGrid, ASCII or binary, read through `vtkio`;
//! written as legacy ASCII PolyData.

use std::io::{Cursor, Write};

use glam::Vec3;

use super::fan;
use crate::mesh::SurfaceMesh;

pub(super) fn read_vtk(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    use vtkio::model::{DataSet, Piece};

    let vtk = vtkio::Vtk::parse_legacy_be(Cursor::new(bytes))
        .map_err(|e| format!("cannot parse legacy VTK: {e}"))?;
    let mut mesh = SurfaceMesh::default();
    match vtk.data {
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
