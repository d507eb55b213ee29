//! The `tissue` command-line tool.
fn main() {}
