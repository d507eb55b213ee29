//! Deformations of a surface that keep its vertices and triangles.
//!
//! Every map here moves points, and [`deform_surface`] applies one to each
//! vertex of a [`SurfaceMesh`]: the result has the same vertices in the same
//! order at new positions and the very same triangles, which is what tracking
//! needs (the deformed skin is the rest skin with moved vertices).
//!
//! **Exact references**, for accuracy tests with known answers: the
//! deformation of the interior is given by the same formula as that of the
//! surface.
//!
//! - [`Rigid`]: a rotation about a centre, then a translation.
//! - [`Affine`]: a homogeneous deformation `p -> c + A (p - c) + t`; the
//!   exact elastic answer for any interior point, whatever the material.
//! - [`Twist`]: torsion about an axis, the angle growing linearly along it;
//!   the exact displacement field of a twisted circular cylinder.
//!
//! **Illustrative** maps, physical-looking but with no exact interior answer,
//! for the demo and the benchmarks. They are smooth, in millimetres in the
//! frame of [`crate::phantom`] (chest wall at `z = 0`, `+z` anterior, `+y`
//! cranial), and leave the chest wall fixed:
//!
//! - [`Sag`]: the breast hangs under gravity, most at the apex.
//! - [`Indentation`]: a probe pushes the skin in.
//!
//! [`sagged_breast`] and [`indented_breast`] apply them, with default
//! parameters, to the default phantom; [`interpolate`] blends two vertex-wise
//! corresponding meshes to make a sequence of small tracking frames.

use glam::{DVec3, Mat3, Quat, Vec2, Vec3};

use crate::mesh::SurfaceMesh;
use crate::phantom::{TumourPhantom, default_breast};

/// A map of points in space, applied vertex by vertex by [`deform_surface`].
pub trait PointMap {
    /// Where the point `p` goes.
    fn apply(&self, p: Vec3) -> Vec3;
}

/// `mesh` with every vertex moved by `map`; triangles are copied unchanged.
pub fn deform_surface(mesh: &SurfaceMesh, map: &impl PointMap) -> SurfaceMesh {
    SurfaceMesh::new(
        mesh.vertices.iter().map(|&v| map.apply(v)).collect(),
        mesh.triangles.clone(),
    )
}

/// A rigid motion: rotation about `centre`, then translation.
///
/// `p -> centre + rotation (p - centre) + translation`. Preserves every
/// distance and the enclosed volume (exact reference).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    /// Rotation, a unit quaternion.
    pub rotation: Quat,
    /// Translation applied after the rotation.
    pub translation: Vec3,
    /// Fixed point of the rotation.
    pub centre: Vec3,
}

impl Rigid {
    /// A rotation by `angle_radians` about `axis` (normalised here; a zero or
    /// non-finite axis gives no rotation) through `centre`, then `translation`.
    pub fn about_axis(axis: Vec3, angle_radians: f32, centre: Vec3, translation: Vec3) -> Self {
        let rotation = axis.try_normalize().map_or(Quat::IDENTITY, |axis| {
            Quat::from_axis_angle(axis, angle_radians)
        });
        Self {
            rotation,
            translation,
            centre,
        }
    }

    /// Where the point `p` goes.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.centre + self.rotation * (p - self.centre) + self.translation
    }
}

impl PointMap for Rigid {
    fn apply(&self, p: Vec3) -> Vec3 {
        Rigid::apply(self, p)
    }
}

/// A homogeneous (affine) deformation about `centre`.
///
/// `p -> centre + matrix (p - centre) + translation`. Constant deformation
/// gradient, so it solves the equilibrium equations of any homogeneous
/// material with the surface displacement as boundary data: every interior
/// point follows the same formula (exact reference). Volumes scale by
/// `det(matrix)`; a negative determinant turns the surface inside out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// The deformation gradient `A`.
    pub matrix: Mat3,
    /// Translation `t` applied after the linear part.
    pub translation: Vec3,
    /// Fixed point of the linear part.
    pub centre: Vec3,
}

impl Affine {
    /// Where the point `p` goes.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.centre + self.matrix * (p - self.centre) + self.translation
    }
}

impl PointMap for Affine {
    fn apply(&self, p: Vec3) -> Vec3 {
        Affine::apply(self, p)
    }
}

/// Torsion about an axis: each point turns about the axis by an angle that
/// grows linearly with its coordinate along it.
///
/// With `h = (p - axis_origin) · axis`, the point turns about the axis by
/// `θ = angle_per_length · h` (right-handed about `axis`). This is the
/// classical torsion of a circular cylinder about its own axis (cross-sections
/// turn rigidly and do not warp), the exact displacement field there (exact
/// reference). It keeps each point's distance from the axis and its axial
/// coordinate, and every volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Twist {
    /// A point on the axis, where the angle is 0.
    pub axis_origin: Vec3,
    /// Direction of the axis, a unit vector (normalised on use; a zero or
    /// non-finite axis gives the identity).
    pub axis: Vec3,
    /// Twist rate `k`, radians per unit length along the axis.
    pub angle_per_length: f32,
}

impl Twist {
    /// Where the point `p` goes.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        let Some(axis) = self.axis.try_normalize() else {
            return p;
        };
        let offset = p - self.axis_origin;
        let angle = self.angle_per_length * offset.dot(axis);
        self.axis_origin + Quat::from_axis_angle(axis, angle) * offset
    }
}

impl PointMap for Twist {
    fn apply(&self, p: Vec3) -> Vec3 {
        Twist::apply(self, p)
    }
}

/// The breast hanging under gravity (illustrative).
///
/// With `s(z) = (max(z, 0) / H)²` and `H = projection_mm`, a point moves by
/// `magnitude_mm · s(z) · direction`: nothing at the chest wall (where `s`
/// and its slope vanish), `magnitude_mm` at the apex's height.
///
/// The part of `direction` in the chest-wall plane is a shear whose amount
/// depends only on `z`, and keeps volumes exactly. Its `z` part would stretch
/// or squash the breast along `z` by `q(z) = 1 + magnitude · d_z · s'(z)`;
/// the map compensates with a lateral scaling by `1 / sqrt(q(z))` about the
/// vertical line through `apex_foot`, so the Jacobian determinant is 1
/// everywhere and the continuum map keeps volume exactly for any direction
/// (a breast pushed towards the chest spreads sideways). That needs `q > 0`
/// on the body, i.e. `2 · magnitude · max(-d_z, 0) · z_max < H²`; for the
/// default breast and a direction straight into the chest, below about 27 mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sag {
    /// Direction of gravity relative to the breast, a unit vector
    /// (normalised on use; a zero or non-finite one gives the identity).
    /// Default `-y`: towards the feet, as when a patient who lay down sits up.
    pub direction: Vec3,
    /// Displacement at the apex's height, mm. Default 12.
    pub magnitude_mm: f32,
    /// Height `H` at which the displacement reaches `magnitude_mm`, mm;
    /// default 55, the default phantom's projection. A non-positive value
    /// gives the identity.
    pub projection_mm: f32,
    /// Where the lateral compensating scaling is centred in the chest-wall
    /// plane `(x, y)`, mm; default `(0, -8)`, under the default apex. Has no
    /// effect when `direction` lies in the chest-wall plane.
    pub apex_foot: Vec2,
}

impl Default for Sag {
    /// 12 mm towards the feet at the apex of the default breast.
    fn default() -> Self {
        Self {
            direction: Vec3::NEG_Y,
            magnitude_mm: 12.0,
            projection_mm: 55.0,
            apex_foot: Vec2::new(0.0, -8.0),
        }
    }
}

impl Sag {
    /// Where the point `p` goes.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        let Some(direction) = self.direction.try_normalize() else {
            return p;
        };
        let height = self.projection_mm;
        if height.is_nan() || height <= 0.0 || !self.magnitude_mm.is_finite() {
            return p;
        }
        let z = p.z.max(0.0);
        let profile = (z / height).powi(2);
        let slope = 2.0 * z / (height * height);
        let amount = self.magnitude_mm * profile;
        // Stretch along z, and the lateral scaling that cancels it: λ² q = 1.
        let stretch = 1.0 + self.magnitude_mm * direction.z * slope;
        let lateral = 1.0 / stretch.max(f32::MIN_POSITIVE).sqrt();
        let across = self.apex_foot + lateral * (p.truncate() - self.apex_foot);
        across.extend(p.z) + amount * direction
    }
}

impl PointMap for Sag {
    fn apply(&self, p: Vec3) -> Vec3 {
        Sag::apply(self, p)
    }
}

/// A probe pushing the skin in (illustrative).
///
/// A point `p` moves by `depth_mm · exp(-r² / (2σ²)) · w(p.z) · direction`,
/// where `r` is the distance from `centre` perpendicular to `direction`,
/// `σ = radius_mm / 2`, and `w` falls smoothly from 1 at the height of
/// `centre` to 0 at the chest wall: `w = smoothstep(z / centre.z)` clamped
/// to `[0, 1]`. So `centre` itself moves by exactly `depth_mm`, the chest
/// wall does not move, and points more than `3 · radius_mm` from the probe's
/// line move less than `depth_mm · e⁻¹⁸`. Meant for surface points; it is not
/// a solution of elasticity inside. A `centre` at or behind the chest wall,
/// or a non-positive radius, gives the identity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Indentation {
    /// Where the probe touches the skin.
    pub centre: Vec3,
    /// Direction of the push, into the breast: a unit vector (normalised on
    /// use; a zero or non-finite one gives the identity).
    pub direction: Vec3,
    /// How far `centre` moves, mm. Default 8.
    pub depth_mm: f32,
    /// Size of the dent: twice the Gaussian's standard deviation, mm. Default 20.
    pub radius_mm: f32,
}

impl Indentation {
    /// Default depth, mm.
    pub const DEFAULT_DEPTH_MM: f32 = 8.0;
    /// Default radius, mm.
    pub const DEFAULT_RADIUS_MM: f32 = 20.0;

    /// A default indentation of the skin above the default tumour.
    ///
    /// The probe touches `mesh` where the ray from
    /// [`TumourPhantom::default`]'s centre `(15, -10, 25)` towards `+z` leaves
    /// it, and pushes along the inward surface normal there; see
    /// [`Indentation::on_ray`].
    pub fn default_on(mesh: &SurfaceMesh) -> Option<Self> {
        Self::on_ray(
            mesh,
            TumourPhantom::default().centre,
            Vec3::Z,
            Self::DEFAULT_DEPTH_MM,
            Self::DEFAULT_RADIUS_MM,
        )
    }

    /// A probe pushing straight down (`-z`) at `mesh`'s highest vertex (the
    /// phantom's tip, 55 mm above its chest wall): with a depth near the
    /// height and a small radius, the deep, narrow indentation the solver
    /// tests use. `None` for a mesh without vertices.
    pub fn down_at_top(mesh: &SurfaceMesh, depth_mm: f32, radius_mm: f32) -> Option<Self> {
        let top = mesh
            .vertices
            .iter()
            .copied()
            .reduce(|a, b| if b.z > a.z { b } else { a })?;
        Some(Self {
            centre: top,
            direction: Vec3::NEG_Z,
            depth_mm,
            radius_mm,
        })
    }

    /// An indentation where the ray from `origin` along `ray` first crosses
    /// `mesh`, pushing along minus the outward normal there.
    ///
    /// The normal is interpolated (barycentrically) from area-weighted vertex
    /// normals, so it varies smoothly over the skin; where it vanishes the
    /// push goes along `-ray`. When the ray misses every triangle, the
    /// vertex nearest the ray (ahead of `origin`) is used instead. `None`
    /// when `ray` is zero or not finite, or when no vertex lies ahead of
    /// `origin`.
    pub fn on_ray(
        mesh: &SurfaceMesh,
        origin: Vec3,
        ray: Vec3,
        depth_mm: f32,
        radius_mm: f32,
    ) -> Option<Self> {
        let ray = ray.try_normalize()?;
        let normals = vertex_normals(mesh);
        let (centre, normal) = match first_hit(mesh, origin, ray) {
            Some((t, bary)) => {
                let [a, b, c] = mesh.triangles[t].map(|i| normals[i as usize]);
                (
                    mesh.point_on(t, bary),
                    a * bary[0] + b * bary[1] + c * bary[2],
                )
            }
            None => {
                let (i, v) = nearest_vertex_to_ray(mesh, origin, ray)?;
                (v, normals[i])
            }
        };
        let direction = (-normal).try_normalize().unwrap_or(-ray);
        Some(Self {
            centre,
            direction,
            depth_mm,
            radius_mm,
        })
    }

    /// Where the point `p` goes.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        let Some(direction) = self.direction.try_normalize() else {
            return p;
        };
        let sigma = 0.5 * self.radius_mm;
        if sigma.is_nan() || sigma <= 0.0 || self.centre.z.is_nan() || self.centre.z <= 0.0 {
            return p;
        }
        let offset = p - self.centre;
        let across = offset - offset.dot(direction) * direction;
        let gaussian = (-across.length_squared() / (2.0 * sigma * sigma)).exp();
        let t = (p.z / self.centre.z).clamp(0.0, 1.0);
        let chest_weight = t * t * (3.0 - 2.0 * t);
        p + self.depth_mm * gaussian * chest_weight * direction
    }
}

impl PointMap for Indentation {
    fn apply(&self, p: Vec3) -> Vec3 {
        Indentation::apply(self, p)
    }
}

/// Area-weighted vertex normals (sums of the incident triangles' cross
/// products), not normalised; zero for unused vertices.
pub fn vertex_normals(mesh: &SurfaceMesh) -> Vec<Vec3> {
    let mut normals = vec![DVec3::ZERO; mesh.vertices.len()];
    for (t, triangle) in mesh.triangles.iter().enumerate() {
        if triangle.iter().any(|&i| i as usize >= normals.len()) {
            continue;
        }
        let [a, b, c] = mesh.corners(t).map(Vec3::as_dvec3);
        let n = (b - a).cross(c - a);
        for &i in triangle {
            normals[i as usize] += n;
        }
    }
    normals.into_iter().map(DVec3::as_vec3).collect()
}

/// The triangle the ray `origin + s · ray` (`s > 0`) crosses first, and the
/// barycentric coordinates of the crossing (Möller–Trumbore, in f64).
fn first_hit(mesh: &SurfaceMesh, origin: Vec3, ray: Vec3) -> Option<(usize, [f32; 3])> {
    let (o, d) = (origin.as_dvec3(), ray.as_dvec3());
    let mut best: Option<(f64, usize, [f32; 3])> = None;
    for (t, triangle) in mesh.triangles.iter().enumerate() {
        if triangle.iter().any(|&i| i as usize >= mesh.vertices.len()) {
            continue;
        }
        let [a, b, c] = mesh.corners(t).map(Vec3::as_dvec3);
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 * e1.length_squared().max(e2.length_squared()) {
            continue;
        }
        let s = o - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let along = e2.dot(q) / det;
        let inside = u >= 0.0 && v >= 0.0 && u + v <= 1.0;
        if inside && along > 0.0 && best.is_none_or(|(nearest, ..)| along < nearest) {
            best = Some((along, t, [(1.0 - u - v) as f32, u as f32, v as f32]));
        }
    }
    best.map(|(_, t, bary)| (t, bary))
}

/// The vertex nearest the ray `origin + s · ray` among those with `s >= 0`.
fn nearest_vertex_to_ray(mesh: &SurfaceMesh, origin: Vec3, ray: Vec3) -> Option<(usize, Vec3)> {
    mesh.vertices
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| (*v - origin).dot(ray) >= 0.0)
        .map(|(i, v)| {
            let offset = v - origin;
            (i, v, (offset - offset.dot(ray) * ray).length_squared())
        })
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(i, v, _)| (i, v))
}

/// The default breast phantom sagging under [`Sag::default`]: 12 mm towards
/// the feet at the apex.
pub fn sagged_breast() -> SurfaceMesh {
    deform_surface(&default_breast(), &Sag::default())
}

/// The default breast phantom dented by [`Indentation::default_on`]: 8 mm
/// deep, 20 mm wide, above the default tumour.
pub fn indented_breast() -> SurfaceMesh {
    let breast = default_breast();
    // The ray from the default tumour's centre always leaves the default
    // breast through the skin; a mesh it missed would come back unchanged.
    match Indentation::default_on(&breast) {
        Some(indentation) => deform_surface(&breast, &indentation),
        None => breast,
    }
}

/// Why two surfaces cannot be blended ([`interpolate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum BlendError {
    /// The blend's parameter is NaN or infinite.
    #[error("interpolation parameter {0} is not finite")]
    NotFinite(f32),
    /// The surfaces have other vertex counts.
    #[error("vertex counts differ: {0} and {1}")]
    Vertices(usize, usize),
    /// The surfaces have other triangle counts.
    #[error("triangle counts differ: {0} and {1}")]
    Triangles(usize, usize),
    /// A triangle differs between the surfaces.
    #[error("triangle {index} differs: {from:?} and {to:?}")]
    Triangle {
        /// The triangle.
        index: usize,
        /// Its corners in the first surface.
        from: [u32; 3],
        /// Its corners in the second.
        to: [u32; 3],
    },
}

/// The vertex-wise linear blend `(1 - t) · from + t · to`.
///
/// Both meshes must have the same triangles (and so the same structure) and
/// the same number of vertices; `t = 0` gives `from` and `t = 1` gives `to`
/// exactly, and `t` outside `[0, 1]` extrapolates.
///
/// # Errors
///
/// Where the vertex counts, the triangle counts or the triangles differ,
/// or `t` is not finite.
pub fn interpolate(
    from: &SurfaceMesh,
    to: &SurfaceMesh,
    t: f32,
) -> Result<SurfaceMesh, BlendError> {
    if !t.is_finite() {
        return Err(BlendError::NotFinite(t));
    }
    if from.vertices.len() != to.vertices.len() {
        return Err(BlendError::Vertices(from.vertices.len(), to.vertices.len()));
    }
    if from.triangles.len() != to.triangles.len() {
        return Err(BlendError::Triangles(
            from.triangles.len(),
            to.triangles.len(),
        ));
    }
    if let Some(index) = (0..from.triangles.len()).find(|&i| from.triangles[i] != to.triangles[i]) {
        return Err(BlendError::Triangle {
            index,
            from: from.triangles[index],
            to: to.triangles[index],
        });
    }
    let vertices = from
        .vertices
        .iter()
        .zip(&to.vertices)
        .map(|(&a, &b)| a * (1.0 - t) + b * t)
        .collect();
    Ok(SurfaceMesh::new(vertices, from.triangles.clone()))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on a broken mesh")]

    use std::f32::consts::PI;

    use super::*;
    use crate::phantom::default_tumour;
    use crate::validate::validate;

    /// The deformed mesh is a valid closed outward surface with the rest
    /// mesh's triangles; returns its volume.
    fn assert_valid_deformation(rest: &SurfaceMesh, deformed: &SurfaceMesh, name: &str) -> f64 {
        assert_eq!(
            deformed.vertices.len(),
            rest.vertices.len(),
            "{name}: vertex count"
        );
        assert_eq!(deformed.triangles, rest.triangles, "{name}: triangles");
        let validation = validate(&mut deformed.clone())
            .unwrap_or_else(|e| panic!("{name}: deformed surface is invalid: {e}"));
        assert!(!validation.flipped, "{name}: deformed surface faces inward");
        assert!(
            validation.volume > 0.0,
            "{name}: volume {}",
            validation.volume
        );
        validation.volume
    }

    fn relative(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    fn apex(mesh: &SurfaceMesh) -> (usize, Vec3) {
        mesh.vertices
            .iter()
            .copied()
            .enumerate()
            .max_by(|a, b| a.1.z.total_cmp(&b.1.z))
            .unwrap()
    }

    fn example_rigid() -> Rigid {
        Rigid::about_axis(
            Vec3::new(1.0, -2.0, 0.5),
            0.7,
            Vec3::new(0.0, -8.0, 20.0),
            Vec3::new(12.0, -5.0, 3.0),
        )
    }

    #[test]
    fn rigid_preserves_pairwise_distances_and_volume() {
        let rigid = example_rigid();
        for (mesh, name) in [(default_tumour(), "tumour"), (default_breast(), "breast")] {
            let moved = deform_surface(&mesh, &rigid);
            let volume = assert_valid_deformation(&mesh, &moved, name);
            assert!(
                relative(volume, mesh.signed_volume()) < 1e-4,
                "{name}: volume {volume} vs {}",
                mesh.signed_volume()
            );
            // Every pair on the tumour; a stride through the breast's pairs.
            let n = mesh.vertices.len();
            let stride = if n > 1_000 { 7 } else { 1 };
            for i in 0..n {
                for j in (i + 1..n).step_by(stride) {
                    let before = mesh.vertices[i].distance(mesh.vertices[j]);
                    let after = moved.vertices[i].distance(moved.vertices[j]);
                    assert!(
                        (after - before).abs() <= 1e-4 * before,
                        "{name}: vertices {i}, {j}: {before} -> {after}"
                    );
                }
            }
        }
        // The centre turns onto itself and is then translated.
        let centre = rigid.apply(rigid.centre);
        assert!(centre.distance(rigid.centre + rigid.translation) < 1e-5);
    }

    #[test]
    fn rigid_about_a_zero_axis_only_translates() {
        let rigid = Rigid::about_axis(Vec3::ZERO, 1.0, Vec3::ONE, Vec3::X);
        assert_eq!(rigid.rotation, Quat::IDENTITY);
        assert_eq!(
            rigid.apply(Vec3::new(3.0, 4.0, 5.0)),
            Vec3::new(4.0, 4.0, 5.0)
        );
    }

    #[test]
    fn affine_scales_volume_by_the_determinant() {
        let affine = Affine {
            matrix: Mat3::from_cols(
                Vec3::new(1.1, 0.05, -0.02),
                Vec3::new(0.1, 0.9, 0.03),
                Vec3::new(-0.05, 0.08, 0.95),
            ),
            translation: Vec3::new(-3.0, 2.0, 1.0),
            centre: Vec3::new(0.0, -8.0, 20.0),
        };
        let det = f64::from(affine.matrix.determinant());
        for (mesh, name) in [(default_tumour(), "tumour"), (default_breast(), "breast")] {
            let deformed = deform_surface(&mesh, &affine);
            let volume = assert_valid_deformation(&mesh, &deformed, name);
            let expected = det * mesh.signed_volume();
            assert!(
                relative(volume, expected) < 1e-4,
                "{name}: volume {volume} vs det(A) · V = {expected}"
            );
        }
        assert!(
            affine
                .apply(affine.centre)
                .distance(affine.centre + affine.translation)
                < 1e-5
        );
    }

    #[test]
    fn twist_keeps_radius_and_axial_coordinate() {
        let twist = Twist {
            axis_origin: Vec3::new(0.0, -8.0, 0.0),
            axis: Vec3::Z,
            angle_per_length: PI / 4.0 / 55.0,
        };
        let mesh = default_breast();
        let twisted = deform_surface(&mesh, &twist);
        for (i, (&p, &q)) in mesh.vertices.iter().zip(&twisted.vertices).enumerate() {
            let (p0, q0) = (p - twist.axis_origin, q - twist.axis_origin);
            let (hp, hq) = (p0.dot(twist.axis), q0.dot(twist.axis));
            assert!((hp - hq).abs() < 1e-4, "vertex {i}: axial {hp} -> {hq}");
            let (rp, rq) = (p0.truncate().length(), q0.truncate().length());
            assert!((rp - rq).abs() < 1e-4, "vertex {i}: radius {rp} -> {rq}");
            // The turn is k · h, right-handed about +z.
            if rp > 1.0 {
                let turned = p0.truncate().angle_to(q0.truncate());
                let expected = twist.angle_per_length * hp;
                assert!(
                    (turned - expected).abs() < 1e-4,
                    "vertex {i}: turned {turned} rad, expected {expected}"
                );
            }
        }
        let volume = assert_valid_deformation(&mesh, &twisted, "twist");
        // Volume-preserving in the continuum; the chords of the turned
        // mesh differ from the exact image by O(edge² × curvature).
        assert!(
            relative(volume, mesh.signed_volume()) < 1e-3,
            "twist: volume {volume} vs {}",
            mesh.signed_volume()
        );
    }

    #[test]
    fn twist_with_zero_rate_is_identity_and_small_rate_is_linear_torsion() {
        let mesh = default_tumour();
        let still = Twist {
            axis_origin: Vec3::new(1.0, 2.0, 3.0),
            axis: Vec3::new(0.0, 0.6, 0.8),
            angle_per_length: 0.0,
        };
        for &p in &mesh.vertices {
            assert!(still.apply(p).distance(p) < 1e-5, "{p} moved");
        }
        // Linearised torsion about z: u = k z (-y, x, 0).
        let k = 1e-4;
        let twist = Twist {
            axis_origin: Vec3::ZERO,
            axis: Vec3::Z,
            angle_per_length: k,
        };
        for &p in &mesh.vertices {
            let u = twist.apply(p) - p;
            let linear = k * p.z * Vec3::new(-p.y, p.x, 0.0);
            // The rest is second order: (cos θ - 1) r ≈ θ² r / 2.
            let angle = k * p.z;
            let radius = p.truncate().length();
            assert!(
                u.distance(linear) < angle * angle * radius + 1e-5,
                "{p}: {u} vs {linear}"
            );
        }
    }

    #[test]
    fn sag_fixes_the_chest_wall_and_moves_the_apex_by_its_magnitude() {
        let sag = Sag::default();
        let rest = default_breast();
        let sagged = sagged_breast();
        for (i, (&p, &q)) in rest.vertices.iter().zip(&sagged.vertices).enumerate() {
            if p.z < 1.0 {
                assert!(p.distance(q) < 0.05, "vertex {i} at {p} moved to {q}");
            }
        }
        let (top, tip) = apex(&rest);
        let moved = sagged.vertices[top] - tip;
        assert!(
            (moved.length() - sag.magnitude_mm).abs() < 0.1 * sag.magnitude_mm,
            "apex moved {moved}"
        );
        assert!(
            moved.normalize().dot(Vec3::NEG_Y) > 0.99,
            "apex moved {moved}"
        );
        let volume = assert_valid_deformation(&rest, &sagged, "sag");
        assert!(
            relative(volume, rest.signed_volume()) < 1e-3,
            "sag: volume {volume} vs {}",
            rest.signed_volume()
        );
    }

    #[test]
    fn sag_into_the_chest_flattens_and_keeps_volume() {
        let rest = default_breast();
        let sag = Sag {
            direction: Vec3::new(0.0, -0.3, -1.0).normalize(),
            ..Sag::default()
        };
        let sagged = deform_surface(&rest, &sag);
        let volume = assert_valid_deformation(&rest, &sagged, "sag into the chest");
        assert!(
            relative(volume, rest.signed_volume()) < 5e-3,
            "volume {volume} vs {}",
            rest.signed_volume()
        );
        let (lo, hi) = rest.bounds().unwrap();
        let (slo, shi) = sagged.bounds().unwrap();
        assert!(
            shi.z < hi.z - 0.9 * 12.0 * 0.95,
            "height {} -> {}",
            hi.z,
            shi.z
        );
        assert!(shi.x - slo.x > hi.x - lo.x, "not wider: {slo} {shi}");
        for (&p, &q) in rest.vertices.iter().zip(&sagged.vertices) {
            if p.z < 1.0 {
                assert!(p.distance(q) < 0.05, "{p} moved to {q}");
            }
        }
    }

    #[test]
    fn indentation_dents_the_skin_above_the_tumour_only() {
        let rest = default_breast();
        let indentation = Indentation::default_on(&rest).unwrap();
        let tumour = TumourPhantom::default().centre;
        // On the skin, straight above the tumour.
        assert!(
            (indentation.centre.x - tumour.x).abs() < 1e-3
                && (indentation.centre.y - tumour.y).abs() < 1e-3
                && indentation.centre.z > 45.0,
            "centre {}",
            indentation.centre
        );
        assert!((indentation.direction.length() - 1.0).abs() < 1e-5);
        assert!(
            indentation.direction.z < -0.9,
            "direction {}",
            indentation.direction
        );
        let moved = indentation.apply(indentation.centre) - indentation.centre;
        assert!(
            (moved.dot(indentation.direction) - indentation.depth_mm).abs()
                < 0.05 * indentation.depth_mm,
            "centre moved {moved}"
        );
        assert!(
            moved.cross(indentation.direction).length() < 1e-3,
            "{moved}"
        );

        let indented = indented_breast();
        let mut nearest = f32::INFINITY;
        let mut nearest_moved = 0.0;
        for (i, (&p, &q)) in rest.vertices.iter().zip(&indented.vertices).enumerate() {
            let distance = p.distance(indentation.centre);
            if distance > 3.0 * indentation.radius_mm {
                assert!(p.distance(q) < 0.01, "far vertex {i} at {p} moved to {q}");
            }
            if p.z < 1e-6 {
                assert!(
                    p.distance(q) < 1e-6,
                    "chest-wall vertex {i} at {p} moved to {q}"
                );
            }
            if distance < nearest {
                nearest = distance;
                nearest_moved = p.distance(q);
            }
        }
        // The vertex nearest the probe goes most of the way.
        assert!(
            nearest_moved > 0.9 * indentation.depth_mm,
            "{nearest_moved} mm"
        );
        let volume = assert_valid_deformation(&rest, &indented, "indentation");
        assert!(
            volume < rest.signed_volume(),
            "a dent adds volume: {volume}"
        );
    }

    #[test]
    fn indentation_without_a_hit_uses_the_nearest_vertex() {
        let rest = default_tumour();
        // Above the tumour (it spans y in [-17, -3]), across it: no hit.
        let origin = Vec3::new(15.0, 20.0, 25.0);
        let indentation = Indentation::on_ray(&rest, origin, Vec3::X, 8.0, 20.0).unwrap();
        assert!(rest.vertices.contains(&indentation.centre));
        assert!(Indentation::on_ray(&rest, Vec3::splat(100.0), Vec3::ONE, 8.0, 20.0).is_none());
        assert!(Indentation::on_ray(&rest, origin, Vec3::ZERO, 8.0, 20.0).is_none());
        assert!(Indentation::default_on(&SurfaceMesh::default()).is_none());
    }

    #[test]
    fn interpolate_gives_the_endpoints_and_rejects_mismatches() {
        let rest = default_breast();
        let sagged = sagged_breast();
        assert_eq!(interpolate(&rest, &sagged, 0.0).unwrap(), rest);
        assert_eq!(interpolate(&rest, &sagged, 1.0).unwrap(), sagged);
        let half = interpolate(&rest, &sagged, 0.5).unwrap();
        let (top, tip) = apex(&rest);
        let moved = half.vertices[top].distance(tip);
        assert!((moved - 6.0).abs() < 0.1, "halfway apex moved {moved}");
        assert_valid_deformation(&rest, &half, "halfway");

        let tumour = default_tumour();
        assert!(interpolate(&rest, &tumour, 0.5).is_err());
        let mut fewer = sagged.clone();
        fewer.triangles.pop();
        assert!(interpolate(&rest, &fewer, 0.5).is_err());
        let mut rewired = sagged.clone();
        rewired.triangles[3].rotate_left(1);
        assert!(interpolate(&rest, &rewired, 0.5).is_err());
        let mut extra = sagged;
        extra.vertices.push(Vec3::ZERO);
        assert!(interpolate(&rest, &extra, 0.5).is_err());
        assert!(interpolate(&rest, &rest, f32::NAN).is_err());
    }
}
