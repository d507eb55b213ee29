//! Invariants of the 3x3 signed SVD and of the best-fit rotation of stage 2.
//!
//! The SVD is tested only through properties that any correct answer has
//! (reconstruction, orthonormality, det +1, ordering, det(m) = Π sigma), never
//! by comparing `u` or `v` element by element: they are not unique.

use glam::{DMat3, Mat3, Vec3};
use tissue_cpu::model::{Svd3, best_rotation, rotation_of, svd3};

/// Relative reconstruction error allowed: `‖u·diag(sigma)·vᵀ − m‖_F / ‖m‖_F`.
const RECONSTRUCTION_TOLERANCE: f64 = 1e-5;
/// Allowed `max |uᵀu − I|`, `max |vᵀv − I|` and `|det − 1|`.
const ORTHONORMAL_TOLERANCE: f64 = 1e-5;

/// xorshift64*: deterministic, dependency-free, good enough for test inputs.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [-1, 1].
    fn signed(&mut self) -> f32 {
        (2.0 * self.unit() - 1.0) as f32
    }

    /// Log-uniform in [lo, hi].
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f32 {
        (lo.ln() + self.unit() * (hi.ln() - lo.ln())).exp() as f32
    }

    fn vec3(&mut self) -> Vec3 {
        Vec3::new(self.signed(), self.signed(), self.signed())
    }

    fn mat3(&mut self) -> Mat3 {
        Mat3::from_cols(self.vec3(), self.vec3(), self.vec3())
    }

    /// A uniformly distributed rotation (normalised quaternion, rejection sampled).
    fn rotation(&mut self) -> Mat3 {
        loop {
            let q = glam::Vec4::new(self.signed(), self.signed(), self.signed(), self.signed());
            let n = q.length();
            if n > 0.1 && n <= 1.0 {
                return Mat3::from_quat(glam::Quat::from_vec4(q / n).normalize());
            }
        }
    }
}

fn frobenius(m: DMat3) -> f64 {
    m.to_cols_array().iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn max_abs(m: DMat3) -> f64 {
    m.to_cols_array()
        .iter()
        .fold(0.0, |acc, x| acc.max(x.abs()))
}

/// Worst values seen over a set, reported with `--nocapture`.
#[derive(Default)]
struct Worst {
    count: usize,
    reconstruction: f64,
    orthonormal: f64,
    det: f64,
    sigma_product: f64,
    rotation_orthonormal: f64,
}

impl Worst {
    fn report(&self, name: &str) {
        eprintln!(
            "{name}: {} matrices; max relative reconstruction {:.2e}, max |uᵀu−I|,|vᵀv−I| {:.2e}, \
             max |det−1| {:.2e}, max |Πσ − det m|/σ₁³ {:.2e}, rotation_of max |RᵀR−I|,|det−1| {:.2e}",
            self.count,
            self.reconstruction,
            self.orthonormal,
            self.det,
            self.sigma_product,
            self.rotation_orthonormal,
        );
    }
}

/// Checks every invariant of `svd3(m)` and `rotation_of(m)`, in f64.
/// `exact_input` is false for subnormal inputs, whose own rounding (fewer
/// mantissa bits) makes the relative reconstruction meaningless.
fn check(m: Mat3, label: &str, worst: &mut Worst, exact_input: bool) -> Svd3 {
    let svd = svd3(m);
    let Svd3 { u, sigma, v } = svd;
    let all = [u.to_cols_array(), v.to_cols_array()].concat();
    assert!(
        all.iter()
            .chain(sigma.to_array().iter())
            .all(|x| x.is_finite()),
        "{label}: non-finite output for {m}: {svd:?}"
    );

    let (md, ud, vd, sd) = (m.as_dmat3(), u.as_dmat3(), v.as_dmat3(), sigma.as_dvec3());
    let identity = DMat3::IDENTITY;
    let orthonormal =
        max_abs(ud.transpose() * ud - identity).max(max_abs(vd.transpose() * vd - identity));
    let det = (ud.determinant() - 1.0)
        .abs()
        .max((vd.determinant() - 1.0).abs());
    assert!(
        orthonormal <= ORTHONORMAL_TOLERANCE && det <= ORTHONORMAL_TOLERANCE,
        "{label}: u, v not rotations for {m}: |QᵀQ−I| {orthonormal:e}, |det−1| {det:e}; {svd:?}"
    );

    assert!(
        sigma.x >= sigma.y && sigma.y >= sigma.z.abs() && sigma.y >= 0.0,
        "{label}: sigma {sigma} not sorted (x ≥ y ≥ |z|) for {m}"
    );

    let rebuilt = ud * DMat3::from_diagonal(sd) * vd.transpose();
    let norm = frobenius(md);
    let error = frobenius(rebuilt - md);
    if exact_input {
        let relative = if norm > 0.0 { error / norm } else { error };
        assert!(
            relative <= RECONSTRUCTION_TOLERANCE,
            "{label}: reconstruction {relative:e} > {RECONSTRUCTION_TOLERANCE:e} (relative) for {m}: {svd:?}"
        );
        worst.reconstruction = worst.reconstruction.max(relative);

        // det(m) = Π sigma, since det u = det v = 1; this pins the sign of sigma.z.
        let scale = sd.x.powi(3);
        let product = if scale > 0.0 {
            (sd.x * sd.y * sd.z - md.determinant()).abs() / scale
        } else {
            md.determinant().abs()
        };
        assert!(
            product <= 1e-5,
            "{label}: Π sigma = {} but det m = {} for {m}",
            sd.x * sd.y * sd.z,
            md.determinant()
        );
        worst.sigma_product = worst.sigma_product.max(product);
    }

    let r = rotation_of(m).as_dmat3();
    let rotation = max_abs(r.transpose() * r - identity).max((r.determinant() - 1.0).abs());
    assert!(
        rotation <= ORTHONORMAL_TOLERANCE,
        "{label}: rotation_of({m}) = {r} is not a rotation ({rotation:e})"
    );

    worst.count += 1;
    worst.orthonormal = worst.orthonormal.max(orthonormal);
    worst.det = worst.det.max(det);
    worst.rotation_orthonormal = worst.rotation_orthonormal.max(rotation);
    svd
}

#[test]
fn random_entries_in_unit_box() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut worst = Worst::default();
    for k in 0..100_000 {
        check(rng.mat3(), &format!("uniform #{k}"), &mut worst, true);
    }
    worst.report("entries in [-1, 1]");
}

#[test]
fn random_log_uniform_scales() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let mut worst = Worst::default();
    for k in 0..100_000 {
        let m = rng.mat3() * rng.log_uniform(1e-6, 1e6);
        check(m, &format!("scaled #{k}"), &mut worst, true);
    }
    worst.report("whole matrix scaled 1e-6..1e6");

    // Graded: every entry its own magnitude, so rows and columns differ by 1e12.
    let mut worst = Worst::default();
    for k in 0..50_000 {
        let entries: [f32; 9] = std::array::from_fn(|_| rng.signed() * rng.log_uniform(1e-6, 1e6));
        check(
            Mat3::from_cols_array(&entries),
            &format!("graded #{k}"),
            &mut worst,
            true,
        );
    }
    worst.report("each entry scaled 1e-6..1e6");
}

/// Structured matrices, each also at extreme scales.
fn adversarial(rng: &mut Rng) -> Vec<(String, Mat3)> {
    let mut cases: Vec<(String, Mat3)> = Vec::new();
    let diagonals = [
        (0.0, 0.0, 0.0),
        (1.0, 1.0, 1.0),
        (-1.0, -1.0, -1.0),
        (2.0, 2.0, 2.0),
        (3.0, 3.0, 1.0),
        (3.0, 1.0, 1.0),
        (1.0, 1.0, 0.0),
        (1.0, 0.0, 0.0),
        (0.0, 0.0, 1.0),
        (1.0, 1.0, -1.0),
        (-1.0, 1.0, 1.0),
        (1.0, -2.0, 3.0),
        (1.0, 1e-8, 1e-8),
        (1.0, 1e-3, 1e-6),
        (1.0, 1e-4, 2e-4),
        (1.0, 1e-7, 3e-7),
        (1.0, 1.0, 1e-7),
        (1.0, 1.0, -1e-7),
        (1.0, 1e-20, 0.0),
    ];
    for (a, b, c) in diagonals {
        let d = Mat3::from_diagonal(Vec3::new(a, b, c));
        cases.push((format!("diag({a}, {b}, {c})"), d));
        for k in 0..200 {
            let (r1, r2) = (rng.rotation(), rng.rotation());
            cases.push((format!("R·diag({a}, {b}, {c})·R' #{k}"), r1 * d * r2));
            cases.push((format!("R·diag({a}, {b}, {c}) #{k}"), r1 * d));
        }
    }
    for k in 0..2000 {
        let (a1, b1, a2, b2) = (rng.vec3(), rng.vec3(), rng.vec3(), rng.vec3());
        let outer = |a: Vec3, b: Vec3| Mat3::from_cols(a * b.x, a * b.y, a * b.z);
        cases.push((format!("rank 1 #{k}"), outer(a1, b1)));
        cases.push((format!("rank 2 #{k}"), outer(a1, b1) + outer(a2, b2)));
        // Two equal columns, and a column that is the sum of the other two.
        cases.push((format!("repeated column #{k}"), Mat3::from_cols(a1, a1, b1)));
        cases.push((
            format!("dependent column #{k}"),
            Mat3::from_cols(a1, b1, a1 + b1),
        ));
        let noise = rng.mat3() * 1e-7;
        cases.push((format!("I + 1e-7 noise #{k}"), Mat3::IDENTITY + noise));
        let r = rng.rotation();
        cases.push((format!("R + 1e-7 noise #{k}"), r + noise));
        cases.push((format!("rotation #{k}"), r));
        // Householder reflection I − 2nnᵀ and a rotation with one axis flipped.
        let n = a1.normalize_or(Vec3::X);
        let householder = Mat3::IDENTITY - Mat3::from_cols(n * n.x, n * n.y, n * n.z) * 2.0;
        cases.push((format!("reflection #{k}"), householder));
        cases.push((
            format!("flipped rotation #{k}"),
            r * Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0)),
        ));
        let kappa = rng.log_uniform(1.0, 1e7);
        let spectrum = Vec3::new(
            1.0,
            1.0 / kappa.sqrt(),
            if k % 2 == 0 { 1.0 } else { -1.0 } / kappa,
        );
        cases.push((
            format!("condition {kappa:e} #{k}"),
            rng.rotation() * Mat3::from_diagonal(spectrum) * r,
        ));
    }
    let mut scaled = Vec::with_capacity(cases.len() * 5);
    for (label, m) in &cases {
        for s in [1e-30f32, 1e-6, 1e6, 1e30] {
            scaled.push((format!("{label} × {s:e}"), *m * s));
        }
    }
    cases.extend(scaled);
    cases
}

#[test]
fn adversarial_matrices() {
    let mut rng = Rng(0xdead_beef_cafe_f00d);
    let mut worst = Worst::default();
    for (label, m) in adversarial(&mut rng) {
        check(m, &label, &mut worst, true);
    }
    worst.report("adversarial");
}

#[test]
fn exact_answers_for_signs_and_repeated_values() {
    let mut worst = Worst::default();
    let svd = check(-Mat3::IDENTITY, "-I", &mut worst, true);
    assert_eq!(svd.sigma, Vec3::new(1.0, 1.0, -1.0));
    let svd = check(Mat3::ZERO, "zero", &mut worst, true);
    assert_eq!(
        (svd.sigma, svd.u, svd.v),
        (Vec3::ZERO, Mat3::IDENTITY, Mat3::IDENTITY)
    );
    let svd = check(
        Mat3::from_diagonal(Vec3::new(2.0, -5.0, 3.0)),
        "diag",
        &mut worst,
        true,
    );
    assert!(
        (svd.sigma - Vec3::new(5.0, 3.0, -2.0)).abs().max_element() < 1e-6,
        "{svd:?}"
    );
    let reflection = Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0));
    let svd = check(reflection, "reflection", &mut worst, true);
    assert!(
        (svd.sigma - Vec3::new(1.0, 1.0, -1.0)).abs().max_element() < 1e-6,
        "{svd:?}"
    );
}

#[test]
fn extreme_magnitudes_stay_finite() {
    let mut rng = Rng(42);
    let mut worst = Worst::default();
    for k in 0..1000 {
        let m = rng.mat3();
        // Large but with every singular value representable.
        check(m * 1e37, &format!("1e37 #{k}"), &mut worst, true);
        // Smallest normal and subnormal: finite, orthonormal factors.
        check(
            m * f32::MIN_POSITIVE,
            &format!("min normal #{k}"),
            &mut worst,
            false,
        );
        check(m * 1e-42, &format!("subnormal #{k}"), &mut worst, false);
    }
    let svd = check(
        Mat3::from_diagonal(Vec3::new(1e-45, 0.0, 0.0)),
        "one subnormal",
        &mut worst,
        false,
    );
    assert_eq!(svd.sigma.y, 0.0);
    worst.report("extreme magnitudes");
}

#[test]
fn rotation_of_beats_every_other_rotation() {
    let mut rng = Rng(7);
    let mut worst_gap = f64::INFINITY;
    for k in 0..1000 {
        // Half with det < 0, where a plain polar factor would be a reflection.
        let m = if k % 2 == 0 {
            rng.mat3()
        } else {
            rng.mat3() * Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0))
        };
        let r = rotation_of(m);
        let md = m.as_dmat3();
        let best = frobenius(r.as_dmat3() - md);
        let mut others: Vec<Mat3> = (0..200).map(|_| rng.rotation()).collect();
        // Nearby rotations probe local optimality more sharply than random ones.
        for _ in 0..20 {
            let axis = rng.vec3().normalize_or(Vec3::Z);
            others.push(r * Mat3::from_axis_angle(axis, 1e-2 * rng.signed()));
        }
        for q in others {
            let other = frobenius(q.as_dmat3() - md);
            assert!(
                best <= other + 1e-6,
                "#{k}: ‖rotation_of(m) − m‖ = {best} > ‖Q − m‖ = {other} for m = {m}, Q = {q}"
            );
            worst_gap = worst_gap.min(other - best);
        }
    }
    eprintln!(
        "rotation_of optimality: smallest (‖Q − m‖ − ‖R − m‖) over 220k rotations {worst_gap:.2e}"
    );
}

#[test]
fn rotation_of_a_rotation_is_itself() {
    let mut rng = Rng(11);
    let mut worst = 0.0f64;
    let half_turn = Mat3::from_diagonal(Vec3::new(1.0, -1.0, -1.0));
    for k in 0..10_000 {
        let r = if k == 0 { half_turn } else { rng.rotation() };
        let error = max_abs(rotation_of(r).as_dmat3() - r.as_dmat3());
        assert!(
            error <= 1e-5,
            "rotation_of({r}) differs from it by {error:e}"
        );
        worst = worst.max(error);
        // Scaling does not change the rotation.
        let error = max_abs(rotation_of(r * 1e-4).as_dmat3() - r.as_dmat3());
        assert!(
            error <= 1e-5,
            "rotation_of({r} × 1e-4) differs from it by {error:e}"
        );
    }
    eprintln!("rotation_of(R) = R: max element error {worst:.2e}");
}

/// Rest positions around particle 0, current positions `rotation · rest + t`,
/// returned as offsets from particle 0.
fn neighbourhood(
    rng: &mut Rng,
    rotation: Mat3,
    rest_shape: impl Fn(Vec3) -> Vec3,
) -> (Vec<Vec3>, Vec<Vec3>) {
    let translation = rng.vec3() * 10.0;
    let rest: Vec<Vec3> = (0..12).map(|_| rest_shape(rng.vec3())).collect();
    let current: Vec<Vec3> = rest.iter().map(|&p| rotation * p + translation).collect();
    let rest_offsets = rest.iter().map(|&p| p - rest[0]).collect();
    let current_offsets = current.iter().map(|&q| q - current[0]).collect();
    (rest_offsets, current_offsets)
}

#[test]
fn procrustes_direction_rest_to_current() {
    let mut rng = Rng(2024);
    let mut worst = 0.0f64;
    for k in 0..2000 {
        let truth = rng.rotation();
        let (rest, current) = neighbourhood(&mut rng, truth, |p| p);
        // Stage 2's matrix: M = Σ p·qᵀ, rest × current.
        let mut m = Mat3::ZERO;
        for (p, q) in rest.iter().zip(&current) {
            m += Mat3::from_cols(*p * q.x, *p * q.y, *p * q.z);
        }
        let paper = rotation_of(m);
        // The paper's R_i = U·Vᵀ maps current onto rest: it is truthᵀ, not truth.
        let error = max_abs(paper.transpose().as_dmat3() - truth.as_dmat3());
        assert!(
            error <= 1e-5,
            "#{k}: rotation_of(Σ p·qᵀ)ᵀ is off from the true rotation by {error:e}"
        );
        let fitted = best_rotation(&rest, &current);
        let error = max_abs(fitted.as_dmat3() - truth.as_dmat3());
        assert!(
            error <= 1e-5,
            "#{k}: best_rotation is off from the true rotation by {error:e}"
        );
        worst = worst.max(error);
        if max_abs(truth.as_dmat3() - truth.transpose().as_dmat3()) > 0.1 {
            assert!(
                max_abs(paper.as_dmat3() - truth.as_dmat3()) > 1e-3,
                "#{k}: rotation_of(Σ p·qᵀ) should be the transpose of the true rotation"
            );
        }
    }
    eprintln!("best_rotation: max element error {worst:.2e}");
}

#[test]
fn procrustes_on_flat_and_degenerate_neighbourhoods() {
    let mut rng = Rng(99);
    for k in 0..2000 {
        let truth = rng.rotation();
        // Coplanar neighbours: M has rank 2 and the rotation is still unique.
        let (rest, current) = neighbourhood(&mut rng, truth, |p| Vec3::new(p.x, p.y, 0.0));
        let error = max_abs(best_rotation(&rest, &current).as_dmat3() - truth.as_dmat3());
        assert!(error <= 1e-4, "coplanar #{k}: off by {error:e}");
        // Collinear: only the line is determined; it must still map onto its image.
        let (rest, current) = neighbourhood(&mut rng, truth, |p| Vec3::new(p.x, 0.0, 0.0));
        let fitted = best_rotation(&rest, &current);
        assert!(
            (fitted.determinant() - 1.0).abs() < 1e-5,
            "collinear #{k}: det {}",
            fitted.determinant()
        );
        for (p, q) in rest.iter().zip(&current) {
            let miss = (fitted * *p - *q).length();
            assert!(
                miss <= 1e-5 * (1.0 + p.length()),
                "collinear #{k}: R·p misses q by {miss:e}"
            );
        }
    }
    assert_eq!(best_rotation(&[], &[]), Mat3::IDENTITY);
    assert_eq!(
        best_rotation(&[Vec3::ZERO; 4], &[Vec3::ZERO; 4]),
        Mat3::IDENTITY
    );
    // Mismatched lengths use the common prefix.
    let r = Mat3::from_axis_angle(Vec3::Z, 0.3);
    let rest = [Vec3::X, Vec3::Y, Vec3::Z];
    let current = [r * Vec3::X, r * Vec3::Y];
    let error = max_abs(best_rotation(&rest, &current).as_dmat3() - r.as_dmat3());
    assert!(error <= 1e-6, "prefix: off by {error:e}");
}

#[test]
fn entries_near_f32_max_overflow_only_sigma() {
    let mut rng = Rng(5);
    for k in 0..1000 {
        let signs: [f32; 9] = std::array::from_fn(|_| {
            if rng.signed() < 0.0 {
                -f32::MAX
            } else {
                f32::MAX
            }
        });
        let m = Mat3::from_cols_array(&signs);
        let svd = svd3(m);
        for (name, q) in [("u", svd.u), ("v", svd.v), ("rotation_of", rotation_of(m))] {
            let qd = q.as_dmat3();
            let error =
                max_abs(qd.transpose() * qd - DMat3::IDENTITY).max((qd.determinant() - 1.0).abs());
            assert!(
                q.is_finite() && error <= ORTHONORMAL_TOLERANCE,
                "#{k}: {name} = {q} for ±f32::MAX entries {m}"
            );
        }
        assert!(!svd.sigma.is_nan(), "#{k}: sigma {} for {m}", svd.sigma);
    }
}
