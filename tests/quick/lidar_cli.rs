//! The `cloudcontrol lidar ...` and `cloudcontrol icp` commands end to end on synthetic
//! tiles: JSON outputs, files written, errors naming the input.

use crate::lidar_synth;

use lidar_synth::*;
use std::path::Path;

use crate::common;
use common::cli;

fn json(args: &[&str]) -> serde_json::Value {
    let (ok, out, err) = cli(args);
    assert!(ok, "{args:?} failed: {err}");
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("{args:?}: not JSON ({e}): {out}"))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn lidar_commands_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let tiles = dir.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    let (pts, _) = two_strips(3.0, 0.25, 0.003, 51);
    let (a, b): (Vec<P>, Vec<P>) = pts.iter().partition(|p| p.x - E0 < 100.0);
    write_las(&tiles.join("a.las"), &a, 2, CrsVlr::GeoKeys(EPSG), false);
    write_las(&tiles.join("b.laz"), &b, 4, CrsVlr::Wkt(EPSG), true);

    let cat_path = dir.path().join("catalogue.json");
    let cat = json(&[
        "--json",
        "lidar",
        "catalogue",
        s(&tiles),
        "--out",
        s(&cat_path),
    ]);
    assert_eq!(cat["point_count"].as_u64().unwrap(), pts.len() as u64);
    assert_eq!(cat["crs"], "EPSG:32650");
    assert!(cat_path.exists());
    let info = json(&["--json", "lidar", "info", s(&tiles.join("b.laz"))]);
    assert_eq!(info[0]["compressed"], true);

    let cps_path = dir.path().join("cps.csv");
    let mut csv = String::from("id,X,Y,Z\n");
    for (id, p) in checkpoints(52) {
        csv.push_str(&format!("{id},{:.4},{:.4},{:.4}\n", p[0], p[1], p[2]));
    }
    std::fs::write(&cps_path, csv).unwrap();
    let eval_path = dir.path().join("eval.json");
    let ev = json(&[
        "--json",
        "lidar",
        "eval",
        "--lidar",
        s(&cat_path),
        "--checkpoints",
        s(&cps_path),
        "--out",
        s(&eval_path),
    ]);
    assert_eq!(ev["count"], 30);
    assert!(ev["rmse_m"].as_f64().unwrap() > 0.15);
    assert!(ev["rows"].as_array().unwrap().len() == 30 && eval_path.exists());
    for key in ["mean_m", "rmse_m", "max_abs_m"] {
        assert!(ev[key].is_number(), "{key}");
    }

    let clean = dir.path().join("clean");
    let rep = json(&[
        "--json",
        "lidar",
        "clean",
        "--lidar",
        s(&tiles),
        "--out-dir",
        s(&clean),
        "--reference",
        "1",
    ]);
    let off = rep["strip_offsets"]["strips"][1]["offset_m"][2]
        .as_f64()
        .unwrap();
    assert!((off - 0.25).abs() < 0.01, "offset {off}");
    assert!(clean.join("a.las").exists() && clean.join("b.laz").exists());
    let ev2 = json(&[
        "--json",
        "lidar",
        "eval",
        "--lidar",
        s(&clean),
        "--checkpoints",
        s(&cps_path),
    ]);
    let rmse2 = ev2["rmse_m"].as_f64().unwrap();
    assert!(rmse2 < 0.05, "RMSE after cleaning {rmse2}");
    // Refuses to overwrite its inputs.
    let (ok, _, err) = cli(&[
        "lidar",
        "clean",
        "--lidar",
        s(&tiles),
        "--out-dir",
        s(&tiles),
    ]);
    assert!(!ok && err.contains("overwrite"), "{err}");

    let dem_path = dir.path().join("dem.tif");
    let dem = json(&[
        "--json",
        "lidar",
        "dem",
        "--lidar",
        s(&clean),
        "--cell",
        "2",
        "--out",
        s(&dem_path),
    ]);
    assert_eq!(
        (dem["width"].as_u64(), dem["height"].as_u64()),
        (Some(100), Some(50))
    );
    assert!(dem_path.exists());

    // Errors name the input.
    let (ok, _, err) = cli(&[
        "lidar",
        "eval",
        "--lidar",
        s(&tiles),
        "--checkpoints",
        s(&tiles.join("nope.csv")),
    ]);
    assert!(!ok && err.contains("nope.csv"), "{err}");
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "id,X,Y,Z\nA,1,2\n").unwrap();
    let (ok, _, err) = cli(&[
        "lidar",
        "eval",
        "--lidar",
        s(&tiles),
        "--checkpoints",
        s(&bad),
    ]);
    assert!(
        !ok && err.contains("bad.csv") && err.contains("line 2"),
        "{err}"
    );
}

#[test]
fn icp_command_recovers_a_shift() {
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(4.0, 0.0, 0.0, 61);
    let lidar = dir.path().join("ground.las");
    write_las(&lidar, &pts, 4, CrsVlr::Wkt(EPSG), false);
    // Source: a subset of the surface shifted by (0, 0, 1.5) m. The sloped, undulating
    // ground fixes height, tilt and the along-slope position.
    let mut csv = String::from("X,Y,Z\n");
    for p in pts.iter().step_by(40) {
        csv.push_str(&format!(
            "{:.3},{:.3},{:.3}\n",
            p.x,
            p.y,
            ground(p.x, p.y) + 1.5
        ));
    }
    let src = dir.path().join("src.csv");
    std::fs::write(&src, csv).unwrap();
    let out = dir.path().join("t.json");
    let t = json(&[
        "--json",
        "icp",
        "--source",
        s(&src),
        "--target",
        s(&lidar),
        "--rigid",
        "--initial-gate",
        "5",
        "--out",
        s(&out),
    ]);
    assert!(out.exists());
    let m = &t["matrix"];
    let tz =
        m[2][3].as_f64().unwrap() + m[2][0].as_f64().unwrap() * E0 + m[2][1].as_f64().unwrap() * N0;
    // Vertical correction at the block: −1.5 m.
    let zc = 52.0;
    let z_after = m[2][0].as_f64().unwrap() * (E0 + 100.0)
        + m[2][1].as_f64().unwrap() * (N0 + 50.0)
        + m[2][2].as_f64().unwrap() * zc
        + m[2][3].as_f64().unwrap();
    assert!((z_after - (zc - 1.5)).abs() < 0.05, "z {z_after} (tz {tz})");
    assert_eq!(t["scale"], 1.0);
    assert!(t["rmse_m"].as_f64().unwrap() < 0.1);
    for k in ["iterations", "inliers", "converged", "timing_s"] {
        assert!(!t[k].is_null(), "{k}");
    }
}
