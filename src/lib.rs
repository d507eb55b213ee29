//! **tissue**: track where the inside of a soft organ goes when its surface moves.
//!
//! The organ's interior is filled with particles (stage 1, uniform sampling);
//! surface particles then follow an observed surface and the interior follows
//! them (stage 2). This crate is the public, backend-agnostic entry point.

pub use tissue_core::*;
