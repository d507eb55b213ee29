//! Particle model files (VTK XML PolyData) and point files (CSV, PLY).
