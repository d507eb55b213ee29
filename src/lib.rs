//! **tissue**: track where the inside of a soft organ goes when its surface moves.
//!
//! The organ's interior is filled with particles (stage 1, uniform sampling,
//! Zhou et al. Section 2); surface particles then follow an observed surface
//! and the interior follows them (stage 2). This crate is the public
//! entry point; [`backend`] chooses where the work runs (`auto`, `gpu`,
//! `cpu`) and runs both stages there. `docs/ARCHITECTURE.md` maps the crates.
//!
//! ```
//! use tissue::{SamplingParams, phantom};
//!
//! // The bundled breast phantom (millimetres), filled with 2,000 particles.
//! let skin = phantom::default_breast();
//! let sampled = tissue::sample(&skin, &SamplingParams::with_particles(2_000))?;
//! assert_eq!(sampled.model.len(), 2_000);
//! assert!(sampled.report.converged);
//! assert!(sampled.report.nn_cv < 0.05);
//! # Ok::<(), tissue::Error>(())
//! ```

use std::path::Path;

pub use tissue_core::io::model::{export_model, load_model, load_points, save_model, save_points};
pub use tissue_core::io::surface::{
    coordinate_tag, load_closed_surface, load_surface, load_surface_as_written, save_surface,
    save_surface_in, weld,
};
pub use tissue_core::params::InitialPlacement;
pub use tissue_core::validate::{Validation, validate};
pub use tissue_core::{
    Attachment, ConnectionStats, Connections, DeformError, Error, FieldError, GpuFailure,
    MeshError, ParamError, ParticleModel, SamplingError, SamplingParams, SamplingReport,
    StageSeconds, SurfaceMesh, SurfaceMode, Vec3,
};
/// Surfaces and fields: self-crossing, the phantom's deformations, the
/// displacement field, the signed distance field, file formats, the
/// bundled phantom.
pub use tissue_core::{crossing, deform, displacement, field, io, phantom};
pub use tissue_solve::stage1::{Progress, Sampled};

/// Structures bound to particles: points carried by their nearest
/// particles' motion, rigid structures by the rotation fitted to theirs.
pub mod structures {
    pub use tissue_solve::model::{
        CARRIERS, Embedding, RigidBinding, RigidMotion, carriers_of, embedding_moved,
    };
}

/// The displacement field from the deformed posture back to rest, on a
/// grid around the organ.
pub mod resampling {
    pub use tissue_solve::model::{FieldGridError, field_grid, resampling_field};
}

pub mod backend;
pub mod gravity;
pub mod observation;
pub mod uncertainty;

/// Stage 2: the deformer (the CPU path; [`backend::Solver`] runs it on the
/// chosen device), its parameters and its report.
pub mod deformation {
    pub use tissue_cpu::deformation::{Deformer, SharedLaplacian};
    pub use tissue_solve::{
        DeformParams, DeformReport, ElasticSolve, FLOAT_FLOOR_ERROR, ForceModel, Inversions,
        PrepareStage, RotationMethod, SolveStep, SolverTuning, StopReason, check_same_topology,
        inversions,
    };
}

/// Under the facade, for tools and research code that need the parts:
/// `model` (the gravity model and the unloaded shape's search, the
/// stiffness fit, the elastic model's mathematics, the 3x3 rotation),
/// `stage2` (the iteration's passes, the plan, the posture search, the
/// tracker over a device), `coarse` (the two-level solves), and stage 1 on
/// the CPU without the facade's checks. These change more freely than the
/// rest of the API.
pub mod advanced {
    pub use tissue_cpu::sample as sample_on_cpu;
    pub use tissue_solve::{SolveDevice, Tracker};
    pub use tissue_solve::{coarse, model, stage2};
}

/// Stage 1: fills a closed surface with `params.particles` particles relaxed
/// to the paper's uniform state, and reports their quality.
///
/// The surface is validated first (one closed, consistently oriented shell;
/// an inward-facing one is turned around), so any mesh gets a clear error
/// rather than garbage.
///
/// ```
/// use tissue::{SamplingParams, SurfaceMesh, Vec3};
///
/// // An open surface (a single triangle) is refused with the defect named.
/// let open = SurfaceMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]);
/// let err = tissue::sample(&open, &SamplingParams::with_particles(100)).unwrap_err();
/// assert!(err.to_string().contains("open"), "{err}");
/// ```
pub fn sample(surface: &SurfaceMesh, params: &SamplingParams) -> Result<Sampled, Error> {
    sample_with_progress(surface, params, &mut |_| {})
}

/// [`sample`], calling `progress` after every iteration.
pub fn sample_with_progress(
    surface: &SurfaceMesh,
    params: &SamplingParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Sampled, Error> {
    params.validate()?;
    usable(tissue_cpu::sample(&checked(surface)?, params, progress)?)
}

/// `sampled`, unless stage 2 could not use its model: no particle inside,
/// or too many that cannot carry a rotation
/// ([`tissue_solve::stage1::check_usable`]).
pub(crate) fn usable(sampled: Sampled) -> Result<Sampled, Error> {
    tissue_solve::stage1::check_usable(&sampled.model)?;
    Ok(sampled)
}

/// `surface` validated for stage 1: one closed, consistently oriented
/// shell, turned outward if it faced inward.
pub(crate) fn checked(surface: &SurfaceMesh) -> Result<SurfaceMesh, Error> {
    let mut surface = surface.clone();
    let _checked = validate(&mut surface).map_err(|source| Error::Mesh {
        path: Default::default(),
        source,
    })?;
    Ok(surface)
}

/// Loads a surface file (STL, OBJ, PLY, legacy VTK), welds, validates and samples it.
///
/// ```
/// use tissue::{SamplingParams, phantom, save_surface};
///
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("breast.obj");
/// save_surface(&phantom::default_breast(), &path)?;
/// let sampled = tissue::sample_file(&path, &SamplingParams::with_particles(1_000))?;
/// assert_eq!(sampled.model.len(), 1_000);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn sample_file(path: &Path, params: &SamplingParams) -> Result<Sampled, Error> {
    params.validate()?;
    let surface = load_closed_surface(path)?;
    usable(tissue_cpu::sample(&surface, params, &mut |_| {})?)
}
