//! What careless use leaves behind: no output folder from a command that fails on its
//! input (`convert --text`), catalogues whose tile paths do not depend on the working
//! directory (and old catalogues still read), and the real `warsaw_small.las` (an empty
//! WKT VLR) read in the CRS given for files without one. (Leftover stage folders of killed
//! runs: pipeline::stages unit tests and tests/pipeline_run.rs.)

use crate::common;
use cloudcontrol::lidar::{Catalogue, CrsSource};
use common::{cli_in as run_in, last_error};
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};

#[test]
fn convert_to_colmap_text_refused_leaves_no_output_folder() {
    let tmp = tempfile::tempdir().unwrap();
    // The sample block with one photo named with blanks, which COLMAP's text format
    // cannot hold (formats/colmap/README.md).
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join(
        "formats/blocks-exchange/synthetic_historical_with_dcp/synthetic_historical_with_dcp.xml",
    );
    let text = std::fs::read_to_string(sample).unwrap();
    let text = text.replacen(
        "<ImagePath>1965_strip03_0412.tif</ImagePath>",
        "<ImagePath>1965 strip03 0412.tif</ImagePath>",
        1,
    );
    let input = tmp.path().join("blanks.xml");
    std::fs::write(&input, text).unwrap();
    let out = tmp.path().join("new/colmap");
    let (ok, _, err) = run_in(
        tmp.path(),
        &["convert", "blanks.xml", "new/colmap", "--text"],
    );
    assert!(!ok);
    assert!(
        err.contains("1965 strip03 0412.tif") && err.contains("write binary instead"),
        "{err}"
    );
    assert!(
        !tmp.path().join("new").exists(),
        "output folder left behind"
    );
    // Through the C ABI too.
    let (i, o) = (
        CString::new(input.to_str().unwrap()).unwrap(),
        CString::new(out.to_str().unwrap()).unwrap(),
    );
    let st = unsafe { cloudcontrol::ffi::ccp_convert(i.as_ptr(), o.as_ptr(), 1, 0) };
    assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
    assert!(
        last_error().contains("write binary instead"),
        "{}",
        last_error()
    );
    assert!(
        !tmp.path().join("new").exists(),
        "output folder left behind"
    );
    // An input that does not exist: nothing made either.
    let (ok, _, _) = run_in(tmp.path(), &["convert", "missing.xml", "new/colmap"]);
    assert!(!ok);
    assert!(!tmp.path().join("new").exists());
    // Binary holds the name: the model is written.
    let (ok, _, err) = run_in(tmp.path(), &["convert", "blanks.xml", "new/colmap"]);
    assert!(ok, "{err}");
    assert!(out.join("images.bin").is_file());
}

/// A LAS 1.4 tile (format 6, ground) of a 20 × 20 m plane z = 100 + 0.1·x at 1 m spacing
/// around (500 000, 5 800 000), in EPSG:2180 (WKT VLR).
fn tile(path: &Path, x0: f64) {
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(6).unwrap();
    let t = |offset| las::Transform {
        scale: 0.001,
        offset,
    };
    b.transforms = las::Vector {
        x: t(500_000.0),
        y: t(5_800_000.0),
        z: t(0.0),
    };
    let mut header = b.into_header().unwrap();
    let wkt = cloudcontrol::formats::crs::Crs::from_epsg(2180)
        .unwrap()
        .to_wkt()
        .unwrap();
    header.set_wkt_crs(wkt.into_bytes()).unwrap();
    let mut w = las::Writer::from_path(path, header).unwrap();
    for i in 0..20 {
        for j in 0..20 {
            let x = x0 + i as f64 + 0.5;
            w.write_point(las::Point {
                x,
                y: 5_800_000.0 + j as f64 + 0.5,
                z: 100.0 + 0.1 * (x - 500_000.0),
                gps_time: Some(0.0),
                classification: las::point::Classification::Ground,
                ..Default::default()
            })
            .unwrap();
        }
    }
    w.close().unwrap();
}

fn files_of(json: &Path) -> Vec<String> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
    assert_eq!(v["schema"], 2);
    v["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["file"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn catalogues_store_paths_that_do_not_depend_on_the_working_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().canonicalize().unwrap();
    std::fs::create_dir_all(root.join("tiles")).unwrap();
    tile(&root.join("tiles/a.las"), 500_000.0);
    tile(&root.join("tiles/b.las"), 500_020.0);
    // Scanned with relative paths: beside the tiles, paths relative to the catalogue;
    // elsewhere, absolute.
    for (out, want) in [
        (
            "tiles/catalogue.json",
            vec!["a.las".to_string(), "b.las".into()],
        ),
        (
            "cat/catalogue.json",
            vec![
                root.join("tiles/a.las").display().to_string(),
                root.join("tiles/b.las").display().to_string(),
            ],
        ),
    ] {
        let (ok, _, err) = run_in(&root, &["lidar", "catalogue", "tiles", "--out", out]);
        assert!(ok, "{err}");
        assert_eq!(files_of(&root.join(out)), want);
    }
    // Used from another working directory, and after the folder moved with its catalogue.
    std::fs::rename(root.join("tiles"), root.join("moved")).unwrap();
    let cat = root.join("moved/catalogue.json");
    let dem = root.join("dem.tif");
    let (ok, _, err) = run_in(
        Path::new("/"),
        &[
            "lidar",
            "dem",
            "--lidar",
            cat.to_str().unwrap(),
            "--cell",
            "2",
            "--out",
            dem.to_str().unwrap(),
        ],
    );
    assert!(ok, "{err}");
    let (d, _) = cloudcontrol::formats::raster::read_dem(&dem).unwrap();
    // Both tiles were read: the DEM spans 40 m of the plane z = 100 + 0.1·(x − 500 000),
    // whose heights average 102 m.
    let z: Vec<f32> = d.data.iter().copied().filter(|v| v.is_finite()).collect();
    let mean = z.iter().map(|&v| v as f64).sum::<f64>() / z.len() as f64;
    println!("DEM {}×{}, mean {mean:.3}", d.width, d.height);
    assert!(d.width as f64 * 2.0 >= 38.0, "{}", d.width);
    assert!((mean - 102.0).abs() < 0.2, "{mean}");
    let loaded = Catalogue::load(&cat).unwrap();
    assert_eq!(loaded.tiles[0].file, root.join("moved/a.las"));

    // A schema 1 catalogue (older builds): absolute paths, and a relative one that only
    // resolves against the catalogue's folder, both read.
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&cat).unwrap()).unwrap();
    v["schema"] = 1.into();
    v["tiles"][1]["file"] = root.join("moved/b.las").display().to_string().into();
    let old = root.join("moved/old.json");
    std::fs::write(&old, v.to_string()).unwrap();
    let loaded = Catalogue::load(&old).unwrap();
    let files: Vec<PathBuf> = loaded.tiles.iter().map(|t| t.file.clone()).collect();
    assert_eq!(files, [root.join("moved/a.las"), root.join("moved/b.las")]);
    assert_eq!(loaded.point_count, 800);
}

#[test]
fn warsaw_small_with_its_empty_wkt_vlr_is_read_in_the_given_crs() {
    let f = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/las_format_samples/warsaw_small.las");
    if !f.is_file() {
        println!("skipped: {} is missing", f.display());
        return;
    }
    // Through the C ABI, as a host would, with the CRS for files without one.
    let path = CString::new(f.to_str().unwrap()).unwrap();
    let crs = CString::new("EPSG:2180").unwrap();
    let ptrs = [path.as_ptr()];
    let mut json = std::ptr::null_mut();
    let st = unsafe {
        cloudcontrol::ffi::ccp_lidar_catalogue_json(ptrs.as_ptr(), 1, crs.as_ptr(), &mut json)
    };
    assert_eq!(st, cloudcontrol::ffi::CcpStatus::Ok, "{}", last_error());
    let text = unsafe { CStr::from_ptr(json) }
        .to_str()
        .unwrap()
        .to_string();
    unsafe { cloudcontrol::ffi::ccp_string_free(json) };
    let cat: Catalogue = serde_json::from_str(&text).unwrap();
    assert_eq!(cat.crs, "EPSG:2180");
    assert_eq!(cat.tiles[0].crs_source, CrsSource::Assumed);
    // laspy 2.5 reads 3000 points.
    assert_eq!(cat.point_count, 3000);
    assert!(
        cat.warnings[0].contains("warsaw_small.las"),
        "{:?}",
        cat.warnings
    );
}
