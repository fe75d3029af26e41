//! Cloud control points from an oriented block over a known surface, and their DCP export.

use cloudcontrol::block::{Block, BlockCamera, Photo};
use cloudcontrol::control::cloud::{self, CloudOptions, ExportInfo};
use cloudcontrol::control::dcp::{Accuracy, DcpPackage, EpochInfo};
use cloudcontrol::geometry::{self, Camera, Dem, FrameCamera, Pose};
use image::{DynamicImage, GrayImage, Luma};
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// Planar ground with a steep rounded hill in the east (curved: no place for plane control).
fn terrain(x: f64, y: f64) -> f64 {
    let r2 = (x - 120.0).powi(2) + y * y;
    50.0 + 0.02 * x + 30.0 * (-r2 / 450.0).exp()
}

fn block() -> Block {
    let mut b = Block {
        crs: Some("EPSG:4547".into()),
        origin: [500_000.0, 4_400_000.0, 0.0],
        ..Default::default()
    };
    b.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "dmc".into(),
            model: Camera::Frame(FrameCamera::pinhole(1600, 1200, 1600.0)),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for i in 0..4u32 {
        let c = Vector3::new(-60.0 + 60.0 * i as f64, 0.0, 300.0);
        b.photos.insert(
            i + 1,
            Photo {
                id: i + 1,
                name: format!("ref_{i}.png"),
                camera: 1,
                pose: Pose::from_opk(0.01, -0.01, 0.02, c),
                status: cloudcontrol::block::PhotoStatus::Oriented,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    b
}

#[test]
fn control_points_lie_on_planar_ground_and_export_as_a_package() {
    let b = block();
    let dem = Dem::from_fn(-300.0, 300.0, 0.5, 1200, 1200, terrain).unwrap();
    // Candidates every 40 px with an interest value that varies.
    let mut interest = BTreeMap::new();
    for &pid in b.photos.keys() {
        let mut v = Vec::new();
        for r in 0..30 {
            for c in 0..40 {
                v.push((
                    [c as f64 * 40.0 + 20.5, r as f64 * 40.0 + 20.5],
                    ((c * 7 + r * 13 + pid as usize) % 17) as f64,
                ));
            }
        }
        interest.insert(pid, v);
    }
    let opts = CloudOptions {
        interval_px: 200.0,
        max_coplanarity: 1e-3,
        ..Default::default()
    };
    let pts = cloud::select(&b, &dem, &interest, &opts).unwrap();
    assert!(pts.len() >= 15, "{} points", pts.len());
    for p in &pts {
        // On the surface, on flat ground, seen in at least two photos at the projected pixel.
        assert!((p.position.z - dem.height_at(p.position.x, p.position.y).unwrap()).abs() < 1e-3);
        let r = ((p.position.x - 120.0).powi(2) + p.position.y.powi(2)).sqrt();
        // The hill top is curved in every direction; its flanks may hold planar patches.
        assert!(
            r > 8.0,
            "no control on the curved hill top: {:?}",
            p.position
        );
        assert!(p.coplanarity < 1e-3);
        assert!(p.measurements.len() >= 2);
        for (pid, px) in &p.measurements {
            let ph = &b.photos[pid];
            let proj = geometry::project(&b.cameras[&1].model, &ph.pose, &p.position)
                .unwrap()
                .pixel;
            assert!((proj.x - px[0]).abs() < 1e-9 && (proj.y - px[1]).abs() < 1e-9);
        }
    }
    // Spread: no two points closer than half the interval on the ground (GSD ≈ 0.19 m).
    for (i, a) in pts.iter().enumerate() {
        for c in &pts[i + 1..] {
            assert!((a.position - c.position).xy().norm() >= 0.5 * 200.0 * 300.0 / 1600.0 - 1e-9);
        }
    }

    // Export: chips are crops of the photos around each measurement.
    let photo_img = |pid: u32| {
        GrayImage::from_fn(1600, 1200, |x, y| {
            Luma([((x * 3 + y * 5 + pid * 11) % 251) as u8])
        })
    };
    let info = ExportInfo {
        crs: "EPSG:4547".into(),
        epoch: EpochInfo {
            name: "ref".into(),
            date: Some("2020-06-01".into()),
        },
        source: "test block".into(),
        gsd_m: 0.19,
        accuracy: Accuracy {
            plan_m: 0.05,
            height_m: 0.05,
        },
        chip_size: 31,
    };
    let (m, chips) = cloud::export(&b, &pts, &info, |pid| {
        Ok(DynamicImage::ImageLuma8(photo_img(pid)))
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let pkg = DcpPackage::write(&dir.path().join("ref.dcp"), m, &chips).unwrap();
    let pkg = DcpPackage::open(&pkg.dir).unwrap();
    assert_eq!(pkg.manifest.points.len(), pts.len());
    let p0 = &pkg.manifest.points[0];
    // World coordinates = local + origin.
    assert!((p0.xyz[0] - (pts[0].position.x + 500_000.0)).abs() < 1e-6);
    let ms = &p0.measurements[0];
    let chip = pkg.chip(&ms.chip).unwrap().to_luma8();
    let full = photo_img(ms.photo);
    assert_eq!(chip.get_pixel(0, 0), full.get_pixel(ms.chip.x0, ms.chip.y0));
    assert_eq!(
        chip.get_pixel(30, 30),
        full.get_pixel(ms.chip.x0 + 30, ms.chip.y0 + 30)
    );
    // The point sits at the chip centre pixel.
    assert_eq!(
        (
            ms.pixel[0].floor() as u32 - ms.chip.x0,
            ms.pixel[1].floor() as u32 - ms.chip.y0
        ),
        (15, 15)
    );
}
