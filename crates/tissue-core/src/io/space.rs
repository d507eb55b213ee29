//! Patient coordinate systems: LPS (DICOM, ITK, and 3D Slicer's files) and
//! RAS (3D Slicer's scene). The two differ by the sign of their first two
//! axes, so a conversion is its own inverse.

use std::fmt;
use std::str::FromStr;

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

/// The patient coordinate system a set of coordinates is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum Space {
    /// x towards the patient's left, y posterior, z superior: how 3D Slicer
    /// saves models, markups and transforms, and how ITK reads everything.
    #[default]
    Lps,
    /// x towards the patient's right, y anterior, z superior: 3D Slicer's
    /// scene, and models saved by Slicer before 4.11.
    Ras,
}

impl Space {
    /// The name markups files and the command line use: `LPS` or `RAS`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lps => "LPS",
            Self::Ras => "RAS",
        }
    }

    /// The signs that take coordinates in `self` to coordinates in `to`:
    /// `(-1, -1, 1)` between LPS and RAS, ones otherwise.
    pub fn signs_to(self, to: Self) -> DVec3 {
        if self == to {
            DVec3::ONE
        } else {
            DVec3::new(-1.0, -1.0, 1.0)
        }
    }

    /// `p`, given in `self`, in `to`.
    pub fn convert(self, to: Self, p: Vec3) -> Vec3 {
        p * self.signs_to(to).as_vec3()
    }
}

impl fmt::Display for Space {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Space {
    type Err = String;

    /// `LPS` or `RAS`, in any case.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_uppercase().as_str() {
            "LPS" => Ok(Self::Lps),
            "RAS" => Ok(Self::Ras),
            _ => Err(format!(
                "unknown coordinate system `{s}` (expected LPS or RAS)"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    #[test]
    fn lps_and_ras_differ_in_the_first_two_signs_and_convert_back() {
        let p = Vec3::new(1.5, -2.0, 3.25);
        assert_eq!(
            Space::Lps.convert(Space::Ras, p),
            Vec3::new(-1.5, 2.0, 3.25)
        );
        assert_eq!(
            Space::Ras.convert(Space::Lps, p),
            Vec3::new(-1.5, 2.0, 3.25)
        );
        assert_eq!(Space::Lps.convert(Space::Lps, p), p);
        assert_eq!(
            Space::Ras.convert(Space::Lps, Space::Lps.convert(Space::Ras, p)),
            p
        );
        assert_eq!("ras".parse::<Space>().unwrap(), Space::Ras);
        assert_eq!("LPS".parse::<Space>().unwrap(), Space::Lps);
        assert!("XYZ".parse::<Space>().unwrap_err().contains("`XYZ`"));
    }
}
