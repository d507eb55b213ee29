//! Checks that a surface is one closed, consistently oriented, outward shell.
