//! `cloudcontrol demo`: runs what the product can do so far on a built-in block and reports
//! numbers against the known truth.

use crate::formats::{self, crs::Crs, raster};
use crate::geometry::{self, Camera, Dem, FrameCamera, Pose, Similarity};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::path::Path;

#[derive(Debug, Serialize)]
pub struct DemoSummary {
    pub photos: usize,
    pub points: usize,
    /// Largest distance between a ground point and its image ray's intersection with the DEM (m).
    pub ray_dem_max_error_m: f64,
    /// Largest reprojection error after projection → back-projection → re-projection (px).
    pub reprojection_max_error_px: f64,
    /// Similarity recovered from the noise-free pairs: errors in scale, rotation (deg), translation (m).
    pub similarity_scale_error: f64,
    pub similarity_rotation_error_deg: f64,
    pub similarity_translation_error_m: f64,
    pub dem_path: String,
    pub crs: String,
    pub time_s: f64,
}

/// Block origin of the demo in EPSG:4547 (CGCS2000 / 3-degree Gauss-Krüger CM 114E).
pub const DEMO_ORIGIN: [f64; 3] = [500_000.0, 4_400_000.0, 0.0];

fn terrain(x: f64, y: f64) -> f64 {
    120.0 + 25.0 * (x / 180.0).sin() * (y / 140.0).cos() + 8.0 * ((x + y) / 45.0).sin()
}

pub fn run(out_dir: &Path) -> Result<DemoSummary, Box<dyn std::error::Error + Send + Sync>> {
    let start = std::time::Instant::now();
    std::fs::create_dir_all(out_dir)?;
    let dem = Dem::from_fn(-300.0, 300.0, 1.0, 600, 600, terrain)?;
    let camera = Camera::Frame(FrameCamera {
        distortion: geometry::Brown {
            k1: -0.05,
            k2: 0.01,
            k3: 0.0,
            p1: 2e-4,
            p2: -1e-4,
        },
        ..FrameCamera::pinhole(4000, 3000, 5000.0)
    });
    let mut poses = Vec::new();
    for i in 0..3 {
        let c = Vector3::new(-120.0 + 120.0 * i as f64, 10.0, 1000.0);
        poses.push(Pose::from_opk(0.01 * i as f64, -0.008, 0.02, c));
    }
    let (mut ray_err, mut reproj_err, mut n) = (0.0_f64, 0.0_f64, 0usize);
    for pose in &poses {
        for gy in -5..=5 {
            for gx in -5..=5 {
                let (x, y) = (
                    pose.center.x + 25.0 * gx as f64,
                    pose.center.y + 25.0 * gy as f64,
                );
                let truth = Vector3::new(x, y, dem.height_at(x, y).ok_or("point off the DEM")?);
                let px = geometry::project(&camera, pose, &truth)?.pixel;
                let ray = geometry::back_project(&camera, pose, [px.x, px.y])?;
                let hit = dem.intersect(&ray)?;
                ray_err = ray_err.max((hit - truth).norm());
                let px2 = geometry::project(&camera, pose, &hit)?.pixel;
                reproj_err = reproj_err.max((px2 - px).norm());
                n += 1;
            }
        }
    }
    // Recover a known datum shift from projection centres and ground points.
    let truth_sim = Similarity::new(
        1.0002,
        geometry::matrix_from_opk(1e-4, -2e-4, 3e-3) * Matrix3::identity(),
        Vector3::new(3.2, -1.5, 0.7),
    );
    let src: Vec<Vector3<f64>> = (0..20)
        .map(|i| {
            let t = i as f64;
            Vector3::new(
                20.0 * t - 200.0,
                13.0 * (t * 0.7).sin() * 10.0,
                terrain(t, t),
            )
        })
        .collect();
    let dst: Vec<Vector3<f64>> = src.iter().map(|p| truth_sim.apply(p)).collect();
    let est = Similarity::estimate(&src, &dst, None, true)?;
    let rot_err = {
        let d = est.rotation * truth_sim.rotation.transpose();
        (((d.trace() - 1.0) / 2.0).clamp(-1.0, 1.0))
            .acos()
            .to_degrees()
    };
    let crs = Crs::from_epsg(4547)?;
    let mut world = dem.clone();
    world.transform.0[0] += DEMO_ORIGIN[0];
    world.transform.0[3] += DEMO_ORIGIN[1];
    let dem_path = out_dir.join("demo_dem.tif");
    raster::write_dem(
        &dem_path,
        &world,
        &crs,
        &formats::raster::GeoTiffOptions::default(),
    )?;
    Ok(DemoSummary {
        photos: poses.len(),
        points: n,
        ray_dem_max_error_m: ray_err,
        reprojection_max_error_px: reproj_err,
        similarity_scale_error: (est.scale - truth_sim.scale).abs(),
        similarity_rotation_error_deg: rot_err,
        similarity_translation_error_m: (est.translation - truth_sim.translation).norm(),
        dem_path: dem_path.display().to_string(),
        crs: crs.label(),
        time_s: start.elapsed().as_secs_f64(),
    })
}
