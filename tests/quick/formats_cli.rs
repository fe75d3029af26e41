//! `cloudcontrol convert` and `cloudcontrol ortho` end to end: exit codes, outputs, and
//! error messages naming the file and element.

use std::path::PathBuf;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
}
fn sample(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("formats")
        .join(p)
}

#[test]
fn convert_round_trip_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let xml = dir.path().join("b.xml");
    let out = bin()
        .args(["--json", "convert"])
        .arg(sample("colmap/kapture_maupertuis_colmap4_bin"))
        .arg(&xml)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["photos"].as_u64(), v["points"].as_u64()),
        (Some(4), Some(1039))
    );
    let model = dir.path().join("m");
    let st = bin()
        .args(["-q", "convert", "--text", "--legacy"])
        .arg(&xml)
        .arg(&model)
        .status()
        .unwrap();
    assert!(st.success());
    assert!(model.join("points3D.txt").exists() && !model.join("rigs.txt").exists());
    let a = cloudcontrol::formats::colmap::read(&sample("colmap/kapture_maupertuis_colmap4_bin"))
        .unwrap();
    let b = cloudcontrol::formats::colmap::read(&model).unwrap();
    assert_eq!(a.num_observations(), b.num_observations());
}

#[test]
fn cli_errors_name_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    let out = bin()
        .arg("convert")
        .arg(sample("colmap/kapture_t265_txt"))
        .arg(dir.path().join("x.xml"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("cameras.txt") && e.contains("OPENCV_FISHEYE"),
        "{e}"
    );
    assert!(!dir.path().join("x.xml").exists());

    // Orthophoto of a block whose images are not there: the missing image is named.
    let dem = dir.path().join("dem.tif");
    let d = cloudcontrol::geometry::Dem::from_fn(499000.0, 5801000.0, 10.0, 200, 200, |_, _| 140.0)
        .unwrap();
    cloudcontrol::formats::raster::write_dem(
        &dem,
        &d,
        &cloudcontrol::formats::crs::Crs::from_epsg(25833).unwrap(),
        &Default::default(),
    )
    .unwrap();
    let out = bin()
        .args(["ortho", "--block"])
        .arg(sample(
            "blocks-exchange/synthetic_historical_with_dcp/synthetic_historical_with_dcp.xml",
        ))
        .arg("--dem")
        .arg(&dem)
        .arg("--images")
        .arg(dir.path())
        .arg("--out")
        .arg(dir.path().join("o.tif"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("1965_strip03_0412.tif") && e.contains("missing"),
        "{e}"
    );
    assert!(!dir.path().join("o.tif").exists());
}
