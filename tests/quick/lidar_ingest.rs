//! LAS/LAZ ingestion, catalogue and tile store against a known synthetic source, and the
//! bad-input errors (each must name the file).

use crate::lidar_synth;

use cloudcontrol::lidar::las::read_points;
use cloudcontrol::lidar::{Bbox, Catalogue, LasStream, LidarError, ScanOptions, TileStore};
use lidar_synth::*;
use std::path::{Path, PathBuf};

fn split_tiles(dir: &Path, pts: &[P], crs: [CrsVlr; 2], minor: u8, laz: bool) -> Vec<PathBuf> {
    let (a, b): (Vec<P>, Vec<P>) = pts.iter().partition(|p| p.x - E0 < 100.0);
    let ext = if laz { "laz" } else { "las" };
    let files = vec![dir.join(format!("t0.{ext}")), dir.join(format!("t1.{ext}"))];
    write_las(&files[0], &a, minor, crs[0], laz);
    write_las(&files[1], &b, minor, crs[1], laz);
    files
}

#[test]
fn reads_las12_las14_and_laz_with_crs_and_attributes() {
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(1.0, 0.0, 0.0, 1);
    for (minor, crs, laz) in [
        (2, CrsVlr::GeoKeys(EPSG), false),
        (4, CrsVlr::Wkt(EPSG), false),
        (4, CrsVlr::Wkt(EPSG), true),
        (2, CrsVlr::GeoKeys(EPSG), true),
    ] {
        let f = dir.path().join(format!(
            "v{minor}_{laz}.{}",
            if laz { "laz" } else { "las" }
        ));
        write_las(&f, &pts, minor, crs, laz);
        let s = LasStream::open(&f).unwrap();
        assert_eq!(s.info().version, format!("1.{minor}"));
        assert_eq!(s.info().compressed, laz);
        assert_eq!(s.info().crs_label.as_deref(), Some("EPSG:32650"), "{f:?}");
        let got = read_points(&f, None, None).unwrap();
        assert_eq!(got.len(), pts.len());
        for (i, p) in pts.iter().enumerate().step_by(97) {
            let q = got.xyz[i];
            assert!(
                (q[0] - p.x).abs() <= 0.0005
                    && (q[1] - p.y).abs() <= 0.0005
                    && (q[2] - p.z).abs() <= 0.0005
            );
            assert_eq!(got.source[i], p.source);
            assert_eq!(got.class[i], p.class);
            assert!((got.gps_time[i] - p.gps).abs() < 1e-6);
        }
        // A bbox + class filter keeps exactly the matching points.
        let bb = [E0 + 10.0, N0 + 10.0, E0 + 30.0, N0 + 40.0];
        let want = got
            .xyz
            .iter()
            .filter(|q| q[0] >= bb[0] && q[0] <= bb[2] && q[1] >= bb[1] && q[1] <= bb[3])
            .count();
        assert_eq!(read_points(&f, Some(bb), Some(&[2])).unwrap().len(), want);
        assert_eq!(read_points(&f, Some(bb), Some(&[6])).unwrap().len(), 0);
    }
}

#[test]
fn catalogue_measures_tiles_and_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(2.0, 0.0, 0.0, 2);
    let files = split_tiles(
        dir.path(),
        &pts,
        [CrsVlr::Wkt(EPSG), CrsVlr::GeoKeys(EPSG)],
        4,
        false,
    );
    // A folder expands to its LAS/LAZ files in name order.
    let cat = Catalogue::scan(&[dir.path().to_path_buf()], &ScanOptions::default()).unwrap();
    assert_eq!(cat.tiles.len(), 2);
    assert_eq!(cat.tiles[0].file, files[0]);
    assert_eq!(cat.crs, "EPSG:32650");
    assert_eq!(cat.point_count, pts.len() as u64);
    let t0 = &cat.tiles[0];
    let n0 = pts.iter().filter(|p| p.x - E0 < 100.0).count() as u64;
    assert_eq!(t0.point_count, n0);
    assert_eq!(t0.classes.get(&2), Some(&n0));
    // Tile 0 (x < 100): strip 1 over 100 m, strip 2 over 20 m, at 2 pts/m².
    let s1 = t0.point_sources[&1] as f64;
    let s2 = t0.point_sources[&2] as f64;
    assert!(
        (s1 / 20_000.0 - 1.0).abs() < 0.02 && (s2 / 4_000.0 - 1.0).abs() < 0.05,
        "{s1} {s2}"
    );
    assert!(
        (t0.density_pts_m2 - 2.4).abs() < 0.1,
        "density {}",
        t0.density_pts_m2
    );
    assert!(t0.bounds[0] >= E0 && t0.bounds[3] < E0 + 100.0 && t0.bounds[1] >= N0);
    assert_eq!(t0.gps_time_type, "standard");
    assert_eq!(t0.acquisition_dates.as_ref().unwrap()[0], "2021-06-15");
    // JSON round trip.
    let json = dir.path().join("cat/catalogue.json");
    cat.save(&json).unwrap();
    let back = Catalogue::load(&json).unwrap();
    assert_eq!(back, cat);
    assert_eq!(
        Catalogue::open(&[json], &ScanOptions::default()).unwrap(),
        cat
    );
    assert!(cat.crs().unwrap().is_projected());
}

#[test]
fn tile_store_loads_only_needed_tiles_within_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(1.0, 0.0, 0.0, 3);
    split_tiles(dir.path(), &pts, [CrsVlr::Wkt(EPSG); 2], 4, false);
    let cat = Catalogue::scan(&[dir.path().to_path_buf()], &ScanOptions::default()).unwrap();
    let biggest = cat.tiles.iter().map(|t| t.point_count).max().unwrap();
    let mut store = TileStore::new(cat, biggest);
    let q0 = Bbox::new(E0 + 10.0, N0 + 10.0, E0 + 20.0, N0 + 20.0);
    let got = store.query(&q0, None).unwrap();
    let want = pts.iter().filter(|p| q0.contains(p.x, p.y)).count();
    assert!(
        (got.len() as i64 - want as i64).abs() <= 1,
        "{} vs {want}",
        got.len()
    );
    assert_eq!(store.loads(), 1);
    store.query(&q0, Some(&[2])).unwrap();
    assert_eq!(store.loads(), 1, "cached tile reused");
    let q1 = Bbox::new(E0 + 150.0, N0 + 10.0, E0 + 160.0, N0 + 20.0);
    store.query(&q1, None).unwrap();
    assert_eq!(store.loads(), 2);
    assert!(
        store.cached_points() <= biggest,
        "LRU bound kept: {}",
        store.cached_points()
    );
    store.query(&q0, None).unwrap();
    assert_eq!(store.loads(), 3, "evicted tile read again");
}

fn err_names(e: &LidarError, f: &Path) {
    let msg = e.to_string();
    assert!(
        msg.contains(&f.display().to_string()),
        "error does not name {f:?}: {msg}"
    );
}

#[test]
fn bad_inputs_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(0.5, 0.0, 0.0, 4);
    let good = dir.path().join("good.las");
    write_las(&good, &pts, 4, CrsVlr::Wkt(EPSG), false);
    let bytes = std::fs::read(&good).unwrap();

    // Truncated LAS.
    let f = dir.path().join("truncated.las");
    std::fs::write(&f, &bytes[..bytes.len() - 1000]).unwrap();
    let e = LasStream::open(&f).err().unwrap();
    assert!(
        matches!(e, LidarError::Truncated { declared, .. } if declared == pts.len() as u64),
        "{e}"
    );
    err_names(&e, &f);

    // Truncated inside the header.
    let f = dir.path().join("stub.las");
    std::fs::write(&f, &bytes[..100]).unwrap();
    let e = LasStream::open(&f).err().unwrap();
    err_names(&e, &f);

    // More records than the header declares.
    let f = dir.path().join("extra.las");
    let mut more = bytes.clone();
    more.extend_from_slice(&bytes[bytes.len() - 30..]);
    std::fs::write(&f, &more).unwrap();
    let e = LasStream::open(&f).err().unwrap();
    assert!(
        matches!(e, LidarError::CountMismatch { found, declared, .. } if found == declared + 1),
        "{e}"
    );
    err_names(&e, &f);

    // Not a LAS file at all.
    let f = dir.path().join("text.las");
    std::fs::write(&f, b"X,Y,Z\n1,2,3\n").unwrap();
    let e = LasStream::open(&f).err().unwrap();
    err_names(&e, &f);

    // Truncated LAZ: the compressed stream ends early.
    let laz = dir.path().join("good.laz");
    write_las(&laz, &pts, 4, CrsVlr::Wkt(EPSG), true);
    let lb = std::fs::read(&laz).unwrap();
    let f = dir.path().join("truncated.laz");
    std::fs::write(&f, &lb[..lb.len() * 2 / 3]).unwrap();
    let e = read_points(&f, None, None).err().unwrap();
    err_names(&e, &f);

    // Missing CRS (unless one is assumed).
    let f = dir.path().join("nocrs.las");
    write_las(&f, &pts, 2, CrsVlr::None, false);
    let e = Catalogue::scan(std::slice::from_ref(&f), &ScanOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, LidarError::MissingCrs { .. }), "{e}");
    err_names(&e, &f);
    let c = Catalogue::scan(
        std::slice::from_ref(&f),
        &ScanOptions {
            assume_crs: Some("EPSG:32650".into()),
        },
    )
    .unwrap();
    assert_eq!(c.tiles[0].crs, "EPSG:32650");

    // Tiles in different CRSs.
    let f = dir.path().join("utm51.las");
    write_las(&f, &pts, 2, CrsVlr::GeoKeys(32651), false);
    let e = Catalogue::scan(&[good.clone(), f.clone()], &ScanOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, LidarError::CrsMismatch { .. }), "{e}");
    err_names(&e, &f);
    assert!(
        e.to_string().contains("EPSG:32651") && e.to_string().contains("good.las"),
        "{e}"
    );

    // Missing file.
    let f = dir.path().join("absent.las");
    let e = LasStream::open(&f).err().unwrap();
    err_names(&e, &f);
}
