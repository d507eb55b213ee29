//! The observation's pull on the model without correspondence, as the
//! solve's kernels apply it: per particle a spring towards a plane, its
//! point `c` and unit normal `n` with a weight `w`, stored as
//! `s = sqrt(w) n` and `s . c` (one `vec4` on a device). Its force is
//! `s (s . c - s . q)` (the plane's pull along its normal, nothing along
//! it, so the surface slides where the mechanics sends it), its part of the
//! potential `(s . q - s . c)^2 / 2 = w (n . (q - c))^2 / 2`, and its part of the
//! operator `K` (the force of a small displacement `u` is `-2 K u`)
//! `s s^T / 2` (docs/METHOD.md, "Observations without correspondence").

use glam::{DVec3, Vec3, Vec4};

/// A spring's weight where nothing says otherwise, in units of the
/// connection Laplacian's largest eigenvalue ([`crate::stage2::plan::Plan::lambda_max`]).
/// The volume smoother takes each spring exactly
/// ([`crate::coarse::VolumeSmoother`]) and the coarse matrix into its
/// aggregate's block, so a stiffer spring costs few iterations and fits
/// the observation more closely. On the phantom at 3,000 particles, its
/// free skin pulled onto the planes of its sag (3.8 mm RMS moved): weights
/// 1, 4, 16 and 64 leave the skin 0.195, 0.057, 0.016 and 0.004 from its
/// planes (RMS) in 55, 57, 61 and 72 iterations (docs/METHOD.md,
/// "Observations without correspondence").
pub const SPRING_WEIGHT: f32 = 16.0;

/// The spring towards the plane through `point` with unit `normal`, of
/// weight `weight` (in the connection Laplacian's units: the force of a
/// displacement `u` along the normal is `-weight u`).
pub fn spring(point: Vec3, normal: Vec3, weight: f32) -> Vec4 {
    let s = weight.max(0.0).sqrt() * normal;
    s.extend(s.dot(point))
}

/// The spring's force at `q`: `s (s . c - s . q)`.
pub fn spring_force(spring: Vec4, q: Vec3) -> Vec3 {
    let s = spring.truncate();
    s * (spring.w - s.dot(q))
}

/// The spring's part of the potential at `q`, in `f64`:
/// `(s . q - s . c)^2 / 2`, the force's potential plus a constant that
/// keeps it the size of the miss.
pub fn spring_potential(spring: Vec4, q: Vec3) -> f64 {
    let s = spring.truncate().as_dvec3();
    let miss = s.dot(q.as_dvec3()) - f64::from(spring.w);
    0.5 * miss * miss
}

/// The spring's part of `K u` for a displacement `u`: `s (s . u) / 2`.
pub fn spring_operator(spring: Vec4, u: DVec3) -> DVec3 {
    let s = spring.truncate().as_dvec3();
    0.5 * s * s.dot(u)
}

/// The spring's block of `K`: `s s^T / 2`.
pub fn spring_block(spring: Vec4) -> glam::DMat3 {
    let s = spring.truncate().as_dvec3();
    let h = 0.5 * s;
    glam::DMat3::from_cols(h * s.x, h * s.y, h * s.z)
}

/// The largest eigenvalue the springs add to `K`: `max |s|^2 / 2`.
pub fn springs_stiffness(springs: &[Vec4]) -> f32 {
    springs
        .iter()
        .map(|s| 0.5 * s.truncate().length_squared())
        .fold(0.0, f32::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_springs_force_is_minus_its_potentials_gradient_and_its_operator_the_gradients_change() {
        let spring = spring(Vec3::new(1.0, -2.0, 0.5), Vec3::new(0.6, 0.0, 0.8), 9.0);
        let q = Vec3::new(0.3, 0.7, -1.1);
        let h = 1e-3f32;
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let slope = (spring_potential(spring, q + h * axis)
                - spring_potential(spring, q - h * axis))
                / (2.0 * f64::from(h));
            let force = f64::from(spring_force(spring, q).dot(axis));
            assert!((slope + force).abs() < 1e-3, "{slope} against {force}");
            // The force of a small displacement `u` is `-2 K u`.
            let change = spring_force(spring, q + h * axis) - spring_force(spring, q);
            let k = spring_operator(spring, (h * axis).as_dvec3());
            assert!(
                (change.as_dvec3() + 2.0 * k).length() < 1e-4,
                "{change} against {k}"
            );
            let block = spring_block(spring) * (h * axis).as_dvec3();
            assert!((block - k).length() < 1e-9);
        }
        // Along the plane nothing pulls: the surface slides freely.
        let along = Vec3::new(0.8, 0.0, -0.6);
        assert!((spring_force(spring, q + 5.0 * along) - spring_force(spring, q)).length() < 1e-5);
        assert!((springs_stiffness(&[spring, Vec4::ZERO]) - 4.5).abs() < 1e-5);
    }
}
