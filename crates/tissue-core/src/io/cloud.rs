//! Point clouds of an observed surface (a surface scanner's, a stereo
//! camera's or a tracked stylus's points), in the formats such devices and
//! 3D Slicer write: CSV, PLY, legacy VTK and VTK XML PolyData (their points,
//! whatever cells they have), and markups files (docs/FORMATS.md, "Point
//! clouds").

use std::path::Path;

use glam::Vec3;

use super::markups::{is_markups, load_markups};
use super::points::load_points;
use super::space::Space;
use super::{extension, format_error, io_error};
use crate::error::Error;

/// The extensions [`load_cloud`] reads.
pub const CLOUD_EXTENSIONS: &str = ".csv, .ply, .vtk, .vtp, .mrk.json";

/// Reads the points of a cloud file, by extension: `.csv` and `.ply` as
/// [`load_points`] reads them (a PLY mesh's vertices too), `.vtk` and
/// `.vtp` the points of every piece (PolyData with vertex cells, or with
/// none; a surface's vertices too), a markups file (`.mrk.json`, any
/// `.json`) its defined control points, converted to `space` (the other
/// formats carry no coordinate system of their own to convert from).
///
/// # Errors
///
/// [`Error::UnsupportedFormat`] for another extension; [`Error::Format`]
/// naming the file and the defect where it cannot be read or holds no
/// point; [`Error::Io`] where it cannot be opened.
///
/// # Example
///
/// ```
/// use tissue_core::Vec3;
/// use tissue_core::io::cloud::load_cloud;
/// use tissue_core::io::space::Space;
///
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("scan.csv");
/// std::fs::write(&path, "x,y,z\n1,2,3\n4.5,-6,0.25\n")?;
/// assert_eq!(load_cloud(&path, Space::Lps)?.len(), 2);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn load_cloud(path: &Path, space: Space) -> Result<Vec<Vec3>, Error> {
    if is_markups(path) {
        return Ok(load_markups(path, space)?.points().to_vec());
    }
    match extension(path).as_deref() {
        Some("csv" | "ply") => load_points(path),
        Some(kind @ ("vtk" | "vtp")) => {
            let bytes = std::fs::read(path).map_err(|source| io_error(path, source))?;
            let points = super::surface::read_vtk_points(&bytes, kind == "vtp")
                .map_err(|message| format_error(path, message))?;
            if points.is_empty() {
                return Err(format_error(path, "the file holds no points"));
            }
            Ok(points)
        }
        _ => Err(Error::UnsupportedFormat {
            path: path.to_path_buf(),
            expected: CLOUD_EXTENSIONS,
        }),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]
    use super::*;

    /// A legacy VTK point cloud as pyvista and VTK write one: PolyData with
    /// a vertex cell per point.
    const LEGACY: &str = "# vtk DataFile Version 5.1\nvtk output\nASCII\nDATASET POLYDATA\n\
        POINTS 3 float\n1 2 3 4 5 6 -7 8.5 9\nVERTICES 2 3\nOFFSETS vtktypeint64\n0 3\n\
        CONNECTIVITY vtktypeint64\n0 1 2\n";

    /// The same points as VTK XML PolyData with no cells at all.
    const XML: &str = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
  <PolyData>
    <Piece NumberOfPoints="3" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="0">
      <Points>
        <DataArray type="Float32" NumberOfComponents="3" format="ascii">1 2 3 4 5 6 -7 8.5 9</DataArray>
      </Points>
    </Piece>
  </PolyData>
</VTKFile>
"#;

    fn expected() -> Vec<Vec3> {
        vec![
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(4.0, 5.0, 6.0),
            Vec3::new(-7.0, 8.5, 9.0),
        ]
    }

    #[test]
    fn every_format_gives_the_same_points() {
        let dir = tempfile::tempdir().unwrap();
        let files = [
            ("scan.csv", "x,y,z\n1,2,3\n4,5,6\n-7,8.5,9\n".to_string()),
            (
                "scan.ply",
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1 2 3\n4 5 6\n-7 8.5 9\n"
                    .to_string(),
            ),
            ("scan.vtk", LEGACY.to_string()),
            ("scan.vtp", XML.to_string()),
            (
                "scan.mrk.json",
                r#"{"markups": [{"type": "Fiducial", "coordinateSystem": "LPS", "controlPoints": [
                    {"position": [1, 2, 3]}, {"position": [4, 5, 6]}, {"position": [-7, 8.5, 9]}]}]}"#
                    .to_string(),
            ),
        ];
        for (name, text) in files {
            let path = dir.path().join(name);
            std::fs::write(&path, text).unwrap();
            assert_eq!(load_cloud(&path, Space::Lps).unwrap(), expected(), "{name}");
        }
        // A markups file in RAS, read into LPS: x and y change sign.
        let path = dir.path().join("ras.mrk.json");
        std::fs::write(
            &path,
            r#"{"markups": [{"type": "Fiducial", "coordinateSystem": "RAS", "controlPoints": [{"position": [1, 2, 3]}]}]}"#,
        )
        .unwrap();
        assert_eq!(
            load_cloud(&path, Space::Lps).unwrap(),
            vec![Vec3::new(-1.0, -2.0, 3.0)]
        );
    }

    #[test]
    fn empty_unreadable_and_unknown_files_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            (
                "empty.vtp",
                XML.replace("1 2 3 4 5 6 -7 8.5 9", "")
                    .replace("NumberOfPoints=\"3\"", "NumberOfPoints=\"0\""),
                "no points",
            ),
            ("nan.csv", "x,y,z\n1,2,3\nnan,0,0\n".to_string(), "line 3"),
            ("cut.vtk", LEGACY.replace("-7 8.5 9", ""), "cut.vtk"),
            ("scan.xyz", "1 2 3\n".to_string(), CLOUD_EXTENSIONS),
        ];
        for (name, text, says) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, text).unwrap();
            let err = load_cloud(&path, Space::Lps).unwrap_err().to_string();
            assert!(err.contains(name) && err.contains(says), "{name}: {err}");
        }
    }
}
