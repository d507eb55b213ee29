//! Wavefront OBJ: `v` and `f` records read through `tobj` (any `v/vt/vn`
//! form, polygons, several objects), written as `v` and `f`.

use std::io::{Cursor, Write};

use glam::Vec3;

use crate::io::space::Space;
use crate::mesh::SurfaceMesh;

pub(super) fn read_obj(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    #[allow(
        clippy::needless_update,
        reason = "which fields LoadOptions has depends on tobj's features"
    )]
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials are irrelevant to the geometry: do not look for .mtl files.
    let (models, _) =
        tobj::load_obj_buf(
            &mut Cursor::new(bytes),
            &options,
            |_| Ok(Default::default()),
        )
        .map_err(|e| format!("cannot parse OBJ: {e}"))?;

    let mut mesh = SurfaceMesh::default();
    for model in &models {
        let offset = mesh.vertices.len() as u32;
        mesh.vertices.extend(
            model
                .mesh
                .positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        mesh.triangles.extend(
            model
                .mesh
                .indices
                .chunks_exact(3)
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }
    Ok(mesh)
}

pub(super) fn write_obj(
    mesh: &SurfaceMesh,
    tag: Option<Space>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    writeln!(
        out,
        "# tissue surface: {} vertices, {} triangles",
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    // In the leading comments, where 3D Slicer looks for it.
    if let Some(space) = tag {
        writeln!(out, "# SPACE={space}")?;
    }
    for v in &mesh.vertices {
        writeln!(out, "v {} {} {}", v.x, v.y, v.z)?;
    }
    for [a, b, c] in &mesh.triangles {
        writeln!(
            out,
            "f {} {} {}",
            u64::from(*a) + 1,
            u64::from(*b) + 1,
            u64::from(*c) + 1
        )?;
    }
    Ok(())
}
