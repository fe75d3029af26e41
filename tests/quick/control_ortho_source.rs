//! An orthophoto with a DEM as a control source (issue 20), on real data: PDAL's Autzen
//! orthophoto (a JPEG georeferenced only by its world file, its CRS a separate WKT in
//! international feet) and a DEM gridded from the Autzen LiDAR (LAZ, the same CRS). The
//! package's control points, taken back into the orthophoto through the world file read
//! here by hand, land on their chips' centres; the chips hold the orthophoto's pixels
//! there; the heights are the DEM's; the CRS is the WKT's projection in metres.

use cloudcontrol::control::dcp::{DcpPackage, EpochInfo};
use cloudcontrol::control::ortho_source::{orthophoto_dcp, OrthoControlOptions, OrthoSource};
use cloudcontrol::formats::crs::{Crs, LinearUnit};
use cloudcontrol::formats::raster::{self, GeoTiffOptions};
use cloudcontrol::lidar::{grid_dem, las, DemOptions};
use std::path::{Path, PathBuf};

fn data() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for d in ["../shared/data", "../../shared/data", "/work/shared/data"] {
        let p = root.join(d).join("autzen_lidar_ortho");
        if p.is_dir() {
            return p;
        }
    }
    panic!("shared/data/autzen_lidar_ortho not found beside the project");
}

const FOOT: f64 = 0.3048;

/// The Autzen LiDAR's ground returns gridded at 1 m into a DEM GeoTIFF in `dir`, in feet as
/// the LiDAR is; with the CRS of the orthophoto's WKT (feet).
fn autzen_dem(dir: &Path) -> (PathBuf, Crs) {
    let d = data();
    let feet = Crs::parse(&std::fs::read_to_string(d.join("autzen-srs.wkt")).unwrap()).unwrap();
    let pts = las::read_points(&d.join("autzen_trim.laz"), None, Some(&[2])).unwrap();
    assert!(pts.xyz.len() > 10_000, "{} ground points", pts.xyz.len());
    let dem = grid_dem(
        &pts.xyz,
        &DemOptions {
            cell: 1.0 / FOOT,
            ..DemOptions::default()
        },
    )
    .unwrap();
    let path = dir.join("autzen_dem_ft.tif");
    raster::write_dem(&path, &dem, &feet, &GeoTiffOptions::default()).unwrap();
    (path, feet)
}

#[test]
fn autzen_orthophoto_and_lidar_dem_give_control_on_chip_centres() {
    let d = data();
    let wkt = std::fs::read_to_string(d.join("autzen-srs.wkt")).unwrap();
    let feet = Crs::parse(&wkt).unwrap();
    assert!((feet.horizontal_unit().unwrap().metres - FOOT).abs() < 1e-12);
    // The package CRS: the same projection in metres.
    let metres = feet.with_units(Some(&LinearUnit::metre()), None).unwrap();
    let tmp = tempfile::tempdir().unwrap();

    // The DEM: the LiDAR's ground returns gridded at 1 m, in feet as the LiDAR is.
    let (dem_path, _) = autzen_dem(tmp.path());
    let out = tmp.path().join("autzen.dcp");
    let (pkg, rep) = orthophoto_dcp(
        &OrthoSource {
            orthophoto: &d.join("autzen.jpg"),
            orthophoto_crs: Some(&wkt),
            dem: &dem_path,
            dem_crs: None,
            epoch: EpochInfo {
                name: "autzen_orthophoto".into(),
                date: None,
            },
        },
        metres.definition(),
        &out,
        &OrthoControlOptions::default(),
    )
    .unwrap();
    eprintln!("{rep:#?}");
    assert_eq!(rep.size_px, [3248, 4385]);
    assert!((rep.unit_m - FOOT).abs() < 1e-12);
    assert!((rep.gsd_m - FOOT).abs() < 1e-9);
    // The DEM covers 360 × 170 m at the orthophoto's southern edge, about 24 of its
    // 150-px cells once the chips' border is kept: control there only (18 points).
    assert!(rep.points >= 12, "{} points", rep.points);
    assert!(rep.outside_dem > rep.points);

    // Read back as any consumer would, and checked against the world file by hand.
    let pkg = DcpPackage::open(&pkg.dir).unwrap();
    let m = &pkg.manifest;
    let crs = Crs::parse(&m.crs).unwrap();
    assert!(crs.same_horizontal(&metres).unwrap());
    assert!(crs.horizontal_unit().unwrap().is_metre());
    let wld: Vec<f64> = std::fs::read_to_string(d.join("autzen.wld"))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    // World file: pixel size x, two rotations, pixel size y, and the centre of the
    // upper-left pixel, in feet.
    let (a, e, c, f) = (wld[0], wld[3], wld[4], wld[5]);
    assert_eq!((wld[1], wld[2]), (0.0, 0.0));
    let ortho = image::open(d.join("autzen.jpg")).unwrap().to_luma8();
    let (dem_m, _) = raster::read_dem(&dem_path).unwrap();
    assert_eq!(m.photos.len(), 1);
    let mut worst_centre: f64 = 0.0;
    let mut worst_pixel: f64 = 0.0;
    let mut worst_height: f64 = 0.0;
    for p in &m.points {
        let (x_ft, y_ft) = (p.xyz[0] / FOOT, p.xyz[1] / FOOT);
        // Pixel coordinates with the corner of the upper-left pixel at (0, 0).
        let col = (x_ft - c) / a + 0.5;
        let row = (y_ft - f) / e + 0.5;
        let ms = &p.measurements[0];
        let ch = &ms.chip;
        assert_eq!((ch.width, ch.height), (193, 193));
        let centre = (
            ch.x0 as f64 + ch.width as f64 / 2.0,
            ch.y0 as f64 + ch.height as f64 / 2.0,
        );
        worst_centre = worst_centre.max((col - centre.0).hypot(row - centre.1));
        worst_pixel = worst_pixel.max((col - ms.pixel[0]).hypot(row - ms.pixel[1]));
        // The height is the DEM's at the point (feet in the file).
        let z = dem_m.height_at(x_ft, y_ft).unwrap() * FOOT;
        worst_height = worst_height.max((z - p.xyz[2]).abs());
        // The chip holds the orthophoto's pixels there.
        let chip = pkg.chip(ch).unwrap().to_luma8();
        let mut diff = 0.0;
        for (i, j) in [(0, 0), (96, 96), (192, 0), (17, 150), (192, 192)] {
            let a = chip.get_pixel(i, j)[0] as f64;
            let b = ortho.get_pixel(ch.x0 + i, ch.y0 + j)[0] as f64;
            diff = f64::max(diff, (a - b).abs());
        }
        assert!(diff <= 1.0, "point {}: chip differs by {diff}", p.id);
        // Height σ: the DEM's, and more on slopes.
        assert!(p.sigma[2] >= 0.5 && p.sigma[0] == FOOT, "{:?}", p.sigma);
        assert!(p.quality.coplanarity <= 0.01);
    }
    eprintln!(
        "{} points: chip centre {worst_centre:.2e} px, measurement {worst_pixel:.2e} px, height {worst_height:.3} m from the DEM",
        m.points.len()
    );
    assert!(
        worst_centre < 1e-6,
        "control point {worst_centre} px from its chip centre"
    );
    assert!(
        worst_pixel < 2e-3,
        "measurement {worst_pixel} px from the orthophoto pixel"
    );
    // Bilinear height at the point against the local plane of ±2 m.
    assert!(worst_height < 0.25, "height {worst_height} m from the DEM");
}

/// An orthophoto and a DEM in another projection than the package's are reprojected by
/// GDAL's warper: the Autzen rasters (Oregon Lambert, feet) into UTM 10N. Each control
/// point, taken back into the original orthophoto through the world file, shows there
/// what its chip shows at its centre. An orthophoto without any CRS is refused naming it.
#[test]
fn orthophoto_in_another_projection_is_reprojected_and_one_without_crs_refused() {
    let d = data();
    let wkt = std::fs::read_to_string(d.join("autzen-srs.wkt")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let (dem_path, feet) = autzen_dem(tmp.path());
    let ortho = d.join("autzen.jpg");
    let run = |ortho_crs: Option<&str>, out: &Path| {
        orthophoto_dcp(
            &OrthoSource {
                orthophoto: &ortho,
                orthophoto_crs: ortho_crs,
                dem: &dem_path,
                dem_crs: None,
                epoch: EpochInfo {
                    name: "o".into(),
                    date: None,
                },
            },
            "EPSG:32610",
            out,
            &OrthoControlOptions::default(),
        )
    };
    let e = run(None, &tmp.path().join("none.dcp"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("autzen.jpg") && e.contains("no CRS"), "{e}");
    assert!(!tmp.path().join("none.dcp").exists());

    let (pkg, rep) = run(Some(&wkt), &tmp.path().join("utm.dcp")).unwrap();
    eprintln!("{rep:#?}");
    assert!(rep.reprojected);
    assert!((rep.gsd_m - FOOT).abs() < 0.01 * FOOT, "{}", rep.gsd_m);
    assert!(rep.points >= 12, "{} points", rep.points);
    // No temporary reprojection is left behind.
    let left: Vec<_> = std::fs::read_dir(std::env::temp_dir())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(&format!("cloudcontrol-warp-{}-", std::process::id()))
        })
        .collect();
    assert!(left.is_empty(), "{left:?}");
    let utm = Crs::parse("EPSG:32610").unwrap();
    let back = cloudcontrol::formats::crs::Transformer::new(&utm, &feet).unwrap();
    let wld: Vec<f64> = std::fs::read_to_string(d.join("autzen.wld"))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let original = image::open(&ortho).unwrap().to_luma8();
    let mut worst: f64 = 1.0;
    for p in &pkg.manifest.points {
        let q = back.transform_point(p.xyz).unwrap();
        let col = (q[0] - wld[4]) / wld[0] + 0.5;
        let row = (q[1] - wld[5]) / wld[3] + 0.5;
        let ch = &p.measurements[0].chip;
        let chip = pkg.chip(ch).unwrap().to_luma8();
        // 15 × 15 px around the point in both (the maps turn by < 2°: < 0.3 px at the rim).
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for j in -7i64..=7 {
            for i in -7i64..=7 {
                a.push(chip.get_pixel((96 + i) as u32, (96 + j) as u32)[0] as f64);
                let (c, r) = (
                    (col.floor() as i64 + i) as u32,
                    (row.floor() as i64 + j) as u32,
                );
                b.push(original.get_pixel(c, r)[0] as f64);
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (ma, mb) = (mean(&a), mean(&b));
        let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        worst = worst.min(cov / (va * vb).sqrt());
    }
    eprintln!(
        "{} points, worst NCC chip centre vs original orthophoto {worst:.3}",
        rep.points
    );
    assert!(
        worst > 0.8,
        "a chip does not show the orthophoto at its point: NCC {worst}"
    );
}

/// The same through the CLI, the CRS read from the WKT file beside the world file; `dcp
/// info` verifies the package.
#[test]
fn cli_writes_the_orthophoto_package() {
    let d = data();
    let tmp = tempfile::tempdir().unwrap();
    let (dem_path, feet) = autzen_dem(tmp.path());
    let metres = feet.with_units(Some(&LinearUnit::metre()), None).unwrap();
    let out = tmp.path().join("autzen.dcp");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["--json", "dcp", "from-orthophoto", "--orthophoto"])
        .arg(d.join("autzen.jpg"))
        .arg("--orthophoto-crs-file")
        .arg(d.join("autzen-srs.wkt"))
        .arg("--dem")
        .arg(&dem_path)
        .args(["--crs", &metres.to_wkt().unwrap(), "--date", "2010"])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["selection"]["points"], 18, "{v}");
    let pkg = DcpPackage::open(&out).unwrap();
    assert_eq!(pkg.manifest.points.len(), 18);
    assert_eq!(pkg.manifest.epoch.name, "autzen");
    assert_eq!(pkg.manifest.epoch.date.as_deref(), Some("2010"));
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
        .args(["dcp", "info"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
