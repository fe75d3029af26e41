//! Synthetic LiDAR for the lidar_* tests, written with the `las` crate (an independent
//! writer: our reader decodes point records itself).
#![allow(dead_code)]

use las::point::{Classification, Format};
use las::{Builder, Point, Transform, Vector, Version, Vlr, Writer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::path::Path;

pub const E0: f64 = 500_000.0;
pub const N0: f64 = 4_400_000.0;
pub const EPSG: u32 = 32650;
/// Adjusted standard GPS time of 2021-06-15 10:00 UTC (GPS seconds − 10⁹).
pub const GPS_T0: f64 = 1_307_786_418.0 - 1e9;

#[derive(Clone, Copy, Debug)]
pub struct P {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub class: u8,
    pub source: u16,
    pub gps: f64,
}

/// CRS of a file: WKT VLR (LAS 1.4), GeoTIFF keys VLR (any version) or none.
#[derive(Clone, Copy)]
pub enum CrsVlr {
    Wkt(u32),
    GeoKeys(u32),
    None,
}

fn geokeys_vlr(epsg: u32) -> Vlr {
    let keys: [u16; 12] = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, epsg as u16];
    Vlr {
        user_id: "LASF_Projection".into(),
        record_id: 34735,
        description: "GeoKeyDirectoryTag".into(),
        data: keys.iter().flat_map(|k| k.to_le_bytes()).collect(),
    }
}

pub fn write_las(path: &Path, pts: &[P], minor: u8, crs: CrsVlr, laz: bool) {
    let mut b = Builder::from(Version::new(1, minor));
    let mut fmt = Format::new(if minor >= 4 { 6 } else { 1 }).unwrap();
    fmt.is_compressed = laz;
    b.point_format = fmt;
    b.gps_time_type = las::GpsTimeType::Standard;
    b.transforms = Vector {
        x: Transform {
            scale: 0.001,
            offset: E0,
        },
        y: Transform {
            scale: 0.001,
            offset: N0,
        },
        z: Transform {
            scale: 0.001,
            offset: 0.0,
        },
    };
    match crs {
        CrsVlr::GeoKeys(c) => b.vlrs.push(geokeys_vlr(c)),
        CrsVlr::Wkt(_) | CrsVlr::None => {}
    }
    let mut header = b.into_header().unwrap();
    if let CrsVlr::Wkt(c) = crs {
        let wkt = cloudcontrol::formats::crs::Crs::from_epsg(c)
            .unwrap()
            .to_wkt()
            .unwrap();
        header.set_wkt_crs(wkt.into_bytes()).unwrap();
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = Writer::new(file, header).unwrap();
    for p in pts {
        w.write_point(Point {
            x: p.x,
            y: p.y,
            z: p.z,
            classification: Classification::new(p.class).unwrap(),
            point_source_id: p.source,
            gps_time: Some(p.gps),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
}

/// True ground height.
pub fn ground(x: f64, y: f64) -> f64 {
    50.0 + 0.02 * (x - E0) + 0.01 * (y - N0) + 1.5 * ((x - E0) / 40.0).sin()
}

/// Two overlapping strips over a 200 m × 100 m sloped ground, `density` pts/m² per strip,
/// σ 5 cm noise; strip 1 covers x ∈ [0, 120], strip 2 x ∈ [80, 200] and is lifted by
/// `offset2`. `noise_fraction` of extra points sit 3–15 m below ground, classified ground
/// (isolated noise a filter must remove). Returns (points, index of the first noise point).
pub fn two_strips(density: f64, offset2: f64, noise_fraction: f64, seed: u64) -> (Vec<P>, usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.05).unwrap();
    let mut pts = Vec::new();
    for (source, x0, x1, dz) in [(1u16, 0.0, 120.0, 0.0), (2u16, 80.0, 200.0, offset2)] {
        let n = (density * (x1 - x0) * 100.0) as usize;
        for i in 0..n {
            let x = E0 + rng.gen_range(x0..x1);
            let y = N0 + rng.gen_range(0.0..100.0);
            pts.push(P {
                x,
                y,
                z: ground(x, y) + dz + noise.sample(&mut rng),
                class: 2,
                source,
                gps: GPS_T0 + source as f64 * 600.0 + i as f64 * 1e-4,
            });
        }
    }
    let first_noise = pts.len();
    let k = (noise_fraction * pts.len() as f64) as usize;
    for _ in 0..k {
        let x = E0 + rng.gen_range(0.0..200.0);
        let y = N0 + rng.gen_range(0.0..100.0);
        pts.push(P {
            x,
            y,
            z: ground(x, y) - rng.gen_range(3.0..15.0),
            class: 2,
            source: if x - E0 < 100.0 { 1 } else { 2 },
            gps: GPS_T0 + 100.0,
        });
    }
    (pts, first_noise)
}

/// Checkpoints on the true ground (surveyed, σ 1 cm) in the single-strip areas:
/// ids "A*" over strip 1 only (x < 75), "B*" over strip 2 only (x > 125).
pub fn checkpoints(seed: u64) -> Vec<(String, [f64; 3])> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut out = Vec::new();
    for (name, x0, x1) in [("A", 5.0, 75.0), ("B", 125.0, 195.0)] {
        for i in 0..15 {
            let x = E0 + rng.gen_range(x0..x1);
            let y = N0 + rng.gen_range(5.0..95.0);
            out.push((
                format!("{name}{i}"),
                [x, y, ground(x, y) + noise.sample(&mut rng)],
            ));
        }
    }
    out
}
