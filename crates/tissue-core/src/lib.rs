//! Core types of **tissue**: surface meshes, particle models, parameters,
//! reports, errors and file formats. Backend-agnostic: the CPU path
//! (`tissue-cpu`) and the GPU path build on these types.

pub mod crossing;
pub mod deform;
pub mod displacement;
pub mod error;
pub mod field;
pub mod io;
pub mod mesh;
pub mod model;
pub mod params;
pub mod phantom;
pub mod report;
pub mod rows;
pub mod validate;

pub use error::{
    DeformError, Error, FieldError, GpuFailure, MeshError, ObservationError, ParamError,
    SamplingError,
};
pub use mesh::SurfaceMesh;
pub use model::{Attachment, Connections, ParticleModel};
pub use params::{SamplingParams, SurfaceMode};
pub use report::{ConnectionStats, SamplingReport, StageSeconds};

/// The vector type used throughout (glam, the version parry3d re-exports).
pub use glam::Vec3;
