//! CRS transformations against an independent formula, and the GeoTIFF round trip.
//!
//! Expected projected coordinates are computed in the test from the transverse Mercator
//! series of J. P. Snyder, "Map Projections — A Working Manual", USGS Professional Paper
//! 1395 (1987), eqs. (3-21), (8-9) and (8-10): the published formulas, independent of PROJ.
//! Truncation error of the series within 2° of the central meridian is far below 1 mm.

use cloudcontrol::formats::crs::{Crs, LinearUnit, Transformer};
use cloudcontrol::formats::raster::{read_dem, write_dem, GeoTiffOptions};
use cloudcontrol::geometry::{Dem, GeoTransform};

struct Tm {
    a: f64,
    inv_f: f64,
    lon0: f64,
    k0: f64,
    false_easting: f64,
}

impl Tm {
    fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let f = 1.0 / self.inv_f;
        let e2 = f * (2.0 - f);
        let ep2 = e2 / (1.0 - e2);
        let (e4, e6) = (e2 * e2, e2 * e2 * e2);
        let phi = lat_deg.to_radians();
        let (s, c) = phi.sin_cos();
        let n = self.a / (1.0 - e2 * s * s).sqrt();
        let t = (s / c).powi(2);
        let cc = ep2 * c * c;
        let a = (lon_deg - self.lon0).to_radians() * c;
        let m = self.a
            * ((1.0 - e2 / 4.0 - 3.0 * e4 / 64.0 - 5.0 * e6 / 256.0) * phi
                - (3.0 * e2 / 8.0 + 3.0 * e4 / 32.0 + 45.0 * e6 / 1024.0) * (2.0 * phi).sin()
                + (15.0 * e4 / 256.0 + 45.0 * e6 / 1024.0) * (4.0 * phi).sin()
                - (35.0 * e6 / 3072.0) * (6.0 * phi).sin());
        let x = self.k0
            * n
            * (a + (1.0 - t + cc) * a.powi(3) / 6.0
                + (5.0 - 18.0 * t + t * t + 72.0 * cc - 58.0 * ep2) * a.powi(5) / 120.0);
        let y = self.k0
            * (m + n
                * (s / c)
                * (a * a / 2.0
                    + (5.0 - t + 9.0 * cc + 4.0 * cc * cc) * a.powi(4) / 24.0
                    + (61.0 - 58.0 * t + t * t + 600.0 * cc - 330.0 * ep2) * a.powi(6) / 720.0));
        (x + self.false_easting, y)
    }
}

/// EPSG:32650 — WGS 84 / UTM zone 50N: central meridian 117°E, k0 = 0.9996, FE 500 km.
const UTM50: Tm = Tm {
    a: 6378137.0,
    inv_f: 298.257223563,
    lon0: 117.0,
    k0: 0.9996,
    false_easting: 500000.0,
};
/// EPSG:4547 — CGCS2000 / 3-degree Gauss-Kruger CM 114E: k0 = 1, FE 500 km, CGCS2000 ellipsoid.
const GK114: Tm = Tm {
    a: 6378137.0,
    inv_f: 298.257222101,
    lon0: 114.0,
    k0: 1.0,
    false_easting: 500000.0,
};

#[test]
fn wgs84_to_utm50n_matches_snyder_and_inverts() {
    let t = Transformer::new(
        &Crs::from_epsg(4326).unwrap(),
        &Crs::from_epsg(32650).unwrap(),
    )
    .unwrap();
    let inv = Transformer::new(
        &Crs::from_epsg(32650).unwrap(),
        &Crs::from_epsg(4326).unwrap(),
    )
    .unwrap();
    // Beijing, and points up to 2° off the central meridian at several latitudes.
    let pts = [
        (116.3975, 39.9087),
        (115.2, 30.0),
        (118.9, 45.5),
        (117.0, 0.5),
        (117.0, 39.0),
    ];
    let mut x: Vec<f64> = pts.iter().map(|p| p.0).collect();
    let mut y: Vec<f64> = pts.iter().map(|p| p.1).collect();
    t.transform(&mut x, &mut y, &mut []).unwrap();
    for (i, &(lon, lat)) in pts.iter().enumerate() {
        let (ex, ey) = UTM50.forward(lon, lat);
        assert!(
            (x[i] - ex).abs() < 1e-3 && (y[i] - ey).abs() < 1e-3,
            "{lon},{lat}: PROJ ({}, {}) vs Snyder ({ex}, {ey})",
            x[i],
            y[i]
        );
    }
    // On the central meridian the easting is exactly the false easting.
    assert!((x[4] - 500000.0).abs() < 1e-6);
    inv.transform(&mut x, &mut y, &mut []).unwrap();
    for (i, &(lon, lat)) in pts.iter().enumerate() {
        assert!(
            (x[i] - lon).abs() < 1e-9 && (y[i] - lat).abs() < 1e-9,
            "inverse: easting/longitude first"
        );
    }
}

#[test]
fn cgcs2000_geographic_to_gauss_kruger_114e_matches_snyder() {
    let t = Transformer::new(
        &Crs::from_epsg(4490).unwrap(),
        &Crs::from_epsg(4547).unwrap(),
    )
    .unwrap();
    // EPSG:4490 is latitude-first by authority; we pass longitude first (GIS order).
    for &(lon, lat) in &[(114.0, 39.7), (114.5, 39.74), (112.6, 36.1), (115.4, 41.0)] {
        let p = t.transform_point([lon, lat, 100.0]).unwrap();
        let (ex, ey) = GK114.forward(lon, lat);
        assert!(
            (p[0] - ex).abs() < 1e-3 && (p[1] - ey).abs() < 1e-3,
            "{lon},{lat}: ({}, {}) vs ({ex}, {ey})",
            p[0],
            p[1]
        );
        assert_eq!(p[2], 100.0, "no vertical transformation between these CRSs");
    }
    // The synthetic block's area (≈ 500 000 E / 4 400 000 N) lies near 39.7°N on the CM.
    let p = t.transform_point([114.0, 39.7, 0.0]).unwrap();
    assert!((p[0] - 500000.0).abs() < 1e-6 && (p[1] - 4_395_000.0).abs() < 5_000.0);
}

#[test]
fn bad_crs_and_coordinates_are_refused_with_a_clear_message() {
    let e = Crs::parse("EPSG:999999").unwrap_err().to_string();
    assert!(e.contains("EPSG:999999"), "{e}");
    let e = Crs::parse("").unwrap_err().to_string();
    assert!(e.contains("empty"), "{e}");
    let t = Transformer::new(
        &Crs::from_epsg(4326).unwrap(),
        &Crs::from_epsg(32650).unwrap(),
    )
    .unwrap();
    let e = t
        .transform(&mut [f64::NAN], &mut [1.0], &mut [])
        .unwrap_err()
        .to_string();
    assert!(e.contains("not finite"), "{e}");
    let e = t
        .transform(&mut [1.0, 2.0], &mut [1.0], &mut [])
        .unwrap_err()
        .to_string();
    assert!(e.contains("differ in length"), "{e}");
    let geo = Crs::from_epsg(4326).unwrap();
    let e = geo
        .require_projected(Some((116.4, 39.9)))
        .unwrap_err()
        .to_string();
    assert!(e.contains("EPSG:32650"), "names the UTM zone: {e}");
    assert!(Crs::from_epsg(4547)
        .unwrap()
        .require_projected(None)
        .is_ok());
}

fn sample_dem() -> Dem {
    let mut dem = Dem::from_fn(499_800.0, 4_400_300.0, 0.5, 300, 200, |x, y| {
        80.0 + 0.01 * (x - 499_800.0) + 3.0 * ((y - 4_400_000.0) / 20.0).sin()
    })
    .unwrap();
    dem.data[1234] = f32::NAN;
    dem.data[5678] = f32::NAN;
    dem
}

#[test]
fn geotiff_dem_round_trip_is_exact_and_gdalinfo_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub").join("dem.tif");
    let dem = sample_dem();
    let crs = Crs::from_epsg(4547).unwrap();
    let opts = GeoTiffOptions {
        overviews: vec![2, 4],
        ..Default::default()
    };
    write_dem(&path, &dem, &crs, &opts).unwrap();
    // No temporary file left beside the output.
    let names: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");

    let (back, back_crs) = read_dem(&path).unwrap();
    assert_eq!(back.width, dem.width);
    assert_eq!(back.transform, dem.transform);
    for (a, b) in dem.data.iter().zip(&back.data) {
        assert!(a == b || (a.is_nan() && b.is_nan()));
    }
    assert_eq!(back_crs.unwrap().epsg(), Some(4547));

    // Independent reader: gdalinfo.
    let out = std::process::Command::new("gdalinfo")
        .arg("-json")
        .arg(&path)
        .output()
        .expect("gdalinfo runs");
    assert!(out.status.success());
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap();
    assert!(wkt.contains("ID[\"EPSG\",4547]"), "{wkt}");
    let gt: Vec<f64> = info["geoTransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(gt, dem.transform.0.to_vec());
    let band = &info["bands"][0];
    assert_eq!(band["type"], "Float32");
    assert_eq!(band["noDataValue"].as_f64(), Some(-9999.0));
    assert_eq!(band["overviews"].as_array().map(|o| o.len()), Some(2));
    assert_eq!(
        info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"],
        "DEFLATE"
    );
    // Cloud-Optimised: GDAL reads the COG layout.
    assert_eq!(info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG");
}

#[test]
fn failed_raster_write_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    // The target is an existing directory: the rename must fail and the temporary go away.
    let path = dir.path().join("occupied.tif");
    std::fs::create_dir(&path).unwrap();
    let err = write_dem(
        &path,
        &sample_dem(),
        &Crs::from_epsg(4547).unwrap(),
        &GeoTiffOptions::default(),
    );
    assert!(err.is_err());
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("occupied.tif")]);
    let e = read_dem(&dir.path().join("missing.tif"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("missing.tif") && e.contains("does not exist"),
        "{e}"
    );
    let _ = GeoTransform::north_up(0.0, 0.0, 1.0);
}

#[test]
fn metric_rule_compound_parts_and_unit_overrides() {
    let c = |d: &str| Crs::parse(d).unwrap();
    // Compound CRSs: projected + vertical, compared by their horizontal part.
    let compound = c("EPSG:32611+5703");
    assert!(compound.is_compound());
    assert_eq!(compound.horizontal().unwrap().label(), "EPSG:32611");
    assert_eq!(compound.vertical().unwrap().unwrap().label(), "EPSG:5703");
    assert!(compound.same_horizontal(&c("EPSG:32611")).unwrap());
    assert!(c("EPSG:32611").same_horizontal(&compound).unwrap());
    assert!(!compound.same_horizontal(&c("EPSG:32612")).unwrap());
    assert!(compound.require_metric_projected(None).is_ok());
    assert_eq!(c("EPSG:32611").vertical().unwrap().map(|v| v.label()), None);
    // A WKT1 `TOWGS84` datum-shift hint (as many LAS writers add it) does not make
    // another horizontal CRS.
    let bound = c("EPSG:2180").to_wkt().unwrap().replacen(
        "AUTHORITY[\"EPSG\",\"7019\"]],",
        "AUTHORITY[\"EPSG\",\"7019\"]],TOWGS84[0,0,0,0,0,0,0],",
        1,
    );
    assert!(bound.contains("TOWGS84"), "{bound}");
    assert!(c(&bound).same_horizontal(&c("EPSG:2180")).unwrap());
    assert_eq!(c(&bound).horizontal().unwrap().label(), "EPSG:2180");
    // Feet are refused naming the unit, horizontal or vertical.
    for (def, words) in [
        ("EPSG:2994", "has horizontal unit foot (0.3048 m)"),
        ("EPSG:2903", "has horizontal unit US survey foot"),
        ("EPSG:32611+6360", "has vertical unit US survey foot"),
    ] {
        let e = c(def)
            .require_metric_projected(None)
            .unwrap_err()
            .to_string();
        assert!(e.contains(words) && e.contains("metres"), "{def}: {e}");
    }
    let ft = c("EPSG:2994").horizontal_unit().unwrap();
    assert_eq!(ft.name, "foot");
    assert!((ft.metres - 0.3048).abs() < 1e-12);
    // A geocentric CRS is not projected.
    let e = c("EPSG:4978")
        .require_metric_projected(None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("geocentric"), "{e}");
    // GeoTIFF unit keys: EPSG:26995 is in metres; with its axes in US survey feet the
    // same coordinates mean 0.3048 of the distance: false easting 700 000 m is
    // 2 296 583.33 ftUS (NAD83 / Mississippi West's definition).
    let usft = LinearUnit::from_epsg(9003).unwrap();
    let ms_ft = c("EPSG:26995").with_units(Some(&usft), None).unwrap();
    let same =
        |a: &LinearUnit, b: &LinearUnit| a.name == b.name && (a.metres - b.metres).abs() < 1e-12;
    assert!(same(&ms_ft.horizontal_unit().unwrap(), &usft));
    assert_eq!(ms_ft.epsg(), None, "no longer the registered CRS");
    let t = Transformer::new(&ms_ft, &c("EPSG:26995")).unwrap();
    let p = t.transform_point([2_296_583.333, 1_000.0, 0.0]).unwrap();
    assert!((p[0] - 700_000.0).abs() < 1e-3, "{p:?}");
    assert!((p[1] - 304.8006).abs() < 1e-3, "{p:?}");
    // A vertical unit without a vertical CRS adds one of unknown datum.
    let with_v = c("EPSG:32611").with_units(None, Some(&usft)).unwrap();
    assert!(with_v.is_compound());
    assert!(same(&with_v.vertical_unit().unwrap().unwrap(), &usft));
    assert!(with_v.same_horizontal(&c("EPSG:32611")).unwrap());
}
