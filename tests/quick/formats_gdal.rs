//! GDAL is opened on first use (src/formats/gdal), not linked: what needs no raster and
//! no CRS runs without it, and what needs it fails naming the library it could not open.

use super::adjust_kite::data;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_cloudcontrol");
const NO_GDAL: &str = "/nonexistent/libgdal.so";

/// `cloudcontrol adjust` of the real kite model with GDAL pointed at a missing library.
fn adjust_without_gdal(extra: &[&std::ffi::OsStr], out: &std::path::Path) -> std::process::Output {
    Command::new(BIN)
        .env("CLOUDCONTROL_GDAL_LIBRARY", NO_GDAL)
        .args(["-q", "adjust", "--model"])
        .arg(data().join("colmap_sparse/txt"))
        .args(extra)
        .args(["--sigma-px", "0.5", "--out"])
        .arg(out)
        .output()
        .unwrap()
}

/// The image lines of a COLMAP text model (those naming a JPEG).
fn images(model: &std::path::Path) -> usize {
    std::fs::read_to_string(model.join("images.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && l.to_lowercase().ends_with(".jpg"))
        .count()
}

#[test]
fn a_colmap_model_adjusts_without_gdal() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = adjust_without_gdal(&[], &out);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert_eq!(images(&out), images(&data().join("colmap_sparse/txt")));
    assert_eq!(images(&out), 12);
}

#[test]
fn a_crs_without_gdal_fails_naming_the_library() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let gcp = data().join("gcp_list_subset.txt");
    let run = adjust_without_gdal(&["--gcp".as_ref(), gcp.as_os_str()], &out);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("no GDAL library could be opened") && err.contains(NO_GDAL),
        "{err}"
    );
    assert!(err.contains("CLOUDCONTROL_GDAL_LIBRARY"), "{err}");
    assert!(
        !out.exists(),
        "nothing is written when the input cannot be read"
    );
}
