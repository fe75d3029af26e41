//! `cloudcontrol demo` / `run` end to end on the small synthetic block (issue 10): the
//! summary's numbers against the checkpoints, products read by GDAL, the film epoch's
//! COLMAP and BlocksExchange from its fiducial-frame images (issue 18), a run killed after
//! its reference stage and rerun skips the finished stages and gives identical products.

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{copy_block, epoch, exe, files_below, gdalinfo, json_of, px, shared_demo};

#[test]
fn demo_runs_the_workflow_and_a_killed_run_resumes_identically() {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("pipeline_run");
    let _ = std::fs::remove_dir_all(&root);
    // The demo, run once for the test binaries, copied: `demo` again finds its block and
    // every stage done (the ledger's fingerprints do not depend on the folder), and
    // prints the summary of the products found.
    let shared = shared_demo();
    copy_block(&shared, &root);
    let t = Instant::now();
    let out = Command::new(exe())
        .args(["--json", "demo", "--out"])
        .arg(&root)
        .output()
        .unwrap();
    let v = json_of(&out);
    eprintln!("demo again: {:.1} s", t.elapsed().as_secs_f64());
    assert_eq!(v["ran"].as_array().unwrap().len(), 0, "{}", v["ran"]);
    let report = &v["report"];
    for e in report["epochs"].as_array().unwrap() {
        eprintln!(
            "{}: {}/{} oriented, plan {:.2} px, height {:.2} px, {} checkpoints",
            e["name"],
            e["photos_oriented"],
            e["photos_total"],
            px(e, "check_rmse_plan_m"),
            px(e, "check_rmse_height_m"),
            e["checkpoints"].as_array().map_or(0, |c| c.len())
        );
    }
    let oriented =
        |e: &Value| e["photos_oriented"].as_f64().unwrap() / e["photos_total"].as_f64().unwrap();
    // Reference against the LiDAR alone: every photo, within a ground pixel.
    let r = epoch(report, "reference_2024");
    assert_eq!(oriented(r), 1.0);
    assert!(px(r, "check_rmse_plan_m") <= 1.0 && px(r, "check_rmse_height_m") <= 1.0);
    // Digital archive from the reference DCPs.
    let d = epoch(report, "digital_2012");
    assert!(oriented(d) >= 0.8, "digital oriented {}", oriented(d));
    assert!(px(d, "check_rmse_plan_m") <= 1.0 && px(d, "check_rmse_height_m") <= 1.5);
    // Film (0.5 m ground pixel, half the scene changed) from the digital epoch's DCPs.
    let f = epoch(report, "film_1978");
    assert!(oriented(f) >= 0.9);
    assert!(px(f, "check_rmse_plan_m") <= 1.0, "film plan");
    assert!(px(f, "check_rmse_height_m") <= 2.0, "film height");

    // Products: GDAL reads the orthophoto with the project CRS and the epoch's pixel.
    let run = root.join("run");
    let ortho = run.join("outputs-reference_2024/orthophoto.tif");
    let info = Command::new("gdalinfo")
        .arg("-json")
        .arg(&ortho)
        .output()
        .unwrap();
    let info: Value = serde_json::from_slice(&info.stdout).expect("gdalinfo JSON");
    let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap_or("");
    assert!(wkt.contains("4547"), "orthophoto CRS: {wkt}");
    let pixel = info["geoTransform"][1].as_f64().unwrap();
    assert!(
        (pixel - r["gsd_m"].as_f64().unwrap()).abs() < 0.03,
        "pixel {pixel}"
    );
    assert!(run.join("outputs-reference_2024/colmap").is_dir());

    // The film epoch: COLMAP and BlocksExchange of its frame images, listed by the demo,
    // nothing skipped; its orthophoto (from the frame images) and the LiDAR DEM read by
    // GDAL.
    let listed: Vec<&str> = v["products"]["film_1978"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|p| p.as_str())
        .collect();
    for f in [
        "colmap",
        "blocks_exchange.xml",
        "orthophoto.tif",
        "resampled",
    ] {
        assert!(
            listed
                .iter()
                .any(|p| p.ends_with(&format!("outputs-film_1978/{f}"))),
            "{f} not listed: {listed:?}"
        );
    }
    let film = run.join("outputs-film_1978");
    assert_eq!(
        std::fs::read_to_string(film.join("skipped.json")).unwrap(),
        "{}"
    );
    let xml = std::fs::read_to_string(film.join("blocks_exchange.xml")).unwrap();
    let photos = xml.matches("<ImagePath>resampled/").count();
    assert!(photos as f64 >= 0.9 * f["photos_total"].as_f64().unwrap());
    assert!(xml.contains("<FocalLength>152.865</FocalLength>"));
    assert!(xml.contains("<CheckPoint>true</CheckPoint>"));
    // The reference's photos are named relative to the XML's folder (no BaseImagePath, no
    // absolute path of this machine): the block moves with the project's folders.
    let ref_dir = run.join("outputs-reference_2024");
    let xml = std::fs::read_to_string(ref_dir.join("blocks_exchange.xml")).unwrap();
    assert!(!xml.contains("<BaseImagePath>"), "BaseImagePath written");
    let paths: Vec<&str> = xml
        .split("<ImagePath>")
        .skip(1)
        .filter_map(|s| s.split("</ImagePath>").next())
        .collect();
    assert!(!paths.is_empty());
    for p in &paths {
        assert!(!p.starts_with('/') && !p.contains('\\'), "{p}");
        assert!(
            ref_dir.join(p).is_file(),
            "{p} not found from the XML's folder"
        );
    }
    // The LiDAR's surfaces once for the project, not in every epoch's outputs.
    let control: Vec<&str> = v["products"]["control"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|p| p.as_str())
        .collect();
    for f in ["control/lidar_dem.tif", "control/lidar_dsm.tif"] {
        assert!(control.iter().any(|p| p.ends_with(f)), "{f}: {control:?}");
    }
    assert!(!film.join("lidar_dem.tif").exists());
    for (tif, bands) in [
        (film.join("orthophoto.tif"), 4),
        (run.join("control/lidar_dem.tif"), 1),
    ] {
        let info = gdalinfo(&tif);
        let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap_or("");
        assert!(wkt.contains("4547"), "{tif:?} CRS: {wkt}");
        assert_eq!(info["bands"].as_array().unwrap().len(), bands, "{tif:?}");
    }
    one_lattice(&run);
    let ortho: Value =
        serde_json::from_slice(&std::fs::read(film.join("orthophoto.json")).unwrap()).unwrap();
    assert!(
        ortho["filled"].as_f64().unwrap()
            > 0.5 * ortho["width"].as_f64().unwrap() * ortho["height"].as_f64().unwrap()
    );
    // The LiDAR of the demo covers just the block: every tile lies under the photos.
    let sel: Value =
        serde_json::from_slice(&std::fs::read(run.join("sources/selection.json")).unwrap())
            .unwrap();
    let total = sel["tiles_total"].as_u64().unwrap() as usize;
    assert!(total > 0);
    assert_eq!(sel["selected"].as_array().unwrap().len(), total);
    assert!(run.join("report/report.html").is_file());

    // A second run of the same project skips every stage.
    let project = root.join("block/project.toml");
    let again = json_of(
        &Command::new(exe())
            .args(["--json", "run"])
            .arg(&project)
            .output()
            .unwrap(),
    );
    assert_eq!(
        again["ran"].as_array().unwrap().len(),
        0,
        "{}",
        again["ran"]
    );

    // Kill a run of the same project into another folder once its reference epoch is
    // done, rerun it, and compare every product with the uninterrupted run.
    let text = std::fs::read_to_string(&project)
        .unwrap()
        .replace("output = \"../run\"", "output = \"../run2\"");
    let project2 = root.join("block/project2.toml");
    std::fs::write(&project2, text).unwrap();
    let run2 = root.join("run2");
    let mut child = Command::new(exe())
        .args(["-q", "run"])
        .arg(&project2)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    loop {
        // Finished when the ledger's record of it has its input fingerprint: its temporary
        // folder is listed under `temporaries` before it is made, and its record is put
        // first without one (`inputs: null`) while the folder is moved into place.
        let ledger = std::fs::read_to_string(run2.join("stages.json")).unwrap_or_default();
        let done = serde_json::from_str::<Value>(&ledger)
            .is_ok_and(|v| v["stages"]["epoch-reference_2024"]["inputs"].is_string());
        if done {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "reference stage never finished"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !run2.join("report").exists(),
        "the killed run got to its end"
    );
    // Temporary outputs of the killed run are removed when the next run takes the folder;
    // a name that only looks like one (not a name the product writes) is kept.
    std::fs::create_dir_all(run2.join(".epoch-old.part-1/sub")).unwrap();
    let resumed = json_of(
        &Command::new(exe())
            .args(["--json", "run"])
            .arg(&project2)
            .output()
            .unwrap(),
    );
    let leftovers: Vec<_> = std::fs::read_dir(&run2)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".part-") && n != ".epoch-old.part-1")
        .collect();
    assert!(leftovers.is_empty(), "left behind: {leftovers:?}");
    assert!(
        run2.join(".epoch-old.part-1/sub").is_dir(),
        "a name not the product's removed"
    );
    let skipped: Vec<&str> = resumed["skipped"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|s| s.as_str())
        .collect();
    assert!(
        skipped.contains(&"sources") && skipped.contains(&"epoch-reference_2024"),
        "finished stages redone: skipped {skipped:?}"
    );
    // Stage folders hold the same files with the same bytes, timing records aside.
    let timing = [
        "result.json",
        "epoch.json",
        "report.json",
        "report.html",
        "reference.json",
        "dsm.json",
    ];
    for dir in std::fs::read_dir(&run).unwrap() {
        let dir = dir.unwrap().path();
        if !dir.is_dir() {
            continue;
        }
        let other = run2.join(dir.file_name().unwrap());
        for f in files_below(&dir) {
            let rel = f.strip_prefix(&run).unwrap();
            if timing.iter().any(|t| rel.ends_with(t)) {
                continue;
            }
            let a = std::fs::read(&f).unwrap();
            let b =
                std::fs::read(run2.join(rel)).unwrap_or_else(|e| panic!("{}: {e}", rel.display()));
            // Products name the photos by absolute paths: the demo's those of the shared
            // folder it ran in, the resumed run's those of this one.
            let same = a == b
                || String::from_utf8(a).is_ok_and(|a| {
                    a.replace(&*shared.to_string_lossy(), &root.to_string_lossy())
                        .into_bytes()
                        == b
                });
            assert!(same, "{} differs after the resumed run", rel.display());
        }
        assert!(other.is_dir());
    }
}

/// An epoch that orients no photo (here: every scan is a truncated file) does not stop the run:
/// every photo is reported with its reason, its checkpoints are not evaluated, its
/// orthophoto is skipped with the reason, its LiDAR DEM is written, and the other epochs
/// and the report are complete.
#[test]
fn an_epoch_without_an_oriented_photo_does_not_stop_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    let o = Command::new(exe())
        .args(["synth", "--preset", "tiny", "--seed", "2", "--out"])
        .arg(&blk)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let images = blk.join("epochs/film_1978/images");
    for e in std::fs::read_dir(&images).unwrap() {
        let p = e.unwrap().path();
        let head = std::fs::read(&p).unwrap()[..64].to_vec();
        std::fs::write(&p, head).unwrap();
    }
    let o = Command::new(exe())
        .args(["run", "--json"])
        .arg(blk.join("project.toml"))
        .output()
        .unwrap();
    // The run finishes partial (exit 3), saying which epoch, how many and why.
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(common::EXIT_PARTIAL), "{err}");
    assert!(
        err.contains("epoch film_1978: 0 of ") && err.contains(": image "),
        "{err}"
    );
    let summary = json_of(&o);
    // The tiny preset's digital epoch may orient fewer than all its photos too: the film
    // epoch is looked up by name.
    let film_partial = summary["partial"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["epoch"] == "film_1978")
        .unwrap_or_else(|| panic!("film_1978 not partial: {summary}"));
    assert_eq!(film_partial["oriented"], 0, "{summary}");
    let run = tmp.path().join("run");
    let film: Value =
        serde_json::from_slice(&std::fs::read(run.join("epoch-film_1978/result.json")).unwrap())
            .unwrap();
    let photos = film["photos"].as_array().unwrap();
    assert!(!photos.is_empty());
    for p in photos {
        assert_eq!(p["oriented"], false, "{p}");
        assert_eq!(p["reason"]["kind"], "image", "{p}");
    }
    let out = run.join("outputs-film_1978");
    let skipped: Value =
        serde_json::from_slice(&std::fs::read(out.join("skipped.json")).unwrap()).unwrap();
    assert_eq!(skipped["orthophoto"], "no photo of the epoch was oriented");
    // No empty model is written, nor listed among the products.
    for model in ["colmap", "blocks_exchange"] {
        assert_eq!(skipped[model], "no photo of the epoch was oriented");
    }
    assert!(!out.join("colmap").exists() && !out.join("blocks_exchange.xml").exists());
    let listed = summary["products"]["film_1978"].to_string();
    assert!(
        !listed.contains("colmap") && !listed.contains("blocks_exchange"),
        "{listed}"
    );
    assert!(!out.join("orthophoto.tif").exists() && run.join("control/lidar_dem.tif").is_file());
    assert!(run.join("report/report.html").is_file());
    assert!(run.join("outputs-reference_2024/orthophoto.tif").is_file());
}

/// Every raster of the run, as GDAL reads it: a Cloud-Optimised GeoTIFF, the same
/// upper-left corner, cells of 1 m times a power of two (the default lattice), no rotation. So any two subtract cell by
/// cell: numpy's `a[::k, ::k]` of the finer against the coarser, no resampling.
fn one_lattice(run: &Path) {
    let rasters: Vec<_> = files_below(run)
        .into_iter()
        .filter(|p| {
            p.extension().is_some_and(|e| e == "tif")
                && !p.components().any(|c| c.as_os_str() == "resampled")
        })
        .collect();
    let names: Vec<String> = rasters.iter().map(|p| p.display().to_string()).collect();
    for want in [
        "orthophoto.tif",
        "dsm.tif",
        "dsm_spread.tif",
        "dh.tif",
        "lidar_dsm.tif",
    ] {
        assert!(
            names.iter().any(|n| n.ends_with(want)),
            "no {want} among {names:?}"
        );
    }
    let mut corner: Option<(f64, f64)> = None;
    for tif in &rasters {
        let info = gdalinfo(tif);
        let gt: Vec<f64> = info["geoTransform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG",
            "{tif:?} is not a Cloud-Optimised GeoTIFF"
        );
        assert_eq!((gt[2], gt[4]), (0.0, 0.0), "{tif:?} rotated");
        assert_eq!(gt[1], -gt[5], "{tif:?} cells not square");
        let n = gt[1].log2();
        assert_eq!(n, n.round(), "{tif:?}: cell {} m is not 2^n m", gt[1]);
        match corner {
            None => corner = Some((gt[0], gt[3])),
            Some(c) => assert_eq!(c, (gt[0], gt[3]), "{tif:?} corner"),
        }
    }
}
