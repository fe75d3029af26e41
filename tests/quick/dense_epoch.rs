//! Each epoch's surface by dense matching on the tiny synthetic block, from the epoch's
//! true orientation (the matching, pairs and fusion alone, without the adjustment), scored
//! against the epoch's true surface (`truth/epochs/<epoch>/dsm.tif`, read with GDAL) away
//! from height edges; in the cells that changed since the present, against that epoch's
//! truth and not the present's.

use crate::common;
use cloudcontrol::dense::epoch::{epoch_dsm, DsmOptions, EpochDsm};
use cloudcontrol::formats::raster::read_dem;
use cloudcontrol::matching::oriented::Surface;
use cloudcontrol::matching::GreyImage;
use cloudcontrol::synth::reading::synth_truth_block;
use cloudcontrol::synth::surface_score::score_surface;
use nalgebra::Vector3;
use std::path::Path;

/// The DSM of `epoch` of block `blk` from its true orientation, searched around the
/// present surface (`orthophoto/dem.tif`) ± the default margin.
pub fn truth_dsm(blk: &Path, epoch: &str) -> (EpochDsm, f64) {
    let block = synth_truth_block(blk, epoch).unwrap();
    let (dem, _) = read_dem(&blk.join("orthophoto/dem.tif")).unwrap();
    let prior = Surface::Dem {
        dem: &dem,
        origin: Vector3::from(block.origin),
        sigma_m: 1.0,
    };
    let image = |p: &cloudcontrol::block::Photo| {
        GreyImage::load(p.image.as_ref().unwrap()).map_err(|e| e.to_string())
    };
    let options = DsmOptions::default();
    let out = epoch_dsm(&block, &image, &prior, None, &options, |_, _, _| {}).unwrap();
    let gsd = out.ground_pixel;
    (out, gsd)
}

#[test]
fn every_epoch_of_the_tiny_block_gets_its_own_surface() {
    let blk = common::shared_block("tiny", 2, "good");
    for epoch in ["reference_2024", "digital_2012", "film_1978"] {
        let (result, gsd) = truth_dsm(&blk, epoch);
        let block = synth_truth_block(&blk, epoch).unwrap();
        let pairs: Vec<(u32, u32)> = result
            .pairs
            .iter()
            .map(|p| (p.pair.left, p.pair.right))
            .collect();
        let s = score_surface(&blk, epoch, &result.surface.dsm, &block, &pairs, gsd).unwrap();
        eprintln!("{epoch}: {} pairs, GSD {gsd:.3} m: {s:?}", pairs.len());
        assert!(s.cells > 1000, "{epoch}: {s:?}");
        assert!(s.median_gsd.abs() <= 0.2, "{epoch}: {s:?}");
        assert!(s.nmad_gsd <= 1.0, "{epoch}: {s:?}");
        assert!(s.completeness >= 0.9, "{epoch}: {s:?}");
        if epoch != "reference_2024" {
            // The archive's surface where it changed, not the present's.
            assert!(s.changed_cells > 50, "{epoch}: {s:?}");
            assert!(s.changed_nmad_gsd <= 1.5, "{epoch}: {s:?}");
            assert!(s.changed_nmad_vs_present_gsd > 2.0, "{epoch}: {s:?}");
        }
    }
}

/// `cloudcontrol dsm` on a COLMAP model of the tiny block's digital epoch (its true
/// orientation, photos named by their image files) with the present DEM as prior: the
/// four files, read back by gdalinfo (size, CRS, nodata) and scored against the epoch's
/// truth.
#[test]
fn the_dsm_command_makes_the_surface_of_a_colmap_block() {
    let blk = common::shared_block("tiny", 2, "good");
    let tmp = tempfile::tempdir().unwrap();
    let mut block = synth_truth_block(&blk, "digital_2012").unwrap();
    for p in block.photos.values_mut() {
        let file = p.image.as_ref().unwrap().file_name().unwrap();
        p.name = file.to_string_lossy().into_owned();
    }
    let model = tmp.path().join("model");
    cloudcontrol::formats::convert::write_block(
        &model,
        &block,
        Some(cloudcontrol::formats::convert::BlockFormat::Colmap),
        &Default::default(),
    )
    .unwrap();
    let out = tmp.path().join("dsm");
    let (ok, stdout, stderr) = common::cli(&[
        "--json",
        "dsm",
        "--block",
        model.to_str().unwrap(),
        "--images",
        blk.join("epochs/digital_2012/images").to_str().unwrap(),
        "--dem",
        blk.join("orthophoto/dem.tif").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(!report["pairs"].as_array().unwrap().is_empty());
    for f in ["dsm.tif", "dsm_count.tif", "dsm_spread.tif", "dsm.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // Independent reader: gdalinfo.
    let info = std::process::Command::new("gdalinfo")
        .args(["-json", out.join("dsm.tif").to_str().unwrap()])
        .output()
        .expect("gdalinfo runs");
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(info["size"][0], report["width"]);
    assert_eq!(info["size"][1], report["height"]);
    assert!(info["coordinateSystem"]["wkt"]
        .as_str()
        .unwrap()
        .contains("4547"));
    assert!(info["bands"][0]["noDataValue"].is_number());
    assert_eq!(
        info["geoTransform"][1].as_f64().unwrap(),
        report["cell_m"].as_f64().unwrap()
    );
    // Against the truth.
    let (dsm, _) = read_dem(&out.join("dsm.tif")).unwrap();
    let parsed = cloudcontrol::dense::products::DsmReport::read(&out.join("dsm.json")).unwrap();
    let pairs = parsed.pair_ids();
    let gsd = report["ground_pixel_m"].as_f64().unwrap();
    let s = score_surface(&blk, "digital_2012", &dsm, &block, &pairs, gsd).unwrap();
    eprintln!("dsm command: {s:?}");
    assert!(
        s.median_gsd.abs() <= 0.2 && s.nmad_gsd <= 1.0 && s.completeness >= 0.9,
        "{s:?}"
    );
}
