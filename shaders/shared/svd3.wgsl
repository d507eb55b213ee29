// 3x3 signed SVD and polar rotation: the twin of `tissue_cpu::svd3` (same
// algorithm, constants and order of operations; see that module's doc for
// the convention, the method and its accuracy). f32 throughout.

// Cyclic Jacobi sweeps over mᵀm (three plane rotations each).
const JACOBI_SWEEPS: u32 = 4u;
// One-sided Jacobi sweeps over the columns of m·v after the symmetric phase.
const POLISH_SWEEPS: u32 = 1u;
// QR Givens rotations below this squared length are skipped (scaled input).
const GIVENS_MIN_LENGTH_SQUARED: f32 = 1e-36;
// Off-diagonals and 2(a − d) terms below this are rounding noise: flushed.
const NEGLIGIBLE: f32 = 1e-15;
// cot²(π/8) = 3 + 2√2, McAdams' γ.
const COT_SQUARED_PI_8: f32 = 5.828427;
const COS_PI_8: f32 = 0.9238795;
const SIN_PI_8: f32 = 0.38268343;
const FRAC_1_SQRT_2: f32 = 0.70710677;
// f32::MIN_POSITIVE, the smallest normal f32.
const MIN_POSITIVE: f32 = 1.1754944e-38;

struct Svd3 {
    u: mat3x3<f32>,
    sigma: vec3<f32>,
    v: mat3x3<f32>,
}

// A rotation [[c, −s], [s, c]] in a plane, with its half-angle (ch, sh).
struct PlaneRotation {
    c: f32,
    s: f32,
    ch: f32,
    sh: f32,
}

// McAdams' approximate Jacobi rotation for [[a, b], [b, d]]: half-angle
// tangent b / 2(a − d), capped at π/8; the choice is a blend, not a branch.
fn approximate_rotation(a: f32, d: f32, b: f32) -> PlaneRotation {
    let sh = select(b, 0.0, abs(b) < NEGLIGIBLE);
    let ch_raw = select(2.0 * (a - d), 1.0, sh == 0.0);
    let ch = select(ch_raw, 0.0, abs(ch_raw) < NEGLIGIBLE);
    let ch2 = ch * ch;
    let sh2 = sh * sh;
    let inverse = 1.0 / (ch2 + sh2);
    let small = select(0.0, 1.0, COT_SQUARED_PI_8 * sh2 < ch2);
    let large = 1.0 - small;
    let sign = select(1.0, -1.0, (ch < 0.0) != (sh < 0.0));
    let normaliser = sqrt(inverse);
    return PlaneRotation(
        small * (ch2 - sh2) * inverse + large * FRAC_1_SQRT_2,
        small * 2.0 * ch * sh * inverse + large * sign * FRAC_1_SQRT_2,
        small * ch * normaliser + large * COS_PI_8,
        small * sh * normaliser + large * sign * SIN_PI_8,
    );
}

// Entries of the symmetric S touched by a rotation in plane (p, q), r the
// third index: a = S_pp, d = S_qq, b = S_pq, rp = S_rp, rq = S_rq.
struct Conjugated {
    a: f32,
    d: f32,
    b: f32,
    rp: f32,
    rq: f32,
    ch: f32,
    sh: f32,
}

// S ← Gᵀ S G for the approximate Jacobi rotation G of b = S_pq.
fn jacobi_conjugate(a: f32, d: f32, b: f32, rp: f32, rq: f32) -> Conjugated {
    let g = approximate_rotation(a, d, b);
    let cc = g.c * g.c;
    let ss = g.s * g.s;
    let cs = g.c * g.s;
    return Conjugated(
        cc * a + 2.0 * cs * b + ss * d,
        ss * a - 2.0 * cs * b + cc * d,
        cs * (d - a) + (cc - ss) * b,
        g.c * rp + g.s * rq,
        g.c * rq - g.s * rp,
        g.ch,
        g.sh,
    );
}

// Hamilton product q ⊗ r of quaternions stored as (x, y, z, w).
fn quat_mul(q: vec4<f32>, r: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(q.w * r.xyz + r.w * q.xyz + cross(q.xyz, r.xyz), q.w * r.w - dot(q.xyz, r.xyz));
}

// Rotation matrix of a quaternion (x, y, z, w), normalised first.
fn quat_to_mat3(q_raw: vec4<f32>) -> mat3x3<f32> {
    let q = q_raw / sqrt(dot(q_raw, q_raw));
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

// (c, s) of the exact Jacobi rotation diagonalising [[a, b], [b, d]], |θ| ≤ π/4.
fn exact_rotation(a: f32, d: f32, b_raw: f32) -> vec2<f32> {
    let b = select(b_raw, 0.0, abs(b_raw) < NEGLIGIBLE);
    // tan θ: the smaller root of t² + ((a − d)/b)·t − 1 = 0, without dividing by b.
    let delta = a - d;
    let sign = select(1.0, -1.0, delta < 0.0);
    let denominator = abs(delta) + sqrt(delta * delta + 4.0 * b * b);
    let t = clamp(2.0 * b * sign / max(denominator, MIN_POSITIVE), -1.0, 1.0);
    let c = 1.0 / sqrt(1.0 + t * t);
    return vec2<f32>(c, t * c);
}

struct ColumnPair {
    bp: vec3<f32>,
    bq: vec3<f32>,
    vp: vec3<f32>,
    vq: vec3<f32>,
}

// One-sided Jacobi rotation making bp · bq = 0, applied to v's columns too.
fn orthogonalise_columns(bp: vec3<f32>, bq: vec3<f32>, vp: vec3<f32>, vq: vec3<f32>) -> ColumnPair {
    let r = exact_rotation(dot(bp, bp), dot(bq, bq), dot(bp, bq));
    let c = r.x;
    let s = r.y;
    return ColumnPair(c * bp + s * bq, c * bq - s * bp, c * vp + s * vq, c * vq - s * vp);
}

// (cos, sin) of the Givens rotation taking (a1, a2) to (|(a1, a2)|, 0).
fn qr_givens(a1: f32, a2: f32) -> vec2<f32> {
    let length_squared = a1 * a1 + a2 * a2;
    let keep = length_squared > GIVENS_MIN_LENGTH_SQUARED;
    let inverse_length = select(0.0, 1.0 / sqrt(length_squared), keep);
    let c = select(1.0, a1 * inverse_length, keep);
    return vec2<f32>(c, a2 * inverse_length);
}

// Signed SVD m = u · diag(sigma) · vᵀ, u and v rotations, sigma.x ≥ sigma.y ≥ |sigma.z|.
fn svd3(m: mat3x3<f32>) -> Svd3 {
    // 1. Scale to a largest |element| of 1 (zero stays zero).
    let largest = max(max(abs(m[0]), abs(m[1])), abs(m[2]));
    let scale = max(max(largest.x, largest.y), largest.z);
    let divisor = select(1.0, scale, scale > 0.0);
    let a = mat3x3<f32>(m[0] / divisor, m[1] / divisor, m[2] / divisor);

    // 2. Symmetric S = aᵀa, diagonalised by cyclic Jacobi: S ← Gᵀ S G, v ← v G.
    var s11 = dot(a[0], a[0]);
    var s22 = dot(a[1], a[1]);
    var s33 = dot(a[2], a[2]);
    var s12 = dot(a[0], a[1]);
    var s13 = dot(a[0], a[2]);
    var s23 = dot(a[1], a[2]);
    var q = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var sweep = 0u; sweep < JACOBI_SWEEPS; sweep++) {
        // Plane (1, 2): a rotation about axis 3.
        var r = jacobi_conjugate(s11, s22, s12, s13, s23);
        s11 = r.a; s22 = r.d; s12 = r.b; s13 = r.rp; s23 = r.rq;
        q = quat_mul(q, vec4<f32>(0.0, 0.0, r.sh, r.ch));
        // Plane (2, 3): about axis 1.
        r = jacobi_conjugate(s22, s33, s23, s12, s13);
        s22 = r.a; s33 = r.d; s23 = r.b; s12 = r.rp; s13 = r.rq;
        q = quat_mul(q, vec4<f32>(r.sh, 0.0, 0.0, r.ch));
        // Plane (3, 1): about axis 2.
        r = jacobi_conjugate(s33, s11, s13, s23, s12);
        s33 = r.a; s11 = r.d; s13 = r.b; s23 = r.rp; s12 = r.rq;
        q = quat_mul(q, vec4<f32>(0.0, r.sh, 0.0, r.ch));
    }
    let v = quat_to_mat3(q);
    var v1 = v[0];
    var v2 = v[1];
    var v3 = v[2];

    // 3. One-sided polish on the columns of b = a v, same planes and order.
    let b = a * v;
    var b1 = b[0];
    var b2 = b[1];
    var b3 = b[2];
    for (var sweep = 0u; sweep < POLISH_SWEEPS; sweep++) {
        var p = orthogonalise_columns(b1, b2, v1, v2);
        b1 = p.bp; b2 = p.bq; v1 = p.vp; v2 = p.vq;
        p = orthogonalise_columns(b2, b3, v2, v3);
        b2 = p.bp; b3 = p.bq; v2 = p.vp; v3 = p.vq;
        p = orthogonalise_columns(b3, b1, v3, v1);
        b3 = p.bp; b1 = p.bq; v3 = p.vp; v1 = p.vq;
    }

    // 4. Sort columns by descending norm; (x, y) → (y, −x) keeps det v = +1.
    var n1 = dot(b1, b1);
    var n2 = dot(b2, b2);
    var n3 = dot(b3, b3);
    if (n1 < n2) {
        let tb = b1; b1 = b2; b2 = -tb;
        let tv = v1; v1 = v2; v2 = -tv;
        let tn = n1; n1 = n2; n2 = tn;
    }
    if (n1 < n3) {
        let tb = b1; b1 = b3; b3 = -tb;
        let tv = v1; v1 = v3; v3 = -tv;
        n3 = n1;
    }
    if (n2 < n3) {
        let tb = b2; b2 = b3; b3 = -tb;
        let tv = v2; v2 = v3; v3 = -tv;
    }

    // 5. QR of b by Givens rotations on its rows; the same rotations on the
    // columns of u give b = u r.
    let bt = transpose(mat3x3<f32>(b1, b2, b3));
    var r1 = bt[0];
    var r2 = bt[1];
    var r3 = bt[2];
    var u1 = vec3<f32>(1.0, 0.0, 0.0);
    var u2 = vec3<f32>(0.0, 1.0, 0.0);
    var u3 = vec3<f32>(0.0, 0.0, 1.0);
    var g = qr_givens(r1.x, r2.x);
    var t_r = r1; var t_u = u1;
    r1 = g.x * t_r + g.y * r2; r2 = g.x * r2 - g.y * t_r;
    u1 = g.x * t_u + g.y * u2; u2 = g.x * u2 - g.y * t_u;
    g = qr_givens(r1.x, r3.x);
    t_r = r1; t_u = u1;
    r1 = g.x * t_r + g.y * r3; r3 = g.x * r3 - g.y * t_r;
    u1 = g.x * t_u + g.y * u3; u3 = g.x * u3 - g.y * t_u;
    g = qr_givens(r2.y, r3.y);
    t_r = r2; t_u = u2;
    r2 = g.x * t_r + g.y * r3; r3 = g.x * r3 - g.y * t_r;
    u2 = g.x * t_u + g.y * u3; u3 = g.x * u3 - g.y * t_u;

    // Clamp to exact order: the diagonal of r is already sorted up to rounding.
    let sigma1 = max(r1.x, 0.0);
    let sigma2 = clamp(r2.y, 0.0, sigma1);
    let sigma3 = clamp(r3.z, -sigma2, sigma2);
    return Svd3(mat3x3<f32>(u1, u2, u3), vec3<f32>(sigma1, sigma2, sigma3) * scale, mat3x3<f32>(v1, v2, v3));
}

// The rotation (det +1) closest to m: u · vᵀ of the signed SVD.
fn rotation_of(m: mat3x3<f32>) -> mat3x3<f32> {
    let svd = svd3(m);
    return svd.u * transpose(svd.v);
}
