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
use tissue_core::field::{SMOOTH_REACH, SurfaceField};

use crate::stage2::pairing::CLOUD_SMOOTHING;
use crate::stage2::rigid::RIGID_TRIM;

use crate::model::svd3;

/// The range of a scan's bounding-box diagonal over the organ's that
/// [`Cloud::check_against`] accepts: from a stylus's patch of the skin (a
/// fiftieth of the organ's size) to the whole organ and what lies around it
/// (five times its size). A scan in metres of an organ in millimetres lies
/// below, one in micrometres or centimetres against millimetres above; a
/// whole scan in centimetres against millimetres (a tenth) looks like a
/// patch, and is left to the solve's residual.
pub const SCAN_SCALE: (f32, f32) = (0.02, 5.0);

/// How many points (the point itself and its nearest others) each normal
/// is fitted to: the plane of least squares through them.
pub const NORMAL_NEIGHBOURS: usize = 12;

/// How far a scan's points may sit above their neighbours' planes, in its
/// noise, for [`Cloud::cleaned`] to move them onto the planes: the noise
/// left after averaging over a plane's [`NORMAL_NEIGHBOURS`] points,
/// `1 / sqrt(12)`. Where the skin bends more within a neighbourhood (a
/// sparse scan, a sharply curved organ) the planes lie under it, and moving
/// the points onto them shifts the whole scan inwards by more than the
/// noise it averages out: such a scan is kept as scanned
/// (docs/METHOD.md, "Observations without correspondence").
pub const FLAT_BEND: f32 = 0.288_675_13;

/// A point cloud with a unit normal at every point.
#[derive(Debug, Clone, PartialEq)]
pub struct Cloud {
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    spacing: f32,
    /// Per point its [`OTHERS`] nearest other points, one row after the
    /// other: the graph its normals are turned alike over and the
    /// neighbours of its points' planes.
    others: Vec<u32>,
}

/// A point whose [`NORMAL_NEIGHBOURS`] nearest points (itself among them)
/// spread across their main direction by less than this share of their
/// spread along it (`sqrt(lambda_2 / lambda_1)` of their covariance) lies
/// on a line of points, not a patch: a tracked stylus's strip. Their
/// least-squares plane then contains the line but turns about it with the
/// noise and the skin's curvature along it (on strips cut from the shared
/// cases' scans, 27-57 degrees off the skin's normal at the median), so
/// its normal is the model's skin's instead ([`Cloud::lines`]). On the
/// shared cases' whole scans the ratio is at least 0.3 at every point (at
/// the tenth percentile 0.67-0.68); on the strips' points off their
/// crossings 0.09-0.2 (docs/METHOD.md, *Points on lines of points*).
pub const LINE_SPREAD: f32 = 0.3;

/// The nearest other points each point's plane is fitted to.
const OTHERS: usize = NORMAL_NEIGHBOURS - 1;

/// A cloud cleaned of its outliers ([`Cloud::cleaned`]).
#[derive(Debug, Clone)]
pub struct Cleaned {
    /// The kept points, each moved onto the plane of its kept nearest
    /// others.
    pub cloud: Cloud,
    /// How many points were set aside as outliers.
    pub set_aside: usize,
    /// The points' scatter across the surface, seen from the cloud alone
    /// (outliers included; the median reads past them): about the
    /// scanner's noise where the surface is flat over a few spacings (a
    /// little more where it bends within them), read low only where the
    /// noise exceeds the spacing ([`scatter_of`]).
    pub scatter: f32,
    /// How far the kept points sit above their neighbours' planes where
    /// the surface bends (the mean, outwards, of the quadric through each
    /// point's neighbours read at the point, [`bends_of`]), and the noise
    /// about those quadrics (the robust deviation of the points from
    /// them): the points were moved onto the planes only where the bend is
    /// at most [`FLAT_BEND`] of that noise (or of the `noise`
    /// [`Cloud::cleaned`] was given, if larger), and kept as scanned
    /// otherwise ([`Cleaned::flattened`]).
    pub bend: (f32, f32),
    /// Whether the kept points were moved onto their neighbours' planes.
    pub flattened: bool,
}

impl Cloud {
    /// The cloud of `points`: its spacing (the median distance from a point
    /// to its nearest other point) and its normals, each the normal of the
    /// least-squares plane through the point and its
    /// [`NORMAL_NEIGHBOURS`]` - 1` nearest others, turned alike to the
    /// side away from the points' centroid ([`Cloud::oriented_from`] turns
    /// them by another centre).
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
        let tree = indexed_tree(&points);
        let fitted: Vec<(Vec3, f32, [u32; OTHERS])> = points
            .par_iter()
            .enumerate()
            .map(|(i, &p)| {
                // The point itself (or a copy of it) and its nearest others,
                // one more than a plane takes: the first `OTHERS` that are
                // not `i` are among them whether `i` is or not.
                let nearest: Vec<usize> = tree
                    .nearest_neighbor_iter(p.to_array())
                    .take(NORMAL_NEIGHBOURS + 1)
                    .map(|n| n.data)
                    .collect();
                let near: Vec<Vec3> = nearest[..NORMAL_NEIGHBOURS]
                    .iter()
                    .map(|&j| points[j])
                    .collect();
                let mean = near.iter().sum::<Vec3>() / near.len() as f32;
                let fit = svd3(covariance(near.iter().copied(), mean));
                // The direction of least spread: `u`'s last column.
                let normal = fit.u.z_axis;
                // The first neighbour is the point itself (or a copy of it).
                let other = near.get(1).map_or(0.0, |q| (*q - p).length());
                let mut others = [0u32; OTHERS];
                for (slot, j) in others
                    .iter_mut()
                    .zip(nearest.into_iter().filter(|&j| j != i))
                {
                    *slot = j as u32;
                }
                (normal, other, others)
            })
            .collect();
        let nearest: Vec<f32> = fitted.iter().map(|f| f.1).collect();
        let normals: Vec<Vec3> = fitted.iter().map(|f| f.0).collect();
        let others: Vec<u32> = fitted.iter().flat_map(|f| f.2).collect();
        let normals = turned_alike(&points, normals, &others, centroid);
        Ok(Self {
            spacing: median(nearest),
            points,
            normals,
            others,
        })
    }

    /// The cloud without its outliers and with its noise across the
    /// surface averaged out, how many points were set aside, and the
    /// points' scatter across the surface ([`Cleaned::scatter`]). Each
    /// point's plane is the least-squares plane of its
    /// [`NORMAL_NEIGHBOURS`]` - 1` nearest others; a point farther from its
    /// plane than [`RIGID_TRIM`] times the larger of `noise` and the robust
    /// deviation of all points' distances (1.4826 times their median) is
    /// set aside. Each kept point then moves onto the plane of its kept
    /// nearest others, and the normals are fitted again (as
    /// [`Cloud::new`] turns them), where those planes fit the surface
    /// within the noise they average out: where the points sit above
    /// them, on average, by at most [`FLAT_BEND`] of the noise
    /// ([`Cleaned::bend`]); elsewhere the kept points stay as scanned.
    ///
    /// # Errors
    ///
    /// As [`Cloud::new`] for what is kept.
    pub fn cleaned(&self, noise: f32) -> Result<Cleaned, ObservationError> {
        let planes = planes_of(&self.points, &self.others);
        let deviation = 1.4826 * median(planes.iter().map(|(offset, _)| offset.abs()).collect());
        let limit = RIGID_TRIM as f32 * deviation.max(noise);
        let kept_index: Vec<usize> = (0..self.points.len())
            .filter(|&i| planes[i].0.abs() <= limit)
            .collect();
        let kept: Vec<Vec3> = kept_index.iter().map(|&i| self.points[i]).collect();
        let set_aside = self.points.len() - kept.len();
        if kept.len() < NORMAL_NEIGHBOURS {
            return Err(ObservationError::TooFew {
                count: kept.len(),
                least: NORMAL_NEIGHBOURS,
            });
        }
        // With nothing set aside the kept points' rows and planes are the
        // ones just fitted.
        let searched;
        let (others, kept_planes) = if set_aside == 0 {
            (&self.others[..], planes)
        } else {
            searched = nearest_others(&kept);
            let planes = planes_of(&kept, &searched);
            (&searched[..], planes)
        };
        let outward: Vec<Vec3> = kept_index.iter().map(|&i| self.normals[i]).collect();
        let bends = bends_of(&kept, others, &outward);
        let bend = bends.iter().map(|b| b.0).sum::<f32>() / bends.len() as f32;
        let about = 1.4826 * median(bends.iter().map(|b| b.1.abs()).collect());
        let flattened = bend <= FLAT_BEND * about.max(noise);
        let cloud = if flattened {
            let projected = kept_planes
                .iter()
                .zip(&kept)
                .map(|(&(offset, normal), &p)| p - offset * normal)
                .collect();
            Self::new(projected)?
        } else {
            log::info!(
                "the scan is kept as scanned: its points sit {bend:.3} above their neighbours' \
                 planes where the skin bends, more than {FLAT_BEND:.2} of their noise \
                 {:.3} (a scan sparse for the skin's curvature)",
                about.max(noise)
            );
            if set_aside == 0 {
                self.clone()
            } else {
                Self::new(kept)?
            }
        };
        Ok(Cleaned {
            cloud,
            set_aside,
            scatter: scatter_of(&self.points),
            bend: (bend, about),
            flattened,
        })
    }

    /// Per point that lies on a line of points ([`LINE_SPREAD`]), its
    /// index and the line's unit direction (the main direction of its
    /// [`NORMAL_NEIGHBOURS`] nearest points); the points of a patch are
    /// not listed.
    pub fn lines(&self) -> Vec<(u32, Vec3)> {
        self.points
            .par_iter()
            .zip(self.others.par_chunks(OTHERS))
            .enumerate()
            .filter_map(|(i, (&p, row))| {
                let near =
                    || std::iter::once(p).chain(row.iter().map(|&j| self.points[j as usize]));
                let mean = near().sum::<Vec3>() / (row.len() + 1) as f32;
                let fit = svd3(covariance(near(), mean));
                let across = (fit.sigma.y / fit.sigma.x).max(0.0).sqrt();
                (fit.sigma.x > 0.0 && across < LINE_SPREAD).then_some((i as u32, fit.u.x_axis))
            })
            .collect()
    }

    /// The same cloud with its normals turned to the side of the surface
    /// away from `centre` (the organ's inside, say): outward where the
    /// cloud is the skin. Each connected part of the cloud is turned alike
    /// from its point farthest from `centre` ([`turned_alike`]), so the
    /// inner side of a bend, which faces `centre`, is turned with the rest.
    #[must_use]
    pub fn oriented_from(mut self, centre: Vec3) -> Self {
        self.normals = turned_alike(&self.points, self.normals, &self.others, centre);
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
    /// ([`SurfaceField::of_cloud`]); its cells also list every point within
    /// [`SMOOTH_REACH`] times [`CLOUD_SMOOTHING`] spacings, for the
    /// smoothed plane ([`SurfaceField::smooth_plane`]).
    ///
    /// # Errors
    ///
    /// [`ObservationError::Field`] where the margin is not a length or the
    /// grid would be absurdly large (a margin of thousands of spacings).
    pub fn field(&self, margin: f32) -> Result<SurfaceField, ObservationError> {
        let cell = self.field_cell();
        Ok(SurfaceField::of_cloud_within(
            &self.points,
            &self.normals,
            cell,
            margin,
            SMOOTH_REACH * CLOUD_SMOOTHING * cell,
        )?)
    }

    /// [`Cloud::field`]'s errors for `margin`, told without making it.
    pub fn check_field(&self, margin: f32) -> Result<(), ObservationError> {
        let (lo, hi) = self.bounds();
        Ok(SurfaceField::check_grid(lo, hi, self.field_cell(), margin)?)
    }

    /// [`Cloud::field`]'s cells: a spacing (points at one place have none:
    /// a thousandth of their spread).
    fn field_cell(&self) -> f32 {
        if self.spacing > 0.0 {
            self.spacing
        } else {
            self.extent() * 1e-3
        }
    }

    /// Refuses a cloud that cannot be a scan of an organ whose rest surface
    /// spans the box `[lo, hi]`: one whose bounding-box diagonal is outside
    /// [`SCAN_SCALE`] times the organ's (another unit; the error names the
    /// unit a power of ten explains), or whose centroid lies farther than
    /// the organ's diagonal from its box (another coordinate frame).
    ///
    /// # Errors
    ///
    /// [`ObservationError::Scale`] and [`ObservationError::Elsewhere`].
    pub fn check_against(&self, lo: Vec3, hi: Vec3) -> Result<(), ObservationError> {
        let size = (hi - lo).length();
        let (cloud_lo, cloud_hi) = self.bounds();
        let ratio = (cloud_hi - cloud_lo).length() / size;
        if !(SCAN_SCALE.0..=SCAN_SCALE.1).contains(&ratio) {
            // Millimetres against centimetres, metres, or micrometres.
            let hint = [(10.0, "ten"), (1000.0, "a thousand")]
                .iter()
                .find_map(|&(factor, words): &(f32, &str)| {
                    let off = |r: f32| (r.ln() - factor.ln()).abs() < 1.5f32.ln() * 2.0;
                    if off(ratio) {
                        Some(format!(
                            ": {words} times too large, as a scan in smaller units than the \
                             organ's (millimetres against {})",
                            if factor == 10.0 {
                                "centimetres"
                            } else {
                                "metres"
                            }
                        ))
                    } else if off(1.0 / ratio) {
                        Some(format!(
                            ": {words} times too small, as a scan in larger units than the \
                             organ's ({} against millimetres)",
                            if factor == 10.0 {
                                "centimetres"
                            } else {
                                "metres"
                            }
                        ))
                    } else {
                        None
                    }
                })
                .unwrap_or_default();
            return Err(ObservationError::Scale { ratio, hint });
        }
        let centroid = self.points.iter().sum::<Vec3>() / self.points.len() as f32;
        let distance = (centroid - centroid.clamp(lo, hi)).length();
        if distance > size {
            return Err(ObservationError::Elsewhere { distance, size });
        }
        Ok(())
    }

    /// The points' bounding box.
    fn bounds(&self) -> (Vec3, Vec3) {
        let lo = self.points.iter().copied().fold(Vec3::INFINITY, Vec3::min);
        let hi = self
            .points
            .iter()
            .copied()
            .fold(Vec3::NEG_INFINITY, Vec3::max);
        (lo, hi)
    }

    /// The largest side of the points' bounding box.
    pub fn extent(&self) -> f32 {
        let (lo, hi) = self.bounds();
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

/// The points in an R*-tree, each with its index: their nearest
/// neighbours.
fn indexed_tree(points: &[Vec3]) -> RTree<GeomWithData<[f32; 3], usize>> {
    RTree::bulk_load(
        points
            .iter()
            .enumerate()
            .map(|(i, p)| GeomWithData::new(p.to_array(), i))
            .collect(),
    )
}

/// `normals` turned so that neighbours agree: over the graph joining each
/// of `points` to its [`NORMAL_NEIGHBOURS`]` - 1` nearest others, part by
/// connected part, from the part's point farthest from `centre` (its normal
/// turned away from `centre`) along a minimum spanning tree, each normal
/// turned to agree with the one it is reached from (Hoppe et al. 1992).
/// An edge costs `1 - |n_i . n_j|` (neighbours on one smooth sheet are
/// nearly parallel) plus how far the offset between them leans out of each
/// one's plane (`|d . n_i| + |d . n_j|` for the unit offset `d`): the points
/// across a thin fold are parallel too, but lie off each other's plane.
/// Turning each normal away from one centre instead misturns the inner side
/// of any bend of the organ (a sixth of a liver's skin, a tenth of a
/// bunny's). Sequential, in a fixed order: the same cloud gives the same
/// normals.
fn turned_alike(
    points: &[Vec3],
    mut normals: Vec<Vec3>,
    others: &[u32],
    centre: Vec3,
) -> Vec<Vec3> {
    let count = points.len();
    // Both ways: a point is joined to its nearest others, then to the
    // points it is among the nearest of.
    let mut joined: Vec<Vec<usize>> = others
        .chunks(OTHERS)
        .map(|row| row.iter().map(|&j| j as usize).collect())
        .collect();
    for (i, row) in others.chunks(OTHERS).enumerate() {
        for &j in row {
            joined[j as usize].push(i);
        }
    }
    let cost = |i: usize, j: usize, normals: &[Vec3]| -> f32 {
        let (ni, nj) = (normals[i], normals[j]);
        let offset = (points[j] - points[i]).normalize_or_zero();
        (1.0 - ni.dot(nj).abs()).max(0.0) + offset.dot(ni).abs() + offset.dot(nj).abs()
    };
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by(|&a, &b| {
        let (da, db) = (
            points[a].distance_squared(centre),
            points[b].distance_squared(centre),
        );
        db.total_cmp(&da).then(a.cmp(&b))
    });
    let mut reached = vec![false; count];
    let mut heap = std::collections::BinaryHeap::new();
    for seed in order {
        if reached[seed] {
            continue;
        }
        if normals[seed].dot(points[seed] - centre) < 0.0 {
            normals[seed] = -normals[seed];
        }
        reached[seed] = true;
        let push = |heap: &mut std::collections::BinaryHeap<_>, i: usize, normals: &[Vec3]| {
            for &j in &joined[i] {
                // Costs are non-negative: their bits order as they do.
                let key = std::cmp::Reverse((cost(i, j, normals).to_bits(), j, i));
                heap.push(key);
            }
        };
        push(&mut heap, seed, &normals);
        while let Some(std::cmp::Reverse((_, j, from))) = heap.pop() {
            if reached[j] {
                continue;
            }
            reached[j] = true;
            if normals[j].dot(normals[from]) < 0.0 {
                normals[j] = -normals[j];
            }
            push(&mut heap, j, &normals);
        }
    }
    normals
}

/// Per point its [`NORMAL_NEIGHBOURS`]` - 1` nearest other points, one
/// row after the other (the rows [`Cloud::new`] keeps).
fn nearest_others(points: &[Vec3]) -> Vec<u32> {
    let tree = indexed_tree(points);
    (0..points.len())
        .into_par_iter()
        .flat_map_iter(|i| {
            tree.nearest_neighbor_iter(points[i].to_array())
                .filter(move |n| n.data != i)
                .take(OTHERS)
                .map(|n| n.data as u32)
        })
        .collect()
}

/// Per point its signed distance from the least-squares plane of its nearest
/// others `others` ([`Cloud`]'s rows), and that plane's unit normal.
fn planes_of(points: &[Vec3], others: &[u32]) -> Vec<(f32, Vec3)> {
    points
        .par_iter()
        .zip(others.par_chunks(OTHERS))
        .map(|(&p, row)| {
            let near: Vec<Vec3> = row.iter().map(|&j| points[j as usize]).collect();
            let mean = near.iter().sum::<Vec3>() / near.len().max(1) as f32;
            let normal = svd3(covariance(near.iter().copied(), mean)).u.z_axis;
            (normal.dot(p - mean), normal)
        })
        .collect()
}

/// Per point, how far it sits above its neighbours' plane where the
/// surface bends, and its offset from the surface: the least-squares
/// quadric `w = a + b u + c v + d u^2 + e u v + f v^2` through its nearest
/// others `row`, in the frame of their plane (`u`, `v` along it, `w` along
/// its normal from their mean), read at the point: its height there, with
/// the sign of the point's own `normals` (positive where the plane lies
/// under a convex surface), and the point's height less it. A neighbourhood
/// whose quadric is not determined (its points on a curve) reads `(0,
/// offset)`.
fn bends_of(points: &[Vec3], others: &[u32], normals: &[Vec3]) -> Vec<(f32, f32)> {
    points
        .par_iter()
        .zip(others.par_chunks(OTHERS))
        .zip(normals)
        .map(|((&p, row), &outward)| {
            let near: Vec<Vec3> = row.iter().map(|&j| points[j as usize]).collect();
            let mean = near.iter().sum::<Vec3>() / near.len().max(1) as f32;
            let axes = svd3(covariance(near.iter().copied(), mean)).u;
            let frame = [axes.x_axis, axes.y_axis, axes.z_axis].map(Vec3::as_dvec3);
            let local = |q: Vec3| {
                let d = (q - mean).as_dvec3();
                frame.map(|axis| d.dot(axis))
            };
            let terms = |u: f64, v: f64| [1.0, u, v, u * u, u * v, v * v];
            let mut normal = [[0.0f64; 6]; 6];
            let mut right = [0.0f64; 6];
            for &q in &near {
                let [u, v, w] = local(q);
                let t = terms(u, v);
                for r in 0..6 {
                    right[r] += t[r] * w;
                    for c in 0..6 {
                        normal[r][c] += t[r] * t[c];
                    }
                }
            }
            let [u, v, w] = local(p);
            let side = f64::from(axes.z_axis.dot(outward)).signum();
            match solve_spd(normal, right) {
                Some(x) => {
                    let height: f64 = terms(u, v).iter().zip(&x).map(|(t, x)| t * x).sum();
                    ((side * height) as f32, (w - height) as f32)
                }
                None => (0.0, w as f32),
            }
        })
        .collect()
}

/// `A x = b` for a symmetric positive definite `A` by its Cholesky factor;
/// `None` where a pivot falls below a millionth of the largest diagonal
/// entry.
fn solve_spd<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    let largest = (0..N).map(|i| a[i][i]).fold(0.0f64, f64::max);
    for j in 0..N {
        let pivot = a[j][j] - (0..j).map(|k| a[j][k] * a[j][k]).sum::<f64>();
        // NaN fails the test as well.
        if pivot.is_nan() || pivot <= 1e-6 * largest {
            return None;
        }
        let pivot = pivot.sqrt();
        a[j][j] = pivot;
        for i in j + 1..N {
            a[i][j] = (a[i][j] - (0..j).map(|k| a[i][k] * a[j][k]).sum::<f64>()) / pivot;
        }
    }
    for i in 0..N {
        b[i] = (b[i] - (0..i).map(|k| a[i][k] * b[k]).sum::<f64>()) / a[i][i];
    }
    for i in (0..N).rev() {
        b[i] = (b[i] - (i + 1..N).map(|k| a[k][i] * b[k]).sum::<f64>()) / a[i][i];
    }
    Some(b)
}

/// How many nearest points (in space) a point's scatter is measured
/// among ([`scatter_of`]).
const SCATTER_POOL: usize = 3 * OTHERS;

/// The noise across the surface, seen from the points alone: the robust
/// deviation (1.4826 times the median) of each point's distance, along the
/// normal of its [`SCATTER_POOL`] nearest others' least-squares plane, from
/// the mean of the [`OTHERS`] of them nearest along that plane, divided by
/// `sqrt(1 + 1 / OTHERS)` (the mean's own noise). A plane fitted to the
/// few nearest others alone turns towards the noise wherever the noise
/// nears the spacing (its normal is the direction of least spread), and
/// the others nearest in space lean to the point's own side: both read the
/// noise low (a cap with noise 1 mm read 0.74 at a spacing of 1.36 mm and
/// 0.31 at 0.59 mm; now 1.00 and 0.68).
fn scatter_of(points: &[Vec3]) -> f32 {
    let tree = indexed_tree(points);
    let offsets: Vec<f32> = points
        .par_iter()
        .enumerate()
        .map(|(i, &p)| {
            let mut pool: Vec<Vec3> = tree
                .nearest_neighbor_iter(p.to_array())
                .filter(|n| n.data != i)
                .take(SCATTER_POOL)
                .map(|n| points[n.data])
                .collect();
            let centre = pool.iter().sum::<Vec3>() / pool.len().max(1) as f32;
            let normal = svd3(covariance(pool.iter().copied(), centre)).u.z_axis;
            let along = |q: &Vec3| {
                let d = *q - p;
                (d - normal * normal.dot(d)).length_squared()
            };
            pool.sort_by(|a, b| along(a).total_cmp(&along(b)));
            pool.truncate(OTHERS);
            let mean = pool.iter().sum::<Vec3>() / pool.len().max(1) as f32;
            normal.dot(p - mean).abs()
        })
        .collect();
    1.4826 * median(offsets) / (1.0 + 1.0 / OTHERS as f32).sqrt()
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
        cap_of(50.0, spacing, sigma)
    }

    /// [`cap`] on a sphere of `radius`.
    fn cap_of(radius: f32, spacing: f32, sigma: f32) -> Vec<Vec3> {
        let mut rng = Pcg64::seed_from_u64(7);
        let mut points = Vec::new();
        let steps = (radius * std::f32::consts::FRAC_PI_2 / spacing) as usize;
        for i in 0..=steps {
            let polar = i as f32 * spacing / radius;
            let around =
                ((2.0 * std::f32::consts::PI * radius * polar.sin() / spacing) as usize).max(1);
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
                points.push(direction * (radius + sigma * noise));
            }
        }
        points
    }

    /// A noisy cap with a few points pushed 5 mm off: the cleaning sets
    /// those aside, and of the others only the noise's far tail (beyond
    /// three deviations: a few in a thousand), and brings the kept points
    /// closer to the sphere than the noise put them (0.49 to 0.26 RMS).
    /// Points on a torus about the z axis (radii 30 and 10) about
    /// `spacing` apart, with their outward normals.
    fn torus(spacing: f32) -> (Vec<Vec3>, Vec<Vec3>) {
        let (big, small) = (30.0f32, 10.0f32);
        let tau = std::f32::consts::TAU;
        let around_tube = (tau * small / spacing) as usize;
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for i in 0..around_tube {
            let v = tau * i as f32 / around_tube as f32;
            let ring = big + small * v.cos();
            let around_axis = (tau * ring / spacing) as usize;
            for j in 0..around_axis {
                let u = tau * (j as f32 + 0.5 * (i % 2) as f32) / around_axis as f32;
                let normal = Vec3::new(v.cos() * u.cos(), v.cos() * u.sin(), v.sin());
                points.push(Vec3::new(ring * u.cos(), ring * u.sin(), small * v.sin()));
                normals.push(normal);
            }
        }
        (points, normals)
    }

    /// The planes fitted to each point's nearest others that the cloud
    /// keeps are the ones a search of its own finds, copies of a point
    /// included (each copy's others are the rest of them first).
    #[test]
    fn a_clouds_kept_neighbours_are_its_points_nearest_others() {
        let mut points = cap(2.0, 0.3);
        let copied = points[40];
        points.extend([copied; 13]);
        let cloud = Cloud::new(points.clone()).unwrap();
        assert_eq!(cloud.others, nearest_others(&points));
        let oriented = cloud.clone().oriented_from(Vec3::ZERO);
        assert_eq!(oriented.others, cloud.others);
    }

    /// A torus's centroid lies in its hole, which the inner side of its
    /// ring faces: turned away from the centroid, a third of its normals
    /// would point inward. Turned alike from the point farthest from the
    /// centre, every one points outward, from either centre given.
    #[test]
    fn the_normals_of_a_bent_cloud_are_turned_alike() {
        let (points, outward) = torus(2.0);
        let facing = points
            .iter()
            .zip(&outward)
            .filter(|&(p, n)| n.dot(*p) < 0.0)
            .count();
        assert!(facing > points.len() / 4, "{facing} of {}", points.len());
        let cloud = Cloud::new(points.clone()).unwrap();
        for (name, turned) in [
            ("the centroid", cloud.clone()),
            (
                "a centre in the tube",
                cloud.oriented_from(Vec3::new(30.0, 0.0, 0.0)),
            ),
        ] {
            let misturned = turned
                .normals()
                .iter()
                .zip(&outward)
                .filter(|&(n, truth)| n.dot(*truth) < 0.9)
                .count();
            assert_eq!(misturned, 0, "from {name}");
        }
    }

    /// Noisy caps from a tenth of the spacing to twice it: the scatter
    /// reads the noise within 10 % up to a noise near the spacing, and
    /// within a third at twice it, where the planes of the nearest
    /// others alone read 0.74 and 0.31 of it.
    #[test]
    fn a_clouds_scatter_is_its_noise_even_where_the_noise_nears_the_spacing() {
        for (lattice, sigma, within) in [
            (2.0f32, 0.2f32, 0.1f32),
            (3.0, 0.5, 0.1),
            (1.3, 0.5, 0.1),
            (3.0, 2.0, 0.1),
            (1.3, 1.0, 0.1),
            (1.0, 1.0, 0.1),
            (0.5, 1.0, 0.35),
        ] {
            let points = cap(lattice, sigma);
            let scatter = Cloud::new(points).unwrap().cleaned(0.0).unwrap().scatter;
            assert!(
                (scatter / sigma - 1.0).abs() < within,
                "noise {sigma} on a lattice of {lattice}: scatter {scatter}"
            );
        }
    }

    #[test]
    fn cleaning_sets_the_outliers_aside_and_averages_the_noise_out() {
        let mut points = cap_of(100.0, 3.0, 0.5);
        let outliers: Vec<usize> = (0..points.len()).step_by(97).collect();
        for &k in &outliers {
            points[k] *= 1.0 + 5.0 / 100.0;
        }
        let cloud = Cloud::new(points.clone()).unwrap();
        let Cleaned {
            cloud: cleaned,
            set_aside,
            scatter,
            flattened,
            ..
        } = cloud.cleaned(0.5).unwrap();
        assert!(flattened);
        // The scatter is the noise (0.5), seen through the outliers.
        assert!((0.4..0.65).contains(&scatter), "scatter {scatter}");
        let tail = set_aside - outliers.len().min(set_aside);
        assert!(
            set_aside >= outliers.len() && tail <= points.len() / 200,
            "{set_aside} set aside of {} points, {} pushed off",
            points.len(),
            outliers.len()
        );
        assert_eq!(cleaned.points().len(), points.len() - set_aside);
        let farthest = cleaned
            .points()
            .iter()
            .map(|p| (p.length() - 100.0).abs())
            .fold(0.0f32, f32::max);
        assert!(farthest < 2.5, "a kept point {farthest} off the sphere");
        let rms = |p: &[Vec3]| {
            (p.iter().map(|p| (p.length() - 100.0).powi(2)).sum::<f32>() / p.len() as f32).sqrt()
        };
        let kept: Vec<Vec3> = (0..points.len())
            .filter(|k| !outliers.contains(k))
            .map(|k| points[k])
            .collect();
        let (before, after) = (rms(&kept), rms(cleaned.points()));
        assert!(after < 0.6 * before, "{before} -> {after} off the sphere");
    }

    /// A scan sparse for its surface's bend keeps its points where they
    /// were scanned: on a sphere of 50 mm, points 8 mm apart sit about
    /// 0.9 mm above their neighbours' planes, far above 0.1 mm of noise,
    /// and moving them onto the planes would shrink the scan by that much.
    /// A denser one is moved onto them where the bend is below
    /// [`FLAT_BEND`] of its noise.
    /// A stylus's strips (points 1.5 mm apart along three arcs of a
    /// 50 mm sphere 20 mm apart, 0.3 mm of noise) lie on lines of points,
    /// each along its arc, while their least-squares planes turn about the
    /// arcs away from the sphere's normal; a scan's patch (a cap, whole or
    /// every 4th point) and a ring of points around the pole lie on none.
    #[test]
    fn a_stylus_strips_points_lie_on_lines_and_a_patchs_do_not() {
        let mut rng = Pcg64::seed_from_u64(3);
        let mut strips = Vec::new();
        let mut along = Vec::new();
        for offset in [-20.0f32, 0.0, 20.0] {
            // Arcs of constant x: the circle of radius r in that plane.
            let r = (50.0f32 * 50.0 - offset * offset).sqrt();
            let steps = (0.8 * r / 1.5) as usize;
            for k in 0..steps {
                let angle = 1.5 * k as f32 / r - 0.4;
                let on = Vec3::new(offset, r * angle.sin(), r * angle.cos());
                let noise: f32 = rng.random_range(-0.3..0.3) * 3f32.sqrt();
                strips.push(on + on.normalize() * noise);
                along.push(Vec3::new(0.0, angle.cos(), -angle.sin()));
            }
        }
        let cloud = Cloud::new(strips.clone()).unwrap();
        let lines = cloud.lines();
        assert!(
            lines.len() * 10 >= strips.len() * 9,
            "{} of {}",
            lines.len(),
            strips.len()
        );
        // Along the arc, within the chord of twelve points at an arc's end.
        for &(i, direction) in &lines {
            let i = i as usize;
            assert!(
                direction.dot(along[i]).abs() > 0.97,
                "point {i}: {direction}"
            );
        }
        let tilts: Vec<f32> = (0..strips.len())
            .map(|i| {
                let sphere = strips[i].normalize();
                cloud.normals()[i]
                    .dot(sphere)
                    .abs()
                    .min(1.0)
                    .acos()
                    .to_degrees()
            })
            .collect();
        let turned = tilts.iter().filter(|&&tilt| tilt > 20.0).count();
        assert!(
            turned * 4 > strips.len(),
            "{turned} of {} turned",
            strips.len()
        );

        for patch in [
            cap(3.0, 0.5),
            cap(3.0, 0.5).into_iter().step_by(4).collect(),
        ] {
            assert!(Cloud::new(patch).unwrap().lines().is_empty());
        }
        let ring: Vec<Vec3> = (0..40)
            .flat_map(|k| {
                let around = k as f32 * std::f32::consts::TAU / 40.0;
                [0.2f32, 0.3].map(|polar| {
                    Vec3::new(
                        polar.sin() * around.cos(),
                        polar.sin() * around.sin(),
                        polar.cos(),
                    ) * 50.0
                })
            })
            .collect();
        assert!(Cloud::new(ring).unwrap().lines().is_empty());
    }

    #[test]
    fn a_scan_sparse_for_its_bend_is_kept_as_scanned() {
        let radial = |points: &[Vec3]| {
            points.iter().map(|p| p.length() - 50.0).sum::<f32>() / points.len() as f32
        };
        let sparse = cap(8.0, 0.1);
        let cleaned = Cloud::new(sparse.clone()).unwrap().cleaned(0.0).unwrap();
        let (bend, noise) = cleaned.bend;
        assert!(!cleaned.flattened, "bend {bend} over noise {noise}");
        assert!(bend > 0.5 && noise < 0.3, "bend {bend}, noise {noise}");
        assert_eq!(cleaned.set_aside, 0);
        assert_eq!(cleaned.cloud.points(), &sparse[..]);
        // Moved onto the planes, the scan would have shrunk by about the
        // bend.
        let planes = planes_of(&sparse, &Cloud::new(sparse.clone()).unwrap().others);
        let flattened: Vec<Vec3> = sparse
            .iter()
            .zip(&planes)
            .map(|(&p, &(offset, normal))| p - offset * normal)
            .collect();
        assert!(radial(&flattened) < -0.5, "{}", radial(&flattened));
        assert!(radial(cleaned.cloud.points()).abs() < 0.05);

        // 3 mm apart on 50 mm, 0.5 mm of noise: the bend (0.2 mm) is a
        // third of the noise, and the points are kept; on 100 mm they are
        // moved onto the planes (the test above).
        let curved = Cloud::new(cap(3.0, 0.5)).unwrap().cleaned(0.0).unwrap();
        let (bend, noise) = curved.bend;
        assert!(
            !curved.flattened && bend > FLAT_BEND * noise,
            "bend {bend} over noise {noise}"
        );
        let flatter = Cloud::new(cap_of(100.0, 3.0, 0.5))
            .unwrap()
            .cleaned(0.0)
            .unwrap();
        let (bend, noise) = flatter.bend;
        assert!(
            flatter.flattened && bend < FLAT_BEND * noise,
            "bend {bend} over noise {noise}"
        );
    }

    #[test]
    fn the_flat_bend_is_the_noise_left_after_a_planes_average() {
        assert!((FLAT_BEND - 1.0 / (NORMAL_NEIGHBOURS as f32).sqrt()).abs() < 1e-7);
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
    fn a_cloud_in_other_units_or_another_frame_is_refused_with_its_cause() {
        let points = cap(3.0, 0.5);
        // The organ: the cap's sphere, radius 50.
        let (lo, hi) = (Vec3::new(-50.0, -50.0, -50.0), Vec3::splat(50.0));
        Cloud::new(points.clone())
            .unwrap()
            .check_against(lo, hi)
            .unwrap();
        let scaled =
            |factor: f32| Cloud::new(points.iter().map(|p| *p * factor).collect()).unwrap();
        for (factor, says) in [
            (1000.0, "a thousand times too large"),
            (0.001, "a thousand times too small"),
            (10.0, "ten times too large"),
        ] {
            let err = scaled(factor)
                .check_against(lo, hi)
                .unwrap_err()
                .to_string();
            assert!(err.contains(says), "scaled by {factor}: {err}");
        }
        // Neither a unit nor a plausible scan: no hint.
        let err = scaled(40.0).check_against(lo, hi).unwrap_err().to_string();
        assert!(
            err.contains("times the organ's size") && !err.contains("units"),
            "{err}"
        );
        // A patch of a tenth of the cap is a scan.
        let patch: Vec<Vec3> = points.iter().copied().filter(|p| p.z > 49.6).collect();
        Cloud::new(patch).unwrap().check_against(lo, hi).unwrap();
        let far: Vec<Vec3> = points
            .iter()
            .map(|p| *p + Vec3::new(400.0, 0.0, 0.0))
            .collect();
        let err = Cloud::new(far).unwrap().check_against(lo, hi).unwrap_err();
        assert!(matches!(err, ObservationError::Elsewhere { .. }), "{err}");
        assert!(
            err.to_string().contains("another coordinate frame"),
            "{err}"
        );
    }

    #[test]
    fn the_defaults_are_pinned() {
        // docs/METHOD.md, "Observations without correspondence".
        assert_eq!(NORMAL_NEIGHBOURS, 12);
        assert_eq!(SCAN_SCALE, (0.02, 5.0));
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
