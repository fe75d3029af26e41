//! Inputs the fuzz targets (fuzz/) found, replayed through the library: each must end in a
//! typed error naming its input, never a panic, abort or leak.

use cloudcontrol::formats::crs::Crs;
use cloudcontrol::formats::FormatError;
use cloudcontrol::lidar::{LasStream, PointBatch};
use std::path::Path;

fn reproducer(target: &str, name: &str) -> Vec<u8> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/artifacts-fixed")
        .join(target)
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// simple.laz with one byte of its arithmetic-coded points changed: the laz crate's
/// decoder meets a symbol beyond 16 bits (a `debug_assert!` in laz 0.12 decoders.rs, a
/// panic only where debug assertions are on, as in the fuzz build). The header and chunk
/// table are intact, so the file opens; reading its points must end in an error naming it.
#[test]
fn laz_with_corrupt_point_data_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corrupt.laz");
    std::fs::write(&path, reproducer("las", "laz_debug_assert_sym_short")).unwrap();
    let mut s = LasStream::open(&path).expect("header and chunk table are intact");
    assert_eq!(s.info().point_count, 1065, "simple.laz's count");
    let mut batch = PointBatch::default();
    let mut read = 0;
    let err = loop {
        match s.read_batch(1 << 16, &mut batch) {
            Ok(0) => panic!("all {read} points read from corrupt point data"),
            Ok(n) => read += n,
            Err(e) => break e.to_string(),
        }
    };
    assert!(
        err.contains(&path.display().to_string()),
        "names the file: {err}"
    );
}

/// A project's `crs = "EPSG:7963"` (no such CRS in PROJ's database) leaked the GDAL
/// spatial reference the import failed on (gdal 0.19 `SpatialRef::from_definition`), as
/// did a refused PROJ string; LeakSanitizer found it. The error names the definition.
#[test]
fn unknown_crs_is_a_typed_error_naming_it() {
    for def in ["EPSG:7963", "+proj=nosuchprojection +ellps=GRS80"] {
        match Crs::parse(def) {
            Err(FormatError::Crs { crs, message }) => {
                assert_eq!(crs, def);
                assert!(message.contains("not a CRS GDAL/PROJ knows"), "{message}");
            }
            other => panic!("{def}: {other:?}"),
        }
    }
    // The same importers still take good definitions.
    assert_eq!(Crs::parse("EPSG:4547").unwrap().label(), "EPSG:4547");
    assert_eq!(
        Crs::parse("+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs")
            .unwrap()
            .spatial_ref()
            .to_proj4()
            .unwrap()
            .trim(),
        "+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs"
    );
}
