//! Errors of the core crate: one enum per concern, one top-level wrapper.

use std::path::PathBuf;

use thiserror::Error;

/// A parameter out of its range.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("parameter {name} is {value}, expected {expected}")]
pub struct ParamError {
    /// The parameter's name, as its field in `SamplingParams` or `DeformParams`.
    pub name: &'static str,
    /// The value given, as written by Rust's shortest round-trip formatting.
    pub value: String,
    /// What it should be.
    pub expected: String,
}

impl ParamError {
    /// `Ok` when `ok`, else the error naming `name`, its `value` and what
    /// it should be: one check of a `validate`.
    pub fn check(
        ok: bool,
        name: &'static str,
        value: impl std::fmt::Display,
        expected: impl Into<String>,
    ) -> Result<(), Self> {
        if ok {
            Ok(())
        } else {
            Err(Self {
                name,
                value: value.to_string(),
                expected: expected.into(),
            })
        }
    }
}

/// A surface mesh that cannot be used: what is wrong, how often, and one place.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The mesh has no triangles (or no vertices).
    #[error("the surface is empty: {vertices} vertices, {triangles} triangles")]
    Empty {
        /// Vertices read.
        vertices: usize,
        /// Triangles read.
        triangles: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("{count} vertices have non-finite coordinates, e.g. vertex {example} = {value:?}")]
    NonFinite {
        /// How many vertices.
        count: usize,
        /// One such vertex index.
        example: usize,
        /// Its coordinates.
        value: [f32; 3],
    },
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "{count} triangles refer to missing vertices, e.g. triangle {example} uses vertex {vertex} of {vertices}"
    )]
    IndexOutOfRange {
        /// How many triangles.
        count: usize,
        /// One such triangle.
        example: usize,
        /// The bad index.
        vertex: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A bounding-box diagonal outside `validate::SIZE_RANGE`.
    #[error(
        "the surface is {diagonal:e} across (its bounding-box diagonal): tissue computes with sizes from {:e} to {:e} in the file's units (an organ is about 0.1 in metres, 100 in millimetres); rescale it",
        range.0,
        range.1
    )]
    Size {
        /// The bounding-box diagonal.
        diagonal: f64,
        /// The sizes accepted.
        range: (f64, f64),
    },
    /// A triangle with (near) zero area or repeated corners.
    #[error(
        "{count} degenerate triangles (zero area or repeated corners), e.g. triangle {example} at {at:?}"
    )]
    Degenerate {
        /// How many triangles.
        count: usize,
        /// One such triangle.
        example: usize,
        /// Its centroid.
        at: [f32; 3],
    },
    /// Edges used by only one triangle: the surface has holes.
    #[error("the surface is open: {count} boundary edges, e.g. the edge between {at:?} and {to:?}")]
    Open {
        /// How many boundary edges.
        count: usize,
        /// One end of one such edge.
        at: [f32; 3],
        /// Its other end.
        to: [f32; 3],
    },
    /// Edges shared by more than two triangles.
    #[error(
        "the surface is non-manifold: {count} edges are shared by more than two triangles, e.g. the edge between {at:?} and {to:?}"
    )]
    NonManifold {
        /// How many such edges.
        count: usize,
        /// One end of one such edge.
        at: [f32; 3],
        /// Its other end.
        to: [f32; 3],
    },
    /// Neighbouring triangles wind in opposite directions.
    #[error(
        "the surface is inconsistently oriented: {count} edges are traversed in the same direction by both their triangles, e.g. the edge between {at:?} and {to:?}"
    )]
    InconsistentOrientation {
        /// How many such edges.
        count: usize,
        /// One end of one such edge.
        at: [f32; 3],
        /// Its other end.
        to: [f32; 3],
    },
    /// More than one connected piece.
    #[error(
        "the surface has {count} disconnected shells (expected one closed surface); the second starts at triangle {example} at {at:?}; to sample only the largest shell, use --largest-shell (`LoadOptions::largest_shell`)"
    )]
    SeveralShells {
        /// Number of shells.
        count: usize,
        /// First triangle of the second shell.
        example: usize,
        /// Its centroid.
        at: [f32; 3],
    },
    /// The closed surface encloses no volume.
    #[error("the surface encloses no volume (signed volume {volume})")]
    ZeroVolume {
        /// The signed volume.
        volume: f64,
    },
}

/// Why a surface field (or an exact distance query) cannot be made for a
/// surface ([`crate::field::SurfaceField::new`],
/// [`crate::field::distances_outside`]).
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum FieldError {
    /// The surface has no vertices.
    #[error("the surface has no vertices")]
    NoVertices,
    /// The cell size is not a positive number.
    #[error("field cell size {0} is not a positive number")]
    Cell(f32),
    /// The exact margin is not a non-negative number.
    #[error("field margin {0} is not a non-negative number")]
    Margin(f32),
    /// The grid over the surface's box would be absurdly large.
    #[error(
        "the surface field would need {cells:.0} cells (more than {most:.0}); the particle \
         count is too large for this surface's bounding box"
    )]
    TooManyCells {
        /// Cells the grid would need.
        cells: f64,
        /// The most allowed.
        most: f64,
    },
    /// The triangles cannot be oriented consistently (parry3d's reason).
    #[error("the surface cannot be oriented: {0}")]
    NotOrientable(String),
    /// A point cloud's normals do not match its points one to one.
    #[error("{normals} normals for {points} points")]
    NormalCount {
        /// Points in the cloud.
        points: usize,
        /// Normals given.
        normals: usize,
    },
}

/// Why stage 1 could not produce a model.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SamplingError {
    /// The surface has no vertices.
    #[error("the surface has no vertices")]
    NoVertices,
    /// The surface encloses no positive volume.
    #[error("the surface encloses no positive volume ({volume}); validate it first")]
    NoVolume {
        /// The signed volume.
        volume: f64,
    },
    /// The surface field could not be built.
    #[error(transparent)]
    Field(#[from] FieldError),
    /// Too few random starting points fell inside the surface.
    #[error("only {placed} of {attempts} random points fell inside the surface")]
    RandomPlacement {
        /// Points inside.
        placed: usize,
        /// Points tried.
        attempts: usize,
    },
    /// The starting lattice did not fit inside the surface.
    #[error(
        "could not place {particles} lattice points inside the surface; is it closed and large enough?"
    )]
    LatticePlacement {
        /// Particles asked for.
        particles: usize,
    },
    /// The iterations diverged.
    #[error(
        "the particle state became non-finite at iteration {iteration}; the parameters make the system unstable"
    )]
    Unstable {
        /// The iteration (counted from 0) whose state was not finite.
        iteration: usize,
    },
    /// Every particle lies on the surface: stage 2 would have nothing to move.
    #[error(
        "all {particles} particles lie on the surface, none inside for the deformation to move: \
         sample more particles"
    )]
    NoInterior {
        /// Particles in the model.
        particles: usize,
    },
    /// Too many particles have too few connections, or all of them in one
    /// plane, to carry a rotation: the model is too coarse for its shape.
    #[error(
        "{weak} of {particles} particles have fewer than 3 connections or all of them in one plane \
         ({percent:.0} %, at most {limit:.0} % allowed), e.g. particle {example} at {at:?}, so the \
         model cannot carry rotations: sample more particles (the thinnest part of the shape, \
         there, needs several across)"
    )]
    TooFewConnections {
        /// Particles that cannot carry a rotation.
        weak: usize,
        /// The first of them, in the thin part of the shape.
        example: usize,
        /// Its position.
        at: [f32; 3],
        /// Particles in the model.
        particles: usize,
        /// `weak` as a percentage.
        percent: f64,
        /// The largest percentage accepted.
        limit: f64,
    },
    /// A particle's position or radius is not finite, so no grid holds it.
    #[error("a particle's position or radius is not finite: no grid")]
    NonFiniteParticle,
    /// A grid or neighbour-row size that is not a finite number.
    #[error("{what} must be finite, not {value}")]
    NonFiniteSize {
        /// Which size.
        what: &'static str,
        /// The value given.
        value: String,
    },
}

/// Why stage 2 cannot run or go on.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum DeformError {
    /// The deformed surface has other counts than the rest surface.
    #[error(
        "the deformed surface has {vertices} vertices and {triangles} triangles; the model's rest surface has {rest_vertices} and {rest_triangles} (it must be the same mesh with moved vertices)"
    )]
    SurfaceSize {
        /// Vertices of the deformed surface.
        vertices: usize,
        /// Its triangles.
        triangles: usize,
        /// Vertices of the rest surface.
        rest_vertices: usize,
        /// Its triangles.
        rest_triangles: usize,
    },
    /// A triangle of the deformed surface differs from the rest surface's.
    #[error(
        "triangle {triangle} of the deformed surface is {deformed:?}, in the rest surface {rest:?} (it must be the same mesh with moved vertices)"
    )]
    TriangleMismatch {
        /// The triangle.
        triangle: usize,
        /// Its corners in the deformed surface.
        deformed: [u32; 3],
        /// Its corners in the rest surface.
        rest: [u32; 3],
    },
    /// A vertex of the deformed surface is NaN or infinite.
    #[error("vertex {vertex} of the deformed surface is not finite: {value}")]
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
        /// Its coordinates.
        value: glam::Vec3,
    },
    /// The deformed surface encloses an implausible volume: turned inside
    /// out (mirrored), collapsed, or in other units than the rest surface.
    #[error(
        "the deformed surface encloses {ratio:.3} times the rest surface's volume; soft tissue keeps \
         its volume, so anything outside {min} to {max} is refused (a mirrored or inside-out \
         surface is negative; other units change it by a power of ten)"
    )]
    ImplausibleVolume {
        /// Deformed over rest volume (signed).
        ratio: f64,
        /// The smallest ratio accepted.
        min: f64,
        /// The largest ratio accepted.
        max: f64,
    },
    /// No particle is on the surface, so nothing follows it.
    #[error("the model has no surface particles to follow the surface")]
    NoControlPoints,
    /// The observed-vertex mask is not one flag per surface vertex.
    #[error(
        "the observed-vertex mask has {got} flags, but the model's surface has {vertices} vertices"
    )]
    ObservedLength {
        /// Flags given.
        got: usize,
        /// Vertices of the model's surface.
        vertices: usize,
    },
    /// No surface particle lies on a triangle whose vertices are all
    /// observed, so nothing pins the model to the surface.
    #[error(
        "no surface particle is observed: {observed} of the surface's {vertices} vertices are \
         observed, and a particle follows the surface only where all three vertices of its \
         triangle are"
    )]
    NothingObserved {
        /// Observed vertices.
        observed: usize,
        /// Vertices of the model's surface.
        vertices: usize,
    },
    /// The two-level solve's coarse space cannot be built.
    #[error("{0}")]
    CoarseSpace(String),
    /// Points bound on one backend were carried by a solver on another.
    #[error("points bound on one backend were carried by another")]
    OtherBackend,
    /// The springs towards an observation do not fit the model.
    #[error("the springs towards the observation: {0}")]
    Springs(String),
}

/// Why a point cloud cannot serve as an observation.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ObservationError {
    /// Too few points to fit a plane through each one's neighbours.
    #[error(
        "the point cloud has {count} points; at least {least} are needed to estimate its normals"
    )]
    TooFew {
        /// Points in the cloud.
        count: usize,
        /// The fewest accepted.
        least: usize,
    },
    /// A point is NaN or infinite.
    #[error("point {index} of the cloud is not finite: {value}")]
    NotFinite {
        /// The point.
        index: usize,
        /// Its coordinates.
        value: glam::Vec3,
    },
    /// The points span no surface.
    #[error("the point cloud's points all lie on one line or at one point: it shows no surface")]
    Degenerate,
    /// The cloud is far larger or smaller than the organ: another unit.
    #[error(
        "the point cloud spans {ratio:.3} times the organ's size; an organ's scan spans from a \
         fiftieth to five times it{hint}"
    )]
    Scale {
        /// The cloud's bounding-box diagonal over the organ's.
        ratio: f32,
        /// The likely cause, when a unit explains the ratio.
        hint: String,
    },
    /// The cloud lies away from the organ: another coordinate frame.
    #[error(
        "the point cloud's centre lies {distance:.1} from the organ's bounding box, more than the \
         organ's size ({size:.1}): it is in another coordinate frame (align it first) or shows \
         something else"
    )]
    Elsewhere {
        /// Distance from the cloud's centroid to the organ's bounding box.
        distance: f32,
        /// The organ's bounding-box diagonal.
        size: f32,
    },
    /// The grid over the cloud could not be built.
    #[error(transparent)]
    Field(#[from] FieldError),
    /// No skin particle could be paired with the observation.
    #[error(
        "none of the model's {skin} free skin particles lies near the observation (all past a \
         cloud's edge or beyond the trim): it shows another part of the organ, or lies in \
         another frame"
    )]
    Unpaired {
        /// Free skin particles.
        skin: usize,
    },
    /// Meeting the observation would change the organ's volume by more
    /// than soft tissue does.
    #[error("{}", volume_change_message(*change, *mean, *most))]
    VolumeChange {
        /// The implied volume over the rest volume, less one.
        change: f32,
        /// The observed points' mean signed distance from the rest skin
        /// (positive outside).
        mean: f32,
        /// The largest change taken.
        most: f32,
    },
    /// The fiducials given to align an observation give no rigid motion.
    #[error("the fiducials cannot align the observation: {reason}")]
    Fiducials {
        /// What is wrong with them.
        reason: String,
    },
    /// No part of the rest surface lies on an observed closed surface.
    #[error(
        "no part of the model's rest surface lies on it (within {tolerance:.3}): nothing is known \
         to be held; give the held region (the chest wall)"
    )]
    NothingHeld {
        /// How near a rest vertex must be.
        tolerance: f32,
    },
    /// The held region does not lie on an observed closed surface.
    #[error(
        "the held region (the chest wall) lies {distance:.3} from the observed surface (the median \
         over its rest vertices), more than {most:.3}, though it does not move: the surface is in \
         another coordinate frame (put it in the model's first) or the held region is not where \
         the organ is fixed"
    )]
    HeldOff {
        /// The median distance of the held rest vertices from the surface.
        distance: f32,
        /// The most that is taken.
        most: f32,
    },
    /// The observation lies too far from the model's skin to be of it.
    #[error(
        "the observation lies {median:.3} from the model's skin (a median distance), more than \
         {most:.3}, a quarter of the model's size: it is in other units, in another frame (align \
         it first), or of another organ"
    )]
    Unreachable {
        /// The median distance of the free skin from the observation.
        median: f32,
        /// The most that is taken.
        most: f32,
    },
}

/// Everything that can go wrong in tissue's core.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A file could be read but not understood.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A file extension tissue does not know.
    #[error("{path}: unsupported file type (expected one of {expected})")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
        /// The extensions that would work.
        expected: &'static str,
    },
    /// A surface that cannot be sampled.
    #[error("{path}: {source}")]
    Mesh {
        /// The file (empty when the mesh did not come from a file).
        path: PathBuf,
        /// The defect.
        source: MeshError,
    },
    /// A particle model that breaks what every part of tissue relies on
    /// ([`ParticleModel::validate`](crate::ParticleModel::validate)): lengths
    /// that disagree, an index out of range, a non-finite value, connections
    /// that are not symmetric.
    #[error("invalid particle model: {0}")]
    InvalidModel(String),
    /// A parameter out of range.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// Sampling could not produce a model.
    #[error("sampling failed: {0}")]
    Sampling(#[from] SamplingError),
    /// Stage 2 cannot run: a surface that is not the model's, a model without
    /// control points, parameters out of range.
    #[error(transparent)]
    Deformation(#[from] DeformError),
    /// An observation (a point cloud) that cannot be used.
    #[error(transparent)]
    Observation(#[from] ObservationError),
    /// The GPU path failed: no adapter, a device limit, device loss, out of
    /// memory. `kind` says which, to act on (fall back to the CPU on
    /// [`GpuFailure::OutOfMemory`], say); `source` is the GPU crate's own
    /// error (`tissue_gpu::GpuError`, to downcast to).
    #[error("{context}: {source}")]
    Gpu {
        /// What was being done, e.g. `stage 2 on NVIDIA H100, Vulkan`.
        context: String,
        /// Which kind of failure.
        kind: GpuFailure,
        /// The GPU crate's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// A backend name that is not `auto`, `gpu` or `cpu`.
    #[error("unknown backend `{0}`, expected auto, gpu or cpu")]
    UnknownBackend(String),
}

/// The kind of a GPU failure ([`Error::Gpu`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum GpuFailure {
    /// No adapter was found.
    NoAdapter,
    /// The adapter would not open a device.
    NoDevice,
    /// A buffer or dispatch above a device limit.
    LimitExceeded,
    /// The device ran out of memory.
    OutOfMemory,
    /// The device was lost or stopped responding.
    DeviceLost,
    /// Anything else: a shader, a validation or internal error, a readback.
    Other,
}

/// Result with tissue's core error.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Whether this is a GPU without room for the work: out of memory, or
    /// a device limit the model exceeds. `auto` runs the work on the CPU
    /// instead (`tissue::backend::with_cpu_fallback`).
    pub fn is_gpu_capacity(&self) -> bool {
        matches!(
            self,
            Error::Gpu {
                kind: GpuFailure::OutOfMemory | GpuFailure::LimitExceeded,
                ..
            }
        )
    }
}

impl From<std::convert::Infallible> for Error {
    fn from(never: std::convert::Infallible) -> Self {
        match never {}
    }
}

/// The words of [`ObservationError::VolumeChange`]: which way the organ
/// would have to change, and what usually explains it.
fn volume_change_message(change: f32, mean: f32, most: f32) -> String {
    let (way, side, cause) = if change > 0.0 {
        (
            "grow",
            "outside",
            "shifted away from the held region (in another coordinate frame: put it in the \
             model's first) or in smaller units than the organ's",
        )
    } else {
        (
            "shrink",
            "inside",
            "shifted into the organ (in another coordinate frame: put it in the model's first) \
             or in larger units than the organ's",
        )
    };
    format!(
        "the observed points lie {:.1} {side} the model's rest skin on average: the organ would \
         have to {way} by about {:.0} % to meet them, where soft tissue keeps its volume (at most \
         {:.0} % is taken); the observation is likely {cause}",
        mean.abs(),
        100.0 * change.abs(),
        100.0 * most
    )
}
