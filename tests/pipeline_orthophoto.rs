//! An orthophoto with a DEM as the only control (issue 20): the small synthetic block's
//! `project_orthophoto.toml` (no LiDAR, no reference flight) orients its digital and film
//! epochs from the orthophoto's control points, each epoch's report names what controlled
//! it, and the products carry the given DEM under its own name; with the LiDAR and the
//! reference flight as well, the archive epochs take both. Project keys of the
//! orthophoto source are checked before any work.

use serde_json::Value;
use std::path::Path;
use std::process::Command;

mod common;
use common::{block_copy, epoch, exe, json_of, px, without_surfaces};

#[test]
fn the_small_block_is_oriented_from_its_orthophoto_and_dem_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    block_copy("small", 2, "rough", &blk);
    without_surfaces(&blk.join("project.toml"));
    without_surfaces(&blk.join("project_orthophoto.toml"));
    let project = std::fs::read_to_string(blk.join("project_orthophoto.toml")).unwrap();
    assert!(!project.contains("lidar") && !project.contains("[reference]"));
    let out = Command::new(exe())
        .args(["--json", "run"])
        .arg(blk.join("project_orthophoto.toml"))
        .output()
        .unwrap();
    let v = json_of(&out);
    let report = &v["report"];
    let oriented =
        |e: &Value| e["photos_oriented"].as_f64().unwrap() / e["photos_total"].as_f64().unwrap();
    for e in report["epochs"].as_array().unwrap() {
        eprintln!(
            "{}: {}/{} oriented, plan {:.2} GSD, height {:.2} GSD; control {}",
            e["name"],
            e["photos_oriented"],
            e["photos_total"],
            px(e, "check_rmse_plan_m"),
            px(e, "check_rmse_height_m"),
            e["control"]
        );
    }
    // Issue 20's targets for a film epoch from an orthophoto and a DEM.
    let f = epoch(report, "film_1978");
    assert!(oriented(f) >= 0.9, "film oriented {}", oriented(f));
    assert!(px(f, "check_rmse_plan_m") <= 1.5, "film plan");
    assert!(px(f, "check_rmse_height_m") <= 2.0, "film height");
    // The digital epoch between them, from the orthophoto alone, to the archive targets.
    let d = epoch(report, "digital_2012");
    assert!(oriented(d) >= 0.8, "digital oriented {}", oriented(d));
    assert!(px(d, "check_rmse_plan_m") <= 1.5 && px(d, "check_rmse_height_m") <= 2.0);
    // What controlled each epoch.
    let control = |e: &Value| e["control"].to_string();
    assert!(control(d).contains("orthophoto") && !control(d).contains("epoch"));
    assert!(control(f).contains("orthophoto") && control(f).contains("digital_2012"));

    let run = tmp.path().join("run_orthophoto");
    assert!(!run.join("sources/lidar").exists());
    let ortho: Value =
        serde_json::from_slice(&std::fs::read(run.join("dcp-orthophoto/orthophoto.json")).unwrap())
            .unwrap();
    assert!(ortho["points"].as_u64().unwrap() >= 20, "{ortho}");
    // The products' DEM is the one given, named as such, read by GDAL in the project CRS.
    let dem = run.join("control/control_dem.tif");
    assert!(!run.join("control/lidar_dem.tif").exists());
    let info = Command::new("gdalinfo")
        .arg("-json")
        .arg(&dem)
        .output()
        .unwrap();
    let info: Value = serde_json::from_slice(&info.stdout).expect("gdalinfo JSON");
    assert!(info["coordinateSystem"]["wkt"]
        .as_str()
        .unwrap_or("")
        .contains("4547"));
    assert!(run.join("outputs-film_1978/orthophoto.tif").is_file());

    // Any combination with the LiDAR works: the block's own project (LiDAR and reference
    // flight) with the orthophoto added; the archive epochs take both packages.
    let text = std::fs::read_to_string(blk.join("project.toml"))
        .unwrap()
        .replace("output = \"../run\"", "output = \"../run_both\"")
        .replace(
            "lidar = [\"lidar\"]\n",
            "lidar = [\"lidar\"]\northophoto = \"orthophoto/orthophoto.tif\"\ndem = \"orthophoto/dem.tif\"\ndem_sigma_m = 0.1\n",
        );
    std::fs::write(blk.join("project_both.toml"), text).unwrap();
    let out = Command::new(exe())
        .args(["--json", "run"])
        .arg(blk.join("project_both.toml"))
        .output()
        .unwrap();
    let v = json_of(&out);
    let report = &v["report"];
    let r = epoch(report, "reference_2024");
    assert!(control(r).contains("LiDAR"), "{}", control(r));
    assert!(px(r, "check_rmse_plan_m") <= 1.0 && px(r, "check_rmse_height_m") <= 1.0);
    for name in ["digital_2012", "film_1978"] {
        let e = epoch(report, name);
        eprintln!(
            "LiDAR + reference + orthophoto, {name}: {}/{} oriented, plan {:.2} GSD, height {:.2} GSD",
            e["photos_oriented"],
            e["photos_total"],
            px(e, "check_rmse_plan_m"),
            px(e, "check_rmse_height_m")
        );
        assert!(control(e).contains("orthophoto") && control(e).contains("reference_2024"));
        assert!(oriented(e) >= 0.8, "{name}");
        assert!(px(e, "check_rmse_plan_m") <= 1.0 && px(e, "check_rmse_height_m") <= 1.5);
    }
    let both = tmp.path().join("run_both");
    assert!(both.join("control/lidar_dem.tif").is_file());
    assert!(both.join("dcp-orthophoto/package/manifest.json").is_file());
}

/// The keys of the orthophoto source are checked before any work, naming the key.
#[test]
fn orthophoto_source_keys_are_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for f in ["ortho.tif", "dem.tif", "cam.json", "pos.csv"] {
        std::fs::write(d.join(f), "").unwrap();
    }
    std::fs::create_dir_all(d.join("photos")).unwrap();
    let load = |control: &str, reference: bool| {
        let reference = if reference {
            "[reference]\nname = \"r\"\ndate = \"2020\"\nphotos = \"photos\"\ncamera = \"cam.json\"\npos = \"pos.csv\"\n"
        } else {
            ""
        };
        let text = format!(
            "name = \"t\"\ncrs = \"EPSG:32611\"\noutput = \"run\"\n[control]\n{control}\n{reference}\
             [[archive]]\nname = \"a\"\ndate = \"1990\"\nphotos = \"photos\"\ncamera = \"cam.json\"\npos = \"pos.csv\""
        );
        let p = Path::new(d).join("p.toml");
        std::fs::write(&p, text).unwrap();
        cloudcontrol::pipeline::project::Project::load(&p)
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let both = "orthophoto = \"ortho.tif\"\ndem = \"dem.tif\"";
    assert!(load(both, false).is_ok());
    let e = load("orthophoto = \"ortho.tif\"", false).unwrap_err();
    assert!(e.contains("control.dem") && e.contains("missing"), "{e}");
    let e = load("dem = \"dem.tif\"", false).unwrap_err();
    assert!(
        e.contains("control.orthophoto") && e.contains("missing"),
        "{e}"
    );
    let e = load("", false).unwrap_err();
    assert!(
        e.contains("control.lidar") && e.contains("no control source"),
        "{e}"
    );
    // A reference epoch is oriented against LiDAR, which the orthophoto does not replace.
    let e = load(both, true).unwrap_err();
    assert!(e.contains("`reference`") && e.contains("LiDAR"), "{e}");
    let e = load(&format!("{both}\ndem_sigma_m = 0"), false).unwrap_err();
    assert!(e.contains("control.dem_sigma_m"), "{e}");
    let e = load(&format!("{both}\northophoto_crs = \"EPSG:999999\""), false).unwrap_err();
    assert!(e.contains("control.orthophoto_crs"), "{e}");
    let e = load(&format!("{both}\northophoto_date = \"spring\""), false).unwrap_err();
    assert!(e.contains("control.orthophoto_date"), "{e}");
    let e = load("orthophoto = \"nowhere.tif\"\ndem = \"dem.tif\"", false).unwrap_err();
    assert!(
        e.contains("control.orthophoto") && e.contains("nowhere.tif"),
        "{e}"
    );
}
