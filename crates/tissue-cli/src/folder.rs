//! A run's hold on its output folder: the advisory lock that keeps a
//! second run out ([`OutputLock`]), and the staging that makes a solve's
//! outputs appear together or not at all ([`Staging`]).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// The advisory lock file a run holds in its output folder.
pub const LOCK_FILE: &str = ".tissue.lock";

/// A run's hold on its output folder: an exclusive advisory lock on
/// [`LOCK_FILE`] there, so that a second `deform` or `track` into the same
/// folder is refused instead of mixing its files with the first's. The
/// lock goes with the process (a killed run holds nothing); the file is
/// removed when the hold is dropped.
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    _file: std::fs::File,
}

impl OutputLock {
    /// Takes the lock of `dir` (which exists), or says who holds it.
    pub fn take(dir: &Path) -> Result<Self> {
        let path = dir.join(LOCK_FILE);
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .with_context(|| format!("cannot write {}: its lock file", path.display()))?;
        match file.try_lock() {
            Ok(()) => Ok(Self { path, _file: file }),
            Err(std::fs::TryLockError::WouldBlock) => bail!(
                "another tissue run is writing into {} (it holds {}): wait for it to end, or \
                 choose another output folder",
                dir.display(),
                path.display()
            ),
            Err(std::fs::TryLockError::Error(e)) => {
                Err(e).with_context(|| format!("cannot lock {}", path.display()))
            }
        }
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The prefix of an output's staged name ([`Staging`]).
pub const STAGED_PREFIX: &str = ".tissue-staged-";

/// Outputs written under staged names beside their final ones
/// (`.tissue-staged-<pid>-NAME`: the extension kept, since the writers go
/// by it), renamed into place together, in the order they were staged, by
/// [`Staging::commit`]. Dropped before that (a failure on the way), the
/// staged files are removed: a run's outputs appear together or not at
/// all. A process killed between the two leaves staged files, which the
/// next run into the folder removes ([`remove_staged`]).
#[derive(Debug, Default)]
pub struct Staging {
    /// (staged, final) pairs.
    staged: Vec<(PathBuf, PathBuf)>,
}

impl Staging {
    /// The staged name of the output `path`, to write it to.
    pub fn stage(&mut self, path: &Path) -> PathBuf {
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let staged = path.with_file_name(format!("{STAGED_PREFIX}{}-{name}", std::process::id()));
        self.staged.push((staged.clone(), path.to_path_buf()));
        staged
    }

    /// Renames every staged output into place.
    pub fn commit(mut self) -> Result<()> {
        let staged = std::mem::take(&mut self.staged);
        for (k, (from, to)) in staged.iter().enumerate() {
            if let Err(e) = std::fs::rename(from, to) {
                // What is not yet in place goes; what is stays, named by
                // no report (the report is renamed last).
                for (rest, _) in &staged[k..] {
                    let _ = std::fs::remove_file(rest);
                }
                return Err(e).with_context(|| format!("moving {} into place", to.display()));
            }
        }
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        for (staged, _) in &self.staged {
            let _ = std::fs::remove_file(staged);
        }
    }
}

/// Removes from `dir` the staged outputs ([`Staging`]) a killed run left,
/// and the temporary files of their writes (`.<staged name>.<random>.part`,
/// `tissue::io::write_atomically`).
pub fn remove_staged(dir: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let staged = path.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
            n.starts_with(STAGED_PREFIX)
                || n.strip_prefix('.')
                    .is_some_and(|n| n.starts_with(STAGED_PREFIX) && n.ends_with(".part"))
        });
        if staged && path.is_file() {
            log::info!("removing {}, left by a stopped run", path.display());
            std::fs::remove_file(&path).with_context(|| format!("removing {}", path.display()))?;
        }
    }
    Ok(())
}
