//! A point cloud's [`SurfaceField`]: each point a triangle whose three
//! corners are the point, with the candidates its band cells list for the
//! nearest point and for the plane smoothed around a query point.

use glam::Vec3;

use super::{CELL_BAND, FieldError, SMOOTH_REACH, SurfaceField};

impl SurfaceField {
    /// The field of a point cloud: each point a triangle whose three
    /// corners are the point, its seven normals the point's `normals`
    /// entry. Band cells (those within `margin` of a point, and the cells
    /// the points lie in) answer the exact nearest point, its distance
    /// signed by that point's normal; every other cell is
    /// [`CELL_OUTSIDE`]: no point within `margin`. A cloud has no inside,
    /// so [`Side::DeepInside`] never comes.
    ///
    /// Fails where there are no points, the normals do not match the
    /// points one to one, the cell or the margin is not a length, or the
    /// grid would be absurdly large.
    pub fn of_cloud(
        points: &[Vec3],
        normals: &[Vec3],
        cell: f32,
        margin: f32,
    ) -> Result<Self, FieldError> {
        Self::of_cloud_within(points, normals, cell, margin, 0.0)
    }

    /// [`SurfaceField::of_cloud`] whose band cells also list every point
    /// within `reach` of any point of the cell: what
    /// [`SurfaceField::smooth_plane`] with a radius of `reach` reads.
    ///
    /// # Errors
    ///
    /// As [`SurfaceField::of_cloud`]; [`FieldError::Margin`] for a
    /// `reach` that is not a length.
    pub fn of_cloud_within(
        points: &[Vec3],
        normals: &[Vec3],
        cell: f32,
        margin: f32,
        reach: f32,
    ) -> Result<Self, FieldError> {
        if !(reach.is_finite() && reach >= 0.0) {
            return Err(FieldError::Margin(reach));
        }
        if normals.len() != points.len() {
            return Err(FieldError::NormalCount {
                points: points.len(),
                normals: normals.len(),
            });
        }
        let lo = points.iter().copied().reduce(Vec3::min);
        let hi = points.iter().copied().reduce(Vec3::max);
        let (Some(lo), Some(hi)) = (lo, hi) else {
            return Err(FieldError::NoVertices);
        };
        let corners = points.iter().map(|&p| [p; 3]).collect();
        let normals = normals.iter().map(|&n| [n; 7]).collect();
        let mut field = Self::unfilled(lo, hi, cell, margin, corners, normals)?;
        let band = field.band_of_points();
        let binned = field.bin_triangles(0.0);
        let outside = vec![true; field.cell_count()];
        // The nearest point to a band cell's centre is at most as far as
        // the nearest of the points in that cell, and some point lies within
        // the margin of the cell, so within the margin and half a diagonal
        // of its centre.
        let within = margin + 0.5 * cell * 3f32.sqrt();
        // A cell's candidates reach `nearest + diagonal` from its centre;
        // every point within `reach` of the cell's points is within
        // `reach + diagonal / 2` of it.
        let smooth = reach - 0.5 * cell * 3f32.sqrt();
        // Each band cell's nearest point lies no farther than the point
        // its neighbours hand on ([`SurfaceField::point_bounds`]): its
        // candidates need reach no farther than that and a diagonal.
        let nearest: Vec<f32> = field
            .point_bounds(&binned, &band)
            .into_iter()
            .map(|bound| bound.min(within).max(smooth))
            .collect();
        field.fill_from_points(&band, &outside, &nearest);
        Ok(field)
    }

    /// The plane of a point cloud's field smoothed around `p` (a moving
    /// least-squares plane): the mean of the points within `3 h` of `p`
    /// and of their normals, each weighted by `exp(-r^2 / h^2)` at its
    /// distance `r`, in the order the cell lists them. It moves with `p`
    /// without the jumps of the nearest point's own plane, where the field
    /// lists every point within `3 h` of its cells
    /// ([`SurfaceField::of_cloud_within`]). `None` outside the band, or
    /// where no point is within `3 h`.
    pub fn smooth_plane(&self, p: Vec3, h: f32) -> Option<(Vec3, Vec3)> {
        let index = self.cell_of(p)?;
        if self.cell_state[index] != CELL_BAND {
            return None;
        }
        let (mut weight, mut point, mut normal) = (0.0f32, Vec3::ZERO, Vec3::ZERO);
        let reach2 = SMOOTH_REACH * SMOOTH_REACH;
        for &t in self.candidates_of(index) {
            let q = self.corners[t as usize][0];
            let r2 = (p - q).length_squared() / (h * h);
            if r2 < reach2 {
                let w = (-r2).exp();
                weight += w;
                point += w * q;
                normal += w * self.normals[t as usize][0];
            }
        }
        (weight > 0.0 && normal.length_squared() > 0.0)
            .then(|| (point / weight, normal.normalize()))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;
    use crate::field::tests::points;
    use crate::field::{CELL_INSIDE, Side};

    /// Points on the unit sphere with their outward normals.
    fn sphere_cloud(n: usize) -> (Vec<Vec3>, Vec<Vec3>) {
        let directions: Vec<Vec3> = points(4 * n, 1.0)
            .into_iter()
            .filter(|p| p.length() > 0.1)
            .map(Vec3::normalize)
            .take(n)
            .collect();
        (directions.clone(), directions)
    }

    #[test]
    fn a_clouds_field_finds_the_nearest_point_within_its_margin() {
        let (cloud, normals) = sphere_cloud(400);
        let margin = 0.3;
        let field = SurfaceField::of_cloud(&cloud, &normals, 0.1, margin).unwrap();
        assert!(field.cell_state.iter().all(|&s| s != CELL_INSIDE));
        let (mut near, mut far) = (0, 0);
        for p in points(3000, 1.6) {
            let d = cloud
                .iter()
                .map(|q| (p - *q).length())
                .fold(f32::INFINITY, f32::min);
            match field.query(p) {
                Side::Near(n) => {
                    near += 1;
                    assert!(
                        (n.distance.abs() - d).abs() <= 1e-5,
                        "{p}: {n:?} against {d}"
                    );
                    assert!((n.point - cloud[n.triangle as usize]).length() == 0.0);
                    assert_eq!(n.normal, normals[n.triangle as usize]);
                    let side = (p - n.point).dot(n.normal);
                    assert!(
                        side == 0.0 || (side > 0.0) == (n.distance > 0.0),
                        "{p}: {n:?}"
                    );
                }
                Side::DeepOutside => {
                    far += 1;
                    assert!(d >= margin, "{p} is {d} from the cloud, inside the margin");
                }
                Side::DeepInside => panic!("a cloud has no inside"),
            }
        }
        assert!(near > 300 && far > 300, "{near} near, {far} far");
    }

    /// A cloud's band marked point by point is the band of its points
    /// binned: the same cells, at margins that put cell centres on and
    /// near the balls' edges.
    #[test]
    fn a_clouds_band_marked_by_its_points_is_its_binned_band() {
        let (cloud, _) = sphere_cloud(300);
        // Points on the corners of a lattice of cells: centres on and
        // near the balls' edges along whole rows.
        let lattice: Vec<Vec3> = (0..125)
            .map(|i| Vec3::new((i % 5) as f32, ((i / 5) % 5) as f32, (i / 25) as f32) * 0.2)
            .collect();
        for (points, cell, margin) in [
            (&cloud, 0.1, 0.3),
            (&cloud, 0.07, 0.2),
            (&cloud, 0.25, 0.25),
            (&cloud, 0.1, 0.0),
            (&cloud, 0.03, 0.41),
            (&lattice, 0.1, 0.2 - 0.05 * 3f32.sqrt()),
            (&lattice, 0.05, 0.15),
        ] {
            let field = SurfaceField::of_cloud(points, points, cell, margin).unwrap();
            let marked = field.band_of_points();
            assert_eq!(marked, field.band(), "cells {cell}, margin {margin}");
            assert!(marked.iter().any(|&b| b) && !marked.iter().all(|&b| b));
        }
    }

    /// The bounds' passes: every band cell takes the best of its 26
    /// neighbours' points where nearer, all cells reading the last pass's
    /// points, until none changes. [`SurfaceField::point_bounds`] measures
    /// only the cells next to a change; it must give these bounds to the bit.
    fn bounds_of_every_pass(field: &SurfaceField, band: &[bool]) -> Vec<f32> {
        let binned = field.bin_triangles(0.0);
        let distance = |index: usize, t: u32| {
            (field.corners[t as usize][0] - field.cell_centre(index)).length()
        };
        let mut best: Vec<(f32, u32)> = (0..field.cell_count())
            .map(|index| {
                binned.items[binned.start[index] as usize..binned.start[index + 1] as usize]
                    .iter()
                    .map(|&t| (distance(index, t), t))
                    .fold(
                        (f32::INFINITY, u32::MAX),
                        |a, b| if b.0 < a.0 { b } else { a },
                    )
            })
            .collect();
        loop {
            let next: Vec<(f32, u32)> = (0..field.cell_count())
                .map(|index| {
                    let mut kept = best[index];
                    if band[index] {
                        field.for_each_neighbour(field.cell_coords(index), |near| {
                            let t = best[field.cell_index(near)].1;
                            if t != u32::MAX && t != kept.1 && distance(index, t) < kept.0 {
                                kept = (distance(index, t), t);
                            }
                        });
                    }
                    kept
                })
                .collect();
            if next == best {
                return best.into_iter().map(|(d, _)| d).collect();
            }
            best = next;
        }
    }

    #[test]
    fn the_bounds_measured_next_to_changes_are_those_of_every_pass() {
        // A sphere's points, and a patch of it spread thin (few points,
        // long chains of passes), at cells that make the band wide.
        let (sphere, _) = sphere_cloud(300);
        let patch: Vec<Vec3> = sphere
            .iter()
            .copied()
            .filter(|p| p.z > 0.6)
            .step_by(3)
            .collect();
        for (cloud, cell, margin) in [
            (&sphere, 0.1, 0.3),
            (&sphere, 0.07, 0.5),
            (&patch, 0.05, 0.4),
        ] {
            let field = SurfaceField::of_cloud(cloud, cloud, cell, margin).unwrap();
            let band = field.band_of_points();
            let bounds = field.point_bounds(&field.bin_triangles(0.0), &band);
            let passes = bounds_of_every_pass(&field, &band);
            assert_eq!(
                bounds.iter().map(|b| b.to_bits()).collect::<Vec<_>>(),
                passes.iter().map(|b| b.to_bits()).collect::<Vec<_>>(),
                "cells {cell}, margin {margin}"
            );
            assert!(bounds.iter().filter(|b| b.is_finite()).count() > 100);
        }
    }

    /// Each band cell lists exactly the points within its reach
    /// (`nearest + diagonal`, with the fill's slack), by distance from its
    /// centre and then by index: against every point measured from every
    /// band cell. Points repeated tie on their distance.
    #[test]
    fn a_clouds_cells_list_the_points_within_their_reach_in_order() {
        let (mut cloud, _) = sphere_cloud(250);
        cloud.extend_from_within(..20);
        let (cell, margin) = (0.1, 0.3);
        let mut field = SurfaceField::of_cloud(&cloud, &cloud, cell, margin).unwrap();
        let band = field.band_of_points();
        let outside = vec![true; field.cell_count()];
        // Reaches from 2 to 5 cells, cell by cell.
        let nearest: Vec<f32> = (0..field.cell_count())
            .map(|i| cell * (0.3 + (i % 7) as f32 * 0.5))
            .collect();
        field.fill_from_points(&band, &outside, &nearest);
        let diagonal = cell * 3f32.sqrt();
        let mut listed = 0;
        for index in 0..field.cell_count() {
            let mut expected: Vec<(f32, u32)> = Vec::new();
            if band[index] {
                let reach = (nearest[index] + diagonal) * (1.0 + 1e-5) + 1e-6 * cell;
                let centre = field.cell_centre(index);
                for (t, p) in cloud.iter().enumerate() {
                    let d = (*p - centre).length();
                    if d <= reach {
                        expected.push((d, t as u32));
                    }
                }
                expected.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            }
            let range = field.cell_start[index] as usize..field.cell_start[index + 1] as usize;
            let got: Vec<(f32, u32)> = field.candidate_distance[range.clone()]
                .iter()
                .copied()
                .zip(field.candidates[range].iter().copied())
                .collect();
            assert_eq!(got, expected, "cell {index}");
            listed += got.len();
        }
        assert!(listed > 10_000, "{listed} candidates");
    }

    /// A flat cloud's smoothed plane is the plane itself, and it moves
    /// with the query point without jumps: across a cell's border, and as
    /// the nearest point changes, a small step moves it a little.
    #[test]
    fn a_clouds_smoothed_plane_is_its_plane_and_moves_smoothly() {
        let mut points = Vec::new();
        for i in -10..=10 {
            for j in -10..=10 {
                // A slightly irregular grid, 1 apart.
                let jitter = 0.1 * ((i * 7 + j * 3) % 5) as f32 / 5.0;
                points.push(Vec3::new(i as f32 + jitter, j as f32 - jitter, 0.0));
            }
        }
        let normals = vec![Vec3::Z; points.len()];
        let field = SurfaceField::of_cloud_within(&points, &normals, 1.0, 4.0, 3.0).unwrap();
        let (point, normal) = field.smooth_plane(Vec3::new(0.3, 0.2, 0.7), 1.0).unwrap();
        assert!(point.z.abs() < 1e-6 && (normal - Vec3::Z).length() < 1e-6);
        let mut last = field
            .smooth_plane(Vec3::new(-3.0, 0.4, 0.5), 1.0)
            .unwrap()
            .0;
        for k in 1..=600 {
            let p = Vec3::new(-3.0 + 0.01 * k as f32, 0.4, 0.5);
            let here = field.smooth_plane(p, 1.0).unwrap().0;
            assert!((here - last).length() < 0.05, "{p}: {last} -> {here}");
            last = here;
        }
        // Outside the band: none.
        assert!(field.smooth_plane(Vec3::new(0.0, 0.0, 50.0), 1.0).is_none());
    }

    /// Every band cell's bound is some point's distance from its centre,
    /// so at least the nearest one's, and near it; the cells' lists,
    /// which reach no farther than their bounds allow, still hold every
    /// point the smoothed plane reads (against all the points' sum).
    #[test]
    fn a_clouds_cells_bound_their_nearest_point_and_list_all_within_reach() {
        let (cloud, normals) = sphere_cloud(400);
        let (cell, margin, reach) = (0.1, 0.3, 0.24);
        let field = SurfaceField::of_cloud_within(&cloud, &normals, cell, margin, reach).unwrap();
        let band: Vec<bool> = field.cell_state.iter().map(|&s| s == CELL_BAND).collect();
        let bounds = field.point_bounds(&field.bin_triangles(0.0), &band);
        let mut loosest = 0.0f32;
        for index in (0..field.cell_count()).filter(|&i| band[i]) {
            let centre = field.cell_centre(index);
            let nearest = cloud
                .iter()
                .map(|q| (centre - *q).length())
                .fold(f32::INFINITY, f32::min);
            assert!(
                bounds[index] >= nearest,
                "{index}: {} < {nearest}",
                bounds[index]
            );
            loosest = loosest.max(bounds[index] - nearest);
        }
        assert!(
            loosest < cell,
            "a bound {loosest} above the nearest point's distance"
        );
        let h = reach / SMOOTH_REACH;
        let mut read = 0;
        for p in points(3000, 1.3) {
            let Some((point, normal)) = field.smooth_plane(p, h) else {
                continue;
            };
            let (mut weight, mut sum, mut summed) = (0.0f32, Vec3::ZERO, Vec3::ZERO);
            for (q, n) in cloud.iter().zip(&normals) {
                let r2 = (p - *q).length_squared() / (h * h);
                if r2 < SMOOTH_REACH * SMOOTH_REACH {
                    let w = (-r2).exp();
                    weight += w;
                    sum += w * *q;
                    summed += w * *n;
                }
            }
            assert!((point - sum / weight).length() < 1e-5, "{p}");
            assert!((normal - summed.normalize()).length() < 1e-5, "{p}");
            read += 1;
        }
        assert!(read > 300, "{read} smoothed planes");
    }

    #[test]
    fn a_cloud_without_points_or_with_other_normals_is_refused() {
        let err = SurfaceField::of_cloud(&[], &[], 0.1, 0.1).unwrap_err();
        assert_eq!(err, FieldError::NoVertices);
        let (cloud, normals) = sphere_cloud(10);
        let err = SurfaceField::of_cloud(&cloud, &normals[1..], 0.1, 0.1).unwrap_err();
        assert_eq!(err.to_string(), "9 normals for 10 points");
    }
}
