//! Displacement vectors sampled on a regular grid: the interior's motion
//! in a form image tools take (3D Slicer's grid transform, ITK's
//! displacement field). Written by `io::nrrd`.

use glam::Vec3;

/// One vector per point of an axis-aligned grid with the same spacing
/// along every axis.
#[derive(Debug, Clone, PartialEq)]
pub struct DisplacementField {
    /// Where grid point (0, 0, 0) is.
    pub origin: Vec3,
    /// The distance between neighbouring grid points.
    pub spacing: f32,
    /// Grid points along x, y and z.
    pub dims: [usize; 3],
    /// The vectors, x fastest, then y, then z.
    pub values: Vec<Vec3>,
}

impl DisplacementField {
    /// The number of grid points.
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// Whether the grid has no point.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The index in [`DisplacementField::values`] of grid point `[i, j, k]`.
    pub fn index(&self, [i, j, k]: [usize; 3]) -> usize {
        (k * self.dims[1] + j) * self.dims[0] + i
    }

    /// Where grid point `index` (of [`DisplacementField::values`]) is.
    pub fn point(&self, index: usize) -> Vec3 {
        let [nx, ny, _] = self.dims;
        let ijk = Vec3::new(
            (index % nx) as f32,
            ((index / nx) % ny) as f32,
            (index / (nx * ny)) as f32,
        );
        self.origin + ijk * self.spacing
    }

    /// The field at `p`, trilinear between the eight grid points around it;
    /// `None` outside the grid.
    pub fn interpolate(&self, p: Vec3) -> Option<Vec3> {
        let g = (p - self.origin) / self.spacing;
        let mut base = [0usize; 3];
        let mut t = [0f32; 3];
        for axis in 0..3 {
            let last = self.dims[axis].checked_sub(1)?;
            if !(g[axis] >= 0.0 && g[axis] <= last as f32) {
                return None;
            }
            let cell = (g[axis].floor() as usize).min(last.saturating_sub(1));
            base[axis] = cell;
            t[axis] = g[axis] - cell as f32;
        }
        let mut sum = Vec3::ZERO;
        for corner in 0..8 {
            let mut weight = 1.0;
            let mut at = base;
            for axis in 0..3 {
                let upper = corner >> axis & 1 == 1;
                weight *= if upper { t[axis] } else { 1.0 - t[axis] };
                at[axis] = (base[axis] + usize::from(upper)).min(self.dims[axis] - 1);
            }
            sum += weight * self.values[self.index(at)];
        }
        Some(sum)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    #[test]
    fn an_affine_field_is_interpolated_exactly_and_nothing_outside() {
        let affine = |p: Vec3| Vec3::new(0.5 * p.x - p.z, 2.0 + p.y, 0.25 * p.x + p.y);
        let mut field = DisplacementField {
            origin: Vec3::new(-1.0, 2.0, 0.5),
            spacing: 0.5,
            dims: [4, 3, 5],
            values: Vec::new(),
        };
        field.values = (0..field.len()).map(|i| affine(field.point(i))).collect();
        assert_eq!(
            field.point(field.index([3, 2, 4])),
            Vec3::new(0.5, 3.0, 2.5)
        );
        for p in [
            Vec3::new(-0.3, 2.2, 1.7),
            Vec3::new(0.5, 3.0, 2.5),
            Vec3::new(-1.0, 2.0, 0.5),
        ] {
            let got = field.interpolate(p).unwrap();
            assert!(
                got.distance(affine(p)) < 1e-5,
                "{p}: {got} vs {}",
                affine(p)
            );
        }
        assert_eq!(field.interpolate(Vec3::new(0.6, 2.5, 1.0)), None);
        assert_eq!(field.interpolate(Vec3::new(0.0, 2.5, f32::NAN)), None);
    }
}
