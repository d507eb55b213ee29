//! Surfaces written by VTK itself (`tests/fixtures/vtk`, made by
//! `make_fixtures.py` with the `vtk` Python package, as 3D Slicer, pyvista
//! and ParaView save them) through every command that reads a surface:
//! `sample`, and `deform` as the deformed skin (`--surface`), a structure
//! (`--structure`) and the observed patch (`--observed`). And the
//! coordinate tag Slicer writes: read on the way in, written on the way
//! out.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::{Path, PathBuf};

use common::{json, s, text, tissue};
use tissue::io::space::Space;
use tissue_testkit::{
    VTK_LEGACY_FIXTURES, VTK_SLICER_FIXTURES, VTK_XML_FIXTURES, vtk_fixture as fixture,
};

/// The fixtures of the rest surface in `ascii.vtp`'s coordinates, with no
/// coordinate tag, and the same surface moved (the same vertices and
/// triangles).
fn untagged() -> impl Iterator<Item = &'static str> {
    VTK_XML_FIXTURES
        .into_iter()
        .chain(VTK_LEGACY_FIXTURES)
        .chain(["moved-appended-zlib.vtp"])
}

fn sampled(dir: &Path, surface: &Path, particles: &str) -> PathBuf {
    let model = dir.join(format!(
        "{}.model.vtp",
        surface.file_name().unwrap().to_string_lossy()
    ));
    let out = tissue(&[
        "sample",
        s(surface),
        "--particles",
        particles,
        "--output",
        s(&model),
        "-q",
    ]);
    assert!(
        out.status.success(),
        "{}: {}",
        surface.display(),
        text(&out)
    );
    model
}

#[test]
fn every_surface_vtk_writes_is_sampled() {
    let dir = tempfile::tempdir().unwrap();
    for name in untagged().chain(VTK_SLICER_FIXTURES) {
        let model = sampled(dir.path(), &fixture(name), "400");
        assert!(tissue::load_model(&model).unwrap().len() >= 300, "{name}");
    }
}

#[test]
fn every_surface_vtk_writes_is_read_as_skin_structure_and_observed_patch() {
    let dir = tempfile::tempdir().unwrap();
    let model = sampled(dir.path(), &fixture("ascii.vtp"), "1000");
    for name in untagged() {
        let file = fixture(name);
        // The observed patch is given at rest.
        let patch = if name.starts_with("moved") {
            fixture("appended-zlib.vtp")
        } else {
            file.clone()
        };
        let out_dir = dir.path().join(name);
        let out = tissue(&[
            "deform",
            "--model",
            s(&model),
            "--surface",
            s(&file),
            "--structure",
            s(&file),
            "--observed",
            s(&patch),
            "-o",
            s(&out_dir),
            "-q",
        ]);
        // A structure on the skin itself may be flagged as outside (4).
        assert!(
            matches!(out.status.code(), Some(0 | 4)),
            "{name}: {}",
            text(&out)
        );
        let report = json(&out_dir.join("report.json"));
        assert_eq!(report["converged"], true, "{name}: {report}");
        assert_eq!(report["structures"].as_array().unwrap().len(), 1);
        assert_eq!(report["observed"]["vertices"], 226, "{name}: {report}");
        let moved = report["max_displacement_mm"].as_f64().unwrap();
        if name.starts_with("moved") {
            assert!(moved > 0.5, "{name}: moved {moved}");
        } else {
            assert!(moved < 1e-3, "{name}: moved {moved}");
        }
    }
}

/// A file Slicer tagged with another system than the run's `--space` is
/// refused before any work, naming the tag and the option; with the
/// matching `--space` it is read. The outputs carry the run's tag.
#[test]
fn slicers_coordinate_tag_is_checked_on_input_and_written_on_output() {
    let dir = tempfile::tempdir().unwrap();
    let model = sampled(dir.path(), &fixture("ascii.vtp"), "1000");
    let ras = fixture("slicer-ras.vtp");
    for (what, flag) in [("surface", "--surface"), ("structure", "--structure")] {
        let out_dir = dir.path().join(format!("refused-{what}"));
        let surface = fixture("ascii.vtp");
        let mut args = vec!["deform", "--model", s(&model), "-o", s(&out_dir), "-q"];
        if flag == "--surface" {
            args.extend(["--surface", s(&ras)]);
        } else {
            args.extend(["--surface", s(&surface), "--structure", s(&ras)]);
        }
        let out = tissue(&args);
        assert_eq!(out.status.code(), Some(1), "{what}: {}", text(&out));
        assert!(
            text(&out).contains("SPACE=RAS") && text(&out).contains("--space ras"),
            "{what}: {}",
            text(&out)
        );
        assert!(!out_dir.join("report.json").exists());
    }
    let out_dir = dir.path().join("ras");
    let out = tissue(&[
        "deform",
        "--model",
        s(&model),
        "--surface",
        s(&ras),
        "--structure",
        s(&ras),
        "--space",
        "ras",
        "-o",
        s(&out_dir),
        "-q",
    ]);
    assert!(matches!(out.status.code(), Some(0 | 4)), "{}", text(&out));
    for file in ["particles.vtp", "slicer-ras.vtp"] {
        assert_eq!(
            tissue::coordinate_tag(&out_dir.join(file)),
            Some(Space::Ras),
            "{file}"
        );
    }
    // The moved particles' file is still ours to read as a result.
    let particles = std::fs::read_to_string(out_dir.join("particles.vtp")).unwrap();
    assert!(particles.contains(r#"Name="SPACE""#), "{particles}");
}
