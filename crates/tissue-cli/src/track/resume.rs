//! `tissue track`'s earlier runs: what a run into the same folder leaves
//! that this one would not replace, and what `--resume` keeps of a run
//! that was cut off.

use std::path::Path;

use anyhow::{Context, Result, bail};
use serde_json::Value;

use super::{COLLECTION_FILE, TRACK_FILE};
use crate::output::REPORT_FILE;

/// Removes what an earlier `track` into `dir` left that this run of
/// `frames` frames would not replace: its `track.json` and `track.pvd`
/// unless `keep_summary` (a resumed run's), its frame folders past this run's last (`frame-NNNN`
/// holding a `report.json`), and the temporary files of a write that was
/// killed (`.NAME.<random>.part`); nothing else is touched.
pub(super) fn remove_stale(dir: &Path, frames: usize, keep_summary: bool) -> Result<()> {
    for name in [TRACK_FILE, COLLECTION_FILE] {
        let summary = dir.join(name);
        if summary.exists() && !keep_summary {
            std::fs::remove_file(&summary)
                .with_context(|| format!("removing the earlier {}", summary.display()))?;
        }
    }
    remove_parts(dir)?;
    let entries = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(number) = name
            .to_str()
            .and_then(|n| n.strip_prefix("frame-"))
            .filter(|n| n.len() == 4)
            .and_then(|n| n.parse::<usize>().ok())
        else {
            continue;
        };
        let folder = entry.path();
        if number > frames && folder.join(REPORT_FILE).is_file() {
            log::info!("removing {}, left by an earlier run", folder.display());
            std::fs::remove_dir_all(&folder)
                .with_context(|| format!("removing the earlier {}", folder.display()))?;
        }
    }
    Ok(())
}

/// Removes the temporary files a killed write left in `dir` and in its
/// `frame-NNNN` folders: hidden, named `.NAME.<random>.part`
/// (`tissue::io::write_atomically`).
fn remove_parts(dir: &Path) -> Result<()> {
    let mut folders = vec![dir.to_path_buf()];
    let entries = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if path.is_dir() && name.starts_with("frame-") {
            folders.push(path);
        }
    }
    for folder in folders {
        let Ok(entries) = std::fs::read_dir(&folder) else {
            continue;
        };
        for entry in entries.flatten() {
            let name = entry.file_name();
            let name = name.to_string_lossy();
            if name.starts_with('.') && name.ends_with(".part") && entry.path().is_file() {
                log::info!(
                    "removing {}, left by a write that was cut off",
                    entry.path().display()
                );
                std::fs::remove_file(entry.path())
                    .with_context(|| format!("removing {}", entry.path().display()))?;
            }
        }
    }
    Ok(())
}

/// The frames an earlier run into `dir` finished, from its `track.json`
/// (`summary`), for `--resume`: refused unless that run's plan is `plan`
/// (the same options and the same files, by their contents' hashes),
/// and when it did all `planned` frames; the frames it lists, in order, up
/// to the first whose folder in `dir` (`frame-NNNN`) has no `report.json`.
pub(super) fn resumed(
    summary: &Path,
    plan: &Value,
    dir: &Path,
    planned: usize,
) -> Result<Vec<Value>> {
    if !summary.is_file() {
        bail!(
            "--resume: {} does not exist, so there is no run to continue; run without --resume",
            summary.display()
        );
    }
    let text = std::fs::read_to_string(summary)
        .with_context(|| format!("--resume: reading {}", summary.display()))?;
    let earlier: Value = serde_json::from_str(&text)
        .with_context(|| format!("--resume: {} is not a track summary", summary.display()))?;
    let Some(earlier_plan) = earlier.get("plan").and_then(Value::as_object) else {
        bail!(
            "--resume: {} holds no `plan` (written by an older tissue?): run without --resume",
            summary.display()
        );
    };
    if let Some(object) = plan.as_object() {
        for (key, value) in object {
            if earlier_plan.get(key) == Some(value) {
                continue;
            }
            let changed = (key == "inputs")
                .then(|| {
                    let before = earlier_plan.get(key)?.as_object()?;
                    value
                        .as_object()?
                        .iter()
                        .find(|(path, hash)| before.get(*path) != Some(*hash))
                        .map(|(path, _)| path.clone())
                })
                .flatten();
            match changed {
                Some(path) => bail!(
                    "--resume: {path} is not what the run in {} read (its contents changed, or \
                     it is another file): resume with the same files, or run without --resume",
                    summary.display()
                ),
                None => bail!(
                    "--resume: this run's {key} differ from those of the run in {}: \
                     resume with the same model, frames, carried files and options, \
                     or run without --resume",
                    summary.display()
                ),
            }
        }
    }
    // The frames done are those whose folder here holds its report, up to
    // the first that does not (whatever folder the summary names).
    let mut done = Vec::new();
    for (k, frame) in earlier["frames"]
        .as_array()
        .into_iter()
        .flatten()
        .enumerate()
    {
        let folder = dir.join(format!("frame-{:04}", k + 1));
        if !folder.join(REPORT_FILE).is_file() {
            break;
        }
        done.push(frame.clone());
    }
    if done.len() >= planned {
        bail!(
            "--resume: the run in {} has done all of its {planned} frames: nothing to continue \
             (run without --resume to solve them again)",
            summary.display()
        );
    }
    Ok(done)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
mod tests {
    use super::*;

    #[test]
    fn an_earlier_runs_leftovers_are_removed_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let write = |name: &str| {
            let path = d.join(name);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, "x").unwrap();
        };
        for name in [
            TRACK_FILE,
            COLLECTION_FILE,
            "notes.txt",
            ".particles.vtp.k3Yq.part",
            "frame-0001/report.json",
            "frame-0001/.report.json.Zx81.part",
            "frame-0001/.hidden",
            "frame-0003/report.json",
            "frame-0004/points.csv",
        ] {
            write(name);
        }
        remove_stale(d, 2, true).unwrap();
        // A resumed run keeps its summary; the frames past its last go,
        // with the killed writes' temporary files.
        assert!(d.join(TRACK_FILE).exists() && d.join(COLLECTION_FILE).exists());
        assert!(!d.join("frame-0003").exists());
        assert!(!d.join(".particles.vtp.k3Yq.part").exists());
        assert!(!d.join("frame-0001/.report.json.Zx81.part").exists());
        // What no run of `track` writes stays: the user's file, a hidden
        // file that is no temporary one, a folder holding no report.
        for kept in [
            "notes.txt",
            "frame-0001/report.json",
            "frame-0001/.hidden",
            "frame-0004/points.csv",
        ] {
            assert!(d.join(kept).exists(), "{kept}");
        }
        remove_stale(d, 2, false).unwrap();
        assert!(!d.join(TRACK_FILE).exists() && !d.join(COLLECTION_FILE).exists());
        assert!(d.join("frame-0001/report.json").exists());
    }
}
