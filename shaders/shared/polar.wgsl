// The warm-started polar rotation (Müller et al. 2016): the twin of
// `tissue_cpu::deformation::polar` (`warm_rotation`, `polar_rotation`),
// with glam's quaternion formulas (`Quat::from_mat3`, the Hamilton product,
// `Mat3::from_quat`) written out in the same order.
// Quaternions are stored as (x, y, z, w).

#import shared/svd3

// Polar updates per solver iteration (`POLAR_ITERATIONS`).
const POLAR_ITERATIONS: u32 = 3u;
// The most updates an unsettled rotation gets before the SVD answers
// (`POLAR_MOST_ITERATIONS`).
const POLAR_MOST_ITERATIONS: u32 = 6u;
// A settled update's last turn is below this, in radians (`POLAR_SETTLED`).
const POLAR_SETTLED: f32 = 1e-3;
// The same past the first POLAR_ITERATIONS updates (`POLAR_SETTLED_LATE`).
const POLAR_SETTLED_LATE: f32 = 2e-4;
// The largest finite f32: a larger (or NaN) scale means a non-finite matrix.
const MAX_FINITE: f32 = 3.4028235e38;

// glam's `Quat::from_rotation_axes`: the quaternion of rotation matrix r.
fn quat_of_rotation(r: mat3x3<f32>) -> vec4<f32> {
    let m00 = r[0].x;
    let m01 = r[0].y;
    let m02 = r[0].z;
    let m10 = r[1].x;
    let m11 = r[1].y;
    let m12 = r[1].z;
    let m20 = r[2].x;
    let m21 = r[2].y;
    let m22 = r[2].z;
    if (m22 <= 0.0) {
        let dif10 = m11 - m00;
        let omm22 = 1.0 - m22;
        if (dif10 <= 0.0) {
            let four_xsq = omm22 - dif10;
            let inv4x = 0.5 / sqrt(four_xsq);
            return vec4<f32>(four_xsq * inv4x, (m01 + m10) * inv4x, (m02 + m20) * inv4x, (m12 - m21) * inv4x);
        }
        let four_ysq = omm22 + dif10;
        let inv4y = 0.5 / sqrt(four_ysq);
        return vec4<f32>((m01 + m10) * inv4y, four_ysq * inv4y, (m12 + m21) * inv4y, (m20 - m02) * inv4y);
    }
    let sum10 = m11 + m00;
    let opm22 = 1.0 + m22;
    if (sum10 <= 0.0) {
        let four_zsq = opm22 - sum10;
        let inv4z = 0.5 / sqrt(four_zsq);
        return vec4<f32>((m02 + m20) * inv4z, (m12 + m21) * inv4z, four_zsq * inv4z, (m01 - m10) * inv4z);
    }
    let four_wsq = opm22 + sum10;
    let inv4w = 0.5 / sqrt(four_wsq);
    return vec4<f32>((m12 - m21) * inv4w, (m20 - m02) * inv4w, (m01 - m10) * inv4w, four_wsq * inv4w);
}

// glam's `normalize`: q times the reciprocal of its length.
fn quat_normalized(q: vec4<f32>) -> vec4<f32> {
    return q * (1.0 / sqrt(dot(q, q)));
}

// glam's `Quat::mul_quat`: the Hamilton product a ⊗ b.
fn quat_product(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(
        a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
        a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
        a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
        a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z,
    );
}

// glam's `Mat3::from_quat` (q of unit length; not normalised again).
fn rotation_of_quat(q: vec4<f32>) -> mat3x3<f32> {
    let x2 = q.x + q.x;
    let y2 = q.y + q.y;
    let z2 = q.z + q.z;
    let xx = q.x * x2;
    let xy = q.x * y2;
    let xz = q.x * z2;
    let yy = q.y * y2;
    let yz = q.y * z2;
    let zz = q.z * z2;
    let wx = q.w * x2;
    let wy = q.w * y2;
    let wz = q.w * z2;
    return mat3x3<f32>(
        vec3<f32>(1.0 - (yy + zz), xy + wz, xz - wy),
        vec3<f32>(xy - wz, 1.0 - (xx + zz), yz + wx),
        vec3<f32>(xz + wy, yz - wx, 1.0 - (xx + yy)),
    );
}

// What the polar update returns: the rotation, and whether it settled.
struct Polar {
    rotation: mat3x3<f32>,
    settled: bool,
}

// `polar_update`: turns `start` towards the rotation R maximising
// trace(Rᵀ m), each step ω = Σ_c r_c × m_c / |Σ_c r_c · m_c| by the
// quaternion (ω / 2, 1) normalised, POLAR_ITERATIONS steps and more while
// the last has not settled, to POLAR_MOST_ITERATIONS; settled when the
// last turn was below POLAR_SETTLED (POLAR_SETTLED_LATE past
// POLAR_ITERATIONS) while trace(Rᵀ m) > 0.
fn polar_rotation(m_raw: mat3x3<f32>, start: mat3x3<f32>) -> Polar {
    let a = max(max(abs(m_raw[0]), abs(m_raw[1])), abs(m_raw[2]));
    let scale = max(max(a.x, a.y), a.z);
    if (scale == 0.0 || !(scale <= MAX_FINITE)) {
        return Polar(start, true);
    }
    let m = m_raw * (1.0 / scale);
    var q = quat_normalized(quat_of_rotation(start));
    var settled = false;
    for (var k = 0u; k < POLAR_MOST_ITERATIONS; k++) {
        let r = rotation_of_quat(q);
        let turn = cross(r[0], m[0]) + cross(r[1], m[1]) + cross(r[2], m[2]);
        let alignment = dot(r[0], m[0]) + dot(r[1], m[1]) + dot(r[2], m[2]);
        let omega = turn * (1.0 / (abs(alignment) + 1e-9));
        let angle = sqrt(dot(omega, omega));
        var settling = POLAR_SETTLED;
        if (k >= POLAR_ITERATIONS) {
            settling = POLAR_SETTLED_LATE;
        }
        settled = alignment > 0.0 && angle < settling;
        if (angle < 1e-9) {
            break;
        }
        q = quat_normalized(quat_product(vec4<f32>(0.5 * omega, 1.0), q));
        if (settled && k + 1u >= POLAR_ITERATIONS) {
            break;
        }
    }
    return Polar(rotation_of_quat(q), settled);
}

// `warm_rotation`: the warm update from `start`, or where it did not
// settle the SVD's rotation of m.
fn warm_rotation(m: mat3x3<f32>, start: mat3x3<f32>) -> mat3x3<f32> {
    let polar = polar_rotation(m, start);
    if (polar.settled) {
        return polar.rotation;
    }
    return rotation_of(m);
}
