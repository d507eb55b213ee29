//! File formats: surfaces in (STL, OBJ, PLY, legacy VTK), models and points out.

pub mod model;
pub mod surface;
mod vtp;
mod xml;
