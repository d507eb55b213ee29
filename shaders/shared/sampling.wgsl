// The parameters every stage-1 kernel reads. Rust mirror:
// `tissue_gpu::sampler::SamplingUniforms` (layout-tested against naga).

#import shared/layout
#import shared/field_grid

// One iteration's parameters, one slot per iteration of a batch (dynamic
// offset); derived values are computed once on the host in f32, as the CPU
// twins compute them.
struct Sampling {
    // Field grid: xyz the corner of cell (0, 0, 0), w the cell edge.
    field_origin: vec4<f32>,
    // Field cells along x, y, z; w the number of triangles.
    field_dims: vec4<u32>,
    // Where `field_cells` holds the CSR starts (x), candidates (y) and
    // candidate distances (z); the cell states begin at 0.
    field_layout: vec4<u32>,
    // Number of particles.
    count: u32,
    // 0: `SurfaceMode::Projection`, 1: `SurfaceMode::PaperForce`.
    surface_mode: u32,
    // 1 when the wall counts in the compression of eq. (6).
    wall_in_compression: u32,
    // Which row of `partials` `change` writes; `halt` records slot + 1.
    slot: u32,
    // Workgroups of a dispatch (x times y), the length of a `partials` row.
    groups: u32,
    // alpha of eq. (4).
    alpha: f32,
    // Pair forces act for d < cutoff (r_i + r_j).
    cutoff: f32,
    // mu of eq. (2) (paper force only).
    mu: f32,
    // Ideal compression of eq. (7).
    ideal: f32,
    // eta of eq. (8).
    eta: f32,
    // exp(max_log_radius_step): the ln argument of eq. (8) lies in [1 / bound, bound].
    radius_bound: f32,
    // 1 / radius_bound.
    radius_bound_inv: f32,
    // r0 / m~: dp = F step_scale, eq. (1).
    step_scale: f32,
    // Largest step, max_step r0.
    max_step: f32,
    // m~, for the wall's reaction d m~ / r0.
    mass: f32,
    // Initial radius.
    r0: f32,
    // Half the Verlet skin: rows are rebuilt beyond this drift.
    half_skin: f32,
    // Entries of the neighbour rows the `neighbours` binding holds; entry
    // k >= row_split is `offsets[count + 1 + k - row_split]`.
    row_split: u32,
    // Particles within surface_band r of the surface are placed on it (`sampling_place`).
    surface_band: f32,
    // The field's margin: deep-inside cells are at least this far from the surface.
    field_margin: f32,
}

@group(0) @binding(0) var<uniform> sampling: Sampling;

// The field's grid, for `shared/surface_field`.
fn field_grid() -> FieldGrid {
    return FieldGrid(sampling.field_origin, sampling.field_dims, sampling.field_layout);
}
