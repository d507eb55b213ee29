//! How a [`SurfaceField`] is built: the triangles binned into cells, the
//! band, the sides of the cells away from the surface, and each band
//! cell's candidate triangles.

use std::collections::HashMap;

use glam::Vec3;
use parry3d::query::PointQuery;
use parry3d::shape::TriMesh;
use rayon::prelude::*;

use super::{CELL_BAND, CELL_INSIDE, CELL_OUTSIDE, SurfaceField, closest_on_triangle};
use crate::mesh::SurfaceMesh;
use crate::rows::rows_in_blocks;

impl SurfaceField {
    /// Fills the cells: their states from `band` and `outside`, and per
    /// band cell its candidates sorted by distance from the centre. Any
    /// triangle nearest to some point of the cell lies within `|d(centre)|
    /// + diagonal` of the centre (triangle inequality twice), where
    /// `nearest(index, centre)` is at least `|d(centre)|`.
    pub(super) fn fill(
        &mut self,
        binned: &Binned,
        band: &[bool],
        outside: &[bool],
        nearest: impl Fn(usize, Vec3) -> f32 + Sync,
    ) {
        let cells = self.cell_count();
        let cell = self.cell;
        let diagonal = cell * 3f32.sqrt();
        let field = &*self;
        let band_cells: Vec<usize> = (0..cells).filter(|&i| band[i]).collect();
        // Each triangle's bounding sphere (its centroid, the farthest
        // corner's distance): a triangle whose sphere lies beyond a cell's
        // reach by more than rounding is not measured exactly.
        let spheres: Vec<(Vec3, f32)> = field
            .corners
            .par_iter()
            .map(|&[a, b, c]| {
                let centroid = (a + b + c) / 3.0;
                let radius = (a - centroid)
                    .length()
                    .max((b - centroid).length())
                    .max((c - centroid).length());
                (centroid, radius)
            })
            .collect();
        let (band_start, kept) = rows_in_blocks(
            band_cells.len(),
            32,
            // The last cell that gathered each triangle, so a triangle
            // binned in many cells is measured once per cell.
            || vec![usize::MAX; field.corners.len()],
            |seen, k, kept: &mut Vec<(f32, u32)>| {
                let index = band_cells[k];
                let centre = field.cell_centre(index);
                let reach = nearest(index, centre) + diagonal;
                let limit = reach * (1.0 + 1e-5) + 1e-6 * cell;
                let beyond = limit * (1.0 + 1e-4) + 1e-5 * cell;
                let first = kept.len();
                field.for_each_binned_near(binned, centre, reach, |t| {
                    if std::mem::replace(&mut seen[t as usize], index) == index {
                        return;
                    }
                    let (centroid, radius) = spheres[t as usize];
                    if (centroid - centre).length() - radius > beyond {
                        return;
                    }
                    let [a, b, c] = field.corners[t as usize];
                    let (q, _, _) = closest_on_triangle(centre, a, b, c);
                    let d = (q - centre).length();
                    if d <= limit {
                        kept.push((d, t));
                    }
                });
                kept[first..].sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            },
        );
        let mut lengths = vec![0u32; cells];
        for (k, &index) in band_cells.iter().enumerate() {
            lengths[index] = band_start[k + 1] - band_start[k];
        }
        self.set_cells(band, outside, &lengths, &kept);
    }

    /// [`SurfaceField::fill`] for a cloud, whose triangles are points, with
    /// `nearest` per cell: each point scattered to the band cells whose
    /// reach it lies within, instead of each band cell gathering over every
    /// cell its reach spans (most of them empty around a scanned patch).
    /// The same candidates in the same order as the gather: a cell's
    /// points within its reach by distance from its centre, then by index
    /// (`a_clouds_cells_list_the_points_within_their_reach_in_order`).
    pub(super) fn fill_from_points(&mut self, band: &[bool], outside: &[bool], nearest: &[f32]) {
        let cells = self.cell_count();
        let cell = self.cell;
        let diagonal = cell * 3f32.sqrt();
        let reach: Vec<f32> = (0..cells)
            .map(|i| {
                if band[i] {
                    (nearest[i] + diagonal) * (1.0 + 1e-5) + 1e-6 * cell
                } else {
                    f32::NEG_INFINITY
                }
            })
            .collect();
        let widest = reach.iter().copied().fold(0.0, f32::max);
        let field = &*self;
        let (_, hits) = rows_in_blocks(
            field.corners.len(),
            64,
            || (),
            |_, t, out: &mut Vec<(u32, f32, u32)>| {
                // A cloud's triangles are its points.
                let a = field.corners[t][0];
                let range = field.cell_range(a - Vec3::splat(widest), a + Vec3::splat(widest));
                field.for_each_cell_near(range, a, widest, |at| {
                    let index = field.cell_index(at);
                    // Outside the band the reach is -inf. Far beyond it by
                    // the squared distance (a margin far above rounding), no
                    // root taken: most cells of the ball are.
                    let (reach, offset) = (reach[index], a - field.centre_of(at));
                    let d2 = offset.length_squared();
                    if !(reach >= 0.0 && d2 <= reach * reach * (1.0 + 1e-4)) {
                        return;
                    }
                    let d = d2.sqrt();
                    if d <= reach {
                        out.push((index as u32, d, t as u32));
                    }
                });
            },
        );
        let mut lengths = vec![0u32; cells];
        for &(index, _, _) in &hits {
            lengths[index as usize] += 1;
        }
        let mut next = Vec::with_capacity(cells);
        let mut total = 0u32;
        for &length in &lengths {
            next.push(total);
            total += length;
        }
        // Each cell's row by distance, then point, as one key: the
        // distances are lengths, never negative, whose order is their
        // bits' as integers.
        let mut keys = vec![0u64; total as usize];
        for &(index, d, t) in &hits {
            let slot = &mut next[index as usize];
            keys[*slot as usize] = (u64::from(d.to_bits()) << 32) | u64::from(t);
            *slot += 1;
        }
        let mut rows = Vec::with_capacity(cells);
        let mut rest = keys.as_mut_slice();
        for &length in &lengths {
            let (row, after) = rest.split_at_mut(length as usize);
            rows.push(row);
            rest = after;
        }
        rows.into_par_iter()
            .with_min_len(256)
            .for_each(|row| row.sort_unstable());
        self.set_states(band, outside, &lengths);
        (self.candidate_distance, self.candidates) = keys
            .par_iter()
            .map(|&key| (f32::from_bits((key >> 32) as u32), key as u32))
            .unzip();
    }

    /// The cells' states from `band` and `outside`, and per cell its
    /// `lengths` candidates, `kept` as `(distance, triangle)` one cell
    /// after the other.
    fn set_cells(&mut self, band: &[bool], outside: &[bool], lengths: &[u32], kept: &[(f32, u32)]) {
        self.set_states(band, outside, lengths);
        self.candidate_distance = kept.iter().map(|&(d, _)| d).collect();
        self.candidates = kept.iter().map(|&(_, t)| t).collect();
    }

    /// The cells' states from `band` and `outside`, and where each cell's
    /// `lengths` candidates start.
    fn set_states(&mut self, band: &[bool], outside: &[bool], lengths: &[u32]) {
        self.cell_state = band
            .iter()
            .zip(outside)
            .map(|(&band, &outside)| match (band, outside) {
                (true, _) => CELL_BAND,
                (false, true) => CELL_OUTSIDE,
                (false, false) => CELL_INSIDE,
            })
            .collect();
        let mut cell_start = Vec::with_capacity(lengths.len() + 1);
        cell_start.push(0u32);
        for &length in lengths {
            cell_start.push(cell_start[cell_start.len() - 1] + length);
        }
        self.cell_start = cell_start;
    }

    /// Per cell an upper bound on the distance from its centre to the
    /// nearest of the triangles' first corners (a cloud's points), for the
    /// band cells (infinite elsewhere, and where no point has reached):
    /// each cell first takes the points binned in it, then, pass after
    /// pass, the best point of its 26 neighbours where that is nearer its
    /// centre, until no bound falls. Any point's distance bounds the
    /// nearest one's, so the bound holds whichever point a cell ends with;
    /// it is near the exact one where the points are dense.
    pub(super) fn point_bounds(&self, binned: &Binned, band: &[bool]) -> Vec<f32> {
        let cells = self.cell_count();
        let point = |t: u32| self.corners[t as usize][0];
        // Per cell its nearest point so far and that point's distance.
        let mut best: Vec<(f32, u32)> = (0..cells)
            .into_par_iter()
            .map(|index| {
                let centre = self.cell_centre(index);
                binned.items[binned.start[index] as usize..binned.start[index + 1] as usize]
                    .iter()
                    .map(|&t| ((point(t) - centre).length(), t))
                    .fold(
                        (f32::INFINITY, u32::MAX),
                        |a, b| if b.0 < a.0 { b } else { a },
                    )
            })
            .collect();
        // Pass after pass, each band cell takes the best of its 26
        // neighbours' points where nearer (Jacobi: every cell reads the
        // last pass's points). A cell none of whose neighbours changed in
        // the last pass would keep its point, so only the band cells next
        // to a change are measured again: the passes of every cell, to the
        // bit, at the cost of the changes.
        let mut changed: Vec<usize> = (0..cells).filter(|&i| best[i].1 != u32::MAX).collect();
        let mut marked = vec![usize::MAX; cells];
        let mut pass = 0;
        while !changed.is_empty() {
            let mut next = Vec::new();
            for &index in &changed {
                self.for_each_neighbour(self.cell_coords(index), |near| {
                    let near = self.cell_index(near);
                    if band[near] && std::mem::replace(&mut marked[near], pass) != pass {
                        next.push(near);
                    }
                });
            }
            let updates: Vec<(usize, (f32, u32))> = next
                .into_par_iter()
                .filter_map(|index| {
                    let at = self.cell_coords(index);
                    let centre = self.centre_of(at);
                    let mut kept = best[index];
                    self.for_each_neighbour(at, |near| {
                        let t = best[self.cell_index(near)].1;
                        if t != u32::MAX && t != kept.1 {
                            let d = (point(t) - centre).length();
                            if d < kept.0 {
                                kept = (d, t);
                            }
                        }
                    });
                    (kept != best[index]).then_some((index, kept))
                })
                .collect();
            changed = updates.iter().map(|&(index, _)| index).collect();
            for (index, kept) in updates {
                best[index] = kept;
            }
            pass += 1;
        }
        best.into_iter().map(|(d, _)| d).collect()
    }

    /// Calls `f` for cell `at` and its (up to 26) neighbours in the grid,
    /// z slowest, x fastest.
    pub(super) fn for_each_neighbour(&self, [x, y, z]: [u32; 3], mut f: impl FnMut([u32; 3])) {
        let [nx, ny, nz] = self.dims;
        for dz in z.saturating_sub(1)..=(z + 1).min(nz - 1) {
            for dy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                for dx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                    f([dx, dy, dz]);
                }
            }
        }
    }

    /// The band cells: those a triangle passes through or comes within the
    /// margin of. A point of any other cell is at least the margin from the
    /// surface.
    ///
    /// The cells [`SurfaceField::bin_triangles`] with the margin would bin
    /// some triangle in, by the same tests, without the bins: a cell one
    /// triangle marked is not measured again against the others.
    pub(super) fn band(&self) -> Vec<bool> {
        let half_diagonal = 0.5 * self.cell * 3f32.sqrt() + self.margin;
        self.cells_marked(64, |[a, b, c], band| {
            let range = self.cell_range(
                a.min(b).min(c) - Vec3::splat(half_diagonal),
                a.max(b).max(c) + Vec3::splat(half_diagonal),
            );
            let normal = (b - a).cross(c - a).normalize_or_zero();
            let point = a == b && b == c;
            for_each_cell(range, |cell| {
                let index = self.cell_index(cell);
                if band[index] {
                    return;
                }
                let centre = self.centre_of(cell);
                let near = if point {
                    (a - centre).length()
                } else {
                    // Far from the triangle's plane means far from the
                    // triangle.
                    if normal.dot(centre - a).abs() > half_diagonal * (1.0 + 1e-5) {
                        return;
                    }
                    (closest_on_triangle(centre, a, b, c).0 - centre).length()
                };
                if near <= half_diagonal * (1.0 + 1e-5) {
                    band[index] = true;
                }
            });
        })
    }

    /// [`SurfaceField::band`] for a cloud, whose triangles are points:
    /// each point marks the cells [`SurfaceField::bin_triangles`] would
    /// bin it in, without the bins (the same cells).
    pub(super) fn band_of_points(&self) -> Vec<bool> {
        let half_diagonal = 0.5 * self.cell * 3f32.sqrt() + self.margin;
        self.cells_marked(256, |[a, _, _], band| {
            let range = self.cell_range(
                a - Vec3::splat(half_diagonal),
                a + Vec3::splat(half_diagonal),
            );
            // Along a row the distance from `a` falls, then rises: the
            // cells within reach are one run, found from its two ends.
            let within = |cell| (a - self.centre_of(cell)).length() <= half_diagonal * (1.0 + 1e-5);
            self.for_each_row_near(range, a, half_diagonal, |y, z, xs| {
                let (mut first, mut last) = (*xs.start(), *xs.end());
                while first <= last && !within([first, y, z]) {
                    first += 1;
                }
                while last > first && !within([last, y, z]) {
                    last -= 1;
                }
                if first <= last {
                    let row = self.cell_index([0, y, z]);
                    band[row + first as usize..=row + last as usize].fill(true);
                }
            });
        })
    }

    /// Per cell whether `mark` marked it for some triangle: the triangles
    /// `chunk` at a time side by side, each chunk's marks made in flags of
    /// its own (which `mark` may read to skip a cell already marked), the
    /// flags then joined.
    fn cells_marked(
        &self,
        chunk: usize,
        mark: impl Fn([Vec3; 3], &mut [bool]) + Sync,
    ) -> Vec<bool> {
        let cells = self.cell_count();
        self.corners
            .par_chunks(chunk)
            .fold(
                || vec![false; cells],
                |mut band, triangles| {
                    for &corners in triangles {
                        mark(corners, &mut band);
                    }
                    band
                },
            )
            .reduce(
                || vec![false; cells],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(a, b)| *a |= b);
                    a
                },
            )
    }

    /// Bins every triangle into the cells whose centre lies within half a cell
    /// diagonal plus `reach` of it (CSR): every cell the triangle passes
    /// through or comes within `reach` of, but not the whole bounding box of
    /// a large triangle. With no reach, a triangle's nearest point to any
    /// point lies in a cell it is binned in, which is what the candidates'
    /// search needs; a wide margin's band binned so would list every
    /// triangle in a great many cells.
    pub(super) fn bin_triangles(&self, reach: f32) -> Binned {
        let half_diagonal = 0.5 * self.cell * 3f32.sqrt() + reach;
        // Appends to `cells` the cells of triangle `t`.
        let cells_of = |t: usize, cells: &mut Vec<u32>| {
            let [a, b, c] = self.corners[t];
            let range = self.cell_range(
                a.min(b).min(c) - Vec3::splat(half_diagonal),
                a.max(b).max(c) + Vec3::splat(half_diagonal),
            );
            if a == b && b == c {
                // A cloud's point: the cells whose centre is near it.
                self.for_each_cell_near(range, a, half_diagonal, |cell| {
                    let index = self.cell_index(cell);
                    if (a - self.cell_centre(index)).length() <= half_diagonal * (1.0 + 1e-5) {
                        cells.push(index as u32);
                    }
                });
                return;
            }
            let normal = (b - a).cross(c - a).normalize_or_zero();
            for_each_cell(range, |cell| {
                let index = self.cell_index(cell);
                let centre = self.cell_centre(index);
                // Far from the triangle's plane means far from the triangle.
                if normal.dot(centre - a).abs() > half_diagonal * (1.0 + 1e-5) {
                    return;
                }
                let (q, _, _) = closest_on_triangle(centre, a, b, c);
                if (q - centre).length() <= half_diagonal * (1.0 + 1e-5) {
                    cells.push(index as u32);
                }
            });
        };
        let (triangle_start, cells) = rows_in_blocks(
            self.corners.len(),
            8,
            || (),
            |_, t, cells| cells_of(t, cells),
        );
        let mut start = vec![0u32; self.cell_count() + 1];
        for &cell in &cells {
            start[cell as usize + 1] += 1;
        }
        for i in 0..self.cell_count() {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; start[self.cell_count()] as usize];
        for (t, ends) in triangle_start.windows(2).enumerate() {
            for &cell in &cells[ends[0] as usize..ends[1] as usize] {
                items[fill[cell as usize] as usize] = t as u32;
                fill[cell as usize] += 1;
            }
        }
        Binned { start, items }
    }

    /// The side of every non-band cell (`true` outside). The surface never
    /// crosses a region of face-connected non-band cells, so one exact
    /// inside test of one cell centre decides the whole region. (A flood fill
    /// from the border alone would call an outside pocket enclosed by the
    /// band, between two lobes say, inside.)
    pub(super) fn sides(&self, band: &[bool], mesh: &TriMesh) -> Vec<bool> {
        let mut outside = vec![false; self.cell_count()];
        let mut seen = band.to_vec();
        let mut stack = Vec::new();
        let [nx, ny, nz] = self.dims;
        for seed in 0..self.cell_count() {
            if seen[seed] {
                continue;
            }
            let side = !mesh
                .project_local_point(self.cell_centre(seed), false)
                .is_inside;
            seen[seed] = true;
            stack.push(seed);
            while let Some(index) = stack.pop() {
                outside[index] = side;
                let [x, y, z] = self.cell_coords(index);
                let steps: [(u32, u32, u32, bool); 6] = [
                    (x.wrapping_sub(1), y, z, x > 0),
                    (x + 1, y, z, x + 1 < nx),
                    (x, y.wrapping_sub(1), z, y > 0),
                    (x, y + 1, z, y + 1 < ny),
                    (x, y, z.wrapping_sub(1), z > 0),
                    (x, y, z + 1, z + 1 < nz),
                ];
                for (a, b, c, ok) in steps {
                    if ok {
                        let next = self.cell_index([a, b, c]);
                        if !seen[next] {
                            seen[next] = true;
                            stack.push(next);
                        }
                    }
                }
            }
        }
        outside
    }

    /// Calls `f` for the triangles binned in cells that the ball `(centre,
    /// reach)` can touch (a triangle's nearest point to `centre` lies in a
    /// cell it is binned in); a triangle may come more than once.
    pub(super) fn for_each_binned_near(
        &self,
        binned: &Binned,
        centre: Vec3,
        reach: f32,
        mut f: impl FnMut(u32),
    ) {
        let range = self.cell_range(centre - Vec3::splat(reach), centre + Vec3::splat(reach));
        for_each_cell(range, |c| {
            let i = self.cell_index(c);
            binned.items[binned.start[i] as usize..binned.start[i + 1] as usize]
                .iter()
                .for_each(|&t| f(t));
        });
    }
}

impl SurfaceField {
    /// Calls `f` for the cells of `range` whose centres may lie within
    /// `radius` of `p`: in each row of cells along x, those the ball
    /// reaches after the row's offset in y and z (with a thousandth of
    /// `radius` and a cell to spare: `f` tests each centre itself), in the
    /// order [`for_each_cell`] gives them.
    fn for_each_cell_near(
        &self,
        range: [[u32; 3]; 2],
        p: Vec3,
        radius: f32,
        mut f: impl FnMut([u32; 3]),
    ) {
        self.for_each_row_near(range, p, radius, |y, z, xs| {
            for x in xs {
                f([x, y, z]);
            }
        });
    }

    /// [`SurfaceField::for_each_cell_near`] a row of cells at a time:
    /// `f(y, z, xs)` for each row along x the ball reaches, `xs` the cells
    /// of the row it may reach.
    fn for_each_row_near(
        &self,
        [lo, hi]: [[u32; 3]; 2],
        p: Vec3,
        radius: f32,
        mut f: impl FnMut(u32, u32, std::ops::RangeInclusive<u32>),
    ) {
        let radius = radius * 1.001;
        let centre = |k: usize, i: u32| self.origin[k] + (i as f32 + 0.5) * self.cell;
        for z in lo[2]..=hi[2] {
            let dz = centre(2, z) - p.z;
            for y in lo[1]..=hi[1] {
                let dy = centre(1, y) - p.y;
                let left = radius * radius - dy * dy - dz * dz;
                if left < 0.0 {
                    continue;
                }
                let half = left.sqrt();
                let first = ((p.x - half - self.origin.x) / self.cell - 0.5).floor() - 1.0;
                let last = ((p.x + half - self.origin.x) / self.cell - 0.5).ceil() + 1.0;
                let first = first.max(lo[0] as f32) as u32;
                let last = last.min(hi[0] as f32);
                if last < first as f32 {
                    continue;
                }
                f(y, z, first..=last as u32);
            }
        }
    }
}

/// Triangles per cell, CSR.
pub(super) struct Binned {
    pub(super) start: Vec<u32>,
    pub(super) items: Vec<u32>,
}

fn for_each_cell([lo, hi]: [[u32; 3]; 2], mut f: impl FnMut([u32; 3])) {
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            for x in lo[0]..=hi[0] {
                f([x, y, z]);
            }
        }
    }
}

/// Face, edge and angle-weighted vertex pseudo-normals of every triangle.
pub(super) fn pseudo_normals(mesh: &SurfaceMesh) -> Vec<[Vec3; 7]> {
    let faces: Vec<Vec3> = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.corners(t);
            (b - a).cross(c - a).normalize_or_zero()
        })
        .collect();
    let mut vertex_sum = vec![Vec3::ZERO; mesh.vertices.len()];
    let mut edge_faces: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t);
        let pts = [a, b, c];
        for k in 0..3 {
            let here = pts[k];
            let e1 = (pts[(k + 1) % 3] - here).normalize_or_zero();
            let e2 = (pts[(k + 2) % 3] - here).normalize_or_zero();
            let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
            vertex_sum[tri[k] as usize] += angle * faces[t];
            let (u, v) = (tri[k], tri[(k + 1) % 3]);
            edge_faces.entry((u.min(v), u.max(v))).or_default().push(t);
        }
    }
    mesh.triangles
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            let edge = |k: usize| {
                let (u, v) = (tri[k], tri[(k + 1) % 3]);
                let sum: Vec3 = edge_faces
                    .get(&(u.min(v), u.max(v)))
                    .map(|fs| fs.iter().map(|&f| faces[f]).sum())
                    .unwrap_or(faces[t]);
                sum.normalize_or(faces[t])
            };
            let vertex = |k: usize| vertex_sum[tri[k] as usize].normalize_or(faces[t]);
            [
                faces[t],
                edge(0),
                edge(1),
                edge(2),
                vertex(0),
                vertex(1),
                vertex(2),
            ]
        })
        .collect()
}
