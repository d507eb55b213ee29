//! Stage 1, uniform sampling of a closed surface's interior: the initial
//! radius and placement, the state the iterations work on and the finish
//! (`sampling`), the uniform grid and neighbour rows both stages search
//! (`grid`), and the sampling's quality report (`quality`).

pub(crate) mod grid;
pub(crate) mod quality;
pub(crate) mod sampling;

pub use grid::{Grid, MAX_CELLS_PER_PARTICLE, grid_build, grid_layout, max_cells, neighbour_rows};
pub use quality::{
    MAX_WEAK_PERCENT, check_usable, nearest_in_grid, nearest_neighbour_distances, quality_report,
};
pub use sampling::{
    FIELD_CELL_IN_R0, FIELD_MARGIN_IN_R0, ForceOut, Prepared, Progress, SKIN_IN_R0, Sampled,
    SamplingState, converged_after, finish, initial_positions, initial_radius,
    place_surface_particles, prepare,
};
