//! A point cloud as an observation of the organ's surface without
//! correspondence (a surface scanner's or a stereo camera's points): its
//! spacing, a normal at every point fitted to its neighbours, and the grid
//! that finds a point's nearest observed point on either device
//! (docs/METHOD.md, "Observations without correspondence").

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use rstar::RTree;
use rstar::primitives::GeomWithData;
use tissue_core::ObservationError;
use tissue_core::field::SurfaceField;

use crate::model::svd3;

/// How many points (the point itself and its nearest others) each normal
/// is fitted to: the plane of least squares through them.
pub const NORMAL_NEIGHBOURS: usize = 12;

/// A point cloud with a unit normal at every point.
#[derive(Debug, Clone, PartialEq)]
pub struct Cloud {
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    spacing: f32,
}

impl Cloud {
    /// The cloud of `points`: its spacing (the median distance from a point
    /// to its nearest other point) and its normals, each the normal of the
    /// least-squares plane through the point and its
    /// [`NORMAL_NEIGHBOURS`]` - 1` nearest others, turned away from the
    /// points' centroid ([`Cloud::oriented_from`] turns them by another
    /// centre).
    ///
    /// # Errors
    ///
    /// [`ObservationError::TooFew`] below [`NORMAL_NEIGHBOURS`] points,
    /// [`ObservationError::NotFinite`] for a NaN or infinite coordinate,
    /// [`ObservationError::Degenerate`] where the points lie on one line.
    pub fn new(points: Vec<Vec3>) -> Result<Self, ObservationError> {
        if points.len() < NORMAL_NEIGHBOURS {
            return Err(ObservationError::TooFew {
                count: points.len(),
                least: NORMAL_NEIGHBOURS,
            });
        }
        if let Some((index, &value)) = points.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(ObservationError::NotFinite { index, value });
        }
        let centroid = points.iter().sum::<Vec3>() / points.len() as f32;
        let spread = svd3(covariance(points.iter().copied(), centroid)).sigma;
        // A plane needs two directions of spread.
        if spread.y <= 1e-10 * spread.x {
            return Err(ObservationError::Degenerate);
        }
        let tree = RTree::bulk_load(
            points
                .iter()
                .enumerate()
                .map(|(i, p)| GeomWithData::new(p.to_array(), i))
                .collect(),
        );
        let (normals, nearest): (Vec<Vec3>, Vec<f32>) = points
            .par_iter()
            .map(|&p| {
                let near: Vec<Vec3> = tree
                    .nearest_neighbor_iter(p.to_array())
                    .take(NORMAL_NEIGHBOURS)
                    .map(|n| points[n.data])
                    .collect();
                let mean = near.iter().sum::<Vec3>() / near.len() as f32;
                let fit = svd3(covariance(near.iter().copied(), mean));
                // The direction of least spread: `u`'s last column.
                let normal = fit.u.z_axis;
                let normal = if normal.dot(p - centroid) < 0.0 {
                    -normal
                } else {
                    normal
                };
                // The first neighbour is the point itself (or a copy of it).
                let other = near.get(1).map_or(0.0, |q| (*q - p).length());
                (normal, other)
            })
            .unzip();
        Ok(Self {
            spacing: median(nearest),
            points,
            normals,
        })
    }

    /// The same cloud with every normal turned to point away from `centre`
    /// (the organ's inside, say): outward where the cloud is the skin.
    #[must_use]
    pub fn oriented_from(mut self, centre: Vec3) -> Self {
        for (n, p) in self.normals.iter_mut().zip(&self.points) {
            if n.dot(*p - centre) < 0.0 {
                *n = -*n;
            }
        }
        self
    }

    /// The points.
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Each point's unit normal.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// The median distance from a point to its nearest other point.
    pub fn spacing(&self) -> f32 {
        self.spacing
    }

    /// The grid that finds a query point's nearest observed point, exactly,
    /// wherever one lies within `margin` of it (and nothing beyond): cells
    /// of one spacing, queried on either device as the surface field is
    /// ([`SurfaceField::of_cloud`]).
    ///
    /// # Errors
    ///
    /// [`ObservationError::Field`] where the margin is not a length or the
    /// grid would be absurdly large (a margin of thousands of spacings).
    pub fn field(&self, margin: f32) -> Result<SurfaceField, ObservationError> {
        // Points at one place have no spacing: a cell from their spread.
        let cell = if self.spacing > 0.0 {
            self.spacing
        } else {
            self.extent() * 1e-3
        };
        Ok(SurfaceField::of_cloud(
            &self.points,
            &self.normals,
            cell,
            margin,
        )?)
    }

    /// The largest side of the points' bounding box.
    pub fn extent(&self) -> f32 {
        let lo = self.points.iter().copied().fold(Vec3::INFINITY, Vec3::min);
        let hi = self
            .points
            .iter()
            .copied()
            .fold(Vec3::NEG_INFINITY, Vec3::max);
        (hi - lo).max_element()
    }
}

/// `sum (p - mean)(p - mean)^T` over `points`.
fn covariance(points: impl Iterator<Item = Vec3>, mean: Vec3) -> Mat3 {
    points.fold(Mat3::ZERO, |sum, p| {
        let d = p - mean;
        sum + Mat3::from_cols(d * d.x, d * d.y, d * d.z)
    })
}

/// The median (the upper one of an even count).
fn median(mut values: Vec<f32>) -> f32 {
    let middle = values.len() / 2;
    *values.select_nth_unstable_by(middle, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Points on the upper half of a sphere of radius 50 centred at the
    /// origin, about `spacing` apart on a jittered lattice, with Gaussian
    /// noise of `sigma` along the radius.
    fn cap(spacing: f32, sigma: f32) -> Vec<Vec3> {
        let mut rng = Pcg64::seed_from_u64(7);
        let mut points = Vec::new();
        let steps = (50.0 * std::f32::consts::FRAC_PI_2 / spacing) as usize;
        for i in 0..=steps {
            let polar = i as f32 * spacing / 50.0;
            let around =
                ((2.0 * std::f32::consts::PI * 50.0 * polar.sin() / spacing) as usize).max(1);
            for j in 0..around {
                let azimuth = (j as f32 + rng.random::<f32>() * 0.3) / around as f32
                    * 2.0
                    * std::f32::consts::PI;
                let direction = Vec3::new(
                    polar.sin() * azimuth.cos(),
                    polar.sin() * azimuth.sin(),
                    polar.cos(),
                );
                // Box-Muller.
                let (u, v): (f32, f32) = (rng.random::<f32>().max(1e-7), rng.random());
                let noise = (-2.0 * u.ln()).sqrt() * (2.0 * std::f32::consts::PI * v).cos();
                points.push(direction * (50.0 + sigma * noise));
            }
        }
        points
    }

    #[test]
    fn a_caps_normals_follow_its_radius_and_point_away_from_the_centre() {
        let points = cap(3.0, 0.0);
        let cloud = Cloud::new(points).unwrap().oriented_from(Vec3::ZERO);
        assert!((cloud.spacing() - 3.0).abs() < 0.6, "{}", cloud.spacing());
        let worst = cloud
            .points()
            .iter()
            .zip(cloud.normals())
            .map(|(p, n)| n.dot(p.normalize()))
            .fold(1.0f32, f32::min);
        // The plane through a point and its neighbours on a sphere of 50 mm
        // turns from the radius by about spacing / radius at the rim.
        assert!(
            worst > 0.99,
            "the worst normal is {:.2} degrees off the radius",
            worst.acos().to_degrees()
        );
    }

    #[test]
    fn a_noisy_caps_normals_stay_near_its_radius() {
        // The shared cases' scanner: 3 mm apart, 0.5 mm of noise.
        let cloud = Cloud::new(cap(3.0, 0.5)).unwrap().oriented_from(Vec3::ZERO);
        let mut cosines: Vec<f32> = cloud
            .points()
            .iter()
            .zip(cloud.normals())
            .map(|(p, n)| n.dot(p.normalize()))
            .collect();
        cosines.sort_by(f32::total_cmp);
        let median = cosines[cosines.len() / 2].acos().to_degrees();
        let tenth = cosines[cosines.len() / 10].acos().to_degrees();
        assert!(
            median < 5.0 && tenth < 9.0,
            "median {median:.1} degrees, 90th percentile {tenth:.1}"
        );
        assert!(cosines[0] > 0.0, "a normal points inwards");
    }

    #[test]
    fn the_field_finds_the_nearest_point_of_the_cloud() {
        let cloud = Cloud::new(cap(3.0, 0.5)).unwrap();
        let field = cloud.field(10.0).unwrap();
        for q in [Vec3::new(3.0, -4.0, 52.0), Vec3::new(30.0, 10.0, 35.0)] {
            let nearest = cloud
                .points()
                .iter()
                .map(|p| (*p - q).length())
                .fold(f32::INFINITY, f32::min);
            match field.query(q) {
                tissue_core::field::Side::Near(n) => {
                    assert!(
                        (n.distance.abs() - nearest).abs() < 1e-4,
                        "{n:?} against {nearest}"
                    );
                }
                other => panic!("{q} is {nearest} from the cloud, answered {other:?}"),
            }
        }
        // Nothing within the margin: no answer.
        assert_eq!(
            field.query(Vec3::new(0.0, 0.0, 20.0)),
            tissue_core::field::Side::DeepOutside
        );
    }

    #[test]
    fn clouds_that_show_no_surface_are_refused() {
        let few: Vec<Vec3> = (0..5).map(|i| Vec3::splat(i as f32)).collect();
        assert_eq!(
            Cloud::new(few).unwrap_err().to_string(),
            "the point cloud has 5 points; at least 12 are needed to estimate its normals"
        );
        let line: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new(i as f32, 2.0 * i as f32, 1.0))
            .collect();
        assert_eq!(Cloud::new(line).unwrap_err(), ObservationError::Degenerate);
        let mut points = cap(5.0, 0.0);
        points[17] = Vec3::new(1.0, f32::NAN, 0.0);
        let err = Cloud::new(points).unwrap_err();
        assert!(
            matches!(err, ObservationError::NotFinite { index: 17, .. }),
            "{err}"
        );
    }
}
