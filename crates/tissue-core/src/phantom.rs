//! The bundled breast-like phantom, made by code.
//!
//! Two closed surfaces, in millimetres, in one frame: the chest wall is the
//! plane `z = 0`, `z` points away from the chest (anterior), `y` points up
//! (cranial) and `x` across the body.
//!
//! - [`breast`]: the skin dome and the flat chest wall behind it, one closed
//!   shell. The footprint on the chest wall is an ellipse (default 140 mm wide
//!   along `x`, 120 mm tall along `y`); the apex (nipple) sits `projection`
//!   (default 55 mm) in front of the chest wall and a little below the
//!   footprint's centre, and the lower pole is fuller than the upper one, as in
//!   a slightly pendulous breast. Skin and chest wall meet in a small rounding
//!   (default radius 4 mm) rather than a crease.
//! - [`tumour`]: an axis-aligned ellipsoid (a subdivided icosahedron, scaled),
//!   by default about 18 × 14 × 16 mm and well inside the default breast.
//!
//! Both meshes are closed and 2-manifold, with counter-clockwise triangles seen
//! from outside (positive [`SurfaceMesh::signed_volume`]); each vertex is used
//! once (the rim where the skin meets the chest wall is one shared ring).
//! Out-of-range parameters are clamped, never rejected, so every call returns
//! a valid mesh; each field's documentation says how it is clamped, and a
//! non-finite (NaN or infinite) value is replaced by the field's default.
//!
//! `cargo run --release -p tissue-cli -- phantom --output-dir assets`
//! regenerates `assets/phantom-breast.obj` and `assets/phantom-tumour.obj`.

use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, TAU};

use glam::{DVec2, DVec3, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::mesh::SurfaceMesh;

/// Fewest skin rings [`breast`] builds: lower values of
/// [`BreastPhantom::rings`] are raised to this.
pub const MIN_RINGS: u32 = 4;
/// Most skin rings [`breast`] builds (about 600,000 triangles): higher values are lowered to this.
pub const MAX_RINGS: u32 = 256;
/// Most subdivisions [`tumour`] applies (327,680 triangles): higher values are lowered to this.
pub const MAX_SUBDIVISIONS: u32 = 7;

/// Shortest length (mm) any size parameter is raised to, so no mesh collapses.
const MIN_LENGTH: f64 = 1.0;
/// Samples per meridian when placing skin rings at equal arc length.
const MERIDIAN_SAMPLES: usize = 128;
/// Directions sampled when measuring mean lengths and ring perimeters.
const PERIMETER_SAMPLES: usize = 96;

/// Shape and resolution of the breast phantom. All lengths in millimetres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BreastPhantom {
    /// Full width of the footprint ellipse along `x`: the widest outline of
    /// the skin, at the top of the rounding. Taken by magnitude and raised
    /// to at least 2 mm.
    pub base_width: f32,
    /// Full height of the footprint ellipse along `y`. Taken by magnitude and
    /// raised to at least 2 mm.
    pub base_height: f32,
    /// Height of the apex above the chest wall (`z`). Taken by magnitude and
    /// raised to at least 2 mm and to `rim_rounding` + 1 mm.
    pub projection: f32,
    /// Position of the apex over the chest wall, relative to the footprint's
    /// centre, `(x, y)`. A negative `y` makes the breast hang. Each component
    /// is clamped to ±40% of the footprint's semi-axis, keeping the apex well
    /// inside the footprint.
    pub apex_offset: Vec2,
    /// How much fuller the lower pole is than the upper one: the skin profile
    /// from apex to rim is `z ∝ sqrt(1 - s^k)` with `k = 2 + fullness * (-sin θ)`,
    /// so the lower pole (`k > 2`) stays high and turns down late while the
    /// upper pole (`k < 2`) slopes. 0 gives a half-ellipsoid-like dome.
    /// Clamped to `[-0.9, 0.9]`, so `k >= 1.1` and every meridian stays concave.
    pub lower_pole_fullness: f32,
    /// Radius of the rounding where the skin meets the chest wall; 0 leaves a
    /// right-angled crease. Clamped to `[0, 40%]` of the smaller of the
    /// projection and the footprint's smaller semi-axis.
    pub rim_rounding: f32,
    /// Resolution: rings of vertices on the skin from the apex to the rim.
    /// Everything else (vertices per ring, rounding and chest-wall rings) is
    /// spaced to match, so triangles are near-equilateral and the count grows
    /// as about `9 * rings^2` (default 25 rings: 5,610 triangles). Clamped
    /// to [`MIN_RINGS`]`..=`[`MAX_RINGS`].
    pub rings: u32,
}

impl Default for BreastPhantom {
    /// An adult breast of about 495 ml: 2,807 vertices, 5,610 triangles.
    fn default() -> Self {
        Self {
            base_width: 140.0,
            base_height: 120.0,
            projection: 55.0,
            apex_offset: Vec2::new(0.0, -8.0),
            lower_pole_fullness: 0.5,
            rim_rounding: 4.0,
            rings: 25,
        }
    }
}

impl BreastPhantom {
    /// A copy with every non-finite field replaced by its default.
    fn finite(&self) -> Self {
        let d = Self::default();
        let scalar = |value: f32, default: f32| if value.is_finite() { value } else { default };
        Self {
            base_width: scalar(self.base_width, d.base_width),
            base_height: scalar(self.base_height, d.base_height),
            projection: scalar(self.projection, d.projection),
            apex_offset: Vec2::select(
                self.apex_offset.is_finite_mask(),
                self.apex_offset,
                d.apex_offset,
            ),
            lower_pole_fullness: scalar(self.lower_pole_fullness, d.lower_pole_fullness),
            rim_rounding: scalar(self.rim_rounding, d.rim_rounding),
            rings: self.rings,
        }
    }
}

/// `value` with each non-finite component replaced by that of `default`.
fn finite_or(value: Vec3, default: Vec3) -> Vec3 {
    Vec3::select(value.is_finite_mask(), value, default)
}

/// Position, size and resolution of the ellipsoidal tumour. Lengths in millimetres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TumourPhantom {
    /// Centre of the ellipsoid.
    pub centre: Vec3,
    /// Semi-axes along `x`, `y`, `z`. Taken by magnitude and each raised to
    /// at least 0.01 mm.
    pub radii: Vec3,
    /// Times each triangle of the starting icosahedron is split in four:
    /// `20 * 4^subdivisions` triangles. 0 is a (valid) icosahedron; lowered
    /// to [`MAX_SUBDIVISIONS`].
    pub subdivisions: u32,
}

impl Default for TumourPhantom {
    /// A 9 × 7 × 8 mm (semi-axes) ellipsoid below and to the `+x` side of the
    /// default breast's apex, 17 mm from the chest wall and 20 mm from the
    /// skin at the closest; 642 vertices, 1,280 triangles.
    fn default() -> Self {
        Self {
            centre: Vec3::new(15.0, -10.0, 25.0),
            radii: Vec3::new(9.0, 7.0, 8.0),
            subdivisions: 3,
        }
    }
}

/// The breast phantom with default parameters.
pub fn default_breast() -> SurfaceMesh {
    breast(&BreastPhantom::default())
}

/// The tumour phantom with default parameters.
pub fn default_tumour() -> SurfaceMesh {
    tumour(&TumourPhantom::default())
}

/// The breast: skin dome and chest wall as one closed, outward-facing shell.
///
/// The surface is a stack of rings swept around the apex, from the apex down
/// the skin, through the rounding, and across the chest wall to a centre
/// vertex behind the apex. Consecutive rings are stitched by angle, so rings
/// may have different vertex counts (few near the poles, more at the rim).
pub fn breast(params: &BreastPhantom) -> SurfaceMesh {
    let shape = Shape::from_params(params);
    let rings = shape.ring_layout(params.rings.clamp(MIN_RINGS, MAX_RINGS));

    let mut vertices = vec![shape.apex()];
    let mut ring_indices: Vec<Vec<u32>> = Vec::with_capacity(rings.len());
    for ring in &rings {
        let start = vertices.len() as u32;
        vertices.extend(
            (0..ring.count).map(|j| shape.point(ring.place, TAU * j as f64 / ring.count as f64)),
        );
        ring_indices.push((start..vertices.len() as u32).collect());
    }
    let centre = vertices.len() as u32;
    vertices.push(shape.chest_centre());

    let mut triangles = Vec::new();
    if let (Some(first), Some(last)) = (ring_indices.first(), ring_indices.last()) {
        fan_from_pole(0, first, &mut triangles);
        for pair in ring_indices.windows(2) {
            stitch(&pair[0], &pair[1], &mut triangles);
        }
        fan_to_pole(last, centre, &mut triangles);
    }
    SurfaceMesh::new(
        vertices.into_iter().map(|v| v.as_vec3()).collect(),
        triangles,
    )
}

/// The tumour: a closed, outward-facing ellipsoid.
///
/// A unit icosahedron is subdivided (new vertices pushed onto the unit
/// sphere), then scaled by the radii and moved to the centre. Scaling keeps
/// the ratio of mesh volume to true volume of the sphere, about 0.99 at three
/// subdivisions.
pub fn tumour(params: &TumourPhantom) -> SurfaceMesh {
    let defaults = TumourPhantom::default();
    let radii = finite_or(params.radii, defaults.radii)
        .abs()
        .max(Vec3::splat(0.01))
        .as_dvec3();
    let centre = finite_or(params.centre, defaults.centre).as_dvec3();
    let (unit, triangles) = icosphere(params.subdivisions.min(MAX_SUBDIVISIONS));
    let vertices = unit
        .into_iter()
        .map(|v| (centre + v * radii).as_vec3())
        .collect();
    SurfaceMesh::new(vertices, triangles)
}

/// The breast's shape in double precision, after clamping.
#[derive(Debug, Clone, Copy)]
struct Shape {
    /// Footprint semi-axes `(x, y)`.
    semi_axes: DVec2,
    /// Apex height `H`.
    projection: f64,
    /// Where the apex stands over the chest wall; every ring is swept around it.
    apex_foot: DVec2,
    fullness: f64,
    /// Rounding radius `r`.
    rounding: f64,
}

/// Where a ring lies on the profile that every ray sweeps.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Place {
    /// On the skin, at this fraction of the meridian's arc length from the apex.
    Skin(f64),
    /// On the rounding, at this angle from its top (0) to the chest wall (π/2).
    Rounding(f64),
    /// On the chest wall, at this fraction of the way from the rim to the centre.
    ChestWall(f64),
}

/// One ring of the breast mesh: where it is and how many vertices it has.
#[derive(Debug, Clone, Copy)]
struct Ring {
    place: Place,
    count: usize,
}

/// The half-line in the chest wall from the apex's foot through the footprint
/// ellipse's point at parameter angle `θ`; its vertical half-plane holds that
/// direction's profile curve.
#[derive(Debug, Clone, Copy)]
struct Ray {
    direction: DVec2,
    /// Distance from the apex's foot to the footprint ellipse, `L`.
    length: f64,
    /// Exponent `k` of the skin profile `sqrt(1 - s^k)`.
    exponent: f64,
}

impl Shape {
    fn from_params(p: &BreastPhantom) -> Self {
        let p = p.finite();
        let semi_axes = DVec2::new(f64::from(p.base_width), f64::from(p.base_height))
            .abs()
            .max(DVec2::splat(2.0 * MIN_LENGTH))
            * 0.5;
        let mut projection = f64::from(p.projection).abs().max(2.0 * MIN_LENGTH);
        let rounding_limit = 0.4 * projection.min(semi_axes.min_element());
        let rounding = f64::from(p.rim_rounding).clamp(0.0, rounding_limit);
        // The dome proper must rise above the rounding.
        projection = projection.max(rounding + MIN_LENGTH);
        let apex_limit = 0.4 * semi_axes;
        let apex_foot = p.apex_offset.as_dvec2().clamp(-apex_limit, apex_limit);
        Self {
            semi_axes,
            projection,
            apex_foot,
            fullness: f64::from(p.lower_pole_fullness).clamp(-0.9, 0.9),
            rounding,
        }
    }

    fn apex(&self) -> DVec3 {
        self.apex_foot.extend(self.projection)
    }

    fn chest_centre(&self) -> DVec3 {
        self.apex_foot.extend(0.0)
    }

    fn ray(&self, theta: f64) -> Ray {
        let rim = DVec2::new(theta.cos(), theta.sin()) * self.semi_axes;
        let to_rim = rim - self.apex_foot;
        let length = to_rim.length();
        Ray {
            direction: to_rim / length,
            length,
            exponent: 2.0 - self.fullness * theta.sin(),
        }
    }

    /// The skin profile of `ray` at angle parameter `phi` in `[0, π/2]`:
    /// `(d, z)` with `d = L s`, `s^k = sin²φ` and `z = r + (H - r) cos φ`,
    /// which is `z = r + (H - r) sqrt(1 - s^k)` without the infinite slope of
    /// that form at the rim.
    fn skin_profile(&self, ray: &Ray, phi: f64) -> DVec2 {
        let s = phi.sin().powf(2.0 / ray.exponent);
        DVec2::new(
            ray.length * s,
            self.rounding + (self.projection - self.rounding) * phi.cos(),
        )
    }

    /// The angle parameter `φ` at `fraction` of the skin meridian's arc length:
    /// equal spacing along the skin keeps triangles near-equilateral on the
    /// steep sides as well as on the top.
    fn skin_phi(&self, ray: &Ray, fraction: f64) -> f64 {
        let step = FRAC_PI_2 / MERIDIAN_SAMPLES as f64;
        let mut cumulative = Vec::with_capacity(MERIDIAN_SAMPLES + 1);
        cumulative.push(0.0);
        let mut previous = self.skin_profile(ray, 0.0);
        for i in 1..=MERIDIAN_SAMPLES {
            let next = self.skin_profile(ray, step * i as f64);
            cumulative.push(cumulative[i - 1] + previous.distance(next));
            previous = next;
        }
        let target = fraction.clamp(0.0, 1.0) * cumulative[MERIDIAN_SAMPLES];
        let i = cumulative
            .partition_point(|&c| c < target)
            .clamp(1, MERIDIAN_SAMPLES);
        let span = cumulative[i] - cumulative[i - 1];
        let within = if span > 0.0 {
            (target - cumulative[i - 1]) / span
        } else {
            0.0
        };
        step * (i as f64 - 1.0 + within)
    }

    fn skin_meridian_length(&self, ray: &Ray) -> f64 {
        let step = FRAC_PI_2 / MERIDIAN_SAMPLES as f64;
        (1..=MERIDIAN_SAMPLES)
            .map(|i| {
                let a = self.skin_profile(ray, step * (i - 1) as f64);
                a.distance(self.skin_profile(ray, step * i as f64))
            })
            .sum()
    }

    /// The point of the ring at `place` in direction `theta`.
    fn point(&self, place: Place, theta: f64) -> DVec3 {
        let ray = self.ray(theta);
        let r = self.rounding;
        let (d, z) = match place {
            Place::Skin(fraction) => {
                let profile = self.skin_profile(&ray, self.skin_phi(&ray, fraction));
                (profile.x, profile.y)
            }
            // Quarter circle centred at (L - r, r), tangent to the vertical
            // skin at its top and to the chest wall at its bottom.
            Place::Rounding(psi) => (ray.length - r + r * psi.cos(), r - r * psi.sin()),
            Place::ChestWall(fraction) => ((ray.length - r) * (1.0 - fraction), 0.0),
        };
        (self.apex_foot + ray.direction * d).extend(z)
    }

    /// Mean over directions of `f(ray)`.
    fn mean_over_rays(&self, f: impl Fn(&Ray) -> f64) -> f64 {
        let sum: f64 = (0..PERIMETER_SAMPLES)
            .map(|j| f(&self.ray(TAU * j as f64 / PERIMETER_SAMPLES as f64)))
            .sum();
        sum / PERIMETER_SAMPLES as f64
    }

    fn perimeter(&self, place: Place) -> f64 {
        let points: Vec<DVec3> = (0..PERIMETER_SAMPLES)
            .map(|j| self.point(place, TAU * j as f64 / PERIMETER_SAMPLES as f64))
            .collect();
        (0..points.len())
            .map(|j| points[j].distance(points[(j + 1) % points.len()]))
            .sum()
    }

    /// Rings from the apex to the chest-wall centre (poles excluded), spaced
    /// about one target edge length `h` apart, each with about
    /// `perimeter / h` vertices. The rim where skin (or rounding) meets the
    /// chest wall is the single ring `Rounding(π/2)` (or `Skin(1)` without a
    /// rounding), so the two parts share its vertices.
    fn ring_layout(&self, skin_rings: u32) -> Vec<Ring> {
        let edge =
            self.mean_over_rays(|ray| self.skin_meridian_length(ray)) / f64::from(skin_rings);
        let rounding_rings = if self.rounding > 0.0 {
            ((self.rounding * FRAC_PI_2 / edge).round() as u32).max(1)
        } else {
            0
        };
        let wall_span = self.mean_over_rays(|ray| ray.length - self.rounding);
        // At least one ring between rim and centre, so the centre fan is not a
        // spray of slivers reaching across the whole chest wall.
        let wall_rings = ((wall_span / edge).round() as u32).max(2);

        let places = (1..=skin_rings)
            .map(|i| Place::Skin(f64::from(i) / f64::from(skin_rings)))
            .chain(
                (1..=rounding_rings)
                    .map(|i| Place::Rounding(FRAC_PI_2 * f64::from(i) / f64::from(rounding_rings))),
            )
            .chain((1..wall_rings).map(|i| Place::ChestWall(f64::from(i) / f64::from(wall_rings))));
        places
            .map(|place| Ring {
                place,
                count: ((self.perimeter(place) / edge).round() as usize).max(6),
            })
            .collect()
    }
}

/// Triangles from a pole vertex to the first ring (`[pole, ring j, ring j+1]`).
fn fan_from_pole(pole: u32, ring: &[u32], triangles: &mut Vec<[u32; 3]>) {
    for j in 0..ring.len() {
        triangles.push([pole, ring[j], ring[(j + 1) % ring.len()]]);
    }
}

/// Triangles from the last ring to a pole vertex, wound as the band before it.
fn fan_to_pole(ring: &[u32], pole: u32, triangles: &mut Vec<[u32; 3]>) {
    for j in 0..ring.len() {
        triangles.push([ring[j], pole, ring[(j + 1) % ring.len()]]);
    }
}

/// Triangulates the band between two consecutive rings, `inner` being the
/// one met first walking from the apex. Both rings start at angle 0 and go
/// counter-clockwise (seen from the apex side); each step advances on the
/// ring whose next vertex comes first in angle, comparing `(i+1)/n_inner`
/// with `(j+1)/n_outer` in integers so ties are exact. Gives
/// `n_inner + n_outer` triangles and uses every ring edge once.
fn stitch(inner: &[u32], outer: &[u32], triangles: &mut Vec<[u32; 3]>) {
    let (n_inner, n_outer) = (inner.len(), outer.len());
    let (mut i, mut j) = (0, 0);
    while i < n_inner || j < n_outer {
        let outer_first = j < n_outer && (i == n_inner || (j + 1) * n_inner <= (i + 1) * n_outer);
        if outer_first {
            triangles.push([inner[i % n_inner], outer[j], outer[(j + 1) % n_outer]]);
            j += 1;
        } else {
            triangles.push([inner[i], outer[j % n_outer], inner[(i + 1) % n_inner]]);
            i += 1;
        }
    }
}

/// A unit icosphere: vertices on the unit sphere and outward triangles.
fn icosphere(subdivisions: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<DVec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .into_iter()
    .map(|v| DVec3::from_array(v).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        // Each edge is split once, shared by its two triangles.
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, vertices: &mut Vec<DVec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push((vertices[a as usize] + vertices[b as usize]).normalize());
                vertices.len() as u32 - 1
            })
        };
        let mut finer = Vec::with_capacity(triangles.len() * 4);
        for [a, b, c] in triangles {
            let ab = midpoint(a, b, &mut vertices);
            let bc = midpoint(b, c, &mut vertices);
            let ca = midpoint(c, a, &mut vertices);
            finer.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = finer;
    }
    (vertices, triangles)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests fail loudly on a broken mesh")]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    /// Fails unless every directed edge appears once and its reverse once:
    /// closed, 2-manifold along edges and consistently oriented.
    fn assert_closed_and_oriented(mesh: &SurfaceMesh, name: &str) {
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for [a, b, c] in mesh.triangles.iter().copied() {
            for edge in [(a, b), (b, c), (c, a)] {
                *directed.entry(edge).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(
                count, 1,
                "{name}: directed edge {a}->{b} used {count} times"
            );
            let reverse = directed.get(&(b, a)).copied().unwrap_or(0);
            assert_eq!(
                reverse, 1,
                "{name}: edge {a}->{b} has {reverse} reverse edges"
            );
        }
        // Euler characteristic of a sphere: one shell, no handles.
        let euler =
            mesh.vertices.len() as i64 - (directed.len() / 2) as i64 + mesh.triangles.len() as i64;
        assert_eq!(euler, 2, "{name}: Euler characteristic");
        let used: std::collections::HashSet<u32> =
            mesh.triangles.iter().flatten().copied().collect();
        assert_eq!(used.len(), mesh.vertices.len(), "{name}: unused vertices");
    }

    fn triangle_areas(mesh: &SurfaceMesh) -> Vec<f64> {
        (0..mesh.triangles.len())
            .map(|t| {
                let [a, b, c] = mesh.corners(t).map(|v| v.as_dvec3());
                0.5 * (b - a).cross(c - a).length()
            })
            .collect()
    }

    /// Smallest interior angle of any triangle, in degrees.
    fn min_angle_degrees(mesh: &SurfaceMesh) -> f64 {
        (0..mesh.triangles.len())
            .flat_map(|t| {
                let p = mesh.corners(t).map(|v| v.as_dvec3());
                (0..3).map(move |k| {
                    let (a, b, c) = (p[k], p[(k + 1) % 3], p[(k + 2) % 3]);
                    (b - a).angle_between(c - a).to_degrees()
                })
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn assert_well_shaped(mesh: &SurfaceMesh, name: &str, min_ratio: f64, min_angle: f64) {
        let areas = triangle_areas(mesh);
        let smallest = areas.iter().copied().fold(f64::INFINITY, f64::min);
        let largest = areas.iter().copied().fold(0.0, f64::max);
        assert!(
            smallest / largest > min_ratio,
            "{name}: min/max triangle area {smallest}/{largest} <= {min_ratio}"
        );
        let angle = min_angle_degrees(mesh);
        assert!(
            angle > min_angle,
            "{name}: smallest angle {angle}° <= {min_angle}°"
        );
    }

    fn assert_no_duplicate_vertices(mesh: &SurfaceMesh, name: &str) {
        let v = &mesh.vertices;
        for i in 0..v.len() {
            for j in i + 1..v.len() {
                let d = v[i].distance(v[j]);
                assert!(
                    d > 1e-3,
                    "{name}: vertices {i} and {j} are {d} mm apart, at {}",
                    v[i]
                );
            }
        }
    }

    /// Distance from `p` to the surface, by parry (an independent oracle).
    fn distance_to_surface(mesh: &parry3d::shape::TriMesh, p: Vec3) -> f32 {
        use parry3d::query::PointQuery;
        let projection = mesh.project_local_point(p, false);
        projection.point.distance(p)
    }

    fn parry_mesh(mesh: &SurfaceMesh) -> parry3d::shape::TriMesh {
        parry3d::shape::TriMesh::new(mesh.vertices.clone(), mesh.triangles.clone()).unwrap()
    }

    /// `∫_0^1 s sqrt(1 - s^k) ds`, substituting `s^k = sin²φ` to remove the
    /// square-root end point (midpoint rule).
    fn profile_moment(k: f64) -> f64 {
        let n = 2_000;
        let h = FRAC_PI_2 / n as f64;
        (0..n)
            .map(|i| {
                let phi = (i as f64 + 0.5) * h;
                (2.0 / k) * phi.sin().powf(4.0 / k - 1.0) * phi.cos().powi(2) * h
            })
            .sum()
    }

    /// Volume of the smooth breast, independent of the mesh: sweeping the
    /// profile region of each ray around the apex's foot `c`, the map
    /// `(d, θ) -> c + d (e(θ) - c) / L` has Jacobian `d |(e - c) × e'| / L²`,
    /// so `V = ∫ |(e - c) × e'| / L² · ∫∫_region d dd dz dθ`. The region is
    /// the area under `z = r + (H - r) sqrt(1 - (d/L)^k)` less the corner
    /// that the rounding cuts (square minus quarter disk).
    fn analytic_breast_volume(params: &BreastPhantom) -> f64 {
        let shape = Shape::from_params(params);
        let (h, r) = (shape.projection, shape.rounding);
        let n = 1_000;
        (0..n)
            .map(|i| {
                let theta = TAU * (i as f64 + 0.5) / n as f64;
                let ray = shape.ray(theta);
                let l = ray.length;
                let rim = DVec2::new(theta.cos(), theta.sin()) * shape.semi_axes;
                let tangent = DVec2::new(-theta.sin(), theta.cos()) * shape.semi_axes;
                let jacobian = (rim - shape.apex_foot).perp_dot(tangent).abs() / (l * l);
                let under_profile =
                    r * l * l / 2.0 + (h - r) * l * l * profile_moment(ray.exponent);
                let corner =
                    r * r * (l - r / 2.0) - PI * r * r / 4.0 * (l - r + 4.0 * r / (3.0 * PI));
                jacobian * (under_profile - corner) * TAU / n as f64
            })
            .sum()
    }

    #[test]
    fn default_breast_is_closed_oriented_and_outward() {
        let mesh = default_breast();
        assert_closed_and_oriented(&mesh, "breast");
        assert!(
            mesh.signed_volume() > 0.0,
            "breast volume {}",
            mesh.signed_volume()
        );
    }

    #[test]
    fn default_tumour_is_closed_oriented_and_outward() {
        let mesh = default_tumour();
        assert_closed_and_oriented(&mesh, "tumour");
        assert!(
            mesh.signed_volume() > 0.0,
            "tumour volume {}",
            mesh.signed_volume()
        );
    }

    #[test]
    fn triangles_are_well_shaped() {
        // Thresholds sit below the measured values (breast 0.47 and 22.7°,
        // tumour 0.62 and 43.8°) with room for parameter tweaks.
        assert_well_shaped(&default_breast(), "breast", 0.2, 20.0);
        assert_well_shaped(&default_tumour(), "tumour", 0.4, 35.0);
    }

    #[test]
    fn vertices_are_distinct() {
        assert_no_duplicate_vertices(&default_breast(), "breast");
        assert_no_duplicate_vertices(&default_tumour(), "tumour");
    }

    #[test]
    fn default_breast_has_documented_size() {
        let mesh = default_breast();
        let triangles = mesh.triangles.len();
        assert!(
            (4_000..=8_000).contains(&triangles),
            "{triangles} triangles"
        );
        let (lo, hi) = mesh.bounds().unwrap();
        let size = hi - lo;
        assert!((size.x - 140.0).abs() < 0.5, "width {}", size.x);
        assert!((size.y - 120.0).abs() < 0.5, "height {}", size.y);
        assert!((size.z - 55.0).abs() < 1e-3, "projection {}", size.z);
        assert!(lo.z.abs() < 1e-6, "chest wall at z = {}", lo.z);
        // The apex hangs below the footprint's centre.
        let apex = mesh
            .vertices
            .iter()
            .copied()
            .max_by(|a, b| a.z.total_cmp(&b.z))
            .unwrap();
        assert!((apex.y - -8.0).abs() < 1e-4, "apex at {apex}");
    }

    #[test]
    fn breast_volume_matches_the_smooth_shape() {
        // The mesh is inscribed in a (nearly) convex surface, so it is a
        // little smaller than the smooth shape, by O(edge² × curvature):
        // measured -0.26% at the default 25 rings and -0.03% at 80.
        let params = BreastPhantom::default();
        let exact = analytic_breast_volume(&params);
        let coarse = breast(&params).signed_volume();
        let fine = breast(&BreastPhantom {
            rings: 80,
            ..params
        })
        .signed_volume();
        assert!(
            (400_000.0..560_000.0).contains(&exact),
            "analytic volume {exact} mm³"
        );
        let coarse_error = (coarse - exact) / exact;
        let fine_error = (fine - exact) / exact;
        assert!(
            (-0.01..0.0).contains(&coarse_error),
            "default: {coarse} vs {exact} mm³"
        );
        assert!(
            (-0.001..0.0).contains(&fine_error),
            "80 rings: {fine} vs {exact} mm³"
        );
    }

    #[test]
    fn breast_volume_matches_without_rounding_or_asymmetry() {
        // A centred half-ellipsoid: V = 2/3 π a b H exactly.
        let params = BreastPhantom {
            apex_offset: Vec2::ZERO,
            lower_pole_fullness: 0.0,
            rim_rounding: 0.0,
            rings: 80,
            ..BreastPhantom::default()
        };
        let exact = 2.0 / 3.0 * PI * 70.0 * 60.0 * 55.0;
        assert!((analytic_breast_volume(&params) - exact).abs() / exact < 1e-6);
        let mesh = breast(&params);
        assert_closed_and_oriented(&mesh, "half-ellipsoid");
        let error = (mesh.signed_volume() - exact) / exact;
        assert!(
            (-0.001..0.0).contains(&error),
            "{} vs {exact} mm³",
            mesh.signed_volume()
        );
    }

    #[test]
    fn tumour_volume_is_within_two_percent_of_the_ellipsoid() {
        let params = TumourPhantom::default();
        let exact = 4.0 / 3.0 * PI * 9.0 * 7.0 * 8.0;
        let volume = default_tumour().signed_volume();
        assert!(
            (volume - exact).abs() / exact < 0.02,
            "{volume} vs {exact} mm³"
        );
        let (lo, hi) = default_tumour().bounds().unwrap();
        assert!(((lo + hi) / 2.0).distance(params.centre) < 0.01);
        assert!(((hi - lo) / 2.0).distance(params.radii) < 0.01);
    }

    #[test]
    fn default_tumour_is_inside_the_breast_with_a_margin() {
        let breast = default_breast();
        let surface = parry_mesh(&breast);
        let tumour = default_tumour();
        let mut nearest = f32::INFINITY;
        for &v in &tumour.vertices {
            let winding = breast.winding_number(v);
            assert!(
                (winding - 1.0).abs() < 1e-6,
                "tumour vertex {v}: winding number {winding}"
            );
            nearest = nearest.min(distance_to_surface(&surface, v));
        }
        assert!(
            nearest > 10.0,
            "tumour comes within {nearest} mm of the breast surface"
        );
        // The winding number is not trivially 1: it is 0 just outside the skin.
        assert!(breast.winding_number(Vec3::new(0.0, -8.0, 55.5)).abs() < 1e-6);
        assert!(breast.winding_number(Vec3::new(0.0, -8.0, -0.5)).abs() < 1e-6);
    }

    #[test]
    fn too_few_rings_are_clamped() {
        let minimum = breast(&BreastPhantom {
            rings: MIN_RINGS,
            ..BreastPhantom::default()
        });
        for rings in [0, 1, MIN_RINGS - 1] {
            let mesh = breast(&BreastPhantom {
                rings,
                ..BreastPhantom::default()
            });
            assert_eq!(mesh, minimum, "rings = {rings}");
        }
        assert_closed_and_oriented(&minimum, "4 rings");
        assert_no_duplicate_vertices(&minimum, "4 rings");
        assert!(minimum.signed_volume() > 0.0);
        assert_well_shaped(&minimum, "4 rings", 0.01, 10.0);
    }

    #[test]
    fn extreme_parameters_still_give_a_closed_outward_mesh() {
        let cases = [
            BreastPhantom {
                base_width: 0.0,
                base_height: -5.0,
                projection: 0.0,
                ..BreastPhantom::default()
            },
            BreastPhantom {
                apex_offset: Vec2::new(500.0, -500.0),
                lower_pole_fullness: 9.0,
                ..BreastPhantom::default()
            },
            BreastPhantom {
                rim_rounding: 1_000.0,
                lower_pole_fullness: -9.0,
                ..BreastPhantom::default()
            },
            BreastPhantom {
                rim_rounding: -1.0,
                rings: 7,
                ..BreastPhantom::default()
            },
            BreastPhantom {
                base_width: f32::NAN,
                projection: f32::INFINITY,
                apex_offset: Vec2::new(f32::NAN, 3.0),
                lower_pole_fullness: f32::NEG_INFINITY,
                rim_rounding: f32::NAN,
                ..BreastPhantom::default()
            },
        ];
        for (i, params) in cases.iter().enumerate() {
            let mesh = breast(params);
            let name = format!("case {i}");
            assert_closed_and_oriented(&mesh, &name);
            assert_no_duplicate_vertices(&mesh, &name);
            assert!(
                mesh.signed_volume() > 0.0,
                "{name}: volume {}",
                mesh.signed_volume()
            );
            assert!(
                triangle_areas(&mesh).iter().all(|&a| a > 1e-6),
                "{name}: degenerate triangle"
            );
        }
    }

    #[test]
    fn tumour_subdivisions_and_radii_are_clamped() {
        let icosahedron = tumour(&TumourPhantom {
            subdivisions: 0,
            ..TumourPhantom::default()
        });
        assert_eq!(icosahedron.triangles.len(), 20);
        assert_closed_and_oriented(&icosahedron, "icosahedron");
        let flat = tumour(&TumourPhantom {
            radii: Vec3::new(-3.0, 0.0, 2.0),
            subdivisions: 1,
            ..TumourPhantom::default()
        });
        assert_closed_and_oriented(&flat, "flat");
        assert!(flat.signed_volume() > 0.0);
        let broken = tumour(&TumourPhantom {
            centre: Vec3::new(f32::NAN, 0.0, 0.0),
            radii: Vec3::new(1.0, f32::INFINITY, 1.0),
            subdivisions: 2,
        });
        assert!(broken.vertices.iter().all(|v| v.is_finite()));
        assert!(broken.signed_volume() > 0.0);
        assert_eq!(default_tumour().triangles.len(), 1_280);
        assert_eq!(default_tumour().vertices.len(), 642);
    }
}
