//! The observation's pull on the model without correspondence, as the
//! solve's kernels apply it: per particle a spring towards a point `c`
//! with a stiffness `P = a I + b u u^T` (`a >= 0`, `a + b |u|^2 >= 0`),
//! stored as `(c, a)` and `(u, b)` (two `vec4` on a device). Its force is
//! `P (c - q)`, its part of the potential `(q - c)^T P (q - c) / 2`, and its
//! part of the operator `K` (the force of a small displacement `v` is
//! `-2 K v`) `P / 2`.
//!
//! The pairing ([`crate::stage2::pairing`]) sets `P` to the Hessian of
//! half the squared distance to the observation at the nearest point, so
//! the springs carry the data term's curvature as well as its pull: on a
//! cloud's plane or a surface's face `w n n^T` (the skin slides freely
//! along it), on a surface's edge `w (I - t t^T)` (free along the edge),
//! at its vertex `w I` (docs/METHOD.md, "Observations without
//! correspondence").

use glam::{DMat3, DVec3, Vec3, Vec4};

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

/// One particle's spring: the potential `(q - c)^T P (q - c) / 2` with
/// `P = a I + b u u^T` (the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Spring {
    /// The point pulled towards, `c`, and the stiffness `a` in every
    /// direction (`w`).
    pub anchor: Vec4,
    /// The axis `u` and the stiffness `b` added along it (`w`).
    pub axis: Vec4,
}

impl Spring {
    /// No spring: no pull, no stiffness.
    pub const ZERO: Self = Self {
        anchor: Vec4::ZERO,
        axis: Vec4::ZERO,
    };

    /// Towards the plane through `point` with unit `normal`, of weight
    /// `weight` (in the connection Laplacian's units: the force of a
    /// displacement `v` along the normal is `-weight v`): `P = w n n^T`.
    pub fn plane(point: Vec3, normal: Vec3, weight: f32) -> Self {
        Self {
            anchor: point.extend(0.0),
            axis: normal.extend(weight.max(0.0)),
        }
    }

    /// Towards the line through `point` along unit `tangent`, of weight
    /// `weight`: `P = w (I - t t^T)`, free along the line.
    pub fn line(point: Vec3, tangent: Vec3, weight: f32) -> Self {
        let weight = weight.max(0.0);
        Self {
            anchor: point.extend(weight),
            axis: tangent.extend(-weight),
        }
    }

    /// Towards `point` in every direction, of weight `weight`: `P = w I`.
    pub fn point(point: Vec3, weight: f32) -> Self {
        Self {
            anchor: point.extend(weight.max(0.0)),
            axis: Vec4::ZERO,
        }
    }

    /// Whether it pulls at all (`P = 0`).
    pub fn is_zero(&self) -> bool {
        self.anchor.w == 0.0 && (self.axis.w == 0.0 || self.axis.truncate() == Vec3::ZERO)
    }

    /// Whether every value is finite.
    pub fn is_finite(&self) -> bool {
        self.anchor.is_finite() && self.axis.is_finite()
    }

    /// Whether `P` is positive semidefinite: `a >= 0` and `a + b |u|^2 >= 0`
    /// (its eigenvalues), up to rounding.
    pub fn is_positive(&self) -> bool {
        let a = self.anchor.w;
        let along = a + self.axis.w * self.axis.truncate().length_squared();
        a >= 0.0 && along >= -1e-6 * a.abs().max(1.0)
    }

    /// The point pulled towards.
    pub fn point_of(&self) -> Vec3 {
        self.anchor.truncate()
    }

    /// `P v` in `f32`.
    pub fn times(&self, v: Vec3) -> Vec3 {
        let u = self.axis.truncate();
        self.anchor.w * v + (self.axis.w * u.dot(v)) * u
    }

    /// `P v` in `f64`.
    pub fn times_f64(&self, v: DVec3) -> DVec3 {
        let u = self.axis.truncate().as_dvec3();
        f64::from(self.anchor.w) * v + (f64::from(self.axis.w) * u.dot(v)) * u
    }

    /// The stiffness `a` in every direction and `b` along `u`, in `f64`.
    pub fn stiffness(&self) -> (f64, f64, DVec3) {
        (
            f64::from(self.anchor.w),
            f64::from(self.axis.w),
            self.axis.truncate().as_dvec3(),
        )
    }

    /// Whether `other` has the same `P` (its point may differ): a device's
    /// operator made with one holds for the other.
    pub fn same_stiffness(&self, other: &Self) -> bool {
        self.anchor.w == other.anchor.w && self.axis == other.axis
    }

    /// Whether every spring of `a` has the same `P` as `b`'s
    /// ([`Spring::same_stiffness`]), one for one.
    pub fn all_same_stiffness(a: &[Self], b: &[Self]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(a, b)| a.same_stiffness(b))
    }

    /// The largest eigenvalue of `P`: `a + max(b |u|^2, 0)`.
    pub fn largest(&self) -> f32 {
        self.anchor.w + (self.axis.w * self.axis.truncate().length_squared()).max(0.0)
    }
}

/// The spring towards the plane through `point` with unit `normal`, of
/// weight `weight` ([`Spring::plane`]).
pub fn spring(point: Vec3, normal: Vec3, weight: f32) -> Spring {
    Spring::plane(point, normal, weight)
}

/// The spring's force at `q`: `P (c - q)`.
pub fn spring_force(spring: Spring, q: Vec3) -> Vec3 {
    spring.times(spring.point_of() - q)
}

/// The spring's part of the potential at `q`, in `f64`:
/// `(q - c)^T P (q - c) / 2`.
pub fn spring_potential(spring: Spring, q: Vec3) -> f64 {
    let miss = (q - spring.point_of()).as_dvec3();
    0.5 * miss.dot(spring.times_f64(miss))
}

/// The spring's part of `K v` for a displacement `v`: `P v / 2`.
pub fn spring_operator(spring: Spring, v: DVec3) -> DVec3 {
    0.5 * spring.times_f64(v)
}

/// The spring's block of `K`: `P / 2`.
pub fn spring_block(spring: Spring) -> DMat3 {
    let (a, b, u) = spring.stiffness();
    let h = 0.5 * b * u;
    DMat3::from_diagonal(DVec3::splat(0.5 * a)) + DMat3::from_cols(h * u.x, h * u.y, h * u.z)
}

/// The largest eigenvalue the springs add to `K`: the largest of `P / 2`.
pub fn springs_stiffness(springs: &[Spring]) -> f32 {
    springs
        .iter()
        .map(|s| 0.5 * s.largest())
        .fold(0.0, f32::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(spring: Spring, q: Vec3) {
        let h = 1e-3f32;
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let slope = (spring_potential(spring, q + h * axis)
                - spring_potential(spring, q - h * axis))
                / (2.0 * f64::from(h));
            let force = f64::from(spring_force(spring, q).dot(axis));
            assert!(
                (slope + force).abs() < 1e-3 * (1.0 + force.abs()),
                "{slope} against {force}"
            );
            // The force of a small displacement `v` is `-2 K v`.
            let change = spring_force(spring, q + h * axis) - spring_force(spring, q);
            let k = spring_operator(spring, (h * axis).as_dvec3());
            assert!(
                (change.as_dvec3() + 2.0 * k).length() < 1e-4,
                "{change} against {k}"
            );
            let block = spring_block(spring) * (h * axis).as_dvec3();
            assert!((block - k).length() < 1e-9);
        }
    }

    #[test]
    fn a_springs_force_is_minus_its_potentials_gradient_and_its_operator_the_gradients_change() {
        let point = Vec3::new(1.0, -2.0, 0.5);
        let q = Vec3::new(0.3, 0.7, -1.1);
        let normal = Vec3::new(0.6, 0.0, 0.8);
        let plane = spring(point, normal, 9.0);
        let line = Spring::line(point, normal, 9.0);
        let vertex = Spring::point(point, 9.0);
        for s in [plane, line, vertex] {
            check(s, q);
            assert!(s.is_positive() && !s.is_zero());
        }
        // Along the plane nothing pulls: the surface slides freely; along
        // the line likewise; a vertex holds in every direction.
        let along = Vec3::new(0.8, 0.0, -0.6);
        assert!((spring_force(plane, q + 5.0 * along) - spring_force(plane, q)).length() < 1e-5);
        assert!((spring_force(line, q + 5.0 * normal) - spring_force(line, q)).length() < 1e-5);
        let moved = spring_force(vertex, q + along) - spring_force(vertex, q);
        assert!((moved + 9.0 * along).length() < 1e-5);
        // The potential is half the squared distance, weighted: to the
        // plane, the line and the point.
        let miss = q - point;
        let w = 9.0_f64;
        let to_plane = f64::from(normal.dot(miss));
        let to_line = f64::from((miss - normal.dot(miss) * normal).length());
        let to_point = f64::from(miss.length());
        for (s, d) in [(plane, to_plane), (line, to_line), (vertex, to_point)] {
            assert!((spring_potential(s, q) - 0.5 * w * d * d).abs() < 1e-4);
        }
        assert!((springs_stiffness(&[plane, Spring::ZERO]) - 4.5).abs() < 1e-5);
        assert!((springs_stiffness(&[line, vertex]) - 4.5).abs() < 1e-5);
        assert!(Spring::ZERO.is_zero() && Spring::ZERO.is_positive());
        let negative = Spring {
            anchor: point.extend(1.0),
            axis: normal.extend(-2.0),
        };
        assert!(!negative.is_positive());
    }

    /// Springs whose points alone differ have the same stiffness, a
    /// quarter of the weight at the same point not.
    #[test]
    fn a_spring_compares_by_its_stiffness() {
        let point = Vec3::new(1.0, -2.0, 0.5);
        let normal = Vec3::new(0.6, 0.0, 0.8);
        let q = Vec3::new(0.3, 0.7, -1.1);
        for s in [
            spring(point, normal, 8.0),
            Spring::line(point, normal, 8.0),
            Spring::point(point, 8.0),
        ] {
            let quarter = Spring {
                anchor: s.anchor.truncate().extend(0.25 * s.anchor.w),
                axis: s.axis.truncate().extend(0.25 * s.axis.w),
            };
            assert_eq!(quarter.point_of(), point);
            assert!((spring_force(quarter, q) - 0.25 * spring_force(s, q)).length() < 1e-5);
            let elsewhere = Spring {
                anchor: (point + normal).extend(s.anchor.w),
                ..s
            };
            assert!(s.same_stiffness(&elsewhere) && !s.same_stiffness(&quarter));
        }
        let (a, b) = (
            [spring(point, normal, 8.0), Spring::ZERO],
            [spring(point + normal, normal, 8.0), Spring::ZERO],
        );
        assert!(Spring::all_same_stiffness(&a, &b));
        assert!(!Spring::all_same_stiffness(&a, &b[..1]));
        assert!(!Spring::all_same_stiffness(
            &a,
            &[Spring::ZERO, Spring::ZERO]
        ));
    }
}
