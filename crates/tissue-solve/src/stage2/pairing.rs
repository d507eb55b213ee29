//! The observation's pairing inside the solve, written once for every
//! device: at the start of each of the elastic force's iterations every
//! free skin particle is paired with its nearest point of the observation
//! (a surface's, or a point cloud's, on a `SurfaceField` the device holds)
//! and its spring ([`crate::stage2::springs`]) set there with the
//! curvature of half its squared distance: a face's or a cloud's plane,
//! an edge's line, a vertex's point ([`Pass::Pair`](crate::stage2::Pass::Pair)).
//! The springs follow the skin as it slides, so the solve ends where the
//! skin lies on the observation and the mechanics decides where along it
//! (docs/METHOD.md, "Observations without correspondence").

use glam::Vec3;
use rayon::prelude::*;
use tissue_core::field::SurfaceField;

use crate::stage2::springs::Spring;

/// A cloud's plane at a particle is smoothed over its points within three
/// of this many spacings of it, each weighted by `exp(-r^2 / h^2)` with
/// `h` this many spacings ([`SurfaceField::smooth_plane`], [`PairingRule::smooth`]):
/// the nearest point's own plane jumps as the nearest point changes, and
/// the solve steps back at every jump. On the shared cases' clouds at
/// 10,000 particles: 261 / 275 / 221 iterations against 1,254 / 1,227 /
/// 1,089, every stage converged to the tolerance, probes and tumour centre
/// as close or closer (docs/METHOD.md, "Observations without
/// correspondence").
pub const CLOUD_SMOOTHING: f32 = 1.0;

/// A pairing limit that sets nothing aside (`f32::MAX`: a device's
/// buffers hold it as it is).
pub const NO_LIMIT: f32 = f32::MAX;

/// How a particle is paired with its nearest observed point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairingRule {
    /// The springs' weight, in the connection Laplacian's units (as
    /// [`spring`]'s).
    pub weight: f32,
    /// For a point cloud: a particle farther than this along the cloud's
    /// plane from its nearest point is past the cloud's edge (or over a
    /// hole in it) and is not pulled. [`NO_LIMIT`] for a surface.
    pub edge: f32,
    /// The robust scale `s` (Huber's): a particle farther than this from
    /// the observation (for a cloud, across its plane) is pulled with the
    /// force it would have at this distance, and the potential grows in
    /// proportion to its distance beyond rather than its square
    /// ([`paired_spring`]): skin that has far to go is pulled all the way,
    /// an outlier's pair moves the skin by about `s` at most. [`NO_LIMIT`]:
    /// every pair is pulled in proportion to its distance.
    pub robust: f32,
    /// Whether the observation is a point cloud: its points' fitted
    /// normals give the planes. A surface's plane is the one across the
    /// direction to the nearest point (the distance's gradient).
    pub cloud: bool,
    /// For a point cloud, the radius `h` its plane is smoothed over
    /// ([`CLOUD_SMOOTHING`] spacings; [`paired_point`]); 0 takes the
    /// nearest point's own plane.
    pub smooth: f32,
}

/// Where on the observation a particle's nearest point lies, which sets
/// the curvature of half its squared distance there ([`paired_spring`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Feature {
    /// Inside a surface's face, or on a cloud's plane.
    Face,
    /// On a surface's edge, along this unit direction.
    Edge(Vec3),
    /// At a surface's vertex.
    Vertex,
}

/// The observed point a particle is paired with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Paired {
    /// The nearest observed point (for a cloud with a smoothing radius,
    /// its smoothed plane's point).
    pub point: Vec3,
    /// The observation's unit normal there.
    pub normal: Vec3,
    /// Where on the observation the point lies.
    pub feature: Feature,
}

/// The feature of triangle `corners` that holds the point of barycentric
/// coordinates `barycentric`, as [`SurfaceField::nearest`] gives them
/// (exact zeros off the face): two zeros a vertex, one an edge (the one
/// opposite the corner whose coordinate is zero), none the face.
pub fn feature_of(corners: [Vec3; 3], barycentric: [f32; 3]) -> Feature {
    let zeros = barycentric.iter().filter(|&&b| b == 0.0).count();
    match (zeros, barycentric.iter().position(|&b| b == 0.0)) {
        (1, Some(k)) => {
            let edge = corners[(k + 2) % 3] - corners[(k + 1) % 3];
            let length = edge.length();
            if length > 0.0 {
                Feature::Edge(edge / length)
            } else {
                Feature::Vertex
            }
        }
        (0, _) => Feature::Face,
        _ => Feature::Vertex,
    }
}

/// The observed point a particle at `x` is paired with on `field`: for a
/// cloud with a smoothing radius, its smoothed plane where one is found
/// ([`SurfaceField::smooth_plane`]); else the nearest point, the normal
/// there, and (for a surface) the feature it lies on. What every device's
/// pairing pass takes.
pub fn paired_point(field: &SurfaceField, x: Vec3, rule: &PairingRule) -> Paired {
    if rule.cloud
        && rule.smooth > 0.0
        && let Some((point, normal)) = field.smooth_plane(x, rule.smooth)
    {
        return Paired {
            point,
            normal,
            feature: Feature::Face,
        };
    }
    let near = field.nearest(x);
    let feature = if rule.cloud {
        Feature::Face
    } else {
        field
            .corners
            .get(near.triangle as usize)
            .map_or(Feature::Face, |&corners| {
                feature_of(corners, near.barycentric)
            })
    };
    Paired {
        point: near.point,
        normal: near.normal,
        feature,
    }
}

/// The free skin particles paired at each iteration, and how.
#[derive(Debug, Clone, PartialEq)]
pub struct Pairing {
    /// The particles paired, in increasing order (the others keep no
    /// spring).
    pub skin: Vec<u32>,
    /// How each is paired.
    pub rule: PairingRule,
}

impl Pairing {
    /// Writes into `springs` (one per particle) the spring of every
    /// particle it pairs ([`paired_spring`] at its position in `positions`
    /// on `field`); the others' are left as they are. What every device's
    /// pairing pass writes (the CPU's runs this).
    pub fn pair_into(&self, field: &SurfaceField, positions: &[Vec3], springs: &mut [Spring]) {
        let paired: Vec<Spring> = self
            .skin
            .par_iter()
            .map(|&i| {
                let x = positions[i as usize];
                paired_spring(x, &paired_point(field, x, &self.rule), &self.rule)
            })
            .collect();
        for (&i, spring) in self.skin.iter().zip(paired) {
            springs[i as usize] = spring;
        }
    }

    /// Per particle of `positions` its spring ([`Pairing::pair_into`]),
    /// zero for the particles it does not pair: the springs a solve starts
    /// from.
    pub fn springs(&self, field: &SurfaceField, positions: &[Vec3]) -> Vec<Spring> {
        let mut springs = vec![Spring::ZERO; positions.len()];
        self.pair_into(field, positions, &mut springs);
        springs
    }

    /// What a solve from `positions` runs with: every paired particle's
    /// spring there ([`Pairing::springs`]), and the pairing its iterations
    /// repeat, which for a cloud leaves out the particles on its rim at
    /// `positions` ([`on_rim`]): theirs stay the springs they start with
    /// for the whole solve. Past half the way to a cloud's edge the
    /// smoothed plane's point is the weighted mean of the rim's points
    /// alone and moves many times as far as the particle does, and the
    /// pull fades ([`taper`]) as the particle slides out: paired at every
    /// iteration, a rim particle stepped back and forth between two planes
    /// (breast_d's scan under its posture options, a cycle of four
    /// iterations that held two re-solves at their error estimate for 500
    /// iterations each) or crept outward as its pull faded (breast_c's
    /// scan, whose last stage ended at the float floor after 367
    /// iterations) (docs/METHOD.md, "Observations without
    /// correspondence").
    pub fn for_solve_from(&self, field: &SurfaceField, positions: &[Vec3]) -> (Vec<Spring>, Self) {
        // Each particle paired once: its spring, and whether it is on the rim.
        let paired: Vec<(Spring, bool)> = self
            .skin
            .par_iter()
            .map(|&i| {
                let x = positions[i as usize];
                let at = paired_point(field, x, &self.rule);
                (
                    paired_spring(x, &at, &self.rule),
                    on_rim(x, &at, &self.rule),
                )
            })
            .collect();
        let mut springs = vec![Spring::ZERO; positions.len()];
        let mut skin = Vec::with_capacity(self.skin.len());
        for (&i, &(spring, rim)) in self.skin.iter().zip(&paired) {
            springs[i as usize] = spring;
            if !rim {
                skin.push(i);
            }
        }
        (
            springs,
            Self {
                skin,
                rule: self.rule,
            },
        )
    }
}

/// Whether a particle at `x` paired with `paired` lies on a cloud's rim:
/// farther along the cloud's plane from its point than half the way to
/// the edge, where its pull fades ([`taper`]). Never for a surface.
pub fn on_rim(x: Vec3, paired: &Paired, rule: &PairingRule) -> bool {
    if !rule.cloud {
        return false;
    }
    let offset = x - paired.point;
    let across = (offset - paired.normal.dot(offset) * paired.normal).length();
    taper(across / rule.edge) < 1.0
}

/// The plane a particle at `x` is pulled to, from its nearest observed
/// point `point` with the observation's unit `normal` there: the plane's
/// unit normal and the particle's distance from the observation (for a
/// cloud, across its plane); `None` past a cloud's edge.
pub fn pair_plane(x: Vec3, point: Vec3, normal: Vec3, rule: &PairingRule) -> Option<(Vec3, f32)> {
    let offset = x - point;
    if rule.cloud {
        let along = normal.dot(offset);
        let across = (offset - along * normal).length();
        return (across <= rule.edge).then_some((normal, along.abs()));
    }
    let length = offset.length();
    // On the surface (to rounding) the direction is lost: its own normal.
    let n = if length > 1e-6 * (1.0 + x.abs().max_element()) {
        offset / length
    } else {
        normal
    };
    Some((n, length))
}

/// The spring of a particle at `x` paired with `paired`: the curvature of
/// half its squared distance there with the rule's weight
/// ([`crate::stage2::springs`]): for a cloud, or on a surface's face,
/// towards the plane of [`pair_plane`]; on a surface's edge towards the
/// edge's line, at its vertex towards the vertex. Faded ([`taper`]) from
/// half the way to a cloud's edge, zero beyond it. Farther from the
/// observation than the robust scale `s` ([`PairingRule::robust`]), at a
/// distance `d`, the spring is Huber's there: its point moved `d - s`
/// past the observation (away from the particle) and its weight times
/// `s / (2 d - s)`, so that its force is the weight times `s` and its
/// potential the weight times `s (d - s / 2)`, both continuous at `s`
/// (the potential is measured at the positions paired, so it is a
/// function of the positions alone).
/// What [`Pass::Pair`](crate::stage2::Pass::Pair) writes for each paired
/// particle on every device.
pub fn paired_spring(x: Vec3, paired: &Paired, rule: &PairingRule) -> Spring {
    let Paired {
        point,
        normal,
        feature,
    } = *paired;
    let offset = x - point;
    let Some((n, distance)) = pair_plane(x, point, normal, rule) else {
        return Spring::ZERO;
    };
    // How far across a cloud's plane the particle is, in its edges.
    let across = if rule.cloud {
        (offset - normal.dot(offset) * normal).length() / rule.edge
    } else {
        0.0
    };
    let mut share = taper(across);
    if share <= 0.0 {
        return Spring::ZERO;
    }
    let mut point = point;
    if distance > rule.robust {
        // Towards the particle: along the plane's normal for a cloud, the
        // direction to the nearest point for a surface.
        let towards = if rule.cloud {
            normal * normal.dot(offset).signum()
        } else {
            n
        };
        point += towards * (rule.robust - distance);
        share *= rule.robust / (2.0 * distance - rule.robust);
    }
    let weight = rule.weight * share;
    match feature {
        Feature::Face => Spring::plane(point, n, weight),
        Feature::Edge(tangent) => Spring::line(point, tangent, weight),
        Feature::Vertex => Spring::point(point, weight),
    }
}

/// The share of a spring's weight a particle `ratio` of the way to a
/// limit keeps: all of it to half the limit, then less in proportion to
/// none at the limit, so that the pull and its potential fade rather than
/// jump as a particle crosses a cloud's edge.
pub fn taper(ratio: f32) -> f32 {
    (2.0 * (1.0 - ratio)).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage2::springs::{spring_force, spring_potential};

    fn rule(cloud: bool) -> PairingRule {
        PairingRule {
            weight: 4.0,
            edge: 1.0,
            robust: 2.0,
            cloud,
            smooth: 0.0,
        }
    }

    /// A cloud's plane is smoothed over one spacing (`h`), its points read
    /// within three.
    #[test]
    fn a_clouds_plane_is_smoothed_over_one_spacing() {
        assert_eq!(CLOUD_SMOOTHING, 1.0);
        assert_eq!(tissue_core::field::SMOOTH_REACH, 3.0);
    }

    fn at(point: Vec3, feature: Feature) -> Paired {
        Paired {
            point,
            normal: Vec3::Z,
            feature,
        }
    }

    #[test]
    fn a_surface_pulls_with_the_curvature_of_its_distance_where_the_nearest_point_lies() {
        // Off a face: the plane across the direction to the nearest point.
        let face = at(Vec3::ZERO, Feature::Face);
        let x = Vec3::new(0.0, 0.0, 0.5);
        assert_eq!(
            paired_spring(x, &face, &rule(false)),
            Spring::plane(Vec3::ZERO, Vec3::Z, 4.0)
        );
        // Off a vertex: every direction; off an edge: all but along it.
        let x = Vec3::new(0.5, 0.5, 0.0);
        let vertex = paired_spring(x, &at(Vec3::ZERO, Feature::Vertex), &rule(false));
        assert_eq!(vertex, Spring::point(Vec3::ZERO, 4.0));
        let edge = paired_spring(x, &at(Vec3::ZERO, Feature::Edge(Vec3::Z)), &rule(false));
        assert_eq!(edge, Spring::line(Vec3::ZERO, Vec3::Z, 4.0));
        // On the surface, its normal.
        let on = paired_spring(Vec3::ZERO, &face, &rule(false));
        assert_eq!(on, Spring::plane(Vec3::ZERO, Vec3::Z, 4.0));
        // Within the robust scale, the whole weight.
        let within = paired_spring(Vec3::new(0.0, 0.0, 1.5), &face, &rule(false));
        assert_eq!(within, Spring::plane(Vec3::ZERO, Vec3::Z, 4.0));
    }

    /// Beyond the robust scale `s` a pair pulls with the force it has at
    /// `s` and its potential grows in proportion to the distance (Huber's),
    /// for every feature, both continuous at `s`.
    #[test]
    fn beyond_the_robust_scale_the_pull_is_hubers() {
        let (weight, s) = (4.0, 2.0);
        let huber = |d: f32| f64::from(weight * s * (d - s / 2.0));
        let x = Vec3::new(0.0, 0.0, 3.0);
        for feature in [Feature::Face, Feature::Edge(Vec3::X), Feature::Vertex] {
            for cloud in [false, true] {
                if cloud && feature != Feature::Face {
                    continue;
                }
                let spring = paired_spring(x, &at(Vec3::ZERO, feature), &rule(cloud));
                let force = spring_force(spring, x);
                assert!(
                    (force - Vec3::new(0.0, 0.0, -weight * s)).length() < 1e-5,
                    "{feature:?}: {force}"
                );
                let potential = spring_potential(spring, x);
                assert!(
                    (potential - huber(3.0)).abs() < 1e-5,
                    "{feature:?}: {potential}"
                );
            }
        }
        // A cloud's pair below its plane is pulled up.
        let below = Vec3::new(0.0, 0.0, -2.5);
        let spring = paired_spring(below, &at(Vec3::ZERO, Feature::Face), &rule(true));
        assert!((spring_force(spring, below) - Vec3::new(0.0, 0.0, weight * s)).length() < 1e-5);
        assert!((spring_potential(spring, below) - huber(2.5)).abs() < 1e-5);
        // Continuous at the scale: just inside and just beyond, the same
        // force and potential.
        let face = at(Vec3::ZERO, Feature::Face);
        let inside = Vec3::new(0.0, 0.0, s - 1e-4);
        let beyond = Vec3::new(0.0, 0.0, s + 1e-4);
        let (a, b) = (
            paired_spring(inside, &face, &rule(false)),
            paired_spring(beyond, &face, &rule(false)),
        );
        assert!((spring_force(a, inside) - spring_force(b, beyond)).length() < 1e-3);
        assert!((spring_potential(a, inside) - spring_potential(b, beyond)).abs() < 3e-3);
    }

    #[test]
    fn the_feature_is_read_from_the_nearest_points_zero_coordinates() {
        let corners = [
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        assert_eq!(feature_of(corners, [0.2, 0.3, 0.5]), Feature::Face);
        assert_eq!(feature_of(corners, [0.0, 1.0, 0.0]), Feature::Vertex);
        // Zero opposite the third corner: the edge from the first to the
        // second.
        assert_eq!(feature_of(corners, [0.5, 0.5, 0.0]), Feature::Edge(Vec3::X));
        assert_eq!(
            feature_of(corners, [0.5, 0.0, 0.5]),
            Feature::Edge(Vec3::NEG_Y)
        );
        let edge = Vec3::new(-2.0, 1.0, 0.0).normalize();
        match feature_of(corners, [0.0, 0.25, 0.75]) {
            Feature::Edge(t) => assert!((t - edge).length() < 1e-6),
            other => panic!("{other:?}"),
        }
    }

    /// A solve from positions with one particle over a flat cloud and one
    /// past its last points, on its rim: both start with their springs,
    /// and only the one over the cloud is paired again at each iteration.
    /// A surface's pairing is repeated whole.
    #[test]
    fn a_clouds_rim_keeps_the_springs_a_solve_starts_with() {
        let mut points = Vec::new();
        for i in -10..=10 {
            for j in -10..=10 {
                points.push(Vec3::new(i as f32, j as f32, 0.0));
            }
        }
        let normals = vec![Vec3::Z; points.len()];
        let field = SurfaceField::of_cloud_within(&points, &normals, 1.0, 4.0, 3.0)
            .unwrap_or_else(|e| panic!("{e}"));
        let rule = PairingRule {
            weight: 4.0,
            edge: 3.0,
            robust: NO_LIMIT,
            cloud: true,
            smooth: 1.0,
        };
        let positions = [Vec3::new(0.2, 0.3, 0.5), Vec3::new(12.0, 0.0, 0.5)];
        let over = paired_point(&field, positions[0], &rule);
        let past = paired_point(&field, positions[1], &rule);
        assert!(!on_rim(positions[0], &over, &rule));
        assert!(on_rim(positions[1], &past, &rule), "{past:?}");
        let pairing = Pairing {
            skin: vec![0, 1],
            rule,
        };
        let (springs, iterated) = pairing.for_solve_from(&field, &positions);
        assert_eq!(springs, pairing.springs(&field, &positions));
        assert!(springs.iter().all(|s| !s.is_zero()), "{springs:?}");
        assert_eq!(iterated.skin, vec![0]);
        assert_eq!(iterated.rule, rule);
        let surface = Pairing {
            rule: PairingRule {
                cloud: false,
                edge: NO_LIMIT,
                ..rule
            },
            ..pairing
        };
        assert_eq!(surface.for_solve_from(&field, &positions).1, surface);
    }

    #[test]
    fn a_cloud_pulls_along_its_normal_and_not_past_its_edge() {
        let plane = at(Vec3::ZERO, Feature::Face);
        let near = paired_spring(Vec3::new(0.25, 0.0, 0.5), &plane, &rule(true));
        assert_eq!(near, Spring::plane(Vec3::ZERO, Vec3::Z, 4.0));
        // Three quarters of the way to the edge: half the weight.
        let edge = paired_spring(Vec3::new(0.75, 0.0, 0.5), &plane, &rule(true));
        assert!((edge.largest() - 2.0).abs() < 1e-5, "{edge:?}");
        let past = paired_spring(Vec3::new(1.5, 0.0, 0.1), &plane, &rule(true));
        assert_eq!(past, Spring::ZERO);
    }
}
