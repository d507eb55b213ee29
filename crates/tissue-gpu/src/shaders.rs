//! WGSL sources, the `#import` step, and naga reflection.
//!
//! Every shader is compiled into the binary (`include_str!`), so nothing is
//! read from disk at run time. `#import shared/NAME` on a line of its own is
//! replaced by `shaders/shared/NAME.wgsl`, once per shader however often it
//! is imported.

use std::collections::HashSet;

use crate::GpuError;

/// Shared WGSL pulled in by `#import`: `(name, source)`.
pub const SHARED: &[(&str, &str)] = &[
    (
        "shared/layout",
        include_str!("../shaders/shared/layout.wgsl"),
    ),
    (
        "shared/offsets",
        include_str!("../shaders/shared/offsets.wgsl"),
    ),
    ("shared/svd3", include_str!("../shaders/shared/svd3.wgsl")),
    ("shared/polar", include_str!("../shaders/shared/polar.wgsl")),
    (
        "shared/sampling",
        include_str!("../shaders/shared/sampling.wgsl"),
    ),
    (
        "shared/field_grid",
        include_str!("../shaders/shared/field_grid.wgsl"),
    ),
    (
        "shared/surface_field",
        include_str!("../shaders/shared/surface_field.wgsl"),
    ),
    ("shared/grid", include_str!("../shaders/shared/grid.wgsl")),
    (
        "shared/tree_sum",
        include_str!("../shaders/shared/tree_sum.wgsl"),
    ),
    ("shared/loads", include_str!("../shaders/shared/loads.wgsl")),
];

/// Shader files with entry points: `(name, source before #import expansion)`.
/// `tests/svd3` is the test-only kernel behind the SVD invariant tests,
/// `tests/reciprocal` the one behind the grid's rounding test.
pub const SHADERS: &[(&str, &str)] = &[
    (
        "local_rotations",
        include_str!("../shaders/local_rotations.wgsl"),
    ),
    (
        "elastic_targets",
        include_str!("../shaders/elastic_targets.wgsl"),
    ),
    (
        "deformation_force",
        include_str!("../shaders/deformation_force.wgsl"),
    ),
    ("integrate", include_str!("../shaders/integrate.wgsl")),
    ("descent", include_str!("../shaders/descent.wgsl")),
    ("pair", include_str!("../shaders/pair.wgsl")),
    ("step_norms", include_str!("../shaders/step_norms.wgsl")),
    ("coarse", include_str!("../shaders/coarse.wgsl")),
    ("multilevel", include_str!("../shaders/multilevel.wgsl")),
    (
        "coarse_elastic",
        include_str!("../shaders/coarse_elastic.wgsl"),
    ),
    (
        "block_multilevel",
        include_str!("../shaders/block_multilevel.wgsl"),
    ),
    (
        "volume_smoother",
        include_str!("../shaders/volume_smoother.wgsl"),
    ),
    ("tests/svd3", include_str!("../shaders/tests/svd3.wgsl")),
    (
        "tests/reciprocal",
        include_str!("../shaders/tests/reciprocal.wgsl"),
    ),
    ("imf_force", include_str!("../shaders/imf_force.wgsl")),
    (
        "sampling_place",
        include_str!("../shaders/sampling_place.wgsl"),
    ),
    (
        "radius_update",
        include_str!("../shaders/radius_update.wgsl"),
    ),
    (
        "sampling_integrate",
        include_str!("../shaders/sampling_integrate.wgsl"),
    ),
    (
        "sampling_change",
        include_str!("../shaders/sampling_change.wgsl"),
    ),
    (
        "needs_rebuild",
        include_str!("../shaders/needs_rebuild.wgsl"),
    ),
    (
        "tests/surface_field",
        include_str!("../shaders/tests/surface_field.wgsl"),
    ),
    ("grid_build", include_str!("../shaders/grid_build.wgsl")),
    (
        "neighbour_rows",
        include_str!("../shaders/neighbour_rows.wgsl"),
    ),
    (
        "embedding_moved",
        include_str!("../shaders/embedding_moved.wgsl"),
    ),
];

/// Expands every `#import shared/NAME` line of `source`.
pub fn preprocess(source: &str) -> Result<String, GpuError> {
    let mut imported = HashSet::new();
    expand(source, &mut imported)
}

fn expand(source: &str, imported: &mut HashSet<&'static str>) -> Result<String, GpuError> {
    let mut out = String::with_capacity(source.len());
    for line in source.lines() {
        if let Some(name) = line.trim().strip_prefix("#import") {
            let name = name.trim();
            let Some(&(found, text)) = SHARED.iter().find(|(n, _)| *n == name) else {
                return Err(GpuError::Shader {
                    name: name.to_owned(),
                    message: format!(
                        "unknown #import; known: {}",
                        SHARED
                            .iter()
                            .map(|(n, _)| *n)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                });
            };
            if imported.insert(found) {
                out.push_str(&expand(text, imported)?);
            }
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(out)
}

/// The WGSL of shader `name` (a [`SHADERS`] entry) with its imports expanded.
pub fn source(name: &str) -> Result<String, GpuError> {
    let Some((_, text)) = SHADERS.iter().find(|(n, _)| *n == name) else {
        return Err(GpuError::Shader {
            name: name.to_owned(),
            message: "no such shader".into(),
        });
    };
    preprocess(text)
}

/// Parses and validates expanded WGSL with naga; errors carry naga's report.
pub fn module_from_source(name: &str, source: &str) -> Result<naga::Module, GpuError> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| GpuError::Shader {
        name: name.to_owned(),
        message: e.emit_to_string(source),
    })?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .map_err(|e| GpuError::Shader {
        name: name.to_owned(),
        message: e.emit_to_string(source),
    })?;
    Ok(module)
}

/// Parses and validates shader `name` (a [`SHADERS`] entry).
pub fn module(name: &str) -> Result<naga::Module, GpuError> {
    module_from_source(name, &source(name)?)
}

/// The workgroup size of entry point `entry`, as the module declares it.
pub fn workgroup_size(module: &naga::Module, entry: &str) -> Result<[u32; 3], GpuError> {
    module
        .entry_points
        .iter()
        .find(|e| e.name == entry)
        .map(|e| e.workgroup_size)
        .ok_or_else(|| GpuError::Shader {
            name: entry.to_owned(),
            message: "no such entry point".into(),
        })
}

/// Names of the bound globals entry point `entry` of `module` uses (naga's
/// per-entry-point analysis); `source` is the module's WGSL, for errors.
pub fn used_globals(
    module: &naga::Module,
    source: &str,
    entry: &str,
) -> Result<Vec<String>, GpuError> {
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(module)
    .map_err(|e| GpuError::Shader {
        name: entry.to_owned(),
        message: e.emit_to_string(source),
    })?;
    let index = module
        .entry_points
        .iter()
        .position(|e| e.name == entry)
        .ok_or_else(|| GpuError::Shader {
            name: entry.to_owned(),
            message: "no such entry point".into(),
        })?;
    let uses = info.get_entry_point(index);
    Ok(module
        .global_variables
        .iter()
        .filter(|&(handle, var)| var.binding.is_some() && !uses[handle].is_empty())
        .filter_map(|(_, var)| var.name.clone())
        .collect())
}

/// Size and member offsets of WGSL struct `name` in `module`, by naga's layouter.
pub fn struct_layout(module: &naga::Module, name: &str) -> Option<(u32, Vec<(String, u32)>)> {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).ok()?;
    module.types.iter().find_map(|(handle, ty)| {
        if ty.name.as_deref() != Some(name) {
            return None;
        }
        match &ty.inner {
            naga::TypeInner::Struct { members, .. } => Some((
                layouter[handle].size,
                members
                    .iter()
                    .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                    .collect(),
            )),
            _ => None,
        }
    })
}

/// Test helper: the size and member offsets of a Rust mirror equal naga's
/// layout of WGSL struct `name` in shader `file`.
#[cfg(test)]
pub(crate) fn assert_layout(
    file: &str,
    name: &str,
    rust_size: usize,
    rust_offsets: &[(&str, usize)],
) {
    let layout = module(file)
        .ok()
        .and_then(|m| struct_layout(&m, name))
        .unwrap_or_else(|| panic!("WGSL struct {name} not found in {file}"));
    assert_eq!(layout.0 as usize, rust_size, "size of {name}");
    let naga: Vec<(String, usize)> = layout.1.into_iter().map(|(n, o)| (n, o as usize)).collect();
    let rust: Vec<(String, usize)> = rust_offsets
        .iter()
        .map(|(n, o)| ((*n).to_owned(), *o))
        .collect();
    assert_eq!(naga, rust, "member names and offsets of {name}");
}

/// A buffer binding of group 0 as the module declares it.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Binding {
    /// Binding number.
    pub binding: u32,
    /// The WGSL variable's name, which is also the buffer's name in Rust.
    pub name: String,
    /// A uniform (bound with a dynamic offset, one slot per iteration).
    pub uniform: bool,
    /// Read-only storage.
    pub read_only: bool,
}

/// The buffer bindings `module` declares, by binding number.
pub fn bindings(module: &naga::Module) -> Vec<Binding> {
    let mut out: Vec<Binding> = module
        .global_variables
        .iter()
        .filter_map(|(_, var)| {
            let binding = var.binding.as_ref()?.binding;
            let name = var.name.clone().unwrap_or_default();
            match var.space {
                naga::AddressSpace::Uniform => Some(Binding {
                    binding,
                    name,
                    uniform: true,
                    read_only: true,
                }),
                naga::AddressSpace::Storage { access } => Some(Binding {
                    binding,
                    name,
                    uniform: false,
                    read_only: !access.contains(naga::StorageAccess::STORE),
                }),
                _ => None,
            }
        })
        .collect();
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shader_parses_and_validates_after_import_expansion() {
        for (name, _) in SHADERS {
            if let Err(e) = module(name) {
                panic!("{e}");
            }
        }
    }

    /// The shaders are read through `crates/tissue-gpu/shaders`, a link to
    /// the workspace's `shaders/`, so that the packaged crate carries them
    /// (`cargo package` copies what the link points at; a path out of the
    /// crate would leave them behind and the published crate would not
    /// build).
    #[test]
    fn shaders_are_read_from_inside_the_crate() {
        let source = include_str!("shaders.rs");
        let escaping = ["include_str!(\"../..", "/..", "/shaders/"].concat();
        let inside = ["include_str!(\"../", "shaders/"].concat();
        assert!(
            !source.contains(&escaping),
            "a shader path leaves the crate"
        );
        assert_eq!(
            source.matches(&inside).count(),
            SHADERS.len() + SHARED.len(),
            "every shader through the crate's shaders/ link"
        );
    }

    /// A WGSL file left out of [`SHADERS`] or [`SHARED`] would escape the
    /// validation above.
    #[test]
    fn every_wgsl_file_is_registered() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
        let mut found = Vec::new();
        for folder in ["", "shared", "tests"] {
            let entries = std::fs::read_dir(root.join(folder))
                .unwrap_or_else(|e| panic!("reading shaders/{folder}: {e}"));
            for entry in entries.flatten() {
                let path = entry.path();
                if path.extension().is_some_and(|x| x == "wgsl") {
                    let stem = path
                        .file_stem()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    found.push(if folder.is_empty() {
                        stem
                    } else {
                        format!("{folder}/{stem}")
                    });
                }
            }
        }
        assert!(found.iter().any(|name| name == "coarse"), "{found:?}");
        for name in found {
            assert!(
                SHADERS.iter().chain(SHARED).any(|(n, _)| *n == name),
                "shaders/{name}.wgsl is in neither SHADERS nor SHARED"
            );
        }
    }

    /// Every shader with entry points has its CPU twin, a module of
    /// `tissue_cpu::kernels` named as the shader, and every twin has its
    /// shader (the test-only kernels under `tests/` have none).
    #[test]
    fn every_shader_has_its_cpu_twin_named_as_it() {
        let twins = tissue_cpu::kernels::TWINS;
        for (name, _) in SHADERS.iter().filter(|(n, _)| !n.starts_with("tests/")) {
            assert!(
                twins.contains(name),
                "shaders/{name}.wgsl has no twin tissue_cpu::kernels::{name}"
            );
        }
        for twin in twins {
            assert!(
                SHADERS.iter().any(|(n, _)| n == twin),
                "tissue_cpu::kernels::{twin} is the twin of no shader"
            );
        }
    }

    #[test]
    fn shared_files_validate_on_their_own() {
        for (name, text) in SHARED {
            if let Err(e) = module_from_source(name, &preprocess(text).unwrap_or_default()) {
                panic!("{e}");
            }
        }
    }

    #[test]
    fn an_import_is_expanded_once_and_an_unknown_one_is_refused() {
        let twice =
            preprocess("#import shared/layout\n#import shared/layout\n").unwrap_or_default();
        assert_eq!(twice.matches("struct Params").count(), 1);
        assert!(preprocess("#import shared/nothing\n").is_err());
    }

    #[test]
    fn workgroup_sizes_come_from_the_modules() {
        for (shader, entry) in [
            ("local_rotations", "local_rotations"),
            ("local_rotations", "local_rotations_warm"),
            ("local_rotations", "turn_rotations"),
            ("elastic_targets", "elastic_targets"),
            ("elastic_targets", "elastic_targets_warm"),
            ("elastic_targets", "elastic_force"),
            ("deformation_force", "deformation_force"),
            ("integrate", "integrate"),
            ("integrate", "chebyshev"),
            ("step_norms", "step_norms"),
            ("coarse", "coarse_residual"),
            ("coarse", "coarse_restrict"),
            ("coarse", "coarse_forward"),
            ("coarse", "coarse_backward"),
            ("coarse", "coarse_apply"),
            ("multilevel", "cycle_start"),
            ("multilevel", "cycle_sweep"),
            ("multilevel", "cycle_restrict"),
            ("multilevel", "cycle_prolong"),
            ("block_multilevel", "block_cycle_start"),
            ("block_multilevel", "block_cycle_sweep"),
            ("block_multilevel", "block_cycle_restrict"),
            ("block_multilevel", "block_cycle_prolong"),
            ("coarse_elastic", "elastic_step_of"),
            ("coarse_elastic", "elastic_change_of"),
            ("coarse_elastic", "elastic_residual_of"),
            ("coarse_elastic", "elastic_restrict"),
            ("coarse_elastic", "elastic_forward"),
            ("coarse_elastic", "elastic_backward"),
            ("coarse_elastic", "elastic_apply"),
            ("imf_force", "imf_force"),
            ("radius_update", "radius_update"),
            ("sampling_integrate", "integrate"),
            ("sampling_change", "change"),
            ("needs_rebuild", "needs_rebuild"),
            ("grid_build", "grid_bounds"),
            ("grid_build", "scan_blocks"),
            ("neighbour_rows", "count_rows"),
        ] {
            let module = module(shader).map_err(|e| e.to_string());
            let size = module.and_then(|m| workgroup_size(&m, entry).map_err(|e| e.to_string()));
            // step_norms halves its workgroup in a tree: a power of two.
            assert!(
                matches!(size, Ok([x, 1, 1]) if x.is_power_of_two()),
                "{shader}::{entry}: {size:?}"
            );
        }
    }

    /// A shader's `const NAME: u32` by naga's reading of it.
    fn u32_constant(shader: &str, name: &str) -> u32 {
        let module = module(shader).unwrap_or_else(|e| panic!("{e}"));
        let value = module
            .constants
            .iter()
            .find(|(_, c)| c.name.as_deref() == Some(name))
            .map(|(_, c)| &module.global_expressions[c.init]);
        match value {
            Some(naga::Expression::Literal(naga::Literal::U32(value))) => *value,
            other => panic!("{shader}::{name} is not a u32 literal: {other:?}"),
        }
    }

    /// The elastic substitutions hold the whole vector in workgroup memory:
    /// the WGSL's `HELD_UNKNOWNS` must be the most unknowns the deformer
    /// binds, and fit wgpu's default 16 KiB of workgroup memory. The
    /// Laplacian's hold what fits there (a `vec3` takes 16 bytes) and
    /// substitute larger vectors where they lie.
    #[test]
    fn the_substitutions_hold_what_fits_in_workgroup_memory() {
        let memory = wgpu::Limits::default().max_compute_workgroup_storage_size;
        let held = u32_constant("coarse_elastic", "HELD_UNKNOWNS");
        assert_eq!(held as usize, crate::GPU_COARSE_UNKNOWNS);
        assert!(4 * held <= memory, "{held} f32 exceed {memory} bytes");
        let held = u32_constant("coarse", "HELD_AGGREGATES");
        assert!(
            16 * held <= memory && 16 * (held + 1) > memory,
            "{held} vec3 do not fill {memory} bytes"
        );
    }
}
