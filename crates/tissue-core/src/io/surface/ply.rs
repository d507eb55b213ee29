//! PLY: ASCII and binary read through `ply-rs`, triangles or polygons;
//! written as ASCII.

use std::io::{Cursor, Write};

use glam::Vec3;

use super::fan;
use crate::io::space::Space;
use crate::mesh::SurfaceMesh;

pub(super) fn read_ply(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};

    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut Cursor::new(bytes))
        .map_err(|e| format!("cannot parse PLY: {e}"))?;
    let vertex_elements = ply
        .payload
        .get("vertex")
        .ok_or("PLY file has no `vertex` element")?;
    let coordinate = |v: &DefaultElement, i: usize, name: &str| {
        v.get(name)
            .and_then(Property::to_f32_lossy)
            .ok_or_else(|| format!("PLY vertex {i} has no numeric `{name}` property"))
    };
    let vertices = vertex_elements
        .iter()
        .enumerate()
        .map(|(i, v)| {
            Ok(Vec3::new(
                coordinate(v, i, "x")?,
                coordinate(v, i, "y")?,
                coordinate(v, i, "z")?,
            ))
        })
        .collect::<Result<Vec<_>, String>>()?;

    let mut triangles = Vec::new();
    let faces = ply.payload.get("face").map_or(&[][..], Vec::as_slice);
    for (f, face) in faces.iter().enumerate() {
        let corners = face
            .get("vertex_indices")
            .or_else(|| face.get("vertex_index"))
            .ok_or_else(|| format!("PLY face {f} has no `vertex_indices` list"))?
            .to_u32_list()
            .ok_or_else(|| {
                format!("PLY face {f}: `vertex_indices` is not a list of non-negative integers")
            })?;
        fan(&corners, &mut triangles).map_err(|n| format!("PLY face {f} has only {n} corners"))?;
    }
    Ok(SurfaceMesh::new(vertices, triangles))
}

pub(super) fn write_ply(
    mesh: &SurfaceMesh,
    tag: Option<Space>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    let index_type = if mesh.vertices.len() <= i32::MAX as usize {
        "int"
    } else {
        "uint"
    };
    let tag = tag.map_or_else(String::new, |space| format!("comment SPACE={space}\n"));
    write!(
        out,
        "ply\nformat ascii 1.0\ncomment tissue surface\n{tag}\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar {index_type} vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    for v in &mesh.vertices {
        writeln!(out, "{} {} {}", v.x, v.y, v.z)?;
    }
    for [a, b, c] in &mesh.triangles {
        writeln!(out, "3 {a} {b} {c}")?;
    }
    Ok(())
}
