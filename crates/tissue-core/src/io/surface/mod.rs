//! Surface mesh files: reading, welding, writing.
//!
//! Formats are chosen by file extension, case-insensitively:
//!
//! | extension | read | written as |
//! |---|---|---|
//! | `.stl` | binary and ASCII | binary |
//! | `.obj` | `v` and `f` records (any `v/vt/vn` form, polygons, several objects) | `v` / `f` |
//! | `.ply` | ASCII and binary, triangles or polygons | ASCII |
//! | `.vtk` | legacy PolyData (`POLYGONS`, `TRIANGLE_STRIPS`) or UnstructuredGrid surface cells, ASCII or binary | legacy ASCII PolyData |
//! | `.vtp` | VTK XML PolyData: ASCII, binary or appended, uncompressed or zlib, LZ4, LZMA | binary, zlib |
//!
//! [`save_surface_in`] also tags the file with its coordinate system as 3D
//! Slicer does (`SPACE=LPS` or `SPACE=RAS`: a header comment, or a
//! `SPACE` field-data string in `.vtp`), and [`coordinate_tag`] reads
//! such a tag back.
//!
//! Polygons are split into triangle fans. Every reader ends with an exact
//! [`weld`], so a vertex is one position however the file spelled it (STL
//! repeats each corner per triangle; OBJ may give one position several
//! texture coordinates). Vertices keep the file's order, except in OBJ
//! where they are numbered in order of first use by a face. Floats are
//! written so they read back bit for bit.

use std::fs;
use std::io::Write;
use std::path::Path;

use crate::error::{Error, MeshError};
use crate::io::space::Space;
use crate::mesh::SurfaceMesh;
use crate::validate::{self, ShellsDropped, Validation};

mod obj;
mod ply;
mod stl;
mod vtk;
mod welding;

pub(crate) use self::vtk::raw_appended_as_base64;
pub use self::welding::weld;

/// The surface file extensions [`load_surface`] and [`save_surface`] accept.
pub const SURFACE_EXTENSIONS: &str = "stl, obj, ply, vtk, vtp";

/// [`load_closed_surface`] welds vertices closer than this times the
/// bounding-box diagonal: about one unit in the last place of an `f32`,
/// enough to absorb rounding in files written by other tools, far too small
/// to merge vertices that are meant to be apart.
pub const RELATIVE_WELD_TOLERANCE: f32 = 1e-7;

/// Choices for [`load_closed_surface_with`]; the default accepts only a
/// surface that is one closed shell as it stands. `#[non_exhaustive]`:
/// build it with [`LoadOptions::keeping_largest_shell`] or `default()`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct LoadOptions {
    /// Keep only the shell enclosing the most volume and drop the others
    /// ([`validate::keep_largest_shell`]) instead of refusing a surface of
    /// several shells with [`MeshError::SeveralShells`]. For files with stray
    /// specks beside the organ; what was dropped is logged and returned.
    /// Default `false`: a second shell may be a second organ, and sampling
    /// one of two without being asked would hide that.
    pub largest_shell: bool,
}

impl LoadOptions {
    /// The options with [`LoadOptions::largest_shell`] set to `keep`.
    pub const fn keeping_largest_shell(keep: bool) -> Self {
        Self {
            largest_shell: keep,
        }
    }
}

/// The surface formats, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Stl,
    Obj,
    Ply,
    Vtk,
    Vtp,
}

impl Format {
    fn of(path: &Path) -> Result<Self, Error> {
        let extension = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match extension.as_deref() {
            Some("stl") => Ok(Self::Stl),
            Some("obj") => Ok(Self::Obj),
            Some("ply") => Ok(Self::Ply),
            Some("vtk") => Ok(Self::Vtk),
            Some("vtp") => Ok(Self::Vtp),
            _ => Err(Error::UnsupportedFormat {
                path: path.to_path_buf(),
                expected: SURFACE_EXTENSIONS,
            }),
        }
    }

    /// Parses a whole file; the message says what is wrong.
    fn read(self, bytes: &[u8]) -> Result<SurfaceMesh, String> {
        match self {
            Self::Stl => stl::read_stl(bytes),
            Self::Obj => obj::read_obj(bytes),
            Self::Ply => ply::read_ply(bytes),
            Self::Vtk => vtk::read_vtk(bytes),
            Self::Vtp => vtk::read_vtp(bytes),
        }
    }

    fn write(
        self,
        mesh: &SurfaceMesh,
        tag: Option<Space>,
        out: &mut impl Write,
    ) -> std::io::Result<()> {
        match self {
            Self::Obj => obj::write_obj(mesh, tag, out),
            Self::Stl => stl::write_stl(mesh, tag, out),
            Self::Ply => ply::write_ply(mesh, tag, out),
            Self::Vtk => vtk::write_vtk(mesh, tag, out),
            Self::Vtp => vtk::write_vtp(mesh, tag, out),
        }
    }
}

/// Reads a triangle surface from an STL, OBJ, PLY, legacy VTK or VTK XML
/// PolyData (`.vtp`) file.
///
/// Vertices at exactly the same position are merged and vertices no
/// triangle uses are dropped (see [`weld`] with tolerance 0); the surface is
/// otherwise as in the file, not yet checked to be closed (for that use
/// [`load_closed_surface`]).
///
/// # Errors
///
/// - [`Error::UnsupportedFormat`] for an extension other than
///   [`SURFACE_EXTENSIONS`];
/// - [`Error::Io`] when the file cannot be read;
/// - [`Error::Format`] when its content cannot be parsed;
/// - [`Error::Mesh`] with [`MeshError::Empty`] when it holds no triangles,
///   or [`MeshError::IndexOutOfRange`] when a face names a missing vertex.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::{load_surface, save_surface};
///
/// let tetrahedron = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// );
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("tetrahedron.stl");
/// save_surface(&tetrahedron, &path)?;
///
/// let loaded = load_surface(&path)?;
/// assert_eq!(loaded.vertices.len(), 4); // STL stores 12 corners; welded back to 4
/// assert_eq!(loaded.triangles.len(), 4);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_surface(path: &Path) -> Result<SurfaceMesh, Error> {
    Ok(weld(&load_surface_as_written(path)?, 0.0))
}

/// Reads a surface file with its vertices as the file lists them: no two
/// merged, even where they coincide ([`load_surface`] welds those). A
/// deformed frame needs this: two vertices that touch in one frame are
/// still two vertices of the rest mesh. (An STL file lists three corners
/// per triangle and no shared vertex: read as written it has three times
/// as many vertices as triangles.)
///
/// # Errors
///
/// Those of [`load_surface`].
pub fn load_surface_as_written(path: &Path) -> Result<SurfaceMesh, Error> {
    let format = Format::of(path)?;
    let bytes = fs::read(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let parsed = format.read(&bytes).map_err(|message| Error::Format {
        path: path.to_path_buf(),
        message,
    })?;
    let mesh_error = |source| Error::Mesh {
        path: path.to_path_buf(),
        source,
    };
    if parsed.triangles.is_empty() {
        return Err(mesh_error(MeshError::Empty {
            vertices: parsed.vertices.len(),
            triangles: 0,
        }));
    }
    validate::check_indices(&parsed).map_err(mesh_error)?;
    Ok(parsed)
}

/// The points of a legacy VTK (`xml` false) or VTK XML PolyData file,
/// whatever cells it has: a point cloud's.
pub(crate) fn read_vtk_points(bytes: &[u8], xml: bool) -> Result<Vec<glam::Vec3>, String> {
    let read = if xml { vtk::read_vtp } else { vtk::read_vtk };
    read(bytes).map(|mesh| mesh.vertices)
}

/// Reads a surface and checks that it bounds one solid: [`load_surface`],
/// then [`weld`] with [`RELATIVE_WELD_TOLERANCE`], then
/// [`validate::validate`], which turns an inward-facing surface outward.
///
/// A flip is only logged (`log::warn!`); use
/// [`load_closed_surface_with_report`] to see it, the volume and the area,
/// and [`load_closed_surface_with`] to accept a surface of several shells.
///
/// # Errors
///
/// Those of [`load_surface`], and [`Error::Mesh`] with the defect
/// [`validate::validate`] found.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::{load_closed_surface, save_surface};
///
/// let tetrahedron = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// );
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("tetrahedron.obj");
/// save_surface(&tetrahedron, &path)?;
///
/// let surface = load_closed_surface(&path)?;
/// assert!((surface.signed_volume() - 1.0 / 6.0).abs() < 1e-6);
///
/// // The same tetrahedron with one triangle missing has a hole.
/// let mut open = tetrahedron.clone();
/// open.triangles.pop();
/// save_surface(&open, &path)?;
/// assert!(load_closed_surface(&path).is_err());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_closed_surface(path: &Path) -> Result<SurfaceMesh, Error> {
    load_closed_surface_with_report(path).map(|(mesh, _)| mesh)
}

/// [`load_closed_surface`], also returning what validation found: whether
/// the surface was flipped to face outward, its volume and its area.
///
/// # Errors
///
/// As [`load_closed_surface`].
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::{load_closed_surface_with_report, save_surface};
///
/// // Every triangle wound clockwise seen from outside: the surface faces inward.
/// let inward = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
/// );
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("inward.ply");
/// save_surface(&inward, &path)?;
///
/// let (surface, report) = load_closed_surface_with_report(&path)?;
/// assert!(report.flipped);
/// assert!(surface.signed_volume() > 0.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_closed_surface_with_report(path: &Path) -> Result<(SurfaceMesh, Validation), Error> {
    load_closed_surface_with(path, &LoadOptions::default())
        .map(|(mesh, validation, _)| (mesh, validation))
}

/// [`load_closed_surface_with_report`] with [`LoadOptions`]: reads, welds
/// with [`RELATIVE_WELD_TOLERANCE`], keeps the largest shell if
/// [`LoadOptions::largest_shell`] asks for it (logging what it drops with
/// `log::warn!`), then validates. Also returns what was dropped
/// ([`ShellsDropped::count`] 0 when nothing was).
///
/// # Errors
///
/// As [`load_closed_surface`]; with `largest_shell` the defects of the kept
/// shell, never [`MeshError::SeveralShells`].
///
/// # Examples
///
/// ```
/// use tissue_core::{MeshError, SurfaceMesh, Vec3, Error};
/// use tissue_core::io::surface::{LoadOptions, load_closed_surface_with, save_surface};
///
/// // A tetrahedron and a speck of a quarter its size far away.
/// let tetrahedron = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
/// let speck = tetrahedron.map(|v| 0.25 * v + Vec3::splat(9.0));
/// let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
/// let mesh = SurfaceMesh::new(
///     [speck, tetrahedron].concat(),
///     faces.iter().chain(&faces.map(|t| t.map(|i| i + 4))).copied().collect(),
/// );
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("with_speck.ply"); // PLY keeps vertex order
/// save_surface(&mesh, &path)?;
///
/// let refused = load_closed_surface_with(&path, &LoadOptions::default());
/// assert!(matches!(refused, Err(Error::Mesh { source: MeshError::SeveralShells { .. }, .. })));
///
/// let options = LoadOptions::keeping_largest_shell(true);
/// let (surface, validation, dropped) = load_closed_surface_with(&path, &options)?;
/// assert_eq!(surface.vertices, tetrahedron);
/// assert!((validation.volume - 1.0 / 6.0).abs() < 1e-6);
/// assert_eq!((dropped.count, dropped.triangles), (1, 4));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_closed_surface_with(
    path: &Path,
    options: &LoadOptions,
) -> Result<(SurfaceMesh, Validation, ShellsDropped), Error> {
    let loaded = load_surface(path)?;
    let mut mesh = weld(&loaded, RELATIVE_WELD_TOLERANCE * diagonal(&loaded));
    let merged = loaded.vertices.len() - mesh.vertices.len();
    if merged > 0 {
        log::info!(
            "{}: merged {merged} vertices within {RELATIVE_WELD_TOLERANCE} of the bounding-box diagonal",
            path.display()
        );
    }
    let mut dropped = ShellsDropped::default();
    if options.largest_shell {
        (mesh, dropped) = validate::keep_largest_shell(&mesh);
        if dropped.count > 0 {
            log::warn!(
                "{}: kept the largest of {} shells ({} triangles); dropped {} shells of {} triangles, the largest of them enclosing {}",
                path.display(),
                dropped.count + 1,
                mesh.triangles.len(),
                dropped.count,
                dropped.triangles,
                dropped.largest_other_volume
            );
        }
    }
    let validation = validate::validate(&mut mesh).map_err(|source| Error::Mesh {
        path: path.to_path_buf(),
        source,
    })?;
    Ok((mesh, validation, dropped))
}

fn diagonal(mesh: &SurfaceMesh) -> f32 {
    mesh.bounds().map_or(0.0, |(lo, hi)| lo.distance(hi))
}

/// Writes `mesh` to `path`, in the format its extension names: `.obj`
/// (`v`/`f` records), `.stl` (binary), `.ply` (ASCII) or `.vtk` (legacy
/// ASCII PolyData). Coordinates are written so that [`load_surface`] reads
/// back the same bits.
///
/// # Errors
///
/// [`Error::UnsupportedFormat`] for another extension, [`Error::Io`] when
/// the file cannot be written, [`Error::Format`] when the mesh cannot be
/// expressed in the format (more than `u32::MAX` triangles for STL).
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::{load_surface, save_surface};
///
/// let tetrahedron = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(0.1, 0.2, 0.7)],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// );
/// let dir = tempfile::tempdir()?;
/// for name in ["t.obj", "t.stl", "t.ply", "t.vtk"] {
///     let path = dir.path().join(name);
///     save_surface(&tetrahedron, &path)?;
///     assert_eq!(load_surface(&path)?.triangles.len(), 4);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn save_surface(mesh: &SurfaceMesh, path: &Path) -> Result<(), Error> {
    save_tagged(mesh, None, path)
}

/// [`save_surface`], with the file tagged as holding coordinates in
/// `space`, the way 3D Slicer tags the models it saves, so that Slicer
/// loads it without asking or mirroring: `SPACE=LPS` or `SPACE=RAS` in the
/// header (a comment line in `.obj` and `.ply`, the title line of a legacy
/// `.vtk`, the 80-byte header of a binary `.stl`) or, in a `.vtp`, a
/// field-data string array named `SPACE`. The coordinates are written as
/// they are: the tag says which system they are in.
///
/// # Errors
///
/// Those of [`save_surface`].
pub fn save_surface_in(mesh: &SurfaceMesh, space: Space, path: &Path) -> Result<(), Error> {
    save_tagged(mesh, Some(space), path)
}

fn save_tagged(mesh: &SurfaceMesh, tag: Option<Space>, path: &Path) -> Result<(), Error> {
    let format = Format::of(path)?;
    if format == Format::Stl && u32::try_from(mesh.triangles.len()).is_err() {
        return Err(Error::Format {
            path: path.to_path_buf(),
            message: format!(
                "{} triangles do not fit a binary STL (at most {})",
                mesh.triangles.len(),
                u32::MAX
            ),
        });
    }
    super::write_atomically(path, |mut out| format.write(mesh, tag, &mut out))
}

/// The coordinate system a surface file says it is in, with 3D Slicer's
/// tag (`SPACE=RAS` or `SPACE=LPS` in its header or comments, or a `.vtp`'s
/// `SPACE` field-data string); `None` when it says nothing (Slicer then
/// assumes LPS) or cannot be read (loading it reports why).
pub fn coordinate_tag(path: &Path) -> Option<Space> {
    let format = Format::of(path).ok()?;
    let bytes = fs::read(path).ok()?;
    let header = match format {
        Format::Vtp => return vtk::vtp_space(&bytes),
        // Slicer reads the legacy header's second line, an STL's header
        // (its `solid` line or 80 bytes), a PLY's comments and an OBJ's
        // leading comments: a tag anywhere in the first lines will do.
        Format::Vtk | Format::Stl | Format::Ply | Format::Obj => {
            let end = bytes.len().min(1024);
            String::from_utf8_lossy(&bytes[..end]).into_owned()
        }
    };
    let header: String = match format {
        Format::Vtk => header.lines().nth(1).unwrap_or_default().to_owned(),
        Format::Stl => header.chars().take(80).collect(),
        Format::Ply => header
            .lines()
            .take_while(|l| l.trim() != "end_header")
            .filter(|l| l.starts_with("comment"))
            .collect::<Vec<_>>()
            .join("\n"),
        Format::Obj => header
            .lines()
            .take_while(|l| l.starts_with('#'))
            .collect::<Vec<_>>()
            .join("\n"),
        Format::Vtp => unreachable!("returned above"),
    };
    space_in(&header)
}

/// The space a header names as Slicer reads it: `SPACE=RAS` first, then
/// `SPACE=LPS`.
fn space_in(header: &str) -> Option<Space> {
    if header.contains("SPACE=RAS") {
        Some(Space::Ras)
    } else if header.contains("SPACE=LPS") {
        Some(Space::Lps)
    } else {
        None
    }
}

/// Splits a polygon into the fan of triangles around its first corner;
/// `Err(n)` for a polygon with fewer than three corners.
fn fan(polygon: &[u32], triangles: &mut Vec<[u32; 3]>) -> Result<(), usize> {
    let [first, rest @ ..] = polygon else {
        return Err(0);
    };
    if rest.len() < 2 {
        return Err(polygon.len());
    }
    triangles.extend(rest.windows(2).map(|w| [*first, w[0], w[1]]));
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]

    use super::*;

    #[test]
    fn fan_splits_a_pentagon_into_three_triangles() {
        let mut triangles = Vec::new();
        fan(&[0, 1, 2, 3, 4], &mut triangles).unwrap();
        assert_eq!(triangles, [[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        assert_eq!(fan(&[0, 1], &mut triangles), Err(2));
    }

    /// An octahedron with coordinates that are awkward to print.
    fn awkward_octahedron() -> SurfaceMesh {
        let (vertices, triangles) = tissue_testkit::awkward_octahedron();
        SurfaceMesh::new(vertices, triangles)
    }

    /// Every prefix of a valid file, and the file with each byte replaced by
    /// a few others: the readers may refuse them but must not panic.
    #[test]
    fn truncated_and_corrupted_files_never_panic() {
        let mesh = awkward_octahedron();
        let mut files = Vec::new();
        for format in [Format::Obj, Format::Stl, Format::Ply, Format::Vtk] {
            let mut bytes = Vec::new();
            format.write(&mesh, None, &mut bytes).unwrap();
            files.push((format, bytes));
        }
        // A binary little-endian PLY with int indices.
        let mut ply = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
             property float y\nproperty float z\nelement face {}\n\
             property list uchar int vertex_indices\nend_header\n",
            mesh.vertices.len(),
            mesh.triangles.len()
        )
        .into_bytes();
        ply.extend(
            mesh.vertices
                .iter()
                .flat_map(|v| v.to_array().map(f32::to_le_bytes))
                .flatten(),
        );
        for t in &mesh.triangles {
            ply.push(3);
            ply.extend(t.iter().flat_map(|i| i.to_le_bytes()));
        }
        files.push((Format::Ply, ply));

        for (format, bytes) in &files {
            let read = format.read(bytes).unwrap();
            assert_eq!(read.triangles.len(), mesh.triangles.len(), "{format:?}");
            for end in 0..bytes.len() {
                let _ = format.read(&bytes[..end]);
            }
            for at in 0..bytes.len() {
                for replacement in [b'9', b'-', b' ', b'\n', 0, 0xff] {
                    let mut corrupted = bytes.clone();
                    corrupted[at] = replacement;
                    let _ = format.read(&corrupted);
                }
            }
        }
    }

    #[test]
    fn extension_is_case_insensitive() {
        assert_eq!(Format::of(Path::new("a/B.STL")).unwrap(), Format::Stl);
        assert_eq!(Format::of(Path::new("x.Obj")).unwrap(), Format::Obj);
        assert!(matches!(
            Format::of(Path::new("mesh.off")),
            Err(Error::UnsupportedFormat { .. })
        ));
        assert!(Format::of(Path::new("no_extension")).is_err());
    }
}
