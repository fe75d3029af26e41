//! Airborne LiDAR simulation and LAS 1.4 / LAZ tile writing: strips with a known
//! systematic offset each (point source id = strip), σ ≈ 5 cm range noise, first/last
//! returns through tree crowns, dropouts on water, a few percent noise points (birds
//! above, multipath below), GPS time along the track, ASPRS classification.

use super::scene::{Class, Scene};
use super::SynthError;
use crate::formats;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;
use std::path::Path;

/// One simulated LiDAR strip and its systematic error (m).
#[derive(Debug, Clone, Serialize)]
pub struct LidarStrip {
    pub point_source_id: u16,
    pub center_x: f64,
    pub swath_m: f64,
    pub offset: [f64; 3],
    pub points: u64,
}

/// A generated point in block-local coordinates.
#[derive(Debug, Clone, Copy)]
pub struct LidarPoint {
    pub xyz: [f64; 3],
    pub intensity: u16,
    pub return_number: u8,
    pub number_of_returns: u8,
    pub class: u8,
    pub scan_angle_deg: f32,
    pub source: u16,
    pub gps_time: f64,
}

/// Adjusted standard GPS time of the first strip (s), a realistic 2024 value.
const GPS_T0: f64 = 4.1e8;

/// Simulates strips along y covering `area` at an average `density` (pts/m²).
pub fn simulate(
    scene: &Scene,
    area: [f64; 4],
    density: f64,
    rng: &mut ChaCha8Rng,
) -> (Vec<LidarStrip>, Vec<LidarPoint>) {
    let w = area[2] - area[0];
    let swath = (w / 2.2).clamp(80.0, 600.0);
    let spacing = swath * 0.7;
    let n_strips = (((w - swath) / spacing).ceil().max(0.0) as usize) + 1;
    // Each point is seen by 1.3 strips on average with 30 % side overlap.
    let strip_density = density * spacing / swath;
    let range_noise = Normal::new(0.0, 0.05).expect("sigma");
    let offset_dist = Normal::new(0.0, 0.06).expect("sigma");
    let flying_height = 800.0;
    let speed = 60.0;
    let cx = 0.5 * (area[0] + area[2]);
    let mut strips = Vec::new();
    let mut points = Vec::new();
    for s in 0..n_strips {
        let x_c = cx + (s as f64 - (n_strips as f64 - 1.0) / 2.0) * spacing;
        let offset = [
            offset_dist.sample(rng),
            offset_dist.sample(rng),
            offset_dist.sample(rng),
        ];
        let x0 = (x_c - swath / 2.0).max(area[0]);
        let x1 = (x_c + swath / 2.0).min(area[2]);
        let n = ((x1 - x0) * (area[3] - area[1]) * strip_density) as usize;
        let t_strip = GPS_T0 + s as f64 * 600.0;
        let north = s % 2 == 0;
        let mut ys: Vec<(f64, f64)> = (0..n)
            .map(|_| (rng.gen_range(area[1]..area[3]), rng.gen_range(x0..x1)))
            .collect();
        // Points are recorded in time order along the track.
        ys.sort_by(|a, b| {
            if north {
                a.0.total_cmp(&b.0)
            } else {
                b.0.total_cmp(&a.0)
            }
        });
        let mut count = 0u64;
        for (y, x) in ys {
            let sp = scene.sample(x, y);
            let along = if north { y - area[1] } else { area[3] - y };
            let gps_time = t_strip + along / speed + rng.gen_range(0.0..1e-4);
            let scan_angle = ((x - x_c) / flying_height).atan().to_degrees() as f32;
            if sp.class == Class::Water && rng.gen_bool(0.85) {
                continue; // specular water returns nothing most of the time
            }
            let albedo = scene.albedo(x, y, &sp, sp.height, 0.3);
            let intensity = (albedo * 40000.0 + rng.gen_range(0.0..2000.0)) as u16;
            // Returns of this pulse: (height, class, return number, number of returns, intensity).
            let mut returns: [(f64, u8, u8, u8, u16); 2] = [(0.0, 0, 0, 0, 0); 2];
            let noise = rng.gen_range(0.0..1.0);
            let n_ret = if noise < 0.01 {
                // Bird or haze well above the surface: high noise.
                returns[0] = (
                    sp.height + rng.gen_range(15.0..120.0),
                    18,
                    1,
                    1,
                    intensity / 4,
                );
                1
            } else if noise < 0.025 {
                // Multipath: below ground.
                returns[0] = (sp.ground - rng.gen_range(0.8..8.0), 7, 1, 1, intensity / 3);
                1
            } else if sp.class == Class::Vegetation && rng.gen_bool(0.4) {
                // The pulse also reaches the ground through the crown.
                let first = sp.ground + (sp.height - sp.ground) * rng.gen_range(0.6..1.0);
                returns[0] = (first, 5, 1, 2, intensity);
                returns[1] = (sp.ground, 2, 2, 2, intensity / 2);
                2
            } else {
                returns[0] = (sp.height, sp.class.las_code(), 1, 1, intensity);
                1
            };
            for &(z, class, rn, nr, intensity) in &returns[..n_ret] {
                points.push(LidarPoint {
                    xyz: [
                        x + offset[0],
                        y + offset[1],
                        z + offset[2] + range_noise.sample(rng),
                    ],
                    intensity,
                    return_number: rn,
                    number_of_returns: nr,
                    class,
                    scan_angle_deg: scan_angle,
                    source: (s + 1) as u16,
                    gps_time,
                });
            }
            count += n_ret as u64;
        }
        strips.push(LidarStrip {
            point_source_id: (s + 1) as u16,
            center_x: x_c,
            swath_m: swath,
            offset,
            points: count,
        });
    }
    (strips, points)
}

/// A written tile.
#[derive(Debug, Clone, Serialize)]
pub struct LidarTile {
    pub path: String,
    pub points: u64,
    /// World bounds [xmin, ymin, xmax, ymax] of the tile cell.
    pub cell: [f64; 4],
}

/// Writes the points on a regular world tile grid (`tile_m`), one LAS 1.4 point format 6
/// file per non-empty tile (LAZ when `laz`), CRS as a WKT VLR, scale 1 mm, offset at the
/// tile's lower-left corner rounded to the tile grid.
#[allow(clippy::too_many_arguments)]
pub fn write_tiles(
    points: &[LidarPoint],
    origin: [f64; 3],
    tile_m: f64,
    wkt: &str,
    laz: bool,
    dir: &Path,
    rel_prefix: &str,
) -> Result<Vec<LidarTile>, SynthError> {
    use std::collections::BTreeMap;
    let mut tiles: BTreeMap<(i64, i64), Vec<usize>> = BTreeMap::new();
    for (k, p) in points.iter().enumerate() {
        let e = ((p.xyz[0] + origin[0]) / tile_m).floor() as i64;
        let n = ((p.xyz[1] + origin[1]) / tile_m).floor() as i64;
        tiles.entry((e, n)).or_default().push(k);
    }
    let mut out = Vec::new();
    for ((e, n), idx) in tiles {
        let x0 = e as f64 * tile_m;
        let y0 = n as f64 * tile_m;
        let name = format!(
            "tile_{}_{}.{}",
            x0 as i64,
            y0 as i64,
            if laz { "laz" } else { "las" }
        );
        let path = dir.join(&name);
        let header = crate::lidar::las_write::new_header([x0, y0, 0.0], laz, wkt)
            .map_err(|e| SynthError::Las(format!("{name}: {e}")))?;
        let points = idx.iter().map(|&k| {
            let p = &points[k];
            Ok(las::Point {
                x: p.xyz[0] + origin[0],
                y: p.xyz[1] + origin[1],
                z: p.xyz[2] + origin[2],
                intensity: p.intensity,
                return_number: p.return_number,
                number_of_returns: p.number_of_returns,
                classification: las::point::Classification::new(p.class)
                    .map_err(|e| formats::FormatError::invalid(&path, e.to_string()))?,
                scan_angle: p.scan_angle_deg,
                point_source_id: p.source,
                gps_time: Some(p.gps_time),
                ..Default::default()
            })
        });
        crate::lidar::las_write::write_points(&path, header, points)?;
        out.push(LidarTile {
            path: format!("{rel_prefix}/{name}"),
            points: idx.len() as u64,
            cell: [x0, y0, x0 + tile_m, y0 + tile_m],
        });
    }
    Ok(out)
}
