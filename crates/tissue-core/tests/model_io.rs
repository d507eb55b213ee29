//! Model (.vtp) and point (.csv, .ply) files: lossless round trips, and
//! malformed files rejected with a message instead of a panic.

#![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

use std::path::{Path, PathBuf};

use tissue_core::io::model::{export_model, load_model, load_points, save_model, save_points};
use tissue_core::{Attachment, Connections, Error, ParticleModel, SurfaceMesh, Vec3};

/// A tetrahedron surface with three surface particles and three interior
/// ones, at coordinates whose decimal forms are awkward.
fn awkward_model() -> ParticleModel {
    let (vertices, triangles) = tissue_testkit::tetrahedron(3.0);
    let surface = SurfaceMesh::new(vertices, triangles);
    let third = 1.0_f32 / 3.0;
    ParticleModel {
        positions: vec![
            Vec3::new(0.1 + 0.2, 1e-30, -0.0),
            Vec3::new(3.4e38, -3.4e38, f32::MIN_POSITIVE),
            Vec3::new(1e-45, 0.7, 1.0 / 7.0),
            Vec3::new(third, third, 0.0),
            Vec3::new(1.5, 0.0, 1.2345679),
            Vec3::new(1.0, 1.0, 1.0 - f32::EPSILON),
        ],
        radii: vec![0.1 + 0.2, 1e-30, f32::MAX, 0.5, third, 2.0],
        attachments: vec![
            None,
            None,
            None,
            Some(Attachment {
                triangle: 0,
                barycentric: [third, third, 1.0 - 2.0 * third],
            }),
            Some(Attachment {
                triangle: 1,
                barycentric: [0.1, 0.2, 0.7],
            }),
            Some(Attachment {
                triangle: 3,
                barycentric: [-0.0, 1e-30, 1.0],
            }),
        ],
        connections: Connections::from_pairs(
            6,
            [
                (0, 1),
                (0, 2),
                (1, 3),
                (2, 3),
                (3, 4),
                (4, 5),
                (5, 0),
                (2, 5),
            ],
        ),
        surface,
    }
}

/// Bitwise equality, so that `-0.0` vs `0.0` would be caught too.
fn bits(points: &[Vec3]) -> Vec<[u32; 3]> {
    points
        .iter()
        .map(|p| p.to_array().map(f32::to_bits))
        .collect()
}

fn format_message(result: Result<ParticleModel, Error>) -> String {
    match result {
        Err(Error::Format { message, .. }) => message,
        other => panic!("expected Error::Format, got {other:?}"),
    }
}

fn write(dir: &Path, name: &str, contents: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

#[test]
fn model_round_trips_through_vtp_bit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.vtp");
    let model = awkward_model();
    save_model(&model, &path).unwrap();
    let loaded = load_model(&path).unwrap();
    assert_eq!(loaded, model);
    assert_eq!(bits(&loaded.positions), bits(&model.positions));
    assert_eq!(
        loaded.radii.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
        model.radii.iter().map(|r| r.to_bits()).collect::<Vec<_>>()
    );
    let [b0, _, _] = loaded.attachments[5].unwrap().barycentric;
    assert!(b0.is_sign_negative(), "-0.0 lost its sign");
}

#[test]
fn model_without_connections_or_surface_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lonely.vtp");
    let model = ParticleModel {
        positions: vec![Vec3::new(1.0, 2.0, 3.0)],
        radii: vec![0.25],
        attachments: vec![None],
        connections: Connections::from_pairs(1, []),
        surface: SurfaceMesh::default(),
    };
    save_model(&model, &path).unwrap();
    assert_eq!(load_model(&path).unwrap(), model);
}

#[test]
fn vtp_is_valid_vtk_xml_for_an_independent_reader() {
    // vtkio parses the file on its own: one piece with the right counts.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.vtp");
    let model = awkward_model();
    save_model(&model, &path).unwrap();
    let vtk = vtkio::Vtk::import(&path).unwrap();
    let vtkio::model::DataSet::PolyData { pieces, .. } = vtk.data else {
        panic!("not PolyData");
    };
    let [piece] = &pieces[..] else {
        panic!("{} pieces", pieces.len());
    };
    let piece = piece.load_piece_data(None).unwrap();
    let (n, v) = (model.len(), model.surface.vertices.len());
    assert_eq!(piece.num_points(), n + v);
    assert_eq!(piece.num_verts(), n);
    assert_eq!(piece.num_lines(), model.connections.pairs());
    assert_eq!(piece.num_polys(), model.surface.triangles.len());
    let names: Vec<&str> = piece.data.point.iter().map(|a| a.name()).collect();
    assert_eq!(names, ["radius", "surface", "triangle", "barycentric"]);
}

/// `awkward_model()` as VTK 9.7's own `vtkXMLPolyDataWriter` re-saves it in
/// ASCII mode: range attributes, `InformationKey` children, empty `Strips`.
const VTK_ASCII_RESAVE: &str = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian" header_type="UInt32" compressor="vtkZLibDataCompressor">
  <PolyData>
    <FieldData>
      <DataArray type="Int32" Name="tissue_model_version" NumberOfTuples="1" format="ascii" RangeMin="1" RangeMax="1">
        1
      </DataArray>
      <DataArray type="Int64" Name="tissue_particles" NumberOfTuples="1" format="ascii" RangeMin="6" RangeMax="6">
        6
      </DataArray>
    </FieldData>
    <Piece NumberOfPoints="10" NumberOfVerts="6" NumberOfLines="8" NumberOfStrips="0" NumberOfPolys="4">
      <PointData Scalars="surface">
        <DataArray type="Float32" Name="radius" format="ascii" RangeMin="0" RangeMax="3.4028234663852886e+38">
          0.3 1e-30 3.4028235e+38 0.5 0.33333334 2
          0 0 0 0
        </DataArray>
        <DataArray type="UInt8" Name="surface" format="ascii" RangeMin="0" RangeMax="2">
          0 0 0 1 1 1
          2 2 2 2
        </DataArray>
        <DataArray type="Int32" Name="triangle" format="ascii" RangeMin="-1" RangeMax="3">
          -1 -1 -1 0 1 3
          -1 -1 -1 -1
        </DataArray>
        <DataArray type="Float32" Name="barycentric" NumberOfComponents="3" format="ascii" RangeMin="0" RangeMax="1">
          0 0 0 0 0 0
          0 0 0 0.33333334 0.33333334 0.3333333
          0.1 0.2 0.7 -0 1e-30 1
          0 0 0 0 0 0
          0 0 0 0 0 0
          <InformationKey name="L2_NORM_RANGE" location="vtkDataArray" length="2">
            <Value index="0">
              0
            </Value>
            <Value index="1">
              1
            </Value>
          </InformationKey>
        </DataArray>
      </PointData>
      <CellData>
      </CellData>
      <Points>
        <DataArray type="Float32" Name="Points" NumberOfComponents="3" format="ascii" RangeMin="0" RangeMax="4.808326044390434e+38">
          0.3 1e-30 -0 3.4e+38 -3.4e+38 1.1754944e-38
          1e-45 0.7 0.14285715 0.33333334 0.33333334 0
          1.5 0 1.2345679 1 1 0.9999999
          0 0 0 3 0 0
          0 3 0 0 0 3
          <InformationKey name="L2_NORM_RANGE" location="vtkDataArray" length="2">
            <Value index="0">
              0
            </Value>
            <Value index="1">
              4.8083260444e+38
            </Value>
          </InformationKey>
        </DataArray>
      </Points>
      <Verts>
        <DataArray type="Int64" Name="connectivity" format="ascii" RangeMin="0" RangeMax="5">
          0 1 2 3 4 5
        </DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii" RangeMin="1" RangeMax="6">
          1 2 3 4 5 6
        </DataArray>
      </Verts>
      <Lines>
        <DataArray type="Int64" Name="connectivity" format="ascii" RangeMin="0" RangeMax="5">
          0 1 0 2 0 5
          1 3 2 3 2 5
          3 4 4 5
        </DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii" RangeMin="2" RangeMax="16">
          2 4 6 8 10 12
          14 16
        </DataArray>
      </Lines>
      <Strips>
        <DataArray type="Int64" Name="connectivity" format="ascii" RangeMin="1e+299" RangeMax="-1e+299">
        </DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii" RangeMin="1e+299" RangeMax="-1e+299">
        </DataArray>
      </Strips>
      <Polys>
        <DataArray type="Int64" Name="connectivity" format="ascii" RangeMin="6" RangeMax="9">
          6 8 7 6 7 9
          6 9 8 7 8 9
        </DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii" RangeMin="3" RangeMax="12">
          3 6 9 12
        </DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
"#;

#[test]
fn vtk_ascii_resave_of_a_model_loads_identically() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "resaved.vtp", VTK_ASCII_RESAVE);
    assert_eq!(load_model(&path).unwrap(), awkward_model());
}

#[test]
fn empty_file_is_a_format_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "empty.vtp", "");
    assert!(format_message(load_model(&path)).contains("empty"));
}

#[test]
fn missing_file_is_an_io_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = load_model(&dir.path().join("absent.vtp")).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
}

#[test]
fn vtp_that_is_not_a_tissue_model_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let plain = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian">
  <PolyData>
    <Piece NumberOfPoints="1" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="0">
      <Points>
        <DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0</DataArray>
      </Points>
    </Piece>
  </PolyData>
</VTKFile>
"#;
    let path = write(dir.path(), "plain.vtp", plain);
    let message = format_message(load_model(&path));
    assert!(
        message.contains("not a tissue model") && message.contains("tissue_model_version"),
        "{message}"
    );

    let path = write(dir.path(), "page.vtp", "<html><body>hello</body></html>");
    let message = format_message(load_model(&path));
    assert!(message.contains("not a VTK PolyData file"), "{message}");

    let path = write(dir.path(), "binary.vtp", "\u{0}\u{1}\u{2}garbage");
    format_message(load_model(&path));
}

#[test]
fn truncated_vtp_is_rejected_at_every_cut() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("model.vtp");
    save_model(&awkward_model(), &full).unwrap();
    let text = std::fs::read_to_string(&full).unwrap();
    let cut_path = dir.path().join("cut.vtp");
    for cut in (0..text.len()).step_by(17) {
        std::fs::write(&cut_path, &text[..cut]).unwrap();
        let result = load_model(&cut_path);
        assert!(
            matches!(result, Err(Error::Format { .. })),
            "cut at byte {cut}: {result:?}"
        );
    }
}

#[test]
fn nan_position_is_rejected_naming_the_particle() {
    let dir = tempfile::tempdir().unwrap();
    let model = ParticleModel {
        positions: vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)],
        radii: vec![0.5, 0.5],
        attachments: vec![None, None],
        connections: Connections::from_pairs(2, [(0, 1)]),
        surface: SurfaceMesh::default(),
    };
    let path = dir.path().join("model.vtp");
    save_model(&model, &path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let edited = text.replacen("4 5 6", "4 NaN 6", 1);
    assert_ne!(edited, text);
    std::fs::write(&path, edited).unwrap();
    let message = format_message(load_model(&path));
    assert!(
        message.contains("particle 1") && message.contains("not finite"),
        "{message}"
    );
}

#[test]
fn vtp_missing_the_radius_array_is_rejected_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.vtp");
    save_model(&awkward_model(), &path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let start = text
        .find(r#"<DataArray type="Float32" Name="radius""#)
        .unwrap();
    let end = start + text[start..].find("</DataArray>").unwrap() + "</DataArray>".len();
    std::fs::write(&path, format!("{}{}", &text[..start], &text[end..])).unwrap();
    let message = format_message(load_model(&path));
    assert!(message.contains("`radius`"), "{message}");
}

#[test]
fn saving_an_inconsistent_model_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.vtp");
    let mut model = awkward_model();
    model.positions[2].y = f32::NAN;
    let message = format_message(save_model(&model, &path).map(|()| model.clone()));
    assert!(message.contains("particle 2"), "{message}");
    assert!(!path.exists());
}

#[test]
fn points_round_trip_through_csv_and_ply_bit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let points = awkward_model().positions;
    for name in ["points.csv", "points.ply", "POINTS.PLY"] {
        let path = dir.path().join(name);
        save_points(&points, &path).unwrap();
        let loaded = load_points(&path).unwrap();
        assert_eq!(bits(&loaded), bits(&points), "{name}");
    }
    let csv = std::fs::read_to_string(dir.path().join("points.csv")).unwrap();
    assert!(csv.starts_with("x,y,z\n0.3,"), "{csv}");
}

#[test]
fn csv_without_header_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "bare.csv", "1,2,3\n4,5,6\n");
    assert_eq!(
        load_points(&path).unwrap(),
        vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]
    );
}

#[test]
fn bad_csv_rows_are_rejected_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    for (contents, needle) in [
        ("x,y,z\n1,2,3\n4,5\n", "line 3"),
        ("x,y,z\n1,2,3,4\n", "line 2"),
        ("1,2,3\n1,abc,3\n", "line 2: `abc` is not a number"),
        ("x,y,z\n1,2,inf\n", "line 2: `inf` is not a finite number"),
        ("x,y,z\n", "no points"),
        ("", "no points"),
    ] {
        let path = write(dir.path(), "bad.csv", contents);
        match load_points(&path) {
            Err(Error::Format { message, .. }) => {
                assert!(message.contains(needle), "{contents:?}: {message}")
            }
            other => panic!("{contents:?}: expected Error::Format, got {other:?}"),
        }
    }
}

#[test]
fn binary_ply_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\n\
        property float x\nproperty float y\nproperty float z\nend_header\n"
        .to_vec();
    for v in [1.0_f32, 2.0, 3.0, -0.5, 0.25, 1e-30] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let path = dir.path().join("binary.ply");
    std::fs::write(&path, bytes).unwrap();
    assert_eq!(
        load_points(&path).unwrap(),
        vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(-0.5, 0.25, 1e-30)]
    );
}

#[test]
fn malformed_ply_is_a_format_error() {
    let dir = tempfile::tempdir().unwrap();
    for contents in [
        "",
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
         property float z\nend_header\n1 2 3\n",
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         end_header\n1 2\n",
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         property float z\nend_header\n1 nan 2\n",
    ] {
        let path = write(dir.path(), "bad.ply", contents);
        let result = load_points(&path);
        assert!(
            matches!(result, Err(Error::Format { .. })),
            "{contents:?}: {result:?}"
        );
    }
}

#[test]
fn unknown_extensions_are_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let points = [Vec3::ZERO];
    for name in ["points.txt", "points"] {
        let path = dir.path().join(name);
        assert!(matches!(
            save_points(&points, &path),
            Err(Error::UnsupportedFormat { .. })
        ));
        assert!(matches!(
            load_points(&path),
            Err(Error::UnsupportedFormat { .. })
        ));
    }
    assert!(matches!(
        export_model(&awkward_model(), &dir.path().join("model.stl")),
        Err(Error::UnsupportedFormat { .. })
    ));
}

#[test]
fn empty_or_non_finite_points_are_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points.csv");
    assert!(matches!(save_points(&[], &path), Err(Error::Format { .. })));
    assert!(matches!(
        save_points(&[Vec3::new(0.0, f32::INFINITY, 0.0)], &path),
        Err(Error::Format { .. })
    ));
    assert!(!path.exists());
}

#[test]
fn export_dispatches_on_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let model = awkward_model();
    let vtp = dir.path().join("model.vtp");
    export_model(&model, &vtp).unwrap();
    assert_eq!(load_model(&vtp).unwrap(), model);
    for name in ["model.csv", "model.ply"] {
        let path = dir.path().join(name);
        export_model(&model, &path).unwrap();
        assert_eq!(bits(&load_points(&path).unwrap()), bits(&model.positions));
    }
}
