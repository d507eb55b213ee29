//! The terminal's progress display, shared by the long commands. indicatif
//! draws on stderr only where it is a terminal; callers leave it out when
//! `--quiet`.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `length` steps, or a spinner without one, drawn by indicatif's
/// `template`.
pub fn bar(template: &str, length: Option<u64>) -> ProgressBar {
    let bar = match length {
        Some(n) => ProgressBar::new(n),
        None => ProgressBar::new_spinner(),
    };
    bar.set_style(
        ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar
}
