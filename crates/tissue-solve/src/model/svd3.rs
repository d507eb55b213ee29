//! 3x3 singular value decomposition and the best-fit rotation of stage 2
//! (docs/METHOD.md, "Rotations").
//!
//! # Convention: the signed SVD
//!
//! [`svd3`] returns `m = u · diag(sigma) · vᵀ` with `u` and `v` proper
//! rotations (det +1) and `sigma.x ≥ sigma.y ≥ |sigma.z|`; only `sigma.z` may
//! be negative, carrying the sign of `det(m)` (either sign, up to rounding,
//! when `m` is singular). This is the "signed SVD" of McAdams et al. 2011: a
//! reflection goes into the smallest singular value rather than into `u` or
//! `v`, so `u · vᵀ` is always the closest rotation to `m` ([`rotation_of`]).
//!
//! # Method (McAdams et al. 2011, plus one exact polish sweep)
//!
//! 1. Divide `m` by its largest |element|, so `mᵀm` neither overflows nor
//!    underflows; `sigma` is scaled back at the end.
//! 2. `v` from [`JACOBI_SWEEPS`] cyclic sweeps of McAdams' approximate
//!    Jacobi rotations on `mᵀm`, accumulated as a quaternion (orthonormal to
//!    rounding).
//! 3. [`POLISH_SWEEPS`] sweep of exact one-sided Jacobi rotations on the
//!    columns of `b = m·v`: `mᵀm` squares the condition number, so the small
//!    singular values must be measured from `b` itself.
//! 4. Sort the columns of `b` and `v` by descending norm (each swap negates one
//!    column so `det v` stays +1).
//! 5. QR of `b` by three Givens rotations: `b = u · r`, `sigma = diag(r)`,
//!    clamped to exact order.
//!
//! Fixed loop counts, no allocation, and every data-dependent choice a select,
//! so the loop bodies match the WGSL twin line for line. Entries far below the
//! rounding of the scaled `mᵀm` are flushed to zero (`NEGLIGIBLE`), as GPUs
//! flush subnormals.
//!
//! # Accuracy
//!
//! `tissue-cpu`'s `tests/svd3.rs` asserts, over random and adversarial
//! matrices (rank 0–2, repeated and negative singular values, scales
//! `1e-30..1e30`), relative reconstruction error, orthonormality of `u`, `v`
//! and `det u`, `det v` all within `1e-5`. A finite `m` never yields NaN;
//! the zero matrix gives `u = v = I`, `sigma = 0`.
//!
//! # Stage 2: which way the rotation goes
//!
//! With rest offsets `p = p_j − p_i`, current `q = q_j − q_i` and
//! `M_i = Σ_j p · qᵀ` (the paper's `A_relaxᵀ · A_current`), the paper's
//! `R_i = U·Vᵀ` is `rotation_of(M_i)` and maps **current onto rest**: if
//! `q = R·p`, `rotation_of(M_i) = Rᵀ`. [`best_rotation`] returns the rotation
//! mapping rest offsets onto current ones, with no transpose.

use std::f32::consts::FRAC_1_SQRT_2;

use glam::{Mat3, Vec3, Vec4};

/// Cyclic Jacobi sweeps over `mᵀm` (three plane rotations each).
pub const JACOBI_SWEEPS: u32 = 4;

/// One-sided Jacobi sweeps over the columns of `m·v` after the symmetric phase.
pub const POLISH_SWEEPS: u32 = 1;

/// Squared length below which a QR Givens rotation is skipped: the matrix is
/// scaled to a largest element of 1, so anything this small is rounding noise,
/// and `1e-36` is still a normal `f32` (no denormal `1/sqrt`).
const GIVENS_MIN_LENGTH_SQUARED: f32 = 1e-36;

/// A 3x3 singular value decomposition `m = u · diag(sigma) · vᵀ` in the signed
/// convention of the module doc.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Svd3 {
    /// Left singular vectors as columns; a rotation (det +1).
    pub u: Mat3,
    /// Singular values, `x ≥ y ≥ |z|`; only `z` may be negative (when `det(m) < 0`).
    pub sigma: Vec3,
    /// Right singular vectors as columns; a rotation (det +1).
    pub v: Mat3,
}

/// Off-diagonal entries of the scaled `mᵀm` (trace ≥ 1), and of `bᵀb` in the
/// polish, below this are treated as zero, and so are `2(a − d)` terms: they
/// are far below the rounding of the trace, and flushing them keeps every
/// product in the normal `f32` range (subnormal arithmetic is ~100x slower on
/// x86, and GPUs flush it anyway). In the polish it means column pairs with
/// `|bp·bq| < 1e-15` are left alone, which costs at most `1e-15 / |bp|` in
/// reconstruction: below `1e-7` for any singular value above `1e-8`, and
/// below `sigma.y` otherwise.
const NEGLIGIBLE: f32 = 1e-15;

/// `cot²(π/8) = 3 + 2√2`: McAdams' γ; half-angle tangents above `tan(π/8)` are capped.
const COT_SQUARED_PI_8: f32 = 5.828_427;
/// `cos(π/8)`.
const COS_PI_8: f32 = 0.923_879_5;
/// `sin(π/8)`.
const SIN_PI_8: f32 = 0.382_683_43;

/// A rotation `G = [[c, −s], [s, c]]` by `θ` in a plane `(p, q)`, with its
/// half-angle quaternion part `(ch, sh) = (cos(θ/2), sin(θ/2))`.
struct PlaneRotation {
    c: f32,
    s: f32,
    ch: f32,
    sh: f32,
}

/// McAdams' approximate Jacobi rotation for the symmetric block
/// `[[a, b], [b, d]]`: half-angle tangent `b / (2(a − d))`, exact to first
/// order in the angle, capped at `π/8` (exact when `a = d`). `c` and `s` come from the rational double-angle
/// formulas, so the critical path has one division and no square root; the
/// quaternion's normalising square root is off that path.
fn approximate_rotation(a: f32, d: f32, b: f32) -> PlaneRotation {
    let sh = if b.abs() < NEGLIGIBLE { 0.0 } else { b };
    // Nothing to rotate: the identity, also for a zero block.
    let ch = if sh == 0.0 { 1.0 } else { 2.0 * (a - d) };
    let ch = if ch.abs() < NEGLIGIBLE { 0.0 } else { ch };
    let (ch2, sh2) = (ch * ch, sh * sh);
    let inverse = 1.0 / (ch2 + sh2);
    // 1 or 0 as a number: the choice is a blend, not a branch.
    let small = f32::from(u8::from(COT_SQUARED_PI_8 * sh2 < ch2));
    let large = 1.0 - small;
    let sign = if (ch < 0.0) != (sh < 0.0) { -1.0 } else { 1.0 };
    let normaliser = inverse.sqrt();
    PlaneRotation {
        c: small * (ch2 - sh2) * inverse + large * FRAC_1_SQRT_2,
        s: small * 2.0 * ch * sh * inverse + large * sign * FRAC_1_SQRT_2,
        ch: small * ch * normaliser + large * COS_PI_8,
        sh: small * sh * normaliser + large * sign * SIN_PI_8,
    }
}

/// The entries of the symmetric `S` touched by a rotation in plane `(p, q)`
/// (`r` the third index): `a = S_pp`, `d = S_qq`, `b = S_pq`, `rp = S_rp`,
/// `rq = S_rq`; with the rotation's half-angle `(ch, sh)`.
struct Conjugated {
    a: f32,
    d: f32,
    b: f32,
    rp: f32,
    rq: f32,
    ch: f32,
    sh: f32,
}

/// `S ← Gᵀ · S · G` for the approximate Jacobi rotation `G` of `b = S_pq`.
fn jacobi_conjugate(a: f32, d: f32, b: f32, rp: f32, rq: f32) -> Conjugated {
    let g = approximate_rotation(a, d, b);
    let (cc, ss, cs) = (g.c * g.c, g.s * g.s, g.c * g.s);
    Conjugated {
        a: cc * a + 2.0 * cs * b + ss * d,
        d: ss * a - 2.0 * cs * b + cc * d,
        b: cs * (d - a) + (cc - ss) * b,
        rp: g.c * rp + g.s * rq,
        rq: g.c * rq - g.s * rp,
        ch: g.ch,
        sh: g.sh,
    }
}

/// Hamilton product `q ⊗ r` of quaternions stored as `(x, y, z, w)`.
fn quat_mul(q: Vec4, r: Vec4) -> Vec4 {
    let qv = q.truncate();
    let rv = r.truncate();
    (q.w * rv + r.w * qv + qv.cross(rv)).extend(q.w * r.w - qv.dot(rv))
}

/// Rotation matrix of a quaternion `(x, y, z, w)`, normalised first.
fn quat_to_mat3(q: Vec4) -> Mat3 {
    let q = q / q.dot(q).sqrt();
    let (x, y, z, w) = (q.x, q.y, q.z, q.w);
    Mat3::from_cols(
        Vec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ),
        Vec3::new(
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ),
        Vec3::new(
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    )
}

/// `(c, s)` of the exact Jacobi rotation `[[c, −s], [s, c]]` that makes
/// `Gᵀ · [[a, b], [b, d]] · G` diagonal, `|θ| ≤ π/4`.
fn exact_rotation(a: f32, d: f32, b: f32) -> (f32, f32) {
    let b = if b.abs() < NEGLIGIBLE { 0.0 } else { b };
    // tan θ: the smaller root of t² + ((a − d)/b)·t − 1 = 0, without dividing by b.
    let delta = a - d;
    let sign = if delta < 0.0 { -1.0 } else { 1.0 };
    let denominator = delta.abs() + (delta * delta + 4.0 * b * b).sqrt();
    let t = (2.0 * b * sign / denominator.max(f32::MIN_POSITIVE)).clamp(-1.0, 1.0);
    let c = 1.0 / (1.0 + t * t).sqrt();
    (c, t * c)
}

/// Two columns after a one-sided Jacobi rotation that makes `bp · bq = 0`,
/// and the same rotation applied to the matching columns of `v`.
struct ColumnPair {
    bp: Vec3,
    bq: Vec3,
    vp: Vec3,
    vq: Vec3,
}

fn orthogonalise_columns(bp: Vec3, bq: Vec3, vp: Vec3, vq: Vec3) -> ColumnPair {
    let (c, s) = exact_rotation(bp.dot(bp), bq.dot(bq), bp.dot(bq));
    ColumnPair {
        bp: c * bp + s * bq,
        bq: c * bq - s * bp,
        vp: c * vp + s * vq,
        vq: c * vq - s * vp,
    }
}

/// `(cos, sin)` of the Givens rotation taking `(a1, a2)` to `(|(a1, a2)|, 0)`;
/// the identity when both are negligible.
fn qr_givens(a1: f32, a2: f32) -> (f32, f32) {
    let length_squared = a1 * a1 + a2 * a2;
    let keep = length_squared > GIVENS_MIN_LENGTH_SQUARED;
    let inverse_length = if keep {
        1.0 / length_squared.sqrt()
    } else {
        0.0
    };
    let c = if keep { a1 * inverse_length } else { 1.0 };
    (c, a2 * inverse_length)
}

/// Signed singular value decomposition of a 3x3 matrix (see the module doc for
/// the convention, method and accuracy).
///
/// `m = u · diag(sigma) · vᵀ`, `u` and `v` rotations,
/// `sigma.x ≥ sigma.y ≥ |sigma.z|`, `sigma.z < 0` only when `det(m) < 0`.
/// Never NaN for finite `m`; `sigma` overflows to infinity only when a
/// singular value exceeds `f32::MAX`.
pub fn svd3(m: Mat3) -> Svd3 {
    // 1. Scale to a largest |element| of 1 (zero stays zero).
    let scale = m
        .x_axis
        .abs()
        .max(m.y_axis.abs())
        .max(m.z_axis.abs())
        .max_element();
    let a = m / if scale > 0.0 { scale } else { 1.0 };

    // 2. Symmetric S = aᵀa, diagonalised by cyclic Jacobi: S ← Gᵀ S G, v ← v G.
    let mut s11 = a.x_axis.dot(a.x_axis);
    let mut s22 = a.y_axis.dot(a.y_axis);
    let mut s33 = a.z_axis.dot(a.z_axis);
    let mut s12 = a.x_axis.dot(a.y_axis);
    let mut s13 = a.x_axis.dot(a.z_axis);
    let mut s23 = a.y_axis.dot(a.z_axis);
    let mut q = Vec4::W;
    for _ in 0..JACOBI_SWEEPS {
        // Plane (1, 2): a rotation about axis 3.
        let r = jacobi_conjugate(s11, s22, s12, s13, s23);
        (s11, s22, s12, s13, s23) = (r.a, r.d, r.b, r.rp, r.rq);
        q = quat_mul(q, Vec4::new(0.0, 0.0, r.sh, r.ch));
        // Plane (2, 3): about axis 1.
        let r = jacobi_conjugate(s22, s33, s23, s12, s13);
        (s22, s33, s23, s12, s13) = (r.a, r.d, r.b, r.rp, r.rq);
        q = quat_mul(q, Vec4::new(r.sh, 0.0, 0.0, r.ch));
        // Plane (3, 1): about axis 2.
        let r = jacobi_conjugate(s33, s11, s13, s23, s12);
        (s33, s11, s13, s23, s12) = (r.a, r.d, r.b, r.rp, r.rq);
        q = quat_mul(q, Vec4::new(0.0, r.sh, 0.0, r.ch));
    }
    let v = quat_to_mat3(q);
    let (mut v1, mut v2, mut v3) = (v.x_axis, v.y_axis, v.z_axis);

    // 3. One-sided polish on the columns of b = a v, same planes and order.
    let b = a * v;
    let (mut b1, mut b2, mut b3) = (b.x_axis, b.y_axis, b.z_axis);
    for _ in 0..POLISH_SWEEPS {
        let r = orthogonalise_columns(b1, b2, v1, v2);
        (b1, b2, v1, v2) = (r.bp, r.bq, r.vp, r.vq);
        let r = orthogonalise_columns(b2, b3, v2, v3);
        (b2, b3, v2, v3) = (r.bp, r.bq, r.vp, r.vq);
        let r = orthogonalise_columns(b3, b1, v3, v1);
        (b3, b1, v3, v1) = (r.bp, r.bq, r.vp, r.vq);
    }

    // 4. Sort columns by descending norm; (x, y) → (y, −x) keeps det v = +1.
    let (mut n1, mut n2, mut n3) = (b1.dot(b1), b2.dot(b2), b3.dot(b3));
    if n1 < n2 {
        (b1, b2, v1, v2, n1, n2) = (b2, -b1, v2, -v1, n2, n1);
    }
    if n1 < n3 {
        (b1, b3, v1, v3, n3) = (b3, -b1, v3, -v1, n1);
    }
    if n2 < n3 {
        (b2, b3, v2, v3) = (b3, -b2, v3, -v2);
    }

    // 5. QR of b by Givens rotations on its rows (the columns of bᵀ); the same
    // rotations applied to the rows of uᵀ (the columns of u) give b = u r.
    let bt = Mat3::from_cols(b1, b2, b3).transpose();
    let (mut r1, mut r2, mut r3) = (bt.x_axis, bt.y_axis, bt.z_axis);
    let (mut u1, mut u2, mut u3) = (Vec3::X, Vec3::Y, Vec3::Z);
    let (c, s) = qr_givens(r1.x, r2.x);
    (r1, r2, u1, u2) = (
        c * r1 + s * r2,
        c * r2 - s * r1,
        c * u1 + s * u2,
        c * u2 - s * u1,
    );
    let (c, s) = qr_givens(r1.x, r3.x);
    (r1, r3, u1, u3) = (
        c * r1 + s * r3,
        c * r3 - s * r1,
        c * u1 + s * u3,
        c * u3 - s * u1,
    );
    let (c, s) = qr_givens(r2.y, r3.y);
    (r2, r3, u2, u3) = (
        c * r2 + s * r3,
        c * r3 - s * r2,
        c * u2 + s * u3,
        c * u3 - s * u2,
    );

    // Clamp to exact order: the diagonal of r is already sorted up to rounding.
    // (`max` then `min`, not `clamp`: a NaN from a diverged solve must not panic.)
    let sigma1 = r1.x.max(0.0);
    let sigma2 = r2.y.max(0.0).min(sigma1);
    let sigma3 = r3.z.max(-sigma2).min(sigma2);
    Svd3 {
        u: Mat3::from_cols(u1, u2, u3),
        sigma: Vec3::new(sigma1, sigma2, sigma3) * scale,
        v: Mat3::from_cols(v1, v2, v3),
    }
}

/// The rotation `R` (det +1) closest to `m` in the Frobenius norm: the
/// rotation factor `u · vᵀ` of the polar decomposition, with the reflection
/// case already handled by the signed SVD (so `det R = +1` even when
/// `det m ≤ 0`).
///
/// For the zero matrix it is the identity; for rank 1 or 2 it is a best
/// rotation (for rank 2 the unique one, for rank 1 one of a circle of them).
/// `rotation_of(mᵀ) = rotation_of(m)ᵀ` wherever the closest rotation is
/// unique (`sigma.y + sigma.z > 0`). For stage 2's `M_i = Σ p·qᵀ` (rest ×
/// current) it maps current offsets onto rest offsets; see the module doc and
/// prefer [`best_rotation`].
pub fn rotation_of(m: Mat3) -> Mat3 {
    let svd = svd3(m);
    svd.u * svd.v.transpose()
}

/// The rotation `R` that best maps `rest` offsets onto `current` offsets,
/// minimising `Σ_k ‖R·rest[k] − current[k]‖²` (orthogonal Procrustes / Kabsch).
///
/// Offsets are taken as given (for stage 2, `p_j − p_i` and `q_j − q_i`); no
/// centroid is subtracted. Pairs are `rest[k]`, `current[k]`; a longer slice
/// is cut to the shorter one. With fewer than two independent directions the
/// rotation about the unconstrained axis is arbitrary; with no offsets it is
/// the identity.
///
/// Equivalent to `rotation_of(Σ p·qᵀ)ᵀ`, the transpose of the paper's `R_i`.
pub fn best_rotation(rest: &[Vec3], current: &[Vec3]) -> Mat3 {
    // Σ q·pᵀ = R·(Σ p·pᵀ) when q = R·p: a rotation times a symmetric factor,
    // whose polar rotation is R itself.
    let mut m = Mat3::ZERO;
    for (p, q) in rest.iter().zip(current) {
        m += Mat3::from_cols(*q * p.x, *q * p.y, *q * p.z);
    }
    rotation_of(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Largest `|uᵀu − I|`, `|vᵀv − I|`, `|det − 1|` and relative reconstruction error.
    fn errors(m: Mat3, svd: &Svd3) -> [f32; 4] {
        let rebuilt = svd.u * Mat3::from_diagonal(svd.sigma) * svd.v.transpose();
        let norm = m.to_cols_array().iter().map(|x| x * x).sum::<f32>().sqrt();
        let diff = (rebuilt - m)
            .to_cols_array()
            .iter()
            .map(|x| x * x)
            .sum::<f32>()
            .sqrt();
        let off = |r: Mat3| {
            (r.transpose() * r - Mat3::IDENTITY)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |acc, x| acc.max(x.abs()))
        };
        [
            off(svd.u),
            off(svd.v),
            (svd.u.determinant() - 1.0)
                .abs()
                .max((svd.v.determinant() - 1.0).abs()),
            if norm > 0.0 { diff / norm } else { diff },
        ]
    }

    #[test]
    fn a_matrix_with_nan_gives_a_result_and_no_panic() {
        // A diverged solve hands the SVD NaN offsets; the solve reports the
        // divergence, so the SVD must only return.
        for m in [
            Mat3::from_cols(Vec3::NAN, Vec3::X, Vec3::Y),
            Mat3::from_cols(Vec3::X, Vec3::new(f32::NAN, 1.0, 0.0), Vec3::Z),
            Mat3::from_cols_array(&[f32::NAN; 9]),
            Mat3::from_cols(Vec3::INFINITY, Vec3::X, Vec3::Y),
        ] {
            let _ = rotation_of(m);
        }
    }

    #[test]
    fn exact_rotation_zeroes_the_off_diagonal() {
        for (a, d, b) in [
            (3.0, 1.0, 0.5),
            (1.0, 3.0, -0.5),
            (2.0, 2.0, 1.0),
            (1.0, 1.0, 0.0),
        ] {
            let (c, s) = exact_rotation(a, d, b);
            let off = c * s * (d - a) + (c * c - s * s) * b;
            assert!(off.abs() < 1e-6, "({a}, {d}, {b}): off-diagonal {off}");
            assert!((c * c + s * s - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn approximate_rotation_shrinks_the_off_diagonal_and_matches_its_quaternion() {
        for (a, d, b) in [
            (3.0, 1.0, 0.5),
            (1.0, 3.0, -0.5),
            (2.0, 2.0, 1.0),
            (1.0, 1.2, 0.9),
            (1.0, 1.0, 0.0),
        ] {
            let g = approximate_rotation(a, d, b);
            let off = g.c * g.s * (d - a) + (g.c * g.c - g.s * g.s) * b;
            assert!(
                off.abs() <= 0.5 * f32::abs(b),
                "({a}, {d}, {b}): off-diagonal {off}"
            );
            // The quaternion about axis 3 must be the rotation [[c, −s], [s, c]] in (1, 2).
            let r = quat_to_mat3(Vec4::new(0.0, 0.0, g.sh, g.ch));
            let expected =
                Mat3::from_cols(Vec3::new(g.c, g.s, 0.0), Vec3::new(-g.s, g.c, 0.0), Vec3::Z);
            assert!(r.abs_diff_eq(expected, 1e-6), "{r} vs {expected}");
        }
    }

    #[test]
    fn small_cases_satisfy_the_invariants() {
        for m in tissue_testkit::small_svd_cases() {
            let svd = svd3(m);
            let e = errors(m, &svd);
            assert!(e.iter().all(|x| *x < 1e-5), "{m}: errors {e:?}, {svd:?}");
            assert!(svd.sigma.x >= svd.sigma.y && svd.sigma.y >= svd.sigma.z.abs());
        }
        assert!(svd3(-Mat3::IDENTITY).sigma.z < 0.0);
        assert_eq!(rotation_of(Mat3::ZERO), Mat3::IDENTITY);
    }
}
