//! The body the particles make: the elastic model and its consistent
//! gradients (`elastic`, `consistent`), the 3x3 SVD and polar rotation
//! (`svd3`), structures bound to particles (`structures`) and the
//! displacement field that carries them back to rest (`resampling`),
//! gravity's load and the unloaded shape (`gravity`), and the stiffness fit
//! (`stiffness`).

pub(crate) mod consistent;
pub(crate) mod elastic;
pub(crate) mod entries;
pub(crate) mod gravity;
pub(crate) mod resampling;
pub(crate) mod stiffness;
pub(crate) mod structures;
pub(crate) mod svd3;

pub use consistent::{
    COARSE_CELL, COARSE_MAX_AGGREGATES, Consistency, FLATNESS, MAX_ITERATIONS, REDUCTION,
    offsets_outer,
};
pub use elastic::{
    Elastic, ElasticTerms, EnergySums, FLAT_NEIGHBOURHOOD, STIFFENING, cofactor, is_round, moment,
    moment_inverse, moment_unit, offsets_product,
};
pub use gravity::{
    Accuracy, CONFIRM_WITHIN, ROUND_CONTRACTION, ROUND_TOLERANCE, STANDARD_GRAVITY, UnloadedShape,
    Unloading, gravity_load, held_vertices, unloaded_shape, unloaded_shape_from,
    unloaded_shape_near,
};
pub use resampling::{
    FADE_SPACINGS, FULL_SPACINGS, FieldGridError, MAX_GRID_POINTS, MIN_GRID_STEPS,
    MIN_VOLUME_RATIO, field_grid, resampling_field,
};
pub use stiffness::{
    Postures, REFINEMENTS, SETTLED, StiffnessFit, TRIAL_TOLERANCE, Trial, fit_stiffness,
    free_skin_targets,
};
pub use structures::{
    CARRIERS, Embedding, RIGID_NEIGHBOURS, RigidBinding, RigidMotion, carriers_of, embedding_moved,
    k_nearest, typical_spacing,
};
pub use svd3::{JACOBI_SWEEPS, POLISH_SWEEPS, Svd3, best_rotation, rotation_of, svd3};
