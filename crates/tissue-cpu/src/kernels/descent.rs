//! Twin of `shaders/descent.wgsl`: the conjugate-gradient elastic phase's
//! per-particle work ([`tissue_solve::stage2::SolveDevice::descent_residual`]
//! and the calls after it): its dot products' parts (`descent_dots`), the
//! direction (`descent_direction`) and the move along it (`descent_move`).

use glam::Vec3;
use rayon::prelude::*;

/// The shader this module is the twin of.
pub const SHADER: &str = "descent";

/// Per particle `(r . z, z . r', r . d', |z|)`, each in `f32` as the shader
/// makes it, from the residual `r`, the two-level step `z`, the residual
/// kept last `r'` and the last direction `d'`; `r'` is then `r`.
pub fn descent_dots(
    residual: &[Vec3],
    step: &[Vec3],
    last_residual: &mut [Vec3],
    direction: &[Vec3],
) -> Vec<[f64; 4]> {
    residual
        .par_iter()
        .zip(step)
        .zip(last_residual.par_iter_mut())
        .zip(direction)
        .map(|(((&r, &z), last), &d)| {
            let part = [z.dot(r), z.dot(*last), r.dot(d), z.length()];
            *last = r;
            part.map(f64::from)
        })
        .collect()
}

/// `d = z + beta d'` in place of `d'`, and the base the line search moves
/// from set to the current positions.
pub fn descent_direction(
    step: &[Vec3],
    beta: f32,
    direction: &mut [Vec3],
    current: &[Vec3],
    base: &mut [Vec3],
) {
    direction
        .par_iter_mut()
        .zip(step)
        .zip(base.par_iter_mut().zip(current))
        .for_each(|((d, &z), (base, &q))| {
            *d = z + beta * *d;
            *base = q;
        });
}

/// Every particle at `base + t d`.
pub fn descent_move(base: &[Vec3], direction: &[Vec3], t: f32, current: &mut [Vec3]) {
    current
        .par_iter_mut()
        .zip(base.par_iter().zip(direction))
        .for_each(|(q, (&base, &d))| *q = base + t * d);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parts are each particle's dot products and step length, the
    /// residual kept is the new one; the direction adds `beta` of the last
    /// and the base is the current positions; a move puts every particle
    /// `t` directions from the base.
    #[test]
    fn the_dots_the_direction_and_the_move_are_each_particles() {
        let residual = [Vec3::new(1.0, 2.0, 0.0), Vec3::new(0.0, 0.0, 3.0)];
        let step = [Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 4.0, 3.0)];
        let mut last = [Vec3::new(0.0, 1.0, 0.0), Vec3::new(1.0, 1.0, 1.0)];
        let mut direction = [Vec3::new(1.0, 1.0, 1.0), Vec3::ZERO];
        let parts = descent_dots(&residual, &step, &mut last, &direction);
        assert_eq!(parts, vec![[2.0, 0.0, 3.0, 2.0], [9.0, 7.0, 0.0, 5.0]]);
        assert_eq!(last, residual);
        let current = [Vec3::new(5.0, 5.0, 5.0), Vec3::new(-1.0, 0.0, 1.0)];
        let mut base = [Vec3::ZERO; 2];
        descent_direction(&step, 0.5, &mut direction, &current, &mut base);
        assert_eq!(
            direction,
            [Vec3::new(2.5, 0.5, 0.5), Vec3::new(0.0, 4.0, 3.0)]
        );
        assert_eq!(base, current);
        let mut moved = [Vec3::ZERO; 2];
        descent_move(&base, &direction, 2.0, &mut moved);
        assert_eq!(
            moved,
            [Vec3::new(10.0, 6.0, 6.0), Vec3::new(-1.0, 8.0, 7.0)]
        );
        descent_move(&base, &direction, 0.0, &mut moved);
        assert_eq!(moved, current);
    }
}
