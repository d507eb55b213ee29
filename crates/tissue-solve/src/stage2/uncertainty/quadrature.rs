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
    at_the_nodes(answer, points, (lo, hi), |x| lagrange(&ratios, x))
}

/// Columns integrating over the Poisson ratio's uniform range `(lo, hi)`
/// the offsets from `answer` given at a few ratios (`points`), as
/// [`over_the_range`] does but taken piecewise linear in the stiffness
/// ratio between them (held at the nearest point beyond them): each
/// node's offset a convex combination of solved ones, so a re-solve's
/// error is not amplified.
pub(super) fn between_the_ratios(
    answer: &[Vec3],
    points: &[(f32, Vec<Vec3>)],
    (lo, hi): (f32, f32),
) -> Vec<(f64, Vec<Vec3>)> {
    let ratios: Vec<f64> = points.iter().map(|p| ratio(p.0)).collect();
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| ratios[a].total_cmp(&ratios[b]));
    at_the_nodes(answer, points, (lo, hi), |x| {
        let mut basis = vec![0.0; points.len()];
        match order.partition_point(|&k| ratios[k] <= x) {
            0 => basis[order[0]] = 1.0,
            n if n == order.len() => basis[order[n - 1]] = 1.0,
            n => {
                let (a, b) = (order[n - 1], order[n]);
                let t = (x - ratios[a]) / (ratios[b] - ratios[a]);
                basis[a] = 1.0 - t;
                basis[b] = t;
            }
        }
        basis
    })
}

/// At each three-point Gauss-Legendre node of `(lo, hi)`, its weight and
/// the answer moved by the points' offsets combined by `basis` of the
/// node's stiffness ratio (one coefficient per point).
fn at_the_nodes(
    answer: &[Vec3],
    points: &[(f32, Vec<Vec3>)],
    (lo, hi): (f32, f32),
    basis: impl Fn(f64) -> Vec<f64>,
) -> Vec<(f64, Vec<Vec3>)> {
    gauss_legendre(lo, hi)
        .into_iter()
        .map(|(node, weight)| {
            let basis = basis(ratio(node));
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
