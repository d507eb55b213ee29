//! Expanding a frame pattern into an ordered list of files.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// The files `pattern` (the value of the option `option`, for the errors)
/// matches (directories skipped), in name order with runs of digits
/// compared as numbers, so `frame-2` comes before `frame-10`.
pub fn expand(option: &str, pattern: &str) -> Result<Vec<PathBuf>> {
    let paths = glob::glob(pattern)
        .with_context(|| format!("{option} '{pattern}' is not a valid pattern"))?;
    let mut files = Vec::new();
    for entry in paths {
        let path = entry.with_context(|| format!("{option} '{pattern}'"))?;
        if path.is_file() {
            files.push(path);
        }
    }
    refuse_unreadable_names(option, pattern)?;
    if files.is_empty() {
        bail!("{option} '{pattern}' matches no file");
    }
    files.sort_by(|a, b| natural_order(&a.to_string_lossy(), &b.to_string_lossy()));
    Ok(files)
}

/// Refuses a file whose name is not UTF-8 and would match `pattern`'s last
/// part: the pattern matcher skips such names without a word, and a
/// sequence with a frame left out is a wrong result. (Checked in the
/// pattern's folder when that folder has no wildcard, as in
/// `frames/*.obj`.)
fn refuse_unreadable_names(option: &str, pattern: &str) -> Result<()> {
    let path = Path::new(pattern);
    let (Some(folder), Some(name)) = (path.parent(), path.file_name().and_then(|n| n.to_str()))
    else {
        return Ok(());
    };
    let folder_text = folder.to_string_lossy();
    if folder_text.contains(['*', '?', '[']) {
        return Ok(());
    }
    let Ok(matcher) = glob::Pattern::new(name) else {
        return Ok(());
    };
    let folder = if folder_text.is_empty() {
        Path::new(".")
    } else {
        folder
    };
    let Ok(entries) = std::fs::read_dir(folder) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        if name.to_str().is_none() && matcher.matches(&name.to_string_lossy()) {
            bail!(
                "{option} '{pattern}': {} has a name that is not valid UTF-8, which the pattern \
                 cannot match; rename it (or move it away) so that no frame is left out",
                entry.path().to_string_lossy()
            );
        }
    }
    Ok(())
}

/// Compares names chunk by chunk: digit runs by value (then by length, so
/// `01` sorts after `1`), everything else by character.
pub fn natural_order(a: &str, b: &str) -> Ordering {
    let (mut a, mut b) = (a, b);
    loop {
        match (a.chars().next(), b.chars().next()) {
            (None, None) => return Ordering::Equal,
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let (da, ra) = split_digits(a);
                let (db, rb) = split_digits(b);
                let (ta, tb) = (da.trim_start_matches('0'), db.trim_start_matches('0'));
                let order = ta
                    .len()
                    .cmp(&tb.len())
                    .then_with(|| ta.cmp(tb))
                    .then_with(|| da.len().cmp(&db.len()));
                if order != Ordering::Equal {
                    return order;
                }
                (a, b) = (ra, rb);
            }
            (Some(x), Some(y)) => {
                if x != y {
                    return x.cmp(&y);
                }
                (a, b) = (&a[x.len_utf8()..], &b[y.len_utf8()..]);
            }
        }
    }
}

/// The leading run of ASCII digits and the rest.
fn split_digits(s: &str) -> (&str, &str) {
    let end = s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    s.split_at(end)
}

#[cfg(test)]
mod tests {
    use super::natural_order;

    #[test]
    fn numbers_in_names_sort_by_value() {
        let mut names = vec![
            "f10.obj", "f2.obj", "f1.obj", "f02.obj", "g.obj", "f.obj", "f1a.obj",
        ];
        names.sort_by(|a, b| natural_order(a, b));
        assert_eq!(
            names,
            [
                "f.obj", "f1.obj", "f1a.obj", "f2.obj", "f02.obj", "f10.obj", "g.obj"
            ]
        );
    }
}
