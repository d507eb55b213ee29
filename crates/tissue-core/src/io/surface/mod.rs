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
//!
//! Polygons are split into triangle fans. Every reader ends with an exact
//! [`weld`], so a vertex is one position however the file spelled it (STL
//! repeats each corner per triangle; OBJ may give one position several
//! texture coordinates). Vertices keep the file's order, except in OBJ
//! where they are numbered in order of first use by a face. Floats are
//! written so they read back bit for bit.

use std::collections::HashMap;
use std::fs;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{BufWriter, Cursor, Write};
use std::path::Path;

use glam::Vec3;

use crate::error::{Error, MeshError};
use crate::mesh::SurfaceMesh;
use crate::validate::{self, ShellsDropped, Validation};

/// The surface file extensions [`load_surface`] and [`save_surface`] accept.
pub const SURFACE_EXTENSIONS: &str = "stl, obj, ply, vtk";

/// [`load_closed_surface`] welds vertices closer than this times the
/// bounding-box diagonal: about one unit in the last place of an `f32`,
/// enough to absorb rounding in files written by other tools, far too small
/// to merge vertices that are meant to be apart.
pub const RELATIVE_WELD_TOLERANCE: f32 = 1e-7;

/// Choices for [`load_closed_surface_with`]; the default accepts only a
/// surface that is one closed shell as it stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoadOptions {
    /// Keep only the shell enclosing the most volume and drop the others
    /// ([`validate::keep_largest_shell`]) instead of refusing a surface of
    /// several shells with [`MeshError::SeveralShells`]. For files with stray
    /// specks beside the organ; what was dropped is logged and returned.
    /// Default `false`: a second shell may be a second organ, and sampling
    /// one of two without being asked would hide that.
    pub largest_shell: bool,
}

/// The surface formats, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Stl,
    Obj,
    Ply,
    Vtk,
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
            _ => Err(Error::UnsupportedFormat {
                path: path.to_path_buf(),
                expected: SURFACE_EXTENSIONS,
            }),
        }
    }

    /// Parses a whole file; the message says what is wrong.
    fn read(self, bytes: &[u8]) -> Result<SurfaceMesh, String> {
        match self {
            Self::Stl => read_stl(bytes),
            Self::Obj => read_obj(bytes),
            Self::Ply => read_ply(bytes),
            Self::Vtk => read_vtk(bytes),
        }
    }

    fn write(self, mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
        match self {
            Self::Obj => write_obj(mesh, out),
            Self::Stl => write_stl(mesh, out),
            Self::Ply => write_ply(mesh, out),
            Self::Vtk => write_vtk(mesh, out),
        }
    }
}

/// Reads a triangle surface from an STL, OBJ, PLY or legacy VTK file.
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
    Ok(weld(&parsed, 0.0))
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
/// let options = LoadOptions { largest_shell: true };
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

/// Merges vertices closer than `tolerance` (in the mesh's units), remaps
/// the triangles and drops vertices no triangle uses.
///
/// With `tolerance` 0 (or negative, or NaN) only exactly equal positions
/// merge (`-0.0` equals `0.0`). Otherwise vertices are visited in order and
/// each joins the first kept vertex within `tolerance`, found through a hash
/// grid of cell size `tolerance`, so the cost is linear. Non-finite
/// positions never merge. Kept vertices stay in their original order.
/// Triangles are kept even when welding makes two of their corners equal
/// ([`validate::validate`] reports those); an index out of range becomes
/// `u32::MAX`.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3};
/// use tissue_core::io::surface::weld;
///
/// // Two triangles that share an edge but each carry their own copy of it.
/// let soup = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X, Vec3::Y, Vec3::ONE, Vec3::NEG_ONE],
///     vec![[0, 1, 2], [3, 5, 4]],
/// );
/// let welded = weld(&soup, 0.0);
/// assert_eq!(welded.vertices, [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE]);
/// assert_eq!(welded.triangles, [[0, 1, 2], [1, 3, 2]]);
/// ```
pub fn weld(mesh: &SurfaceMesh, tolerance: f32) -> SurfaceMesh {
    let count = mesh.vertices.len();
    let mut used = vec![false; count];
    for &index in mesh.triangles.iter().flatten() {
        if let Some(u) = used.get_mut(index as usize) {
            *u = true;
        }
    }

    let mut welder = Welder::new(tolerance);
    let remap: Vec<u32> = mesh
        .vertices
        .iter()
        .zip(&used)
        .map(|(&p, &used)| if used { welder.insert(p) } else { u32::MAX })
        .collect();
    let triangles = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| remap.get(i as usize).copied().unwrap_or(u32::MAX)))
        .collect();
    SurfaceMesh::new(welder.vertices, triangles)
}

/// Kept vertices and a lookup from position to kept vertex.
struct Welder {
    vertices: Vec<Vec3>,
    lookup: Lookup,
}

enum Lookup {
    /// Exact positions, by bit pattern (after turning `-0.0` into `0.0`).
    Exact(FastMap<[u32; 3], u32>),
    /// A hash grid: the first kept vertex of each cell, and for each kept
    /// vertex the next one in the same cell (`u32::MAX` ends the chain).
    Grid {
        cell_size: f64,
        first: FastMap<[i64; 3], u32>,
        next: Vec<u32>,
    },
}

impl Welder {
    fn new(tolerance: f32) -> Self {
        let lookup = if tolerance > 0.0 && tolerance.is_finite() {
            Lookup::Grid {
                cell_size: f64::from(tolerance),
                first: FastMap::default(),
                next: Vec::new(),
            }
        } else {
            Lookup::Exact(FastMap::default())
        };
        Self {
            vertices: Vec::new(),
            lookup,
        }
    }

    /// The index of the kept vertex `p` merges into, adding `p` if none.
    fn insert(&mut self, p: Vec3) -> u32 {
        let new = self.vertices.len() as u32;
        if !p.is_finite() {
            self.vertices.push(p);
            if let Lookup::Grid { next, .. } = &mut self.lookup {
                next.push(u32::MAX);
            }
            return new;
        }
        let found = match &mut self.lookup {
            Lookup::Exact(seen) => {
                let key = (p + Vec3::ZERO).to_array().map(f32::to_bits);
                *seen.entry(key).or_insert(new)
            }
            Lookup::Grid {
                cell_size,
                first,
                next,
            } => {
                let cell = (p.as_dvec3() / *cell_size).floor().as_i64vec3().to_array();
                let limit = *cell_size * *cell_size;
                // The lowest-numbered kept vertex within reach, so the
                // result does not depend on the order cells are visited in.
                let mut found = new;
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let key = [
                                cell[0].saturating_add(dx),
                                cell[1].saturating_add(dy),
                                cell[2].saturating_add(dz),
                            ];
                            let mut at = first.get(&key).copied().unwrap_or(u32::MAX);
                            while at != u32::MAX {
                                let q = self.vertices[at as usize].as_dvec3();
                                if q.distance_squared(p.as_dvec3()) <= limit {
                                    found = found.min(at);
                                }
                                at = next[at as usize];
                            }
                        }
                    }
                }
                if found == new {
                    let head = first.entry(cell).or_insert(u32::MAX);
                    next.push(*head);
                    *head = new;
                }
                found
            }
        };
        if found == new {
            self.vertices.push(p);
        }
        found
    }
}

/// A hash map keyed by a few integers, with a multiply-rotate hash: the
/// keys are not attacker-chosen, and SipHash would triple the cost of welding.
type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<WordHasher>>;

#[derive(Default)]
struct WordHasher(u64);

impl WordHasher {
    fn add(&mut self, word: u64) {
        self.0 = (self.0 ^ word)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(26);
    }
}

impl Hasher for WordHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.add(u64::from_le_bytes(word));
        }
    }

    fn write_u32(&mut self, i: u32) {
        self.add(u64::from(i));
    }

    fn write_u64(&mut self, i: u64) {
        self.add(i);
    }

    fn write_i64(&mut self, i: i64) {
        self.add(i as u64);
    }

    fn write_usize(&mut self, i: usize) {
        self.add(i as u64);
    }

    fn finish(&self) -> u64 {
        // Final avalanche (murmur3's fmix64) so low and high bits both vary.
        let mut h = self.0;
        h ^= h >> 33;
        h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
        h ^= h >> 33;
        h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
        h ^ (h >> 33)
    }
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
    let io_error = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = fs::File::create(path).map_err(io_error)?;
    let mut out = BufWriter::new(file);
    format
        .write(mesh, &mut out)
        .and_then(|()| out.flush())
        .map_err(io_error)
}

// --- STL ---------------------------------------------------------------

/// Binary STL: 80-byte header, `u32` triangle count, then per triangle a
/// normal, three corners (12 little-endian `f32`) and a 2-byte attribute.
const STL_HEADER: usize = 84;
const STL_RECORD: usize = 50;

fn read_stl(bytes: &[u8]) -> Result<SurfaceMesh, String> {
    let announced = bytes
        .get(80..STL_HEADER)
        .and_then(|b| b.try_into().ok())
        .map(|b: [u8; 4]| u32::from_le_bytes(b) as usize);
    let binary_size = announced.map(|n| STL_HEADER.saturating_add(n.saturating_mul(STL_RECORD)));
    let text = bytes.trim_ascii_start();
    let looks_ascii = text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"solid");
    // Binary files whose header happens to start with "solid" are common, so
    // a size that matches the binary layout exactly wins.
    match (announced, binary_size) {
        (Some(n), Some(size)) if size == bytes.len() => Ok(read_binary_stl(bytes, n)),
        _ if looks_ascii => read_ascii_stl(text),
        (Some(n), Some(size)) if size < bytes.len() => {
            log::warn!(
                "binary STL has {} bytes after its {n} triangles; ignored",
                bytes.len() - size
            );
            Ok(read_binary_stl(bytes, n))
        }
        (Some(n), Some(size)) => Err(format!(
            "not an ASCII STL (does not start with `solid`) and not a binary STL: the header \
             announces {n} triangles ({size} bytes) but the file has {} bytes",
            bytes.len()
        )),
        _ => Err(format!(
            "not an ASCII STL (does not start with `solid`) and too short for a binary STL \
             ({} bytes, the header alone is {STL_HEADER})",
            bytes.len()
        )),
    }
}

/// Reads `triangles` records; the caller has checked the length.
fn read_binary_stl(bytes: &[u8], triangles: usize) -> SurfaceMesh {
    let corners = bytes[STL_HEADER..]
        .chunks_exact(STL_RECORD)
        .take(triangles)
        .flat_map(|record| {
            let float = |i: usize| {
                let at = 12 + 4 * i;
                f32::from_le_bytes([record[at], record[at + 1], record[at + 2], record[at + 3]])
            };
            (0..3).map(move |c| Vec3::new(float(3 * c), float(3 * c + 1), float(3 * c + 2)))
        });
    triangle_soup(corners)
}

fn read_ascii_stl(text: &[u8]) -> Result<SurfaceMesh, String> {
    // stl_io wants "solid " with a space; a bare "solid" line is also valid STL.
    let mut input = b"solid ".to_vec();
    input.extend_from_slice(&text[5..]);
    let indexed = stl_io::read_stl(&mut Cursor::new(input))
        .map_err(|e| format!("cannot parse ASCII STL: {e}"))?;
    let vertices: Vec<Vec3> = indexed
        .vertices
        .iter()
        .map(|v| Vec3::from_array(v.0))
        .collect();
    let triangles = indexed
        .faces
        .iter()
        .map(|f| f.vertices.map(|i| i as u32))
        .collect();
    Ok(SurfaceMesh::new(vertices, triangles))
}

/// A mesh with three fresh vertices per triangle, to be welded.
fn triangle_soup(corners: impl Iterator<Item = Vec3>) -> SurfaceMesh {
    let vertices: Vec<Vec3> = corners.collect();
    let triangles = (0..vertices.len() as u32 / 3)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    SurfaceMesh::new(vertices, triangles)
}

/// Binary STL; the caller has checked that the triangle count fits a `u32`.
fn write_stl(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
    let triangles = (0..mesh.triangles.len()).map(|t| {
        let [a, b, c] = mesh.corners(t);
        stl_io::Triangle {
            normal: stl_io::Normal::new((b - a).cross(c - a).normalize_or_zero().to_array()),
            vertices: [a, b, c].map(|v| stl_io::Vertex::new(v.to_array())),
        }
    });
    stl_io::write_stl(out, triangles)
}

// --- OBJ ---------------------------------------------------------------

fn read_obj(bytes: &[u8]) -> Result<SurfaceMesh, String> {
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

fn write_obj(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
    writeln!(
        out,
        "# tissue surface: {} vertices, {} triangles",
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
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

// --- PLY ---------------------------------------------------------------

fn read_ply(bytes: &[u8]) -> Result<SurfaceMesh, String> {
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

fn write_ply(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
    let index_type = if mesh.vertices.len() <= i32::MAX as usize {
        "int"
    } else {
        "uint"
    };
    write!(
        out,
        "ply\nformat ascii 1.0\ncomment tissue surface\n\
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

// --- legacy VTK ----------------------------------------------------------

fn read_vtk(bytes: &[u8]) -> Result<SurfaceMesh, String> {
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

fn write_vtk(mesh: &SurfaceMesh, out: &mut impl Write) -> std::io::Result<()> {
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
    fn fan_splits_a_pentagon_into_three_triangles() {
        let mut triangles = Vec::new();
        fan(&[0, 1, 2, 3, 4], &mut triangles).unwrap();
        assert_eq!(triangles, [[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        assert_eq!(fan(&[0, 1], &mut triangles), Err(2));
    }

    #[test]
    fn strip_keeps_the_orientation_of_its_first_triangle() {
        let mut triangles = Vec::new();
        strip(&[0, 1, 2, 3, 4], 10, &mut triangles);
        assert_eq!(triangles, [[10, 11, 12], [12, 11, 13], [12, 13, 14]]);
    }

    #[test]
    fn weld_with_tolerance_merges_near_duplicates_only() {
        let eps = 1e-6;
        let mesh = SurfaceMesh::new(
            vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec3::new(1.0 + eps, 0.0, 0.0),
                Vec3::new(0.0, 1.0, eps),
                Vec3::ONE,
            ],
            vec![[0, 1, 2], [3, 5, 4]],
        );
        assert_eq!(weld(&mesh, 0.0).vertices.len(), 6);
        let welded = weld(&mesh, 1e-5);
        assert_eq!(welded.vertices, [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE]);
        assert_eq!(welded.triangles, [[0, 1, 2], [1, 3, 2]]);
    }

    #[test]
    fn weld_merges_signed_zeros_but_never_nan() {
        let mesh = SurfaceMesh::new(
            vec![Vec3::ZERO, Vec3::new(-0.0, 0.0, -0.0), Vec3::NAN, Vec3::NAN],
            vec![[0, 1, 2], [0, 2, 3]],
        );
        for tolerance in [0.0, 0.5] {
            let welded = weld(&mesh, tolerance);
            assert_eq!(welded.vertices.len(), 3, "tolerance {tolerance}");
            assert_eq!(welded.triangles, [[0, 0, 1], [0, 1, 2]]);
        }
    }

    #[test]
    fn weld_survives_cells_beyond_i64() {
        let far = Vec3::new(3e38, -3e38, 0.0);
        let mesh = SurfaceMesh::new(vec![far, far, Vec3::ZERO], vec![[0, 1, 2]]);
        let welded = weld(&mesh, 1e-30);
        assert_eq!(welded.vertices, [far, Vec3::ZERO]);
        assert_eq!(welded.triangles, [[0, 0, 1]]);
    }

    #[test]
    fn weld_marks_out_of_range_indices() {
        let mesh = SurfaceMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 7]]);
        let welded = weld(&mesh, 0.0);
        assert_eq!(welded.vertices.len(), 2);
        assert_eq!(welded.triangles, [[0, 1, u32::MAX]]);
    }

    /// An octahedron with coordinates that are awkward to print.
    fn awkward_octahedron() -> SurfaceMesh {
        SurfaceMesh::new(
            vec![
                Vec3::new(1.0 / 3.0, 1e-30, -0.0),
                Vec3::new(-123_456.79, 0.1, 2.0 / 7.0),
                Vec3::new(f32::MIN_POSITIVE, 0.7, 1e-7),
                Vec3::NEG_Y,
                Vec3::new(0.3, 0.2, 3.4e38),
                Vec3::NEG_Z,
            ],
            vec![
                [0, 2, 4],
                [2, 1, 4],
                [1, 3, 4],
                [3, 0, 4],
                [2, 0, 5],
                [1, 2, 5],
                [3, 1, 5],
                [0, 3, 5],
            ],
        )
    }

    /// Every prefix of a valid file, and the file with each byte replaced by
    /// a few others: the readers may refuse them but must not panic.
    #[test]
    fn truncated_and_corrupted_files_never_panic() {
        let mesh = awkward_octahedron();
        let mut files = Vec::new();
        for format in [Format::Obj, Format::Stl, Format::Ply, Format::Vtk] {
            let mut bytes = Vec::new();
            format.write(&mesh, &mut bytes).unwrap();
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
