//! The CPU twin of every WGSL shader, one module per shader file and named
//! as it (`local_rotations` is the twin of `shaders/local_rotations.wgsl`).
//! Each holds the per-particle functions its shader mirrors, or, where the
//! work is written once for the host in `tissue-solve` (the coarse spaces'
//! corrections and cycles, the grid, the structures), names the function
//! that is the twin. The GPU crate's tests hold each shader to its twin on
//! lavapipe, and its registry test checks that every shader has one here
//! ([`TWINS`]).

pub mod block_multilevel;
pub mod coarse;
pub mod coarse_elastic;
pub mod deformation_force;
pub mod descent;
pub mod elastic_targets;
pub mod embedding_moved;
pub mod grid_build;
pub mod imf_force;
pub mod integrate;
pub mod local_rotations;
pub mod multilevel;
pub mod needs_rebuild;
pub mod neighbour_rows;
pub mod pair;
pub mod polar;
pub mod radius_update;
pub mod sampling_change;
pub mod sampling_integrate;
pub mod sampling_place;
pub mod step_norms;
pub mod volume_smoother;

/// The shaders with a twin here, each by its module's [`SHADER`](local_rotations::SHADER).
pub const TWINS: &[&str] = &[
    block_multilevel::SHADER,
    coarse::SHADER,
    coarse_elastic::SHADER,
    deformation_force::SHADER,
    descent::SHADER,
    elastic_targets::SHADER,
    embedding_moved::SHADER,
    grid_build::SHADER,
    imf_force::SHADER,
    integrate::SHADER,
    local_rotations::SHADER,
    multilevel::SHADER,
    needs_rebuild::SHADER,
    neighbour_rows::SHADER,
    pair::SHADER,
    radius_update::SHADER,
    sampling_change::SHADER,
    sampling_integrate::SHADER,
    sampling_place::SHADER,
    step_norms::SHADER,
    volume_smoother::SHADER,
];

#[cfg(test)]
mod tests {
    use super::TWINS;

    /// Each twin module is named as its shader: every file here but this
    /// one and `polar` (the twin of `shaders/shared/polar.wgsl`, which has
    /// no entry point of its own) is in [`TWINS`] under its own name, and
    /// every name in [`TWINS`] is a file here.
    #[test]
    fn every_twin_module_is_named_as_its_shader() {
        let folder = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/kernels");
        let mut files: Vec<String> = std::fs::read_dir(&folder)
            .unwrap_or_else(|e| panic!("{}: {e}", folder.display()))
            .flatten()
            .filter_map(|entry| {
                let path = entry.path();
                let stem = path.file_stem()?.to_string_lossy().into_owned();
                (path.extension()? == "rs" && stem != "mod" && stem != "polar").then_some(stem)
            })
            .collect();
        files.sort();
        let mut twins: Vec<String> = TWINS.iter().map(|s| s.to_string()).collect();
        twins.sort();
        assert_eq!(files, twins);
    }
}
