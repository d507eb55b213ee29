//! File formats: surfaces (STL, OBJ, PLY, legacy VTK) in [`surface`],
//! particle models (VTK XML PolyData) in [`model`], point files (CSV, PLY)
//! in [`points`], point clouds of an observed surface in [`cloud`], 3D
//! Slicer's markups in [`markups`], ITK transform files
//! in [`itk`] and displacement fields in [`nrrd`], in the coordinate
//! systems of [`space`].

use std::io::{self, BufWriter, Write};
use std::path::Path;

use crate::error::Error;

pub mod cloud;
pub mod itk;
pub mod markups;
pub mod model;
pub mod nrrd;
pub mod points;
pub mod space;
pub mod surface;
mod vtk_binary;
mod vtp;
mod xml;

// What the model and point files share: errors that name the file, reading
// text, buffered writing.

fn format_error(path: &Path, message: impl Into<String>) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

fn io_error(path: &Path, source: io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn extension(path: &Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
}

fn read_text(path: &Path) -> Result<String, Error> {
    let bytes = std::fs::read(path).map_err(|source| io_error(path, source))?;
    String::from_utf8(bytes).map_err(|e| {
        format_error(
            path,
            format!(
                "not a text file (invalid UTF-8 at byte {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

thread_local! {
    /// Whether a panic on this thread is being caught by [`catch_quietly`],
    /// so the panic hook stays silent.
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `work`, returning a panic inside it as `Err` (as
/// [`std::panic::catch_unwind`]) without the process's panic hook printing
/// it: for a dependency that panics on a damaged file, whose caller turns
/// the panic into an error that says what is wrong. The first call installs,
/// once for the process, a hook that stays silent while a `catch_quietly`
/// runs on the panicking thread and otherwise calls the hook that was
/// there before (Rust's default, or the application's).
///
/// # Errors
///
/// The panic's payload, when `work` panicked.
pub fn catch_quietly<T>(work: impl FnOnce() -> T) -> std::thread::Result<T> {
    static INSTALL: std::sync::Once = std::sync::Once::new();
    INSTALL.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    let was = QUIET.with(|q| q.replace(true));
    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
    QUIET.with(|q| q.set(was));
    out
}

/// Writes `path` whole or not at all: `body` writes a temporary file in
/// the same folder, which is flushed to disk and renamed over `path` only
/// when `body` succeeds. A failure, a kill or a full disk leaves the file
/// that was there (or none), never a truncated one.
///
/// # Errors
///
/// [`Error::Io`] naming `path` for any failure: creating the temporary
/// file (a missing or read-only folder), writing, flushing or renaming.
pub fn write_atomically(
    path: &Path,
    body: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<(), Error> {
    let folder = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    };
    let name = path.file_name().map_or_else(
        || std::ffi::OsString::from("output"),
        std::ffi::OsStr::to_os_string,
    );
    let mut prefix = std::ffi::OsString::from(".");
    prefix.push(&name);
    prefix.push(".");
    let temporary = tempfile::Builder::new()
        .prefix(&prefix)
        .suffix(".part")
        .tempfile_in(folder)
        .map_err(|source| io_error(path, source))?;
    let mut w = BufWriter::new(temporary);
    body(&mut w)
        .and_then(|()| w.flush())
        .map_err(|source| io_error(path, source))?;
    let temporary = w.into_inner().map_err(|e| io_error(path, e.into_error()))?;
    temporary
        .as_file()
        .sync_all()
        .map_err(|source| io_error(path, source))?;
    // A temporary file is private (0600); the output gets the permissions
    // of the file it replaces, or a new file's usual ones.
    let permissions = match std::fs::metadata(path) {
        Ok(old) => old.permissions(),
        Err(_) => new_file_permissions(temporary.as_file())?,
    };
    temporary
        .as_file()
        .set_permissions(permissions)
        .map_err(|source| io_error(path, source))?;
    temporary
        .persist(path)
        .map_err(|e| io_error(path, e.error))?;
    Ok(())
}

/// A new file's permissions: read and write for the owner, read for the rest.
#[cfg(unix)]
fn new_file_permissions(_: &std::fs::File) -> Result<std::fs::Permissions, Error> {
    use std::os::unix::fs::PermissionsExt;
    Ok(std::fs::Permissions::from_mode(0o644))
}

/// A new file's permissions: the temporary file's.
#[cfg(not(unix))]
fn new_file_permissions(file: &std::fs::File) -> Result<std::fs::Permissions, Error> {
    file.metadata()
        .map(|m| m.permissions())
        .map_err(|source| io_error(Path::new("output"), source))
}

fn write_file(
    path: &Path,
    body: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<(), Error> {
    write_atomically(path, body)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    /// The names in `folder`, sorted.
    fn names(folder: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(folder)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_whole_and_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.vtp");
        write_atomically(&path, |out| out.write_all(b"the good model\n")).unwrap();
        // A writer that fails half-way (a full disk, a killed process's
        // partial output): the good file stays as it was.
        let failed = write_atomically(&path, |out| {
            out.write_all(b"half of a new mod")?;
            Err(io::Error::other("the disk is full"))
        });
        let err = failed.unwrap_err().to_string();
        assert!(
            err.contains("model.vtp") && err.contains("the disk is full"),
            "{err}"
        );
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "the good model\n");
        assert_eq!(names(dir.path()), ["model.vtp"]);
        // A write that succeeds replaces it whole.
        write_atomically(&path, |out| out.write_all(b"the new model\n")).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "the new model\n");
        assert_eq!(names(dir.path()), ["model.vtp"]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&path).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o644, "{mode:o}");
        }
    }

    #[test]
    fn a_write_into_a_missing_folder_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/folder/out.csv");
        let err = write_atomically(&path, |out| out.write_all(b"x")).unwrap_err();
        assert!(matches!(err, Error::Io { .. }), "{err:?}");
        assert!(err.to_string().contains("out.csv"), "{err}");
    }
}
