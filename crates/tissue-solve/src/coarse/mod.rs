//! The two-level solves' coarse spaces and their solvers: the aggregates
//! (`aggregates`) and their envelope ordering (`envelope`), the
//! Laplacian's coarse space (`laplacian`), the elastic operator's
//! (`elastic`), the dense and sparse factors (`cholesky`), two-grid cycles
//! over groups of aggregates (`multilevel`), and the volume smoother
//! (`volume_smoother`).

pub(crate) mod aggregates;
pub(crate) mod cholesky;
pub(crate) mod elastic;
pub(crate) mod envelope;
pub(crate) mod laplacian;
pub(crate) mod multilevel;
pub(crate) mod volume_smoother;

pub use aggregates::{Aggregates, OUTSIDE, members_of};
pub use cholesky::Cholesky;
pub use elastic::{
    CorrectionFor, ElasticCoarse, FREE_SKIN_SWEEPS, RATE_STEPS, REST_RATE_STEPS, SMOOTHER_MAX_CELL,
    SMOOTHER_MAX_RATE, SMOOTHER_MIN_LOWEST, elastic_aggregates, rest_rate, volume_smoother,
};
pub use envelope::Envelope;
pub use laplacian::{
    CoarseSpace, RATE_ITERATIONS, SharedLaplacian, coarse_space, coarse_space_shared,
    laplacian_key, norm, power_start,
};
pub use multilevel::{
    BLOCK_GROUP, BlockMultilevel, CYCLES, GROUP, JACOBI_WEIGHT, Multilevel, SWEEPS, WEIGHT_MARGIN,
    WEIGHT_STEPS,
};
pub use volume_smoother::{
    MAX_SMOOTHER_SWEEPS, RELAXATION, SHEAR_STEP, SMOOTHER_SWEEPS, Smoothing, VolumeSmoother,
};
