//! Twin of `shaders/step_norms.wgsl`: the largest and RMS step, what the
//! stopping rule measures.

use glam::Vec3;
use rayon::prelude::*;

/// The shader this module is the twin of.
pub const SHADER: &str = "step_norms";

/// Largest and RMS plain step over all particles (`old` to `new`), as
/// `Deformer::solve` measures each iteration.
pub fn step_norms(old: &[Vec3], new: &[Vec3]) -> (f32, f32) {
    let squares: Vec<f32> = old
        .par_iter()
        .zip(new)
        .map(|(a, b)| (*b - *a).length_squared())
        .collect();
    let max = squares.iter().copied().fold(0.0, f32::max).sqrt();
    let mean = squares.iter().map(|&x| f64::from(x)).sum::<f64>() / squares.len().max(1) as f64;
    (max, mean.sqrt() as f32)
}
