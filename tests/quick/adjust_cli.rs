//! `cloudcontrol adjust` and `cloudcontrol resect` end to end on a COLMAP text model.

use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::block::PointKind;
use cloudcontrol::geometry::{quaternion_wxyz_from_matrix, rotation_from_vector, Similarity};
use nalgebra::Vector3;
use std::fmt::Write as _;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_cloudcontrol");

#[test]
fn adjust_a_colmap_model_with_control_measurements_and_check_points() {
    let o = SyntheticOptions {
        strips: 3,
        photos_per_strip: 8,
        tie_points: 3000,
        control_grid: (3, 2),
        check_points: 4,
        seed: 21,
        ..Default::default()
    };
    let syn = generate(&o);
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model");
    std::fs::create_dir_all(&model).unwrap();
    // The model lives in an arbitrary SfM frame; the control is in a projected CRS.
    let sfm = Similarity::new(
        0.01,
        rotation_from_vector(&Vector3::new(0.1, -0.2, 0.7)),
        Vector3::new(3.0, -1.0, 2.0),
    );
    let world = Vector3::new(500_000.0, 3_000_000.0, 0.0);
    let b = &syn.start;
    std::fs::write(
        model.join("cameras.txt"),
        "1 PINHOLE 6000 4000 5000 5000 3000 2000\n",
    )
    .unwrap();
    let mut images = String::new();
    let mut idx = std::collections::BTreeMap::new();
    let (mut ctrl, mut chk, mut meas) = (
        String::from("id,x,y,z,sigma_xy,sigma_z\n"),
        String::from("id,x,y,z\n"),
        String::from("id,image_name,x,y\n"),
    );
    for p in b.photos.values() {
        let pose = sfm.apply_pose(&p.pose);
        let q = quaternion_wxyz_from_matrix(&pose.rotation);
        let t = pose.translation();
        writeln!(
            images,
            "{} {} {} {} {} {} {} {} 1 {}",
            p.id, q[0], q[1], q[2], q[3], t.x, t.y, t.z, p.name
        )
        .unwrap();
        let mut items = Vec::new();
        for pt in b.points.values() {
            for ob in pt.observations.iter().filter(|ob| ob.photo == p.id) {
                let named = pt.kind == PointKind::Check
                    || (pt.kind == PointKind::Control && pt.id % 2 == 0);
                if named {
                    writeln!(
                        meas,
                        "{},{},{},{}",
                        pt.name, p.name, ob.pixel[0], ob.pixel[1]
                    )
                    .unwrap();
                } else {
                    idx.entry(pt.id)
                        .or_insert_with(Vec::new)
                        .push((p.id, items.len()));
                    items.push(format!("{} {} {}", ob.pixel[0], ob.pixel[1], pt.id));
                }
            }
        }
        images += &items.join(" ");
        images += "\n";
    }
    let mut points = String::new();
    for pt in b.points.values() {
        let w = pt.position + world;
        match pt.kind {
            PointKind::Control if pt.id % 2 == 0 => {
                writeln!(ctrl, "{},{},{},{},0.02,0.03", pt.name, w.x, w.y, w.z).unwrap()
            }
            PointKind::Control => {
                writeln!(ctrl, "{},{},{},{},0.02,0.03", pt.id, w.x, w.y, w.z).unwrap()
            }
            PointKind::Check => writeln!(chk, "{},{},{},{}", pt.name, w.x, w.y, w.z).unwrap(),
            PointKind::Tie => {}
        }
        if let Some(tr) = idx.get(&pt.id) {
            let x = sfm.apply(&pt.position);
            let tr: Vec<String> = tr.iter().map(|(i, k)| format!("{i} {k}")).collect();
            writeln!(
                points,
                "{} {} {} {} 128 128 128 0 {}",
                pt.id,
                x.x,
                x.y,
                x.z,
                tr.join(" ")
            )
            .unwrap();
        }
    }
    std::fs::write(model.join("images.txt"), images).unwrap();
    std::fs::write(model.join("points3D.txt"), points).unwrap();
    for (n, s) in [
        ("control.csv", &ctrl),
        ("check.csv", &chk),
        ("meas.csv", &meas),
    ] {
        std::fs::write(dir.path().join(n), s).unwrap();
    }
    let out = dir.path().join("out");
    let report = dir.path().join("report.json");
    let st = Command::new(BIN)
        .args(["-q", "adjust", "--model"])
        .arg(&model)
        .arg("--out")
        .arg(&out)
        .arg("--control")
        .arg(dir.path().join("control.csv"))
        .arg("--check")
        .arg(dir.path().join("check.csv"))
        .arg("--measurements")
        .arg(dir.path().join("meas.csv"))
        .arg("--report")
        .arg(&report)
        .arg("--observations")
        .arg(dir.path().join("observations.csv"))
        .arg("--photos")
        .arg(dir.path().join("photos.csv"))
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    for k in [
        "sigma0",
        "rmse_px",
        "iterations",
        "rejected",
        "photos",
        "points",
        "observations",
        "time_s",
        "check",
    ] {
        assert!(r.get(k).is_some(), "report lacks {k}");
    }
    let s0 = r["sigma0"].as_f64().unwrap();
    assert!((s0 / 0.5 - 1.0).abs() < 0.15, "σ0 {s0}");
    assert_eq!(r["datum"], "control");
    assert_eq!(r["photos"], 24);
    let chk = &r["check"];
    assert_eq!(chk["count"], 4);
    assert!(
        chk["rmse_plan_m"].as_f64().unwrap() < 0.2 && chk["rmse_height_m"].as_f64().unwrap() < 0.5,
        "{chk}"
    );
    // The report is the bounded summary; the listings hold every observation and photo:
    // the kept ones' residual components are the report's scalar observations.
    assert!(r.get("residuals").is_none());
    let count = r["rejected"]["count"].as_u64().unwrap();
    assert_eq!(r["rejected"]["listed"].as_u64().unwrap(), count.min(100));
    let rows: Vec<csv::StringRecord> = csv::Reader::from_path(dir.path().join("observations.csv"))
        .unwrap()
        .records()
        .map(|r| r.unwrap())
        .collect();
    let status = |row: &csv::StringRecord| row[5].to_string();
    assert_eq!(
        rows.iter().filter(|row| status(row) == "rejected").count() as u64,
        count
    );
    let components: usize = rows
        .iter()
        .filter(|row| status(row) == "used")
        .map(|row| (7..10).filter(|&k| !row[k].is_empty()).count())
        .sum();
    assert_eq!(components as u64, r["observations"].as_u64().unwrap());
    let photos = csv::Reader::from_path(dir.path().join("photos.csv"))
        .unwrap()
        .records()
        .count();
    assert_eq!(photos, 24);
    assert_eq!(r["photo_precision"]["photos"], 24);
    // The adjusted model is block-local; the side file carries the origin that brings the
    // photo centres back to world coordinates and onto the truth.
    let side: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out.join(cloudcontrol::formats::colmap::SIDE_FILE)).unwrap(),
    )
    .unwrap();
    let o = &side["origin"];
    let origin = Vector3::new(
        o[0].as_f64().unwrap(),
        o[1].as_f64().unwrap(),
        o[2].as_f64().unwrap(),
    );
    let text = std::fs::read_to_string(out.join("images.txt")).unwrap();
    let mut worst: f64 = 0.0;
    for l in text.lines().filter(|l| !l.starts_with('#')).step_by(2) {
        let t: Vec<f64> = l
            .split_whitespace()
            .take(8)
            .map(|v| v.parse().unwrap())
            .collect();
        let r = cloudcontrol::geometry::matrix_from_quaternion_wxyz([t[1], t[2], t[3], t[4]]);
        let c = -(r.transpose() * Vector3::new(t[5], t[6], t[7]));
        let id = t[0] as u32;
        worst = worst.max((c + origin - world - syn.truth.photos[&id].pose.center).norm());
    }
    assert!(worst < 1.0, "largest centre error {worst} m");

    // Bad input names the problem.
    std::fs::write(
        dir.path().join("bad.csv"),
        "id,x,y,z,sigma_xy,sigma_z\nNOPE,1,2,3,0.1,0.1\n",
    )
    .unwrap();
    let st = Command::new(BIN)
        .args(["-q", "adjust", "--model"])
        .arg(&model)
        .arg("--out")
        .arg(dir.path().join("o2"))
        .arg("--control")
        .arg(dir.path().join("bad.csv"))
        .output()
        .unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("NOPE"));
}

#[test]
fn resect_from_a_csv_with_outliers_in_world_coordinates() {
    use cloudcontrol::geometry::{project, Camera, FrameCamera, Pose};
    let cam = Camera::Frame(FrameCamera::pinhole(6000, 4000, 5000.0));
    let world = Vector3::new(400_000.0, 2_500_000.0, 0.0);
    let truth = Pose::from_opk(0.01, 0.02, 0.3, Vector3::new(20.0, -30.0, 1000.0));
    let mut csv = String::from("x,y,X,Y,Z\n");
    let mut n = 0;
    for i in 0..6 {
        for j in 0..4 {
            let x = Vector3::new(
                -400.0 + 160.0 * i as f64,
                -250.0 + 170.0 * j as f64,
                10.0 * ((i * j) % 5) as f64,
            );
            let mut p = project(&cam, &truth, &x).unwrap().pixel;
            if n % 4 == 1 {
                p.x += 60.0;
            }
            let w = x + world;
            writeln!(csv, "{},{},{},{},{}", p.x, p.y, w.x, w.y, w.z).unwrap();
            n += 1;
        }
    }
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("p.csv"), csv).unwrap();
    let out = dir.path().join("pose.json");
    let st = Command::new(BIN)
        .args([
            "-q",
            "resect",
            "--camera",
            "5000,5000,3000,2000",
            "--width",
            "6000",
            "--height",
            "4000",
            "--points",
        ])
        .arg(dir.path().join("p.csv"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let c: Vec<f64> = r["pose"]["center"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let e = (Vector3::new(c[0], c[1], c[2]) - world - truth.center).norm();
    assert!(e < 1e-3, "centre error {e} m");
    assert_eq!(r["num_inliers"], 18);
}
