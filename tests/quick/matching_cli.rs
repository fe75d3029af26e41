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

/// `ties --block`: a strip of three photos of a textured plane, written as 16-bit TIFF
/// with a block JSON whose EO is off by ~2 m / 0.3°; the command predicts through the
/// mean height, writes the report and the block with tie points.
#[test]
fn ties_subcommand_uses_the_approximate_orientation() {
    use cloudcontrol::block::{Block, BlockCamera, Photo, PosPrior};
    use cloudcontrol::geometry::{back_project, Camera, FrameCamera, Pose};
    use nalgebra::{Matrix3, Vector3};

    let (w, h) = (320usize, 240usize);
    let camera = Camera::Frame(FrameCamera::pinhole(w as u32, h as u32, 400.0));
    let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    // Ground at z = 0, 400 m below: 1 m per pixel; base 128 m = 60 % overlap.
    let tex = |x: f64, y: f64| {
        100.0
            + 30.0 * (x / 7.3 + 0.4 * y / 5.1).sin()
            + 25.0 * (y / 6.7 - 0.3 * x / 9.9).cos()
            + 20.0 * ((x + y) / 4.3).sin() * ((x - y) / 11.0).cos()
    };
    let dir = tempfile::tempdir().unwrap();
    let mut block = Block::new();
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "cam".into(),
            model: camera.clone(),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for k in 0..3u32 {
        let pose = Pose::new(nadir, Vector3::new(128.0 * k as f64, 0.0, 400.0));
        let img = GreyImage::from_fn(w, h, |x, y| {
            let ray = back_project(&camera, &pose, [x, y]).unwrap();
            let p = ray.at(-ray.origin.z / ray.direction.z);
            tex(p.x, p.y) * 200.0
        });
        let name = format!("p{k}.tif");
        img.save(&dir.path().join(&name), true).unwrap();
        let s = if k % 2 == 0 { 1.0 } else { -1.0 };
        let approx = Pose::new(
            cloudcontrol::geometry::rotation_from_vector(&Vector3::new(0.005 * s, -0.004, 0.005))
                * nadir,
            pose.center + Vector3::new(2.0 * s, -1.5, 2.0),
        );
        block.photos.insert(
            k + 1,
            Photo {
                id: k + 1,
                name,
                camera: 1,
                pose: approx,
                status: cloudcontrol::block::PhotoStatus::Approximate,
                prior: Some(PosPrior {
                    center: approx.center,
                    center_sigma: [2.0; 3],
                    rotation: Some(approx.rotation),
                    rotation_sigma_rad: 0.3f64.to_radians(),
                }),
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    let bpath = dir.path().join("block.json");
    std::fs::write(&bpath, serde_json::to_string(&block).unwrap()).unwrap();
    let (out, out_block) = (dir.path().join("ties.json"), dir.path().join("tied.json"));
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["ties", "--block"])
        .arg(&bpath)
        .args(["--height", "0", "--height-sigma", "1", "--out"])
        .arg(&out)
        .arg("--out-block")
        .arg(&out_block)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(report["pairs"].as_array().unwrap().len(), 3);
    let tied: Block = serde_json::from_str(&std::fs::read_to_string(&out_block).unwrap()).unwrap();
    tied.validate().unwrap();
    assert!(tied.points.len() >= 50, "{report}");
    assert!(tied.points.values().any(|p| p.observations.len() == 3));
    // Without a surface the guided path refuses with a clear message.
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["ties", "--block"])
        .arg(&bpath)
        .arg("--out")
        .arg(dir.path().join("x.json"))
        .output()
        .unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("--dem or --height"));
    // An unreadable image of the block is a clear error naming the file.
    std::fs::write(dir.path().join("p1.tif"), b"not a tiff").unwrap();
    let st = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["ties", "--block"])
        .arg(&bpath)
        .args(["--height", "0", "--out"])
        .arg(dir.path().join("y.json"))
        .output()
        .unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("p1.tif"));
    assert!(!dir.path().join("y.json").exists());
}
