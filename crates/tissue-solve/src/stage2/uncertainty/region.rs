//! A target's 95 % region from the spread's columns: its covariance, the
//! ellipsoid's semi-axes, one radius, and which unknown the spread owes
//! most to.

use glam::{DVec3, Vec3};
use serde::Serialize;

use super::Unknown;

/// The 95 % quantile of the chi-square distribution with 3 degrees of
/// freedom: a Gaussian offset `e` of covariance `C` lies inside
/// `e^T C^-1 e <= CHI2_3_95` with probability 0.95.
pub const CHI2_3_95: f64 = 7.814_727_903_251_178;

/// The standard normal's 95 % quantile, for the radius's chi-square
/// approximation ([`radius_95`]).
const Z_95: f64 = 1.644_853_626_951_472_2;

/// A covariance's smallest eigenvalue as a fraction of its largest, for
/// [`Region::contains`]: a spread flat in one direction (one column) still
/// has a region of some thickness there.
pub const FLAT_FLOOR: f64 = 1e-3;

/// A symmetric 3x3 matrix by its six entries: `xx, yy, zz, xy, xz, yz`.
pub type Symmetric = [f64; 6];

/// Where one target (a particle, a carried point, a structure's centroid)
/// may be: a Gaussian around the answer with the spread's covariance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Region {
    /// The covariance, model units squared: `xx, yy, zz, xy, xz, yz`.
    pub covariance: Symmetric,
    /// The 95 % ellipsoid's semi-axes (`sqrt(CHI2_3_95 lambda)` for each
    /// eigenvalue `lambda` of the covariance), largest first.
    pub semi_axes: [f32; 3],
    /// Their directions (unit vectors), in the same order.
    pub axes: [Vec3; 3],
    /// The distance from the answer within which the target lies with
    /// probability 0.95 ([`radius_95`]): at most the largest semi-axis.
    pub radius: f32,
    /// Each unknown's share of the variance (the covariance's trace), in
    /// [`Unknown::ALL`] order; zero shares where there is no spread.
    pub shares: [f32; Unknown::ALL.len()],
    /// The unknown with the largest share; `None` where there is no spread.
    pub dominant: Option<Unknown>,
}

impl Region {
    /// The region of offsets `columns` (each an offset from the answer,
    /// its weight and its unknown): covariance `sum w d d^T`.
    pub fn of(columns: impl IntoIterator<Item = (Unknown, f64, Vec3)>) -> Self {
        let mut covariance = [0.0; 6];
        let mut by_unknown = [0.0; Unknown::ALL.len()];
        for (unknown, weight, offset) in columns {
            let d = offset.as_dvec3();
            let w = weight;
            covariance[0] += w * d.x * d.x;
            covariance[1] += w * d.y * d.y;
            covariance[2] += w * d.z * d.z;
            covariance[3] += w * d.x * d.y;
            covariance[4] += w * d.x * d.z;
            covariance[5] += w * d.y * d.z;
            by_unknown[unknown.index()] += w * d.length_squared();
        }
        let (values, vectors) = symmetric_eigen(covariance);
        let total: f64 = by_unknown.iter().sum();
        let shares = by_unknown.map(|v| if total > 0.0 { (v / total) as f32 } else { 0.0 });
        let dominant = (total > 0.0)
            .then(|| {
                Unknown::ALL
                    .into_iter()
                    .zip(by_unknown)
                    .max_by(|a, b| a.1.total_cmp(&b.1))
                    .map(|(u, _)| u)
            })
            .flatten();
        Self {
            covariance,
            semi_axes: values.map(|l| (CHI2_3_95 * l.max(0.0)).sqrt() as f32),
            axes: vectors.map(DVec3::as_vec3),
            radius: radius_95(values) as f32,
            shares,
            dominant,
        }
    }

    /// Whether `offset` (the truth less the answer) lies inside the 95 %
    /// ellipsoid, its thinnest axes floored at [`FLAT_FLOOR`] of the
    /// largest eigenvalue. With no spread at all, only a zero offset does.
    pub fn contains(&self, offset: Vec3) -> bool {
        let (values, vectors) = symmetric_eigen(self.covariance);
        let largest = values[0].max(0.0);
        if largest == 0.0 {
            return offset == Vec3::ZERO;
        }
        let d = offset.as_dvec3();
        let distance: f64 = values
            .iter()
            .zip(&vectors)
            .map(|(&l, v)| d.dot(*v).powi(2) / l.max(FLAT_FLOOR * largest))
            .sum();
        distance <= CHI2_3_95
    }
}

/// The radius within which a Gaussian offset of covariance eigenvalues
/// `values` lies with probability 0.95: `|e|^2` is a weighted sum of
/// chi-squares, taken as `c chi2_k` with the same mean and variance
/// (Welch and Satterthwaite: `c = sum l^2 / sum l`, `k = (sum l)^2 /
/// sum l^2`) and its quantile by Wilson and Hilferty's cube-root normal
/// approximation. Within 2 % of the exact radius for one, two or three
/// equal eigenvalues; zero without spread.
pub fn radius_95(values: [f64; 3]) -> f64 {
    let values = values.map(|l| l.max(0.0));
    let sum: f64 = values.iter().sum();
    let squares: f64 = values.iter().map(|l| l * l).sum();
    if sum <= 0.0 || squares <= 0.0 {
        return 0.0;
    }
    let (c, k) = (squares / sum, sum * sum / squares);
    let h = 2.0 / (9.0 * k);
    let quantile = k * (1.0 - h + Z_95 * h.sqrt()).powi(3);
    (c * quantile).sqrt()
}

/// The eigenvalues (largest first) and unit eigenvectors of a symmetric
/// matrix, by cyclic Jacobi rotations in `f64`.
pub fn symmetric_eigen(m: Symmetric) -> ([f64; 3], [DVec3; 3]) {
    let mut a = [[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let scale = m.iter().map(|x| x.abs()).fold(0.0, f64::max);
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off <= 1e-15 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in &mut a {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
            let (row_p, row_q) = (a[p], a[q]);
            a[p] = std::array::from_fn(|k| c * row_p[k] - s * row_q[k]);
            a[q] = std::array::from_fn(|k| s * row_p[k] + c * row_q[k]);
            for row in &mut v {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
        }
    }
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    (
        order.map(|i| a[i][i]),
        order.map(|i| DVec3::new(v[0][i], v[1][i], v[2][i])),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The eigen-decomposition gives the matrix back, its values sorted.
    #[test]
    fn eigen_decomposition_rebuilds_the_matrix() {
        let m = [4.0, 2.0, 1.0, 0.5, -0.3, 0.2];
        let (values, vectors) = symmetric_eigen(m);
        assert!(values[0] >= values[1] && values[1] >= values[2]);
        let rebuilt = |i: usize, j: usize| -> f64 {
            (0..3)
                .map(|k| values[k] * vectors[k][i] * vectors[k][j])
                .sum()
        };
        let full = [[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]];
        for (i, row) in full.iter().enumerate() {
            for (j, &entry) in row.iter().enumerate() {
                assert!((rebuilt(i, j) - entry).abs() < 1e-12, "{i} {j}");
            }
        }
    }

    /// The radius matches the chi distribution's 95 % quantile for one,
    /// two and three equal variances (1.960, 2.448, 2.795) within 2 %.
    #[test]
    fn the_radius_is_the_chi_quantile_for_equal_variances() {
        for (values, exact) in [
            ([1.0, 0.0, 0.0], 1.959_964),
            ([1.0, 1.0, 0.0], 2.447_747),
            ([1.0, 1.0, 1.0], 2.795_483),
        ] {
            let r = radius_95(values);
            assert!(
                (r / exact - 1.0).abs() < 0.02,
                "{values:?}: {r} against {exact}"
            );
        }
        assert_eq!(radius_95([0.0; 3]), 0.0);
    }

    /// A region of one unknown's columns names it dominant; its ellipsoid
    /// holds an offset inside and not one three deviations out.
    #[test]
    fn a_region_names_its_unknown_and_holds_what_is_inside() {
        let columns = [
            (Unknown::Poisson, 0.5, Vec3::new(1.0, 0.0, 0.0)),
            (Unknown::Poisson, 0.5, Vec3::new(-1.0, 0.0, 0.0)),
            (Unknown::Surface, 0.5, Vec3::new(0.0, 0.1, 0.0)),
            (Unknown::Surface, 0.5, Vec3::new(0.0, 0.0, 0.1)),
        ];
        let region = Region::of(columns);
        assert_eq!(region.dominant, Some(Unknown::Poisson));
        assert!((region.semi_axes[0] - CHI2_3_95.sqrt() as f32).abs() < 1e-5);
        assert!(region.contains(Vec3::new(2.0, 0.0, 0.0)));
        assert!(!region.contains(Vec3::new(3.0, 0.0, 0.0)));
        assert!(!region.contains(Vec3::new(0.0, 0.3, 0.0)));
        let none = Region::of([]);
        assert_eq!((none.radius, none.dominant), (0.0, None));
        assert!(none.contains(Vec3::ZERO) && !none.contains(Vec3::X));
    }
}
