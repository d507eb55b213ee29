//! A rigid structure's motion as an ITK transform file (`.tfm`, the text
//! format of ITK's `TxtTransformIO`), which 3D Slicer loads as a linear
//! transform.
//!
//! ITK stores the *resampling* transform: it maps points of the fixed
//! (output) space to the moving (input) space, so that an image of the
//! moving space can be resampled onto the fixed one. For a motion that
//! takes a structure from rest to moved, the fixed space is the moved
//! configuration and the moving space the rest one: the file holds the
//! motion's inverse. ITK files are in LPS. docs/FORMATS.md, "A rigid
//! structure's motion: ITK `.tfm`".

use std::path::Path;

use glam::{DMat3, DVec3};

use super::space::Space;
use super::{format_error, write_file};
use crate::error::Error;

/// An affine map `x -> matrix * x + translation`, in double precision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// The linear part.
    pub matrix: DMat3,
    /// The translation.
    pub translation: DVec3,
}

impl Affine {
    /// From a 4x4 homogeneous matrix, row-major (as `report.json` holds a
    /// rigid structure's `transform`); the last row is ignored.
    pub fn from_rows(rows: &[[f32; 4]; 4]) -> Self {
        let row = |r: usize| DVec3::new(rows[r][0].into(), rows[r][1].into(), rows[r][2].into());
        Self {
            matrix: DMat3::from_cols(row(0), row(1), row(2)).transpose(),
            translation: DVec3::new(rows[0][3].into(), rows[1][3].into(), rows[2][3].into()),
        }
    }

    /// Where the map takes `p`.
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.matrix * p + self.translation
    }

    /// The inverse map, or `None` when the linear part is singular or not finite.
    pub fn inverse(&self) -> Option<Self> {
        let det = self.matrix.determinant();
        if !(det.is_finite() && det.abs() > 1e-12 && self.translation.is_finite()) {
            return None;
        }
        let matrix = self.matrix.inverse();
        Some(Self {
            matrix,
            translation: -(matrix * self.translation),
        })
    }

    /// The same map for coordinates in `to`, given one for coordinates in
    /// `from` (`S A S` with `S` the sign change, its own inverse).
    pub fn in_space(&self, from: Space, to: Space) -> Self {
        let signs = DMat3::from_diagonal(from.signs_to(to));
        Self {
            matrix: signs * self.matrix * signs,
            translation: signs * self.translation,
        }
    }
}

/// The ITK transform that goes with `motion` (rest to moved, in `space`):
/// its inverse, the resampling transform from moved to rest, in LPS.
pub fn resampling_transform(motion: &Affine, space: Space) -> Option<Affine> {
    motion
        .inverse()
        .map(|inverse| inverse.in_space(space, Space::Lps))
}

/// The text of an ITK transform file holding `motion`'s resampling
/// transform ([`resampling_transform`]) as an `AffineTransform_double_3_3`:
/// `Parameters` the 3x3 matrix row by row, then the translation;
/// `FixedParameters` the centre of rotation, 0 0 0, so that the
/// translation is the map's offset.
pub(crate) fn tfm_text(motion: &Affine, space: Space) -> Result<String, String> {
    let transform = resampling_transform(motion, space)
        .ok_or("the motion cannot be inverted (singular or not finite)")?;
    let m = transform.matrix.transpose().to_cols_array(); // rows, one after another
    let t = transform.translation.to_array();
    let parameters: Vec<String> = m.iter().chain(&t).map(|x| format!("{x}")).collect();
    Ok(format!(
        "#Insight Transform File V1.0\n\
         #Transform 0\n\
         Transform: AffineTransform_double_3_3\n\
         Parameters: {}\n\
         FixedParameters: 0 0 0\n",
        parameters.join(" ")
    ))
}

/// Writes `motion` (rest to moved, in `space`) as an ITK transform file
/// (`tfm_text`).
///
/// # Errors
///
/// [`Error::Format`] for a motion that cannot be inverted; [`Error::Io`]
/// when the file cannot be written.
pub fn save_motion_tfm(motion: &Affine, space: Space, path: &Path) -> Result<(), Error> {
    let text = tfm_text(motion, space)
        .map_err(|message| format_error(path, format!("cannot write the transform: {message}")))?;
    write_file(path, |w| w.write_all(text.as_bytes()))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    fn turn() -> Affine {
        let matrix = DMat3::from_axis_angle(DVec3::new(0.3, 1.0, 0.2).normalize(), 0.4);
        Affine {
            matrix,
            translation: DVec3::new(6.0, -4.0, 3.0),
        }
    }

    #[test]
    fn the_inverse_and_the_space_change_undo_each_other() {
        let motion = turn();
        let p = DVec3::new(1.0, -2.0, 30.0);
        let inverse = motion.inverse().unwrap();
        assert!(inverse.apply(motion.apply(p)).distance(p) < 1e-12);
        let ras = motion.in_space(Space::Lps, Space::Ras);
        let flip = |p: DVec3| DVec3::new(-p.x, -p.y, p.z);
        assert!(ras.apply(flip(p)).distance(flip(motion.apply(p))) < 1e-12);
        assert_eq!(ras.in_space(Space::Ras, Space::Lps), motion);
    }

    #[test]
    fn a_singular_or_non_finite_motion_is_refused() {
        let flat = Affine {
            matrix: DMat3::from_diagonal(DVec3::new(1.0, 1.0, 0.0)),
            translation: DVec3::ZERO,
        };
        assert!(
            tfm_text(&flat, Space::Lps)
                .unwrap_err()
                .contains("cannot be inverted")
        );
        let nan = Affine {
            translation: DVec3::new(f64::NAN, 0.0, 0.0),
            ..turn()
        };
        assert!(tfm_text(&nan, Space::Lps).is_err());
    }

    #[test]
    fn the_rows_of_a_homogeneous_matrix_are_read_as_rows() {
        let rows = [
            [0.0, -1.0, 0.0, 5.0],
            [1.0, 0.0, 0.0, 6.0],
            [0.0, 0.0, 1.0, 7.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let map = Affine::from_rows(&rows);
        assert_eq!(map.apply(DVec3::X), DVec3::new(5.0, 7.0, 7.0));
    }
}
