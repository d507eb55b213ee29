//! 3D Slicer markups files through the file system: a file laid out as
//! Slicer 5 saves a point list (schema v1.0.3, every field Slicer writes)
//! is read, its points converted between LPS and RAS both ways, and a file
//! we write reads back equal with every other field carried over.
#![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

use serde_json::Value;
use tissue_core::Vec3;
use tissue_core::io::markups::{load_markups, save_markups};
use tissue_core::io::space::Space;

/// A point list as Slicer 5 saves it (`F.mrk.json`), in `system`.
fn slicer_point_list(system: &str) -> String {
    format!(
        r#"{{
    "@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#",
    "markups": [
        {{
            "type": "Fiducial",
            "coordinateSystem": "{system}",
            "coordinateUnits": "mm",
            "locked": false,
            "fixedNumberOfControlPoints": false,
            "labelFormat": "%N-%d",
            "lastUsedControlPointNumber": 3,
            "controlPoints": [
                {{
                    "id": "1",
                    "label": "nipple",
                    "description": "",
                    "associatedNodeID": "vtkMRMLModelNode4",
                    "position": [15.0, -10.0, 25.0],
                    "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
                    "selected": true,
                    "locked": false,
                    "visibility": true,
                    "positionStatus": "defined"
                }},
                {{
                    "id": "2",
                    "label": "clip-2",
                    "description": "surgical clip",
                    "associatedNodeID": "",
                    "position": [-20.125, 10.5, 12.75],
                    "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
                    "selected": false,
                    "locked": true,
                    "visibility": true,
                    "positionStatus": "defined"
                }},
                {{
                    "id": "3",
                    "label": "F-3",
                    "description": "",
                    "associatedNodeID": "",
                    "position": [0.0, 0.0, 0.0],
                    "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
                    "selected": true,
                    "locked": false,
                    "visibility": true,
                    "positionStatus": "undefined"
                }}
            ],
            "measurements": [],
            "display": {{
                "visibility": true,
                "opacity": 1.0,
                "color": [0.4, 1.0, 1.0],
                "selectedColor": [1.0, 0.5000076295109484, 0.5000076295109484],
                "activeColor": [0.4, 1.0, 0.0],
                "propertiesLabelVisibility": false,
                "pointLabelsVisibility": true,
                "textScale": 3.0,
                "glyphType": "Sphere3D",
                "glyphScale": 3.0,
                "glyphSize": 5.0,
                "useGlyphScale": true,
                "sliceProjection": false,
                "sliceProjectionUseFiducialColor": true,
                "sliceProjectionOutlinedBehindSlicePlane": false,
                "sliceProjectionColor": [1.0, 1.0, 1.0],
                "sliceProjectionOpacity": 0.6,
                "lineThickness": 0.2,
                "lineColorFadingStart": 1.0,
                "lineColorFadingEnd": 10.0,
                "lineColorFadingSaturation": 1.0,
                "lineColorFadingHueOffset": 0.0,
                "handlesInteractive": false,
                "snapMode": "toVisibleSurface"
            }}
        }}
    ]
}}
"#
    )
}

#[test]
fn a_point_list_saved_by_slicer_is_read_with_its_labels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("F.mrk.json");
    std::fs::write(&path, slicer_point_list("LPS")).unwrap();
    let markups = load_markups(&path, Space::Lps).unwrap();
    // The undefined third point is not a landmark.
    assert_eq!(
        markups.points(),
        [
            Vec3::new(15.0, -10.0, 25.0),
            Vec3::new(-20.125, 10.5, 12.75)
        ]
    );
    assert_eq!(markups.labels(), ["nipple", "clip-2"]);
}

#[test]
fn ras_markups_convert_to_lps_surfaces_on_reading_and_back_on_writing() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("F.mrk.json");
    std::fs::write(&input, slicer_point_list("RAS")).unwrap();
    let markups = load_markups(&input, Space::Lps).unwrap();
    assert_eq!(
        markups.points(),
        [
            Vec3::new(-15.0, 10.0, 25.0),
            Vec3::new(20.125, -10.5, 12.75)
        ],
        "RAS to LPS negates x and y"
    );
    // Moved by 1 mm towards the patient's left (+x in LPS).
    let moved: Vec<Vec3> = markups.points().iter().map(|p| *p + Vec3::X).collect();
    let output = dir.path().join("points.mrk.json");
    save_markups(&markups, &moved, &output).unwrap();
    let written: Value = serde_json::from_str(&std::fs::read_to_string(&output).unwrap()).unwrap();
    let markup = &written["markups"][0];
    assert_eq!(markup["coordinateSystem"], "RAS");
    let points = &markup["controlPoints"];
    // In RAS, 1 mm to the left is -1 in x.
    assert_eq!(
        points[0]["position"],
        serde_json::json!([14.0, -10.0, 25.0])
    );
    assert_eq!(
        points[1]["position"],
        serde_json::json!([-21.125, 10.5, 12.75])
    );
    // The surfaces' space read back: the moved points exactly.
    let back = load_markups(&output, Space::Lps).unwrap();
    assert_eq!(back.points(), moved);
    assert_eq!(back.labels(), markups.labels());
    // Read for RAS surfaces, the RAS file's numbers are taken as they are.
    let as_ras = load_markups(&output, Space::Ras).unwrap();
    assert_eq!(as_ras.points()[0], Vec3::new(14.0, -10.0, 25.0));
}

#[test]
fn a_written_file_reads_back_equal_and_keeps_every_other_field() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("F.mrk.json");
    std::fs::write(&input, slicer_point_list("LPS")).unwrap();
    let markups = load_markups(&input, Space::Lps).unwrap();
    let moved = [
        Vec3::new(15.1, -10.2, 25.3),
        Vec3::new(-20.0, 1e-7, 12.123_457),
    ];
    let output = dir.path().join("points.mrk.json");
    save_markups(&markups, &moved, &output).unwrap();
    let back = load_markups(&output, Space::Lps).unwrap();
    assert_eq!(back.points(), moved, "bit for bit");
    assert_eq!(back.labels(), markups.labels());

    let original: Value = serde_json::from_str(&slicer_point_list("LPS")).unwrap();
    let mut written: Value =
        serde_json::from_str(&std::fs::read_to_string(&output).unwrap()).unwrap();
    // Only the moved positions differ, and the stale measurements are gone.
    for (k, p) in moved.iter().enumerate() {
        let position = &mut written["markups"][0]["controlPoints"][k]["position"];
        let read: Vec<f32> = position
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect();
        assert_eq!(read, p.to_array());
        *position = original["markups"][0]["controlPoints"][k]["position"].clone();
    }
    let mut expected = original.clone();
    expected["markups"][0]
        .as_object_mut()
        .unwrap()
        .remove("measurements");
    assert_eq!(written, expected);
}
