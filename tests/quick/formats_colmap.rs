//! COLMAP reader/writer against the real kapture model and its pycolmap 4.2.1 rewrites.

use cloudcontrol::block::Block;
use cloudcontrol::formats::colmap::{self, Encoding, Layout, WriteOptions};
use std::path::{Path, PathBuf};

fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("formats/colmap")
        .join(name)
}

/// Largest difference between two blocks' cameras, poses, points and observations.
fn max_diff(a: &Block, b: &Block) -> f64 {
    assert_eq!(a.cameras.len(), b.cameras.len());
    assert_eq!(a.photos.len(), b.photos.len());
    assert_eq!(a.points.len(), b.points.len());
    let mut d: f64 = 0.0;
    for (k, c) in &a.cameras {
        let pa = c.model.params();
        let pb = b.cameras[k].model.params();
        assert_eq!(c.model.image_size(), b.cameras[k].model.image_size());
        for (x, y) in pa.iter().zip(&pb) {
            d = d.max((x - y).abs());
        }
    }
    for (k, p) in &a.photos {
        let q = &b.photos[k];
        assert_eq!(p.name, q.name);
        assert_eq!(p.camera, q.camera);
        d = d.max((p.pose.rotation - q.pose.rotation).abs().max());
        d = d.max((p.pose.center - q.pose.center).abs().max());
    }
    for (k, p) in &a.points {
        let q = &b.points[k];
        assert_eq!(p.color, q.color);
        assert_eq!(p.kind, q.kind);
        d = d.max((p.position - q.position).abs().max());
        assert_eq!(p.observations.len(), q.observations.len(), "point {k}");
        for (o, r) in p.observations.iter().zip(&q.observations) {
            assert_eq!(o.photo, r.photo);
            d = d.max(
                (o.pixel[0] - r.pixel[0])
                    .abs()
                    .max((o.pixel[1] - r.pixel[1]).abs()),
            );
        }
    }
    assert_eq!(a.keypoints, b.keypoints);
    d
}

#[test]
fn legacy_text_and_colmap4_binary_and_text_agree() {
    let legacy = colmap::read(&sample("kapture_maupertuis_txt")).unwrap();
    assert_eq!(legacy.cameras.len(), 1);
    assert_eq!(legacy.photos.len(), 4);
    assert_eq!(legacy.points.len(), 1039);
    let bin = colmap::read(&sample("kapture_maupertuis_colmap4_bin")).unwrap();
    let txt = colmap::read(&sample("kapture_maupertuis_colmap4_txt")).unwrap();
    // pycolmap re-normalises quaternions; the text files hold 6 significant digits.
    assert!(
        max_diff(&legacy, &bin) < 1e-6,
        "{}",
        max_diff(&legacy, &bin)
    );
    assert!(max_diff(&bin, &txt) < 1e-12);
    // Mean track length as printed in the header of points3D.txt.
    let mean = legacy.num_observations() as f64 / legacy.points.len() as f64;
    assert!((mean - 3.2290664100096245).abs() < 1e-12);
}

#[test]
fn write_read_roundtrip_is_exact_in_every_encoding_and_layout() {
    let block = colmap::read(&sample("kapture_maupertuis_colmap4_bin")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for encoding in [Encoding::Binary, Encoding::Text] {
        for layout in [Layout::Legacy, Layout::Rigs] {
            let out = dir.path().join(format!("{encoding:?}_{layout:?}"));
            colmap::write(&out, &block, &WriteOptions { encoding, layout }).unwrap();
            let back = colmap::read(&out).unwrap();
            // Poses pass through a quaternion: exact to rounding (a few 1e-15).
            assert!(max_diff(&block, &back) < 1e-13, "{encoding:?} {layout:?}");
            // Everything else (cameras, points, pixels) is bit-exact.
            for (k, p) in &block.points {
                assert_eq!(p, &back.points[k]);
            }
            assert_eq!(block.cameras, back.cameras);
            assert_eq!(
                out.join("rigs.bin").exists(),
                layout == Layout::Rigs && encoding == Encoding::Binary
            );
        }
    }
}

#[test]
fn side_file_carries_crs_origin_and_control_points() {
    let mut block = colmap::read(&sample("kapture_maupertuis_txt")).unwrap();
    block.crs = Some("EPSG:32650".into());
    block.origin = [500000.0, 4400000.0, 30.0];
    let p = block.points.get_mut(&1).unwrap();
    p.kind = cloudcontrol::block::PointKind::Check;
    p.name = "CHK1".into();
    p.sigma = Some([0.02, 0.02, 0.05]);
    block.photos.get_mut(&1).unwrap().date = Some("1965-06-01".into());
    let dir = tempfile::tempdir().unwrap();
    colmap::write(dir.path(), &block, &WriteOptions::default()).unwrap();
    let back = colmap::read(dir.path()).unwrap();
    assert!(max_diff(&block, &back) < 1e-13);
    assert_eq!(back.crs, block.crs);
    assert_eq!(back.origin, block.origin);
    assert_eq!(back.points[&1], block.points[&1]);
    assert_eq!(back.photos[&1].date.as_deref(), Some("1965-06-01"));
}

#[test]
fn truncated_binary_model_is_refused_naming_file_and_record() {
    let dir = tempfile::tempdir().unwrap();
    for f in [
        "cameras.bin",
        "images.bin",
        "points3D.bin",
        "rigs.bin",
        "frames.bin",
    ] {
        std::fs::copy(
            sample("kapture_maupertuis_colmap4_bin").join(f),
            dir.path().join(f),
        )
        .unwrap();
    }
    let p = dir.path().join("points3D.bin");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = colmap::read(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("points3D.bin") && e.contains("truncated") && e.contains("point"),
        "{e}"
    );

    let p = dir.path().join("images.bin");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..1000]).unwrap();
    let e = colmap::read(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("images.bin") && e.contains("truncated") && e.contains("image"),
        "{e}"
    );
}

#[test]
fn unsupported_model_and_malformed_text_are_named() {
    // kapture's t265 export: OPENCV_FISHEYE cameras, comma-separated fields.
    let e = colmap::read(&sample("kapture_t265_txt"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cameras.txt") && e.contains("OPENCV_FISHEYE") && e.contains("camera 1"),
        "{e}"
    );

    let dir = tempfile::tempdir().unwrap();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::copy(sample("kapture_maupertuis_txt").join(f), dir.path().join(f)).unwrap();
    }
    std::fs::write(dir.path().join("cameras.txt"), "1 FOOCAM 100 100 1 2 3\n").unwrap();
    let e = colmap::read(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("cameras.txt") && e.contains("line 1") && e.contains("FOOCAM"),
        "{e}"
    );
    std::fs::remove_file(dir.path().join("images.txt")).unwrap();
    let e = colmap::read(dir.path()).unwrap_err().to_string();
    assert!(e.contains("images.bin / images.txt"), "{e}");
}

#[test]
fn every_supported_model_round_trips() {
    use cloudcontrol::geometry::{Brown, Camera, FrameCamera};
    let mut block = colmap::read(&sample("kapture_maupertuis_txt")).unwrap();
    let base = FrameCamera::pinhole(4000, 3000, 3500.0);
    let variants = [
        (base.clone(), "SIMPLE_PINHOLE"),
        (
            FrameCamera {
                fy: 3501.0,
                ..base.clone()
            },
            "PINHOLE",
        ),
        (
            FrameCamera {
                distortion: Brown {
                    k1: -0.1,
                    ..Default::default()
                },
                ..base.clone()
            },
            "SIMPLE_RADIAL",
        ),
        (
            FrameCamera {
                distortion: Brown {
                    k1: -0.1,
                    k2: 0.02,
                    ..Default::default()
                },
                ..base.clone()
            },
            "RADIAL",
        ),
        (
            FrameCamera {
                distortion: Brown {
                    k1: -0.1,
                    p1: 1e-4,
                    ..Default::default()
                },
                ..base.clone()
            },
            "OPENCV",
        ),
        (
            FrameCamera {
                distortion: Brown {
                    k1: -0.1,
                    k2: 0.01,
                    k3: 0.001,
                    p1: 1e-4,
                    p2: -2e-4,
                },
                ..base.clone()
            },
            "FULL_OPENCV",
        ),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (cam, name) in variants {
        block.cameras.get_mut(&1).unwrap().model = Camera::Frame(cam.clone());
        colmap::write(
            dir.path(),
            &block,
            &WriteOptions {
                encoding: Encoding::Text,
                layout: Layout::Legacy,
            },
        )
        .unwrap();
        let text = std::fs::read_to_string(dir.path().join("cameras.txt")).unwrap();
        assert!(text.contains(&format!("1 {name} ")), "{text}");
        let back = colmap::read(dir.path()).unwrap();
        assert_eq!(back.cameras[&1].model, Camera::Frame(cam));
    }
}
