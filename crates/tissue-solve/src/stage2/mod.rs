//! Stage 2, the deformation, device-neutral: the parameters (`params`),
//! what a solve knows before it starts (`plan`, with the Laplacian's
//! spectrum from `spectrum`), Chebyshev acceleration and the stopping rule
//! (`acceleration`), the tracking prediction (`predict`), the deformed
//! surface's checks (`controls`), what one iteration runs (`passes`), the
//! seam a device implements (`device`), batches and their replay
//! (`batches`), what a phase runs with and the elastic phase's rules
//! (`phase`), the one tracker over any device (`tracker`), how a solve
//! went (`report`), inverted neighbourhoods (`inversion`), the search
//! a change of posture makes (`posture`), a point cloud observed
//! without correspondence (`observation`), the springs that pull the
//! model towards an observation (`springs`), and the pairing that sets
//! them from the observation at each iteration (`pairing`), and how sure
//! an answer is (`uncertainty`).

pub(crate) mod acceleration;
pub(crate) mod batches;
pub(crate) mod controls;
pub(crate) mod device;
pub(crate) mod inversion;
pub(crate) mod observation;
pub(crate) mod pairing;
pub(crate) mod params;
pub(crate) mod passes;
pub(crate) mod phase;
pub(crate) mod plan;
pub(crate) mod posture;
pub(crate) mod predict;
pub(crate) mod report;
pub(crate) mod rigid;
pub(crate) mod spectrum;
pub(crate) mod springs;
pub(crate) mod tracker;
pub mod uncertainty;

pub use acceleration::{
    CHEBYSHEV_ENVELOPE, Chebyshev, STALL_FACTOR, STALL_WINDOW, StoppingRule, accelerated_rate,
    error_bound,
};
pub use batches::{Batches, run_batched, run_batched_from};
pub use controls::{VOLUME_RATIO, check_same_topology};
pub use device::{DescentDots, Iteration, Potential, SolveDevice};
pub use inversion::{INVERTED_VOLUME_RATIO, Inversions, inversions};
pub use observation::{Cleaned, Cloud, FLAT_BEND, LINE_SPREAD, NORMAL_NEIGHBOURS, SCAN_SCALE};
pub use pairing::{
    CLOUD_SMOOTHING, Feature, NO_LIMIT, Paired, Pairing, PairingRule, feature_of, on_rim,
    pair_plane, paired_point, paired_spring, taper,
};
pub use params::{
    DeformParams, ElasticSolve, ForceModel, MAX_COARSE_AGGREGATES, MAX_COARSE_DIRECT_AGGREGATES,
    MAX_ELASTIC_COARSE_AGGREGATES, MAX_ELASTIC_COARSE_DIRECT_AGGREGATES, MAX_HISTORY, MAX_POISSON,
    MAX_SHEAR_VOLUME_SHARE, RotationMethod, SolverTuning,
};
pub use passes::{Choices, Correction, Holds, Pass};
pub use phase::{
    ENERGY_WATCH, FIRST_BATCH, MAX_BACKTRACKS, MAX_RELINEARISATIONS, SHEAR_CHECK, SHEAR_TOLERANCE,
    WATCH_SETTLED,
};
pub use plan::{
    MAX_LOAD_SIZE, Plan, SharedElastic, SharedSpectrum, control_points, elastic_key, laplacian_key,
};
pub use posture::{
    DENSITY_KG_M3, FIT_BOUNDS_KPA, FIT_PARTICLES, FIT_START_KPA, Fit, Gravity, HELD_SPACINGS,
    MAX_GRAVITY_G, MIN_FIT_PARTICLES, NO_CHANGE, ORGAN_SIZE_M, PostureDevice, SolveProgress,
    UNLOADED_TOLERANCE_M, Unloaded, unload,
};
pub use predict::{FrameHistory, affine_fit, predict, predict_paired};
pub use report::{
    DeformReport, ENERGY_ROUNDING, FLOAT_FLOOR_ERROR, PrepareStage, SolveStep, StopReason,
};
pub use rigid::{
    FIDUCIAL_MISFIT, FiducialFit, RIGID_SHARE, RIGID_STEPS, RIGID_TRIM, RigidFit, fiducial_fit,
    rigid_fit,
};
pub use spectrum::{lanczos_extremes, laplacian_extremes, laplacian_extremes_with};
pub use springs::{
    SPRING_WEIGHT, Spring, spring, spring_block, spring_force, spring_operator, spring_potential,
    springs_stiffness,
};
pub use tracker::Tracker;
pub use tracker::conjugate::{
    ARMIJO, DESCENT_ERROR_BOUND, DESCENT_RELINEARISE, LONGEST_STEP, SMALLEST_STEP,
};
