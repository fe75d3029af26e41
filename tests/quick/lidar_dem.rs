//! DEM gridding of ground points against the true surface, hole filling, and the GeoTIFF
//! written through formats::raster (CRS, nodata) read back.

use crate::lidar_synth;

use cloudcontrol::formats::crs::Crs;
use cloudcontrol::formats::raster::{read_dem, write_dem, GeoTiffOptions};
use cloudcontrol::lidar::{grid_dem, Bbox, DemMethod, DemOptions};
use lidar_synth::*;

fn ground_points(hole: bool) -> Vec<[f64; 3]> {
    let (pts, _) = two_strips(4.0, 0.0, 0.0, 41);
    pts.iter()
        .filter(|p| !hole || ((p.x - E0 - 50.0).powi(2) + (p.y - N0 - 50.0).powi(2)).sqrt() > 3.0)
        .map(|p| [p.x, p.y, p.z])
        .collect()
}

/// (max |error|, RMS error, nodata cells) inside the data extent less `margin`.
fn errors(dem: &cloudcontrol::geometry::Dem, margin: f64) -> (f64, f64, usize) {
    let (mut worst, mut nodata, mut s2, mut n) = (0.0f64, 0, 0.0, 0usize);
    for r in 0..dem.height {
        for c in 0..dem.width {
            let (x, y) = dem.transform.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            if x < E0 + margin
                || x > E0 + 200.0 - margin
                || y < N0 + margin
                || y > N0 + 100.0 - margin
            {
                continue;
            }
            let v = dem.data[r * dem.width + c];
            if !v.is_finite() {
                nodata += 1;
                continue;
            }
            let e = v as f64 - ground(x, y);
            worst = worst.max(e.abs());
            s2 += e * e;
            n += 1;
        }
    }
    (worst, (s2 / n.max(1) as f64).sqrt(), nodata)
}

#[test]
fn mean_and_idw_dem_match_the_true_ground() {
    let pts = ground_points(false);
    for method in [DemMethod::Mean, DemMethod::Idw { power: 2.0 }] {
        let dem = grid_dem(
            &pts,
            &DemOptions {
                cell: 2.0,
                method,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(dem.transform.0[0], E0);
        assert_eq!(dem.transform.0[1], 2.0);
        let (worst, rms, nodata) = errors(&dem, 2.0);
        println!("{method:?}: |DEM − truth| max {worst:.4} m, RMS {rms:.4} m");
        assert_eq!(nodata, 0);
        // Mean: σ 5 cm over ≥ 16 points per cell → ≈ 1.25 cm. IDW is an exact interpolator:
        // the point nearest the centre dominates, so its error approaches the point noise.
        let (max_rms, max_worst) = if method == DemMethod::Mean {
            (0.02, 0.07)
        } else {
            (0.035, 0.2)
        };
        assert!(
            rms < max_rms && worst < max_worst,
            "{method:?} rms {rms} worst {worst}"
        );
    }
}

#[test]
fn holes_are_filled_within_the_limit_and_written_as_geotiff() {
    let pts = ground_points(true);
    let opts = DemOptions {
        cell: 1.0,
        ..Default::default()
    };
    let dem = grid_dem(&pts, &opts).unwrap();
    let (worst, rms, nodata) = errors(&dem, 1.0);
    println!("filled: |DEM − truth| max {worst:.4} m, RMS {rms:.4} m, nodata {nodata}");
    assert_eq!(nodata, 0, "a 6 m hole is filled at max_fill_cells 5");
    // 1 m cells hold ≈ 4 points (σ 2.5 cm per cell).
    assert!(rms < 0.035 && worst < 0.2, "rms {rms} worst {worst}");
    // No filling: the hole stays nodata.
    let raw = grid_dem(
        &pts,
        &DemOptions {
            max_fill_cells: 0,
            ..opts
        },
    )
    .unwrap();
    let (_, _, holes) = errors(&raw, 1.0);
    assert!(holes >= 20, "holes {holes}");

    // A fixed extent beyond the data: far cells stay nodata.
    let wide = grid_dem(
        &pts,
        &DemOptions {
            bbox: Some(Bbox::new(E0 - 50.0, N0, E0 + 200.0, N0 + 100.0)),
            ..opts
        },
    )
    .unwrap();
    assert!(!wide.data[wide.width * 50].is_finite());

    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("dem.tif");
    let crs = Crs::from_epsg(EPSG).unwrap();
    write_dem(&f, &raw, &crs, &GeoTiffOptions::default()).unwrap();
    let (back, bcrs) = read_dem(&f).unwrap();
    assert_eq!(bcrs.unwrap().epsg(), Some(EPSG));
    assert_eq!((back.width, back.height), (raw.width, raw.height));
    assert_eq!(back.transform, raw.transform);
    for (a, b) in back.data.iter().zip(&raw.data) {
        assert!(a == b || (a.is_nan() && b.is_nan()));
    }
}

#[test]
fn bad_dem_options_are_errors() {
    let pts = ground_points(false);
    for bad in [0.0, -1.0, f64::NAN] {
        let e = grid_dem(
            &pts,
            &DemOptions {
                cell: bad,
                ..Default::default()
            },
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("cell size"), "{e}");
    }
    let e = grid_dem(
        &pts,
        &DemOptions {
            cell: 0.001,
            max_cells: 1_000_000,
            ..Default::default()
        },
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("exceeds"), "{e}");
    assert!(grid_dem(&[], &DemOptions::default()).is_err());
}

#[test]
fn streamed_tiles_give_the_in_memory_mean_dem() {
    use cloudcontrol::lidar::dem::grid_dem_tiles;
    use cloudcontrol::lidar::{Catalogue, ScanOptions};
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(2.0, 0.0, 0.0, 43);
    let (a, b): (Vec<P>, Vec<P>) = pts.iter().partition(|p| p.x - E0 < 100.0);
    write_las(&dir.path().join("a.las"), &a, 4, CrsVlr::Wkt(EPSG), false);
    write_las(&dir.path().join("b.laz"), &b, 4, CrsVlr::Wkt(EPSG), true);
    let cat = Catalogue::scan(&[dir.path().to_path_buf()], &ScanOptions::default()).unwrap();
    let bbox = Bbox::new(E0 + 10.0, N0 + 10.0, E0 + 190.0, N0 + 90.0);
    let opts = DemOptions {
        cell: 2.0,
        bbox: Some(bbox),
        ..Default::default()
    };
    let (streamed, n) = grid_dem_tiles(&cat, &bbox, Some(&[2]), &opts).unwrap();
    let inside: Vec<[f64; 3]> = pts
        .iter()
        .filter(|p| bbox.contains(p.x, p.y))
        .map(|p| [p.x, p.y, p.z])
        .collect();
    assert!((n as i64 - inside.len() as i64).abs() <= 2);
    let mem = grid_dem(&inside, &opts).unwrap();
    assert_eq!((streamed.width, streamed.height), (mem.width, mem.height));
    // The last column and row lie on the bbox edge (cells only partly inside it).
    let w = mem.width;
    let (mut worst, mut differ, mut cells) = (0.0f32, 0, 0);
    for r in 0..mem.height - 1 {
        for c in 0..w - 1 {
            let d = (streamed.data[r * w + c] - mem.data[r * w + c]).abs();
            worst = worst.max(d);
            differ += (d > 0.001) as usize;
            cells += 1;
        }
    }
    assert!(differ * 100 < cells, "{differ} of {cells} cells differ");
    // Only the mm quantisation of the tiles differs (a point may change cells).
    assert!(worst < 0.05, "worst {worst}");
    assert!(grid_dem_tiles(&cat, &bbox, Some(&[9]), &opts).is_err());
}
