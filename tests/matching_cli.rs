//! The `io` and `match` subcommands end to end on files: a synthetic RC10 scan written
//! as TIFF, io.json written atomically with marks, transform and RMSE.

use cloudcontrol::matching::fiducial::{CameraDefinition, ScanOrientation};
use cloudcontrol::matching::GreyImage;
use nalgebra::{Matrix2, Vector2};
use std::path::Path;
use std::process::Command;

#[test]
fn io_subcommand_writes_io_json() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cam_path = root.join("formats/cameras/wild_rc10.json");
    let cam = CameraDefinition::load(&cam_path).unwrap();
    let (n, s) = (2400usize, 0.1);
    let o = ScanOrientation {
        rotation_deg: 180,
        mirrored: false,
    };
    let lin = o.linear(s) * Matrix2::new(1.001, 0.0, 0.0, 0.999);
    let origin = Vector2::new(1201.7, 1198.2);
    let mut img = GreyImage::filled(n, n, 40.0);
    let mut truth = Vec::new();
    for f in &cam.fiducials {
        let c = origin + lin.try_inverse().unwrap() * Vector2::new(f.x_mm, f.y_mm);
        truth.push(c);
        for r in c.y as usize - 10..c.y as usize + 10 {
            for col in c.x as usize - 10..c.x as usize + 10 {
                let mut hit = 0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let p = Vector2::new(
                            col as f64 + (sx as f64 + 0.5) / 4.0,
                            r as f64 + (sy as f64 + 0.5) / 4.0,
                        );
                        let mm = lin * (p - origin) - Vector2::new(f.x_mm, f.y_mm);
                        hit += f.shape.covers(mm.x, mm.y) as u32;
                    }
                }
                img.data[r * n + col] += 150.0 * hit as f32 / 16.0;
            }
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan.tif");
    img.save(&scan, false).unwrap();
    let out = dir.path().join("io.json");
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["io", "--camera"])
        .arg(&cam_path)
        .arg(&scan)
        .args(["--orientation", "180", "--pixel-um", "100", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(doc["transform"]["type"], "affine");
    assert!(doc["rmse_um"].as_f64().unwrap() < 10.0);
    let marks = doc["marks"].as_array().unwrap();
    assert_eq!(marks.len(), 8);
    for (m, t) in marks.iter().zip(&truth) {
        let e = (m["x"].as_f64().unwrap() - t.x).hypot(m["y"].as_f64().unwrap() - t.y);
        assert!(e < 0.2, "mark {}: {e} px", m["id"]);
        assert!(m["residual_um"][0].is_number());
    }
    // A missing scan is a clear error naming the file, and nothing is written.
    let out2 = dir.path().join("io2.json");
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["io", "--camera"])
        .arg(&cam_path)
        .arg(dir.path().join("nope.tif"))
        .arg("--out")
        .arg(&out2)
        .output()
        .unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("nope.tif"));
    assert!(!out2.exists());
    // `match` of a crop of the scan around mark 1.
    let c = truth[0];
    let tpl = img
        .crop(c.x as usize - 12, c.y as usize - 12, 25, 25)
        .unwrap();
    let tp = dir.path().join("tpl.png");
    tpl.save(&tp, false).unwrap();
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .arg("match")
        .arg(&scan)
        .arg(&tp)
        .args([
            "--window",
            &format!("{},{},80,80", c.x as usize - 40, c.y as usize - 40),
        ])
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let m: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    assert_eq!(m["accepted"], true);
    assert!((m["x"].as_f64().unwrap() - (c.x.floor() + 0.5)).abs() < 0.05);
}
