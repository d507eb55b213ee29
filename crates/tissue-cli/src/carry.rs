//! What the particles carry: internal structures (deformable or rigid) and
//! landmark points, bound to the rest particles once and moved after every solve.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use serde::Serialize;
use tissue::backend::BoundRigid;
use tissue::field::distances_outside;
use tissue::io::markups::{Markups, is_markups, load_markups};
use tissue::io::space::Space;
use tissue::structures::RigidMotion;
use tissue::{ParticleModel, SurfaceMesh};

use crate::backend::{BoundPoints, Solver};
use crate::output::{MARKUPS_FILE, PARTICLES_FILE, POINTS_FILE, REPORT_FILE};

/// Options naming what to carry, shared by `deform` and `track`.
#[derive(Debug, clap::Args)]
pub struct CarryArgs {
    /// Landmark points to carry (.csv, .ply, or a 3D Slicer markups file
    /// .mrk.json); the moved points are written as `points.csv`, in input
    /// order, or, for markups, as `points.mrk.json` with the same labels and
    /// coordinate system.
    #[arg(long, value_name = "FILE")]
    pub points: Option<PathBuf>,
    /// The coordinate system of the model and the surfaces: `lps` (how 3D
    /// Slicer saves models) or `ras`. Markups in the other system are
    /// converted on reading and back on writing; transform files (.tfm,
    /// .nrrd) are written in LPS, as ITK and Slicer read them.
    #[arg(long, default_value = "lps", value_parser = parse_space)]
    pub space: Space,
    /// An internal structure that deforms with the tissue (any surface file);
    /// every vertex is carried. Written under its own file name. Repeatable.
    #[arg(long = "structure", value_name = "FILE")]
    pub structures: Vec<PathBuf>,
    /// An internal structure that moves rigidly (a stiff tumour); its motion
    /// is fitted to the particles around its centroid. Written under its own
    /// file name, or `<stem>-rigid.<ext>` when that name is taken. Repeatable.
    #[arg(long = "rigid-structure", value_name = "FILE")]
    pub rigid_structures: Vec<PathBuf>,
}

impl CarryArgs {
    /// The files these options read, as `(what, path)`.
    pub fn inputs(&self) -> Vec<(&'static str, &Path)> {
        let points = self.points.iter().map(|p| ("points file", p.as_path()));
        let structures = self
            .structures
            .iter()
            .chain(&self.rigid_structures)
            .map(|p| ("structure", p.as_path()));
        points.chain(structures).collect()
    }
}

/// `--space`: `lps` or `ras`, in any case.
fn parse_space(text: &str) -> Result<Space, String> {
    text.parse()
}

/// How a structure moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// Vertex by vertex with the particles around it.
    Deformable,
    /// As one rigid body.
    Rigid,
}

impl Kind {
    fn word(self) -> &'static str {
        match self {
            Kind::Deformable => "deformable",
            Kind::Rigid => "rigid",
        }
    }
}

/// Points farther outside the model's rest surface than this many mean
/// connection lengths are flagged: no particle neighbourhood holds them,
/// and they are carried by extrapolation (a wrong frame or units, most
/// likely). docs/FORMATS.md, "Exit codes and files".
pub const OUTSIDE_SPACINGS: f32 = 1.0;

/// How many of a set of rest points lie outside the model's rest surface
/// by more than [`OUTSIDE_SPACINGS`], and the farthest.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Outside {
    /// Points beyond the tolerance.
    pub count: usize,
    /// The largest distance outside the rest surface of any point (0 when
    /// every point is inside).
    pub max_mm: f32,
}

impl Outside {
    /// Points `distances` outside the rest surface; `tolerance` in model
    /// units.
    fn of(distances: &[f32], tolerance: f32) -> Self {
        distances.iter().fold(Self::default(), |o, &d| Self {
            count: o.count + usize::from(d > tolerance),
            max_mm: o.max_mm.max(d),
        })
    }
}

/// Points farther than this many of the rest surface's bounding-box
/// diagonals from its centre are refused: no particle can carry them (their
/// extrapolation overflows single precision long before 1e20), and they
/// are a unit or typing mistake rather than a place in the patient.
pub const FARTHEST_DIAGONALS: f32 = 1000.0;

/// The rest surface and the tolerance of [`Outside`], for a model.
pub struct OutsideCheck {
    rest: SurfaceMesh,
    tolerance: f32,
    centre: Vec3,
    diagonal: f32,
}

impl OutsideCheck {
    /// For a model with rest surface `rest` and mean connection length `spacing`.
    pub fn new(rest: &SurfaceMesh, spacing: f32) -> Self {
        let diagonal = rest
            .bounds()
            .map_or(1.0, |(lo, hi)| (hi - lo).length())
            .max(f32::MIN_POSITIVE);
        let tolerance = OUTSIDE_SPACINGS * spacing.max(1e-6 * diagonal);
        let centre = rest.bounds().map_or(Vec3::ZERO, |(lo, hi)| 0.5 * (lo + hi));
        Self {
            rest: rest.clone(),
            tolerance,
            centre,
            diagonal,
        }
    }

    fn check(&self, what: &str, points: &[Vec3]) -> Result<Outside> {
        let farthest = FARTHEST_DIAGONALS * self.diagonal;
        if let Some((k, p)) = points.iter().enumerate().find(|(_, p)| {
            let distance = p.distance(self.centre);
            distance.is_nan() || distance > farthest
        }) {
            bail!(
                "{what}: point {} is at {p}, more than {FARTHEST_DIAGONALS} times the organ's \
                 size ({:.3}) from it: no particle can carry it; is it in another unit, or \
                 mistyped?",
                k + 1,
                self.diagonal
            );
        }
        let distances = distances_outside(&self.rest, points)
            .map_err(|e| anyhow::anyhow!("the model's rest surface: {e}"))?;
        let outside = Outside::of(&distances, self.tolerance);
        if outside.count > 0 {
            log::warn!(
                "{} of {} points of {what} lie outside the model's rest surface, up to {:.2} \
                 (more than one particle spacing, {:.2}): they are carried by extrapolation; \
                 check their frame and units",
                outside.count,
                points.len(),
                outside.max_mm,
                self.tolerance
            );
        }
        Ok(outside)
    }
}

/// How the structure is bound to the rest particles.
#[derive(Debug)]
enum Binding {
    /// Every vertex carried.
    Deformable(BoundPoints),
    /// The centre carried, the rotation fitted to the particles around it.
    Rigid(BoundRigid),
}

/// One internal structure, bound at rest.
#[derive(Debug)]
pub struct Structure {
    /// The file name it is written under, e.g. `tumour.obj`.
    pub name: String,
    /// Where it came from: a path, or a description for a built-in one.
    pub source: String,
    rest: SurfaceMesh,
    binding: Binding,
    /// Its rest vertices outside the model's rest surface.
    pub outside: Outside,
}

/// Landmark points bound at rest.
#[derive(Debug)]
pub struct Points {
    /// Where they came from.
    pub source: String,
    /// The markups file they were read from, written back moved; `None`
    /// for a CSV or PLY file.
    pub markups: Option<Markups>,
    carrier: BoundPoints,
    /// The points outside the model's rest surface.
    pub outside: Outside,
}

/// Everything the particles carry.
#[derive(Debug, Default)]
pub struct Carried {
    /// Landmark points, if any.
    pub points: Option<Points>,
    /// Structures, deformable ones first, each in the order given.
    pub structures: Vec<Structure>,
    /// The coordinate system of the model and the surfaces (`--space`).
    pub space: Space,
}

/// Where one structure went, as the JSON report holds it.
#[derive(Debug, Clone, Serialize)]
pub struct StructureReport {
    /// The output file name.
    pub name: String,
    /// How it moved.
    pub kind: Kind,
    /// The file it was read from.
    pub source: String,
    /// Mean of its rest vertices.
    pub rest_centroid: [f32; 3],
    /// Mean of its moved vertices (for a rigid one, where the motion takes the rest centroid).
    pub moved_centroid: [f32; 3],
    /// Distance between the two centroids, in the model's units (mm for the phantom).
    pub displacement_mm: f32,
    /// Largest distance any vertex moved.
    pub max_vertex_displacement_mm: f32,
    /// For a rigid structure, the angle of its rotation in degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_degrees: Option<f32>,
    /// For a rigid structure, the 4x4 homogeneous transform (row-major)
    /// taking rest coordinates to moved ones.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transform: Option<[[f32; 4]; 4]>,
    /// For a rigid structure, the ITK transform file its motion is written
    /// to ([`Structure::transform_file`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transform_file: Option<String>,
    /// Its rest vertices outside the model's rest surface (flagged).
    pub outside: Outside,
}

/// A structure after a solve.
#[derive(Debug, Clone)]
pub struct MovedStructure {
    /// The structure at its new place: same vertices, same triangles.
    pub mesh: SurfaceMesh,
    /// Where it went.
    pub report: StructureReport,
}

impl Carried {
    /// Reads and binds what `args` names to the solver's rest particles.
    /// Reads and binds what `args` names; warns of points or vertices
    /// outside `model`'s rest surface ([`Outside`]).
    pub fn load(args: &CarryArgs, solver: &Solver, model: &ParticleModel) -> Result<Self> {
        let names = output_names(&args.structures, &args.rigid_structures)?;
        let any = args.points.is_some()
            || !args.structures.is_empty()
            || !args.rigid_structures.is_empty();
        let check = any.then(|| OutsideCheck::new(&model.surface, model.mean_connection_length()));
        let points = match &args.points {
            Some(path) => {
                let markups = if is_markups(path) {
                    Some(load_markups(path, args.space)?)
                } else {
                    None
                };
                let points = match &markups {
                    Some(markups) => markups.points().to_vec(),
                    None => tissue::load_points(path)?,
                };
                let source = path.display().to_string();
                let outside = match &check {
                    Some(c) => c.check(&source, &points)?,
                    None => Outside::default(),
                };
                Some(Points {
                    source,
                    markups,
                    carrier: solver.bind(&points)?,
                    outside,
                })
            }
            None => None,
        };
        let mut named = Vec::new();
        let spacing = model.mean_connection_length();
        for path in &args.structures {
            let mesh = load(path, args.space, spacing)?;
            named.push((Kind::Deformable, path.display().to_string(), mesh));
        }
        for path in &args.rigid_structures {
            let mesh = load(path, args.space, spacing)?;
            named.push((Kind::Rigid, path.display().to_string(), mesh));
        }
        let structures = named
            .into_iter()
            .zip(names)
            .map(|((kind, source, mesh), name)| {
                let mut structure = Structure::bind(name, source, kind, mesh, solver)?;
                if let Some(check) = &check {
                    structure.outside = check.check(&structure.source, &structure.rest.vertices)?;
                }
                Ok(structure)
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            points,
            structures,
            space: args.space,
        })
    }

    /// Whether a point or structure was flagged as outside the organ.
    pub fn flagged(&self) -> bool {
        self.points.as_ref().is_some_and(|p| p.outside.count > 0)
            || self.structures.iter().any(|s| s.outside.count > 0)
    }

    /// Where the points and structures are for the solver's current state.
    pub fn moved(&self, solver: &Solver) -> Result<(Option<Vec<Vec3>>, Vec<MovedStructure>)> {
        let points = match &self.points {
            Some(p) => Some(solver.carry(&p.carrier)?),
            None => None,
        };
        let structures = self
            .structures
            .iter()
            .map(|s| s.moved(solver))
            .collect::<Result<_>>()?;
        Ok((points, structures))
    }
}

/// The particles that carry a target and their weights (summing to one).
pub type Carriers = Vec<(u32, f32)>;

impl Carried {
    /// Per landmark point, and per structure (by name) for its centroid,
    /// the particles that carry it and their weights: the targets of the
    /// uncertainty's regions. A deformable structure's centroid is the
    /// mean of its vertices, a rigid one's carried as a landmark.
    pub fn target_carriers(&self) -> (Option<Vec<Carriers>>, Vec<(String, Carriers)>) {
        let points = self.points.as_ref().map(|p| p.carrier.carriers().to_vec());
        let structures = self
            .structures
            .iter()
            .map(|s| {
                let carriers = match &s.binding {
                    Binding::Deformable(bound) => {
                        let share = 1.0 / bound.carriers().len().max(1) as f32;
                        bound
                            .carriers()
                            .iter()
                            .flatten()
                            .map(|&(j, w)| (j, w * share))
                            .collect()
                    }
                    Binding::Rigid(rigid) => rigid.centre().carriers().concat(),
                };
                (s.name.clone(), carriers)
            })
            .collect();
        (points, structures)
    }
}

impl Points {
    /// The file name the moved points are written under: `points.mrk.json`
    /// for markups, else `points.csv`.
    pub fn output_name(&self) -> &'static str {
        if self.markups.is_some() {
            MARKUPS_FILE
        } else {
            POINTS_FILE
        }
    }

    /// The points at rest, in input order.
    pub fn rest(&self) -> &[Vec3] {
        self.carrier.rest()
    }
}

impl Structure {
    /// The structure at rest.
    pub fn rest_mesh(&self) -> &SurfaceMesh {
        &self.rest
    }

    /// Binds `mesh` (rest coordinates) to the solver's rest particles.
    pub fn bind(
        name: String,
        source: String,
        kind: Kind,
        mesh: SurfaceMesh,
        solver: &Solver,
    ) -> Result<Self> {
        let binding = match kind {
            Kind::Deformable => Binding::Deformable(solver.bind(&mesh.vertices)?),
            Kind::Rigid => Binding::Rigid(solver.bind_rigid(&mesh.vertices)?),
        };
        Ok(Self {
            name,
            source,
            rest: mesh,
            binding,
            outside: Outside::default(),
        })
    }

    /// For a rigid structure, the file name of its motion as an ITK
    /// transform: `tumour.obj` -> `tumour-rigid.tfm` (and `tumour-rigid.obj`
    /// -> `tumour-rigid.tfm`).
    pub fn transform_file(&self) -> Option<String> {
        if self.kind() != Kind::Rigid {
            return None;
        }
        let stem = Path::new(&self.name)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("structure");
        Some(if stem.ends_with("-rigid") {
            format!("{stem}.tfm")
        } else {
            format!("{stem}-rigid.tfm")
        })
    }

    /// How the structure moves.
    pub fn kind(&self) -> Kind {
        match self.binding {
            Binding::Deformable(_) => Kind::Deformable,
            Binding::Rigid(..) => Kind::Rigid,
        }
    }

    fn moved(&self, solver: &Solver) -> Result<MovedStructure> {
        let rest_centroid = centroid(&self.rest.vertices);
        let (vertices, moved_centroid, motion) = match &self.binding {
            Binding::Deformable(carrier) => {
                let vertices = solver.carry(carrier)?;
                let c = centroid(&vertices);
                (vertices, c, None)
            }
            Binding::Rigid(bound) => {
                let motion = solver.carry_rigid(bound)?;
                let vertices = self
                    .rest
                    .vertices
                    .iter()
                    .map(|&x| motion.apply(x))
                    .collect();
                (vertices, motion.moved_centre, Some(motion))
            }
        };
        let max_vertex_displacement_mm = self
            .rest
            .vertices
            .iter()
            .zip(&vertices)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f32::max);
        let mesh = SurfaceMesh::new(vertices, self.rest.triangles.clone());
        Ok(MovedStructure {
            mesh,
            report: StructureReport {
                name: self.name.clone(),
                kind: self.kind(),
                source: self.source.clone(),
                rest_centroid: rest_centroid.to_array(),
                moved_centroid: moved_centroid.to_array(),
                displacement_mm: rest_centroid.distance(moved_centroid),
                max_vertex_displacement_mm,
                rotation_degrees: motion.as_ref().map(rotation_degrees),
                transform: motion.as_ref().map(RigidMotion::homogeneous),
                transform_file: self.transform_file(),
                outside: self.outside,
            },
        })
    }
}

impl StructureReport {
    /// One line for the terminal, e.g.
    /// `tumour.obj (rigid): centroid moved 2.31 mm (+0.05, -2.20, -0.70), turned 1.2°`.
    pub fn line(&self) -> String {
        let d = Vec3::from_array(self.moved_centroid) - Vec3::from_array(self.rest_centroid);
        let mut line = format!(
            "{} ({}): centroid moved {:.2} mm ({:+.2}, {:+.2}, {:+.2})",
            self.name,
            self.kind.word(),
            self.displacement_mm,
            d.x,
            d.y,
            d.z
        );
        if let Some(angle) = self.rotation_degrees {
            line += &format!(", turned {angle:.2}°");
        }
        line
    }
}

/// A structure smaller than this fraction of the model's mean connection
/// length is refused: it is in another unit (metres in a model in
/// millimetres), not a structure the particles can carry.
pub const SMALLEST_STRUCTURE: f32 = 0.01;

/// Refuses a surface file whose 3D Slicer coordinate tag (`SPACE=RAS` or
/// `SPACE=LPS`, [`tissue::coordinate_tag`]) names another system than the
/// run's `--space`: read as it is, it would be mirrored in x and y.
pub fn check_space_tag(path: &Path, space: Space) -> Result<()> {
    match tissue::coordinate_tag(path) {
        Some(tagged) if tagged != space => bail!(
            "{}: the file says its coordinates are {tagged} (its SPACE={tagged} tag, as 3D \
             Slicer writes it), but the run's coordinates are {space}: give --space {}, or \
             save the file in {space}",
            path.display(),
            tagged.name().to_ascii_lowercase()
        ),
        _ => Ok(()),
    }
}

/// Reads a structure's surface and refuses non-finite coordinates, a
/// coordinate tag other than `space`, and a structure far smaller than the
/// particles' `spacing` (another unit).
fn load(path: &Path, space: Space, spacing: f32) -> Result<SurfaceMesh> {
    check_space_tag(path, space)?;
    let mesh = tissue::load_surface(path)?;
    if let Some((v, p)) = mesh
        .vertices
        .iter()
        .enumerate()
        .find(|(_, p)| !p.is_finite())
    {
        bail!(
            "{}: vertex {v} is not finite: {p} (a structure must have finite coordinates)",
            path.display()
        );
    }
    let across = mesh
        .bounds()
        .map_or(0.0, |(lo, hi)| (hi - lo).max_element());
    if across < SMALLEST_STRUCTURE * spacing {
        bail!(
            "{}: the structure is {across:.3e} across, less than a hundredth of the model's \
             particle spacing ({spacing:.3}): is it in another unit than the model (metres in a \
             model in millimetres)?",
            path.display()
        );
    }
    Ok(mesh)
}

/// Output file names: each structure's own, a rigid one whose name a
/// deformable one already has gets `-rigid` before its extension; two of the
/// same kind with the same name are an error.
fn output_names(deformable: &[PathBuf], rigid: &[PathBuf]) -> Result<Vec<String>> {
    let mut taken: HashMap<String, &Path> = HashMap::new();
    let mut names = Vec::new();
    for (path, is_rigid) in deformable
        .iter()
        .map(|p| (p, false))
        .chain(rigid.iter().map(|p| (p, true)))
    {
        let mut name = path
            .file_name()
            .and_then(|n| n.to_str())
            .map(str::to_owned)
            .with_context(|| format!("{}: not a file name", path.display()))?;
        if is_rigid && taken.contains_key(&name) {
            name = rigid_name(path);
        }
        if let Some(other) = taken.get(&name) {
            bail!(
                "{} and {} would both be written as {name}; give them different file names",
                other.display(),
                path.display()
            );
        }
        if [PARTICLES_FILE, POINTS_FILE, MARKUPS_FILE, REPORT_FILE].contains(&name.as_str()) {
            bail!(
                "{}: a structure may not be called {name}, the name of another output file",
                path.display()
            );
        }
        taken.insert(name.clone(), path);
        names.push(name);
    }
    Ok(names)
}

/// `tumour.obj` -> `tumour-rigid.obj`.
fn rigid_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("structure");
    match path.extension().and_then(|e| e.to_str()) {
        Some(ext) => format!("{stem}-rigid.{ext}"),
        None => format!("{stem}-rigid"),
    }
}

/// Vertex mean, summed in `f64`.
fn centroid(points: &[Vec3]) -> Vec3 {
    let sum = points
        .iter()
        .fold(glam::DVec3::ZERO, |s, p| s + p.as_dvec3());
    (sum / points.len().max(1) as f64).as_vec3()
}

/// The angle of a rotation: `atan2(sin, cos)` with `2 sin` the length of the
/// skew part's axial vector and `2 cos + 1` the trace, accurate for small angles
/// (unlike `acos` of the trace alone).
fn rotation_degrees(motion: &RigidMotion) -> f32 {
    let r = motion.rotation;
    let axial = Vec3::new(r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]);
    let cos = 0.5 * (r[0][0] + r[1][1] + r[2][2] - 1.0);
    (0.5 * axial.length()).atan2(cos).to_degrees()
}
