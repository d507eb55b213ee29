//! The Poisson ratio's quadrature: the answer taken as quadratic in the
//! stiffness ratio through the solved ratios, integrated over the prior's
//! range by three-point Gauss-Legendre.

use glam::Vec3;

/// The stiffness ratio `mu / lambda = (1 - 2 nu) / (2 nu)` the answer is
/// taken as quadratic in.
pub(super) fn ratio(nu: f32) -> f64 {
    let nu = f64::from(nu);
    (1.0 - 2.0 * nu) / (2.0 * nu)
}

/// The three-point Gauss-Legendre nodes and weights of the uniform
/// distribution on `[lo, hi]` (the weights sum to one); one node of
/// weight one for a point range.
pub(super) fn gauss_legendre(lo: f32, hi: f32) -> Vec<(f32, f64)> {
    if lo == hi {
        return vec![(lo, 1.0)];
    }
    let (mid, half) = (
        0.5 * (f64::from(lo) + f64::from(hi)),
        0.5 * f64::from(hi - lo),
    );
    let node = (0.6_f64).sqrt() * half;
    vec![
        ((mid - node) as f32, 5.0 / 18.0),
        (mid as f32, 8.0 / 18.0),
        ((mid + node) as f32, 5.0 / 18.0),
    ]
}

/// The Lagrange basis of the distinct points `xs` at `x`.
pub(super) fn lagrange(xs: &[f64], x: f64) -> Vec<f64> {
    (0..xs.len())
        .map(|j| {
            (0..xs.len())
                .filter(|&m| m != j)
                .map(|m| (x - xs[m]) / (xs[j] - xs[m]))
                .product()
        })
        .collect()
}

/// Columns integrating over the Poisson ratio's uniform range `(lo, hi)`
/// the offsets from `answer` given at a few ratios (`points`: ratio,
/// offset per particle): the offsets taken as polynomial in the stiffness
/// ratio through them, at the three-point Gauss-Legendre nodes, each
/// column its node's weight and the answer moved by the offset there.
pub(super) fn over_the_range(
    answer: &[Vec3],
    points: &[(f32, Vec<Vec3>)],
    (lo, hi): (f32, f32),
) -> Vec<(f64, Vec<Vec3>)> {
    let ratios: Vec<f64> = points.iter().map(|p| ratio(p.0)).collect();
    gauss_legendre(lo, hi)
        .into_iter()
        .map(|(node, weight)| {
            let basis = lagrange(&ratios, ratio(node));
            let positions = answer
                .iter()
                .enumerate()
                .map(|(i, &x0)| {
                    x0 + points
                        .iter()
                        .zip(&basis)
                        .map(|((_, offsets), &b)| b as f32 * offsets[i])
                        .sum::<Vec3>()
                })
                .collect();
            (weight, positions)
        })
        .collect()
}

/// Columns integrating over the Poisson ratio's uniform range `(lo, hi)`
/// the offsets from `answer` given at a few ratios (`points`), as
/// [`over_the_range`] does but taken piecewise linear in the stiffness
/// ratio between them (held at the nearest point beyond them): each
/// node's offset a convex combination of solved ones, so a re-solve's
/// error is not amplified. (The quadratic through the answer's 0.49 and
/// the range's 0.495, so close, multiplied each one's error by 2-3 at the
/// middle node.)
pub(super) fn between_the_ratios(
    answer: &[Vec3],
    points: &[(f32, Vec<Vec3>)],
    (lo, hi): (f32, f32),
) -> Vec<(f64, Vec<Vec3>)> {
    let mut sorted: Vec<(f64, &Vec<Vec3>)> = points.iter().map(|(nu, o)| (ratio(*nu), o)).collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    gauss_legendre(lo, hi)
        .into_iter()
        .map(|(node, weight)| {
            let x = ratio(node);
            let at = sorted.partition_point(|p| p.0 <= x);
            let (a, b, t) = match at {
                0 => (0, 0, 0.0),
                n if n == sorted.len() => (n - 1, n - 1, 0.0),
                n => {
                    let (x0, x1) = (sorted[n - 1].0, sorted[n].0);
                    (n - 1, n, ((x - x0) / (x1 - x0)) as f32)
                }
            };
            let positions = answer
                .iter()
                .enumerate()
                .map(|(i, &x0)| x0 + sorted[a].1[i] * (1.0 - t) + sorted[b].1[i] * t)
                .collect();
            (weight, positions)
        })
        .collect()
}
