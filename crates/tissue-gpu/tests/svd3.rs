//! The WGSL 3x3 SVD (`shaders/shared/svd3.wgsl`) on the adapter, tested by
//! invariants (never U or V element by element): U·S·Vᵀ rebuilds M, U and V
//! orthonormal with det +1, singular values sorted, |sigma.z| carrying
//! det(M)'s sign, no NaN; over random and adversarial matrices.

mod common;

use glam::{Mat3, Vec3};
use rand::{Rng, SeedableRng};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Matrix([[f32; 4]; 3]);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Decomposition {
    u: Matrix,
    sigma: [f32; 4],
    v: Matrix,
}

fn to_gpu(m: Mat3) -> Matrix {
    Matrix([
        m.x_axis.extend(0.0).to_array(),
        m.y_axis.extend(0.0).to_array(),
        m.z_axis.extend(0.0).to_array(),
    ])
}

fn from_gpu(m: Matrix) -> Mat3 {
    let c = |v: [f32; 4]| Vec3::new(v[0], v[1], v[2]);
    Mat3::from_cols(c(m.0[0]), c(m.0[1]), c(m.0[2]))
}

fn random_rotation(rng: &mut impl Rng) -> Mat3 {
    let axis = Vec3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    );
    let axis = if axis.length() > 1e-3 {
        axis.normalize()
    } else {
        Vec3::Z
    };
    Mat3::from_axis_angle(
        axis,
        rng.random_range(-std::f32::consts::PI..std::f32::consts::PI),
    )
}

/// Random matrices (entries in [-1, 1], log-uniform scales) and adversarial ones.
fn matrices() -> Vec<Mat3> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5eed_5fd3);
    let mut out = tissue_testkit::small_svd_cases().to_vec();
    for _ in 0..8_000 {
        let scale = 10f32.powf(rng.random_range(-6.0..6.0));
        let entries: [f32; 9] = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
        out.push(Mat3::from_cols_array(&entries) * scale);
    }
    let spectra = [
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(2.0, 2.0, 1.0),
        Vec3::new(1.0, 1.0, -1.0),
        Vec3::new(1.0, 0.5, -0.5),
        Vec3::new(1.0, 1e-3, 1e-6),
        Vec3::new(1.0, 1e-4, -1e-4),
        Vec3::new(1.0, 1e-8, 0.0),
        Vec3::new(3.0, 3.0, -3.0),
    ];
    for k in 0..4_000 {
        let sigma = spectra[k % spectra.len()];
        let scale = 10f32.powf(rng.random_range(-20.0..20.0));
        let m = random_rotation(&mut rng)
            * Mat3::from_diagonal(sigma)
            * random_rotation(&mut rng).transpose();
        out.push(m * scale);
    }
    // Near the identity: stage 2's usual case (I + 1e-7 noise, and coplanar
    // neighbourhoods: a rank-2 M with noise).
    for k in 0..1_000 {
        let noise: [f32; 9] = std::array::from_fn(|_| rng.random_range(-1e-7f32..1e-7));
        let base = if k % 2 == 0 {
            Mat3::IDENTITY
        } else {
            Mat3::from_diagonal(Vec3::new(1.0, 1.0, 0.0))
        };
        out.push(base + Mat3::from_cols_array(&noise));
    }
    out
}

fn frobenius(m: Mat3) -> f32 {
    m.to_cols_array().iter().map(|x| x * x).sum::<f32>().sqrt()
}

#[test]
fn the_wgsl_svd_satisfies_the_invariants_on_the_adapter() {
    let Some((device, queue)) = common::gpu("svd3 invariants") else {
        return;
    };
    let inputs = matrices();
    assert!(inputs.len() >= 10_000);
    let gpu_inputs: Vec<Matrix> = inputs.iter().map(|&m| to_gpu(m)).collect();
    let started = std::time::Instant::now();
    let bytes = common::run_list_kernel(
        &device,
        &queue,
        ("tests/svd3", "svd3_test"),
        &gpu_inputs,
        (inputs.len() * std::mem::size_of::<Decomposition>()) as u64,
    );
    eprintln!(
        "{} matrices decomposed (the kernel compiled) and read back in {:.1} ms",
        inputs.len(),
        started.elapsed().as_secs_f64() * 1e3
    );
    let results: Vec<Decomposition> = bytemuck::pod_collect_to_vec(&bytes);

    let tolerance = 2e-5;
    let mut worst = [0.0f32; 4];
    for (k, (&m, d)) in inputs.iter().zip(&results).enumerate() {
        let (u, v, s) = (
            from_gpu(d.u),
            from_gpu(d.v),
            Vec3::new(d.sigma[0], d.sigma[1], d.sigma[2]),
        );
        assert!(
            u.is_finite() && v.is_finite() && s.is_finite(),
            "matrix {k} {m}: non-finite result u {u} sigma {s} v {v}"
        );
        let norm = frobenius(m);
        let rebuilt = u * Mat3::from_diagonal(s) * v.transpose();
        let reconstruction = if norm > 0.0 {
            frobenius(rebuilt - m) / norm
        } else {
            frobenius(rebuilt)
        };
        let orthonormal = frobenius(u.transpose() * u - Mat3::IDENTITY)
            .max(frobenius(v.transpose() * v - Mat3::IDENTITY));
        let det = (u.determinant() - 1.0)
            .abs()
            .max((v.determinant() - 1.0).abs());
        let order =
            (s.y - s.x).max(s.z.abs() - s.y).max(-s.y).max(0.0) / s.x.max(f32::MIN_POSITIVE);
        for (w, e) in worst
            .iter_mut()
            .zip([reconstruction, orthonormal, det, order])
        {
            *w = w.max(e);
        }
        assert!(
            reconstruction <= tolerance,
            "matrix {k} {m}: |U S Vt - M| / |M| = {reconstruction:e} > tolerance {tolerance:e} (sigma {s})"
        );
        assert!(
            orthonormal <= tolerance,
            "matrix {k} {m}: |UtU - I|, |VtV - I| = {orthonormal:e} > tolerance {tolerance:e}"
        );
        assert!(
            det <= tolerance,
            "matrix {k} {m}: det U = {}, det V = {}, tolerance {tolerance:e}",
            u.determinant(),
            v.determinant()
        );
        assert!(
            order <= 1e-6,
            "matrix {k} {m}: sigma {s} not sorted (x >= y >= |z|), off by {order:e} relative"
        );
        // A clearly negative determinant must show up as a negative sigma.z.
        let det_m = m.determinant();
        let scale3 = norm * norm * norm;
        if det_m < -1e-3 * scale3 {
            assert!(s.z < 0.0, "matrix {k} {m}: det {det_m:e} < 0 but sigma {s}");
        }
    }
    eprintln!(
        "worst over {}: reconstruction {:e}, orthonormality {:e}, |det - 1| {:e}, order {:e}",
        inputs.len(),
        worst[0],
        worst[1],
        worst[2],
        worst[3]
    );
}
