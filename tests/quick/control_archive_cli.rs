//! `cloudcontrol orient` end to end on a tiny synthetic block: a DEM GeoTIFF and a reference
//! DCP package in, the oriented digital archive epoch out (block close to the truth, report
//! with per-iteration records); a damaged package is refused before anything is written.

use cloudcontrol::control::checkpoints;
use cloudcontrol::control::cloud::CloudOptions;
use cloudcontrol::control::dcp::EpochInfo;
use cloudcontrol::control::export::{export_dcp, DcpExportOptions};
use cloudcontrol::formats::crs::Crs;
use cloudcontrol::formats::raster::{write_dem, GeoTiffOptions};
use cloudcontrol::synth::reading::synth_truth_block;
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common;
use common::synth_checkpoints;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
}

fn prepare(root: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let dir = root.join("block");
    synth::generate(
        &SynthConfig {
            preset: Preset::Tiny,
            seed: 2,
            change: 0.5,
            pos: PosQuality::Good,
            laz: false,
        },
        &dir,
    )
    .unwrap();
    let tiles = cloudcontrol::lidar::catalogue::expand_inputs(&[dir.join("lidar")]).unwrap();
    let block = synth_truth_block(&dir, "reference_2024").unwrap();
    let surface = cloudcontrol::lidar::lidar_surfaces(&tiles, block.origin, 1.0, None).unwrap();
    // The DEM as a user has it: world coordinates in a GeoTIFF.
    let o = block.origin;
    let world = surface.ground.shifted([-o[0], -o[1], -o[2]]).unwrap();
    let dem = root.join("dem.tif");
    write_dem(
        &dem,
        &world,
        &Crs::parse("EPSG:4547").unwrap(),
        &GeoTiffOptions::default(),
    )
    .unwrap();
    let pkg = export_dcp(
        &block,
        &surface,
        EpochInfo {
            name: "reference_2024".into(),
            date: None,
        },
        &root.join("reference.dcp"),
        &DcpExportOptions {
            cloud: CloudOptions {
                interval_px: 40.0,
                max_coplanarity: 0.02,
                ..CloudOptions::default()
            },
            chip_size: 129,
            interest_level: 1,
            ..DcpExportOptions::default()
        },
    )
    .unwrap();
    (dir, dem, pkg.dir)
}

#[test]
fn orient_cli_writes_the_oriented_epoch_and_refuses_a_damaged_package() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, dem, pkg) = prepare(tmp.path());
    let out = tmp.path().join("out");
    let o = bin()
        .args(["orient", "--dcp"])
        .arg(&pkg)
        .arg("--synth")
        .arg(&dir)
        .args(["--epoch", "digital_2012", "--dem"])
        .arg(&dem)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    println!("{stdout}{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success());
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let photos = report["photos"].as_array().unwrap();
    assert_eq!(photos.len(), 2);
    for p in photos {
        assert!(
            p["iterations"].as_array().is_some_and(|i| !i.is_empty()),
            "{p}"
        );
        assert!(
            p["oriented"].as_bool().unwrap() || p["reason"].is_string(),
            "{p}"
        );
    }
    // The written block (world = local + origin) reproduces the checkpoints.
    let block: cloudcontrol::block::Block =
        serde_json::from_slice(&std::fs::read(out.join("block.json")).unwrap()).unwrap();
    // The origin is the one rule's: a whole kilometre south-west of the photos.
    assert!(
        block.origin.iter().all(|v| v % 1000.0 == 0.0),
        "{:?}",
        block.origin
    );
    assert!(!block.photos.is_empty(), "no photo oriented:\n{stdout}");
    let (meas, surveyed) = synth_checkpoints(&dir, "digital_2012");
    let gsd = report["gsd_m"].as_f64().unwrap();
    let e = checkpoints::evaluate_checkpoints(&block, &meas, &surveyed, gsd).unwrap();
    // Height comes from the photos' stereo base: its error is the plan error times the
    // height-to-base ratio (4.4 for this epoch's two photos).
    let centres: Vec<_> = block.photos.values().map(|p| p.pose.center).collect();
    let base = (1..centres.len())
        .map(|k| (centres[k] - centres[0]).xy().norm())
        .fold(0.0, f64::max);
    let ground = surveyed.iter().map(|s| s.1[2]).sum::<f64>() / surveyed.len() as f64;
    let height =
        centres.iter().map(|c| c.z).sum::<f64>() / centres.len() as f64 + block.origin[2] - ground;
    let h_over_b = height / base;
    println!(
        "checkpoints {}: plan {:.2} px, height {:.2} px (H/B {h_over_b:.1})",
        e.count, e.rmse_plan_px, e.rmse_height_px
    );
    assert!(
        e.rmse_plan_px <= 1.0 && e.rmse_height_px <= 0.5 * h_over_b,
        "{e:?}"
    );
    assert!(out.join("colmap").is_dir() && out.join("blocks_exchange.xml").is_file());

    // A damaged chip: refused with the package and chip named, nothing written.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(pkg.join("manifest.json")).unwrap()).unwrap();
    let chip = m["points"][0]["measurements"][0]["chip"]["file"]
        .as_str()
        .unwrap()
        .to_string();
    let path = pkg.join(&chip);
    let mut img = image::open(&path).unwrap().to_luma8();
    let v = img.get_pixel(1, 1).0[0];
    img.put_pixel(1, 1, image::Luma([v.wrapping_add(50)]));
    img.save(&path).unwrap();
    let out2 = tmp.path().join("out2");
    let o = bin()
        .args(["orient", "--dcp"])
        .arg(&pkg)
        .arg("--synth")
        .arg(&dir)
        .args(["--epoch", "digital_2012", "--dem"])
        .arg(&dem)
        .arg("--out")
        .arg(&out2)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("checksum mismatch") && err.contains(&chip),
        "{err}"
    );
    assert!(!out2.exists(), "nothing is written for a refused package");
    // --help carries an example.
    let h = bin().args(["orient", "--help"]).output().unwrap();
    assert!(String::from_utf8_lossy(&h.stdout).contains("Example"));
}
