//! A displacement field as a NRRD file (`.nrrd`, format 4, gzip
//! encoding), which 3D Slicer loads as a grid transform and ITK reads as a
//! displacement field image. docs/FORMATS.md, "The interior's motion:
//! displacement field `.nrrd`".

use std::io::{self, Write};
use std::path::Path;

use flate2::Compression;
use flate2::write::GzEncoder;

use super::space::Space;
use super::{format_error, write_file};
use crate::displacement::DisplacementField;

use crate::error::Error;

/// The NRRD header of `field`, given in `space`, written in LPS: the grid's
/// x and y axes (and the vectors' x and y components) change sign for RAS.
pub fn nrrd_header(field: &DisplacementField, space: Space) -> String {
    let s = space.signs_to(Space::Lps).as_vec3();
    let h = field.spacing;
    let o = field.origin * s;
    let [nx, ny, nz] = field.dims;
    format!(
        "NRRD0004\n\
         # Complete NRRD file format specification at:\n\
         # http://teem.sourceforge.net/nrrd/format.html\n\
         # Written by tissue: displacement, in LPS millimetres, from a point of the deformed\n\
         # configuration to where that tissue is at rest (the resampling direction)\n\
         type: float\n\
         dimension: 4\n\
         space: left-posterior-superior\n\
         sizes: 3 {nx} {ny} {nz}\n\
         space directions: none ({},0,0) (0,{},0) (0,0,{})\n\
         kinds: vector domain domain domain\n\
         endian: little\n\
         encoding: gzip\n\
         space origin: ({},{},{})\n\
         measurement frame: (1,0,0) (0,1,0) (0,0,1)\n\
         displacement field type:=resampling\n\
         intent_code:=1006\n\n",
        s.x * h,
        s.y * h,
        s.z * h,
        o.x,
        o.y,
        o.z
    )
}

/// Writes `field` (grid and vectors in `space`) as a gzip-encoded NRRD
/// file in LPS ([`nrrd_header`], then the vectors as little-endian
/// `float` triples, x fastest).
///
/// # Errors
///
/// [`Error::Format`] for an empty grid, a count of vectors that does not
/// match it, a spacing that is not positive, or a non-finite value;
/// [`Error::Io`] when the file cannot be written.
pub fn save_displacement_field(
    field: &DisplacementField,
    space: Space,
    path: &Path,
) -> Result<(), Error> {
    check(field).map_err(|message| {
        format_error(
            path,
            format!("cannot write the displacement field: {message}"),
        )
    })?;
    let header = nrrd_header(field, space);
    let signs = space.signs_to(Space::Lps).as_vec3();
    write_file(path, |w| {
        w.write_all(header.as_bytes())?;
        let mut gz = GzEncoder::new(w, Compression::default());
        write_values(&field.values, signs, &mut gz)?;
        gz.finish().map(|_| ())
    })
}

fn write_values(values: &[glam::Vec3], signs: glam::Vec3, w: &mut impl Write) -> io::Result<()> {
    let mut bytes = Vec::with_capacity(12 * 4096);
    for chunk in values.chunks(4096) {
        bytes.clear();
        for v in chunk {
            for x in (*v * signs).to_array() {
                bytes.extend_from_slice(&x.to_le_bytes());
            }
        }
        w.write_all(&bytes)?;
    }
    Ok(())
}

fn check(field: &DisplacementField) -> Result<(), String> {
    if field.is_empty() {
        return Err(format!("the grid {:?} has no points", field.dims));
    }
    if field.values.len() != field.len() {
        return Err(format!(
            "{} vectors for a grid of {} points",
            field.values.len(),
            field.len()
        ));
    }
    if !(field.spacing.is_finite() && field.spacing > 0.0 && field.origin.is_finite()) {
        return Err(format!(
            "spacing {} and origin {} do not place a grid",
            field.spacing, field.origin
        ));
    }
    match field.values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(format!(
            "the vector at grid point {i} is not finite: {}",
            field.values[i]
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use glam::Vec3;

    use super::*;

    fn field() -> DisplacementField {
        DisplacementField {
            origin: Vec3::new(-1.0, 2.0, 0.5),
            spacing: 2.5,
            dims: [2, 1, 3],
            values: vec![Vec3::X; 6],
        }
    }

    #[test]
    fn the_header_says_lps_and_turns_ras_grids() {
        let lps = nrrd_header(&field(), Space::Lps);
        for line in [
            "sizes: 3 2 1 3\n",
            "space directions: none (2.5,0,0) (0,2.5,0) (0,0,2.5)\n",
            "space origin: (-1,2,0.5)\n",
            "kinds: vector domain domain domain\n",
            "measurement frame: (1,0,0) (0,1,0) (0,0,1)\n",
            // 3D Slicer opens the file as a grid transform only with the
            // intent code, and reads its direction from the type.
            "displacement field type:=resampling\n",
        ] {
            assert!(lps.contains(line), "{lps}");
        }
        assert!(lps.ends_with("\nintent_code:=1006\n\n"), "{lps}");
        let ras = nrrd_header(&field(), Space::Ras);
        assert!(
            ras.contains("space directions: none (-2.5,0,0) (0,-2.5,0) (0,0,2.5)\n"),
            "{ras}"
        );
        assert!(ras.contains("space origin: (1,-2,0.5)\n"), "{ras}");
    }

    #[test]
    fn a_field_that_does_not_fit_its_grid_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("field.nrrd");
        let mut short = field();
        short.values.pop();
        let mut nan = field();
        nan.values[3].y = f32::NAN;
        let mut flat = field();
        flat.spacing = 0.0;
        let mut empty = field();
        empty.dims = [0, 1, 3];
        empty.values.clear();
        for (bad, expected) in [
            (short, "5 vectors for a grid of 6 points"),
            (nan, "grid point 3 is not finite"),
            (flat, "do not place a grid"),
            (empty, "has no points"),
        ] {
            let err = save_displacement_field(&bad, Space::Lps, &path)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(expected) && err.contains("field.nrrd"),
                "{err}"
            );
            assert!(!path.exists());
        }
    }
}
