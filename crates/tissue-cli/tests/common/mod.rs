//! Helpers shared by the CLI test files.
#![allow(dead_code, reason = "each test file uses a different subset")]
#![allow(clippy::expect_used, clippy::unwrap_used, reason = "tests")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `tissue` binary.
pub fn tissue(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tissue"))
        .args(args)
        .output()
        .expect("the tissue binary runs")
}

/// Its stdout and stderr together.
pub fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The bundled assets folder.
pub fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
}

/// A path as `&str`.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A JSON file, parsed.
pub fn json(path: &Path) -> serde_json::Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A JSON array of three numbers.
pub fn vec3(v: &serde_json::Value) -> tissue::Vec3 {
    let a: Vec<f32> = v
        .as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect();
    tissue::Vec3::new(a[0], a[1], a[2])
}

/// Whether a GPU adapter exists (the test log names it); `false` after
/// printing "SKIPPED: no GPU adapter", a panic under `CI=true`.
pub fn gpu(test: &str) -> bool {
    match tissue::backend::Device::pick(tissue::backend::Backend::Gpu) {
        Ok(picked) => {
            eprintln!("{test}: adapter {}", picked.device.name());
            true
        }
        Err(why) if why.to_string().contains("no GPU adapter") => {
            if std::env::var("CI").as_deref() == Ok("true") {
                panic!("{test}: no GPU adapter under CI=true ({why}); install Mesa lavapipe");
            }
            eprintln!("SKIPPED: no GPU adapter ({test}: {why})");
            false
        }
        Err(e) => panic!("{test}: the adapter would not open a device: {e}"),
    }
}

/// A case of `../shared/cases/` (its folder), or `None` (printing why)
/// when it is absent; under `CI=true` its absence is a failure.
pub fn shared_case(name: &str) -> Option<PathBuf> {
    shared("cases", name, "truth.json")
}

/// A mesh of `../shared/meshes/`, or `None` (printing why) when it is
/// absent; under `CI=true` its absence is a failure.
pub fn shared_mesh(name: &str) -> Option<PathBuf> {
    shared("meshes", name, "")
}

/// `../shared/FOLDER/NAME` where `NAME/INSIDE` exists (`NAME` itself for
/// an empty `INSIDE`).
fn shared(folder: &str, name: &str, inside: &str) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared")
        .join(folder)
        .join(name);
    let marker = if inside.is_empty() {
        path.clone()
    } else {
        path.join(inside)
    };
    if marker.exists() {
        return Some(path);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared {folder} entry {} is missing",
        path.display()
    );
    eprintln!("SKIPPED: {} not found", path.display());
    None
}

/// The bundled phantom sampled by `tissue sample` at 2,000 particles, read back.
pub fn sampled_model(dir: &Path) -> (PathBuf, tissue::ParticleModel) {
    let path = dir.join("model.vtp");
    let breast = assets().join("phantom-breast.obj");
    let out = tissue(&[
        "sample",
        s(&breast),
        "-n",
        "2000",
        "-o",
        s(&path),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let model = tissue::load_model(&path).unwrap();
    (path, model)
}

/// Bounding-box diagonal of the rest particles (`Deformer::size`).
pub fn size(model: &tissue::ParticleModel) -> f32 {
    let (lo, hi) = model.positions.iter().fold(
        (tissue::Vec3::splat(f32::MAX), tissue::Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    (hi - lo).length()
}

/// One named `DataArray` of an ASCII `.vtp`, as numbers.
pub fn vtp_array(text: &str, name: &str) -> Vec<f32> {
    let tag = format!("Name=\"{name}\"");
    let start = text.find(&tag).unwrap_or_else(|| panic!("no array {name}"));
    let body = &text[start..];
    let open = body.find('>').unwrap() + 1;
    let close = body.find("</DataArray>").unwrap();
    body[open..close]
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect()
}
