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
            // The archive's surface where it changed, not the present's (over enough
            // changed cells for an NMAD: the tiny block's digital epoch has 47 of its
            // DSM's 0.25 m cells where the scene changed).
            assert!(s.changed_cells > 30, "{epoch}: {s:?}");
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
        "--points",
    ]);
    assert!(ok, "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(!report["pairs"].as_array().unwrap().is_empty());
    for f in [
        "dsm.tif",
        "dsm_count.tif",
        "dsm_spread.tif",
        "dsm.json",
        "dsm_points.laz",
    ] {
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
    // A Cloud-Optimised GeoTIFF, as GDAL reads its layout.
    assert_eq!(
        info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG",
        "{info}"
    );
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
    // The points, read by the las crate: one a cell with a height, at its centre, with
    // the cell's height and count, in the block's CRS.
    let (count, _) = read_dem(&out.join("dsm_count.tif")).unwrap();
    let mut reader = las::Reader::from_path(out.join("dsm_points.laz")).unwrap();
    let wkt = reader
        .header()
        .all_vlrs()
        .find(|v| v.record_id == 2112)
        .unwrap();
    assert!(String::from_utf8_lossy(&wkt.data).contains("4547"));
    let mut n = 0;
    for p in reader.points() {
        let p = p.unwrap();
        let t = &dsm.transform.0;
        let (c, r) = ((p.x - t[0]) / t[1], (p.y - t[3]) / t[5]);
        // Stored in millimetres.
        let off = |v: f64| (v.fract() - 0.5).abs() * t[1];
        assert!(off(c) <= 0.000_501 && off(r) <= 0.000_501, "{c} {r}");
        let i = r as usize * dsm.width + c as usize;
        assert!(
            (p.z - f64::from(dsm.data[i])).abs() <= 0.000_501,
            "{} {}",
            p.z,
            dsm.data[i]
        );
        assert_eq!(f32::from(p.intensity), count.data[i]);
        n += 1;
    }
    assert_eq!(n, report["cells_with_height"].as_u64().unwrap());
    assert_eq!(report["points"].as_u64(), Some(n));
    assert!(
        s.median_gsd.abs() <= 0.2 && s.nmad_gsd <= 1.0 && s.completeness >= 0.9,
        "{s:?}"
    );
}

/// `[outputs] ortho_surface = "dsm"`: the tiny block's reference epoch (the one its
/// photos orient; its archive epochs are too small to) gets its orthophoto rectified onto
/// its own surface. Its report's cells, set against the DSM read back with GDAL: every
/// cell with a height is the DSM's own, the others the LiDAR DEM's; the DEM product is
/// still the LiDAR's. A project asking for it without `dsm` is refused, naming the key.
#[test]
fn the_orthophoto_can_be_rectified_onto_the_epochs_own_surface() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("blk");
    common::block_copy("tiny", 2, "good", &blk);
    let toml = std::fs::read_to_string(blk.join("project.toml"))
        .unwrap()
        .replace("output = \"../run\"", "output = \"run\"");
    let project = blk.join("ortho_on_dsm.toml");
    std::fs::write(
        &project,
        format!("{toml}\n[outputs]\northo_surface = \"dsm\"\n"),
    )
    .unwrap();
    let out = std::process::Command::new(common::exe())
        .args(["--json", "run", project.to_str().unwrap()])
        .output()
        .unwrap();
    // Done, or partial: the tiny block's film scans are too small to orient.
    assert!(
        matches!(out.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = blk.join("run");
    let outputs = run.join("outputs-reference_2024");
    let ortho: serde_json::Value =
        serde_json::from_slice(&std::fs::read(outputs.join("orthophoto.json")).unwrap()).unwrap();
    let s = &ortho["surface"];
    assert_eq!(s["surface"], "dsm", "{ortho}");
    let (dsm, _) = read_dem(&run.join("surface-reference_2024/dsm.tif")).unwrap();
    let own = dsm.data.iter().filter(|v| v.is_finite()).count();
    assert_eq!(s["cells_from_dsm"].as_u64(), Some(own as u64));
    // The DEM product is still the LiDAR's, once for the project (its cell, not the
    // DSM's), on the same lattice: the same corner.
    let (lidar, _) = read_dem(&run.join("control/lidar_dem.tif")).unwrap();
    // The holes are filled from the LiDAR DEM, exactly where it has a height (the DSM's
    // grid starts at the lattice's corner, out in a margin the LiDAR does not cover).
    let holes_under_lidar = (0..dsm.data.len())
        .filter(|&i| {
            let (c, r) = ((i % dsm.width) as f64 + 0.5, (i / dsm.width) as f64 + 0.5);
            let (x, y) = dsm.transform.pixel_to_world(c, r);
            !dsm.data[i].is_finite() && lidar.height_at(x, y).is_some()
        })
        .count();
    assert_eq!(
        s["cells_from_control"].as_u64(),
        Some(holes_under_lidar as u64)
    );
    assert!(holes_under_lidar > 0);
    assert!(
        own as f64 >= 0.5 * dsm.data.len() as f64,
        "{own} of {}",
        dsm.data.len()
    );
    assert!(!outputs.join("lidar_dem.tif").exists());
    assert_ne!(lidar.transform.0[1], dsm.transform.0[1]);
    assert_eq!(
        (lidar.transform.0[0], lidar.transform.0[3]),
        (dsm.transform.0[0], dsm.transform.0[3])
    );

    std::fs::write(
        &project,
        format!("{toml}\n[outputs]\ndsm = false\northo_surface = \"dsm\"\n"),
    )
    .unwrap();
    let (ok, stdout, stderr) = common::cli(&["--json", "run", project.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stdout.contains("outputs.ortho_surface") && stdout.contains("outputs.dsm"),
        "{stdout}{stderr}"
    );
}
