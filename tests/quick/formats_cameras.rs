//! The camera JSON samples of formats/cameras/ read as formats/cameras/README.md documents
//! them: values, pixel origin, Brown distortion as OpenCV, `pixel_to_mm` row by row.

use cloudcontrol::geometry::{Camera, InteriorTransformKind};
use nalgebra::{Vector2, Vector3};
use std::path::Path;

fn sample(name: &str) -> (Camera, serde_json::Value) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("formats/cameras")
        .join(name);
    let text = std::fs::read_to_string(&path).unwrap();
    let camera: Camera = serde_json::from_str(&text).unwrap();
    camera.validate().unwrap();
    (camera, serde_json::from_str(&text).unwrap())
}

/// Brown as OpenCV, written out from the README's formula.
fn opencv_distort(d: [f64; 5], x: f64, y: f64) -> (f64, f64) {
    let [k1, k2, k3, p1, p2] = d;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

#[test]
fn frame_example_reads_as_documented() {
    let (camera, _) = sample("frame_example.json");
    let Camera::Frame(f) = &camera else {
        panic!("frame_example.json is not a frame camera")
    };
    assert_eq!((f.width, f.height), (6000, 4000));
    assert_eq!((f.fx, f.fy, f.cx, f.cy), (8560.5, 8558.9, 3001.25, 1998.75));
    let d = [-0.0421, 0.0613, -0.0087, 0.00012, -0.00008];
    assert_eq!(f.distortion.as_array(), d);

    // On the optical axis: the principal point; the image centre is (width/2, height/2)
    // with the origin at the top-left corner of the top-left pixel.
    let px = camera.project(&Vector3::new(0.0, 0.0, 10.0)).unwrap();
    assert_eq!((px.x, px.y), (f.cx, f.cy));
    // Off axis, towards the lower right (x right, y down): u = fx·x_d + cx, v = fy·y_d + cy.
    let (x, y) = (0.21, 0.13);
    let (xd, yd) = opencv_distort(d, x, y);
    let px = camera
        .project(&Vector3::new(x * 5.0, y * 5.0, 5.0))
        .unwrap();
    assert!((px.x - (f.fx * xd + f.cx)).abs() < 1e-9, "{px:?}");
    assert!((px.y - (f.fy * yd + f.cy)).abs() < 1e-9, "{px:?}");
    assert!(px.x > f.cx && px.y > f.cy);
    let back = camera.pixel_to_normalized([px.x, px.y]).unwrap();
    assert!((back - Vector2::new(x, y)).norm() < 1e-9);
}

#[test]
fn film_example_reads_its_interior_orientation_row_by_row() {
    let (camera, json) = sample("film_example.json");
    let Camera::Film(c) = &camera else {
        panic!("film_example.json is not a film camera")
    };
    assert_eq!((c.width, c.height), (11500, 11500));
    assert_eq!(c.focal_mm, 152.865);
    assert_eq!(c.principal_point_mm, [-0.030, -0.001]);
    assert_eq!(c.interior.kind, InteriorTransformKind::Affine);
    let rows = &json["interior"]["pixel_to_mm"];
    for i in 0..3 {
        for j in 0..3 {
            assert_eq!(c.interior.pixel_to_mm[(i, j)], rows[i][j].as_f64().unwrap());
        }
    }
    // Scan pixel (0, 0), the top-left corner of the scan, is at the top left of the frame
    // in fiducial mm (x right, y up), i.e. the translation column of the matrix.
    let corner = c.interior.pixel_to_mm(Vector2::new(0.0, 0.0));
    assert_eq!((corner.x, corner.y), (-115.052, 114.961));
    // A step along a scan row moves right (x), a step down a column moves down (y).
    let step = c.interior.pixel_to_mm(Vector2::new(1.0, 1.0)) - corner;
    assert!((step.x - (0.020008 + 0.000031)).abs() < 1e-12);
    assert!((step.y - (0.000027 - 0.019994)).abs() < 1e-12);

    // The optical axis meets the scan where pixel_to_mm gives the principal point.
    let px = camera.project(&Vector3::new(0.0, 0.0, 1.0)).unwrap();
    let mm = c.interior.pixel_to_mm(px);
    assert!((mm.x - c.principal_point_mm[0]).abs() < 1e-9);
    assert!((mm.y - c.principal_point_mm[1]).abs() < 1e-9);
    // Camera y is down, fiducial y up: x_mm = x0 + f·x, y_mm = y0 − f·y.
    let px = camera.project(&Vector3::new(0.1, 0.2, 1.0)).unwrap();
    let mm = c.interior.pixel_to_mm(px);
    assert!((mm.x - (c.principal_point_mm[0] + c.focal_mm * 0.1)).abs() < 1e-9);
    assert!((mm.y - (c.principal_point_mm[1] - c.focal_mm * 0.2)).abs() < 1e-9);

    // Written back, the camera is the same JSON (rows and all).
    assert_eq!(serde_json::to_value(&camera).unwrap(), json);
}

#[test]
fn a_flat_pixel_to_mm_is_refused_with_a_reason() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/cameras/film_example.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    json["interior"]["pixel_to_mm"] = serde_json::json!([
        0.020008, 0.000031, -115.052, 0.000027, -0.019994, 114.961, 0.0, 0.0, 1.0
    ]);
    let e = serde_json::from_value::<Camera>(json)
        .unwrap_err()
        .to_string();
    assert!(e.contains("three rows"), "{e}");
}
