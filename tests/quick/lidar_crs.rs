//! The CRS of LiDAR tiles as real files carry it (PDAL's sample files in
//! shared/data/las_format_samples: no CRS, an empty WKT VLR, US survey feet in GeoTIFF keys
//! and in WKT, a geocentric WKT) and as compound CRSs written by hand: files without a CRS
//! take the given one with a warning, compound CRSs match by their horizontal part, and
//! units other than the metre are refused naming the file and the unit.

use cloudcontrol::formats::crs::Crs;
use cloudcontrol::lidar::{Catalogue, CrsSource, LasStream, LidarError, ScanOptions};
use cloudcontrol::synth::lidar::{write_tiles, LidarPoint};
use std::path::{Path, PathBuf};

use crate::common;
use common::cli;

fn samples() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/las_format_samples");
    if dir.is_dir() {
        Some(dir)
    } else {
        println!("skipped: {} is missing", dir.display());
        None
    }
}

fn scan(files: &[PathBuf], assume: Option<&str>) -> Result<Catalogue, LidarError> {
    Catalogue::scan(
        files,
        &ScanOptions {
            assume_crs: assume.map(str::to_string),
        },
    )
}

fn names_file_and(e: &LidarError, file: &Path, words: &[&str]) {
    let m = e.to_string();
    assert!(
        m.contains(&file.display().to_string()),
        "names the file: {m}"
    );
    for w in words {
        assert!(m.contains(w), "says {w:?}: {m}");
    }
}

#[test]
fn files_without_a_crs_take_the_given_one_with_a_warning() {
    let Some(dir) = samples() else { return };
    // simple.las has no VLR at all; warsaw_small.las has a WKT VLR holding `''` (an empty
    // string, quoted).
    for name in ["simple.las", "warsaw_small.las"] {
        let f = dir.join(name);
        assert!(
            LasStream::open(&f).unwrap().info().crs_wkt.is_none(),
            "{name}"
        );
        let e = scan(std::slice::from_ref(&f), None).unwrap_err();
        assert!(matches!(e, LidarError::MissingCrs { .. }), "{name}: {e}");
        names_file_and(&e, &f, &["no coordinate reference system", "--crs"]);
    }
    // warsaw_small.las is PUWG 1992 (EPSG:2180, metres).
    let f = dir.join("warsaw_small.las");
    let cat = scan(std::slice::from_ref(&f), Some("EPSG:2180")).unwrap();
    assert_eq!(cat.crs, "EPSG:2180");
    let t = &cat.tiles[0];
    assert_eq!(t.crs, "EPSG:2180");
    assert_eq!(t.crs_source, CrsSource::Assumed);
    assert_eq!(t.vertical_crs, None);
    assert_eq!(cat.warnings.len(), 1, "{:?}", cat.warnings);
    let w = &cat.warnings[0];
    assert!(
        w.contains("1 of 1 tiles carry no CRS") && w.contains("warsaw_small.las"),
        "{w}"
    );
    assert!(w.contains("EPSG:2180"), "{w}");
    // Independent reader (laspy 2.5): 3000 points, bounds from the header.
    assert_eq!(t.point_count, 3000);
    let want = [639913.26, 485143.14, 84.70, 639946.75, 485175.91, 104.55];
    for (k, (got, want)) in t.bounds.iter().zip(want).enumerate() {
        assert!((got - want).abs() < 0.006, "bound {k}: {:?}", t.bounds);
    }
    // The catalogue keeps the source of the CRS through its JSON.
    let json: serde_json::Value = serde_json::from_str(&cat.to_json()).unwrap();
    assert_eq!(json["tiles"][0]["crs_source"], "assumed");
    assert_eq!(json["warnings"][0].as_str().unwrap(), w);

    // simple.las is Autzen in Oregon GIC Lambert, international feet: assuming that CRS
    // is refused for its unit.
    let f = dir.join("simple.las");
    let e = scan(std::slice::from_ref(&f), Some("EPSG:2994")).unwrap_err();
    let m = e.to_string();
    assert!(
        m.contains("Oregon GIC Lambert (ft)") && m.contains("horizontal unit foot"),
        "{m}"
    );
    assert!(m.contains("--crs, or the project's crs"), "{m}");
}

#[test]
fn crs_in_feet_is_refused_naming_file_and_unit() {
    let Some(dir) = samples() else { return };
    // mvk-thin.las: GeoTIFF keys ProjectedCSTypeGeoKey 26995 (NAD83 / Mississippi West, a
    // metric EPSG code) with ProjLinearUnitsGeoKey and VerticalUnitsGeoKey 9003: the
    // coordinates (2 045 001, 1 267 501) are US survey feet.
    let f = dir.join("mvk-thin.las");
    let info = LasStream::open(&f).unwrap().info().clone();
    let label = info.crs_label.unwrap();
    assert!(
        label.contains("NAD83 / Mississippi West (axes in US survey foot)"),
        "{label}"
    );
    let crs = Crs::parse(&info.crs_wkt.unwrap()).unwrap();
    let u = crs.horizontal_unit().unwrap();
    assert_eq!(u.name, "US survey foot");
    assert!((u.metres - 1200.0 / 3937.0).abs() < 1e-12);
    assert_eq!(crs.vertical_unit().unwrap().unwrap().name, "US survey foot");
    for assume in [None, Some("EPSG:26995")] {
        let e = scan(std::slice::from_ref(&f), assume).unwrap_err();
        assert!(matches!(e, LidarError::Crs { .. }), "{e}");
        names_file_and(
            &e,
            &f,
            &[
                "Mississippi West",
                "has horizontal unit US survey foot",
                "cloudcontrol works in metres",
                "reproject",
            ],
        );
    }
    // test1_4.las: a WKT VLR for EPSG:2903 (New Mexico Central, ftUS) with a VERTCS nested
    // in the PROJCS (Global Mapper's layout).
    let f = dir.join("test1_4.las");
    let e = scan(std::slice::from_ref(&f), None).unwrap_err();
    names_file_and(
        &e,
        &f,
        &[
            "NAD83(HARN) / New Mexico Central (ftUS)",
            "has horizontal unit US survey foot",
        ],
    );
}

#[test]
fn geocentric_wkt_is_refused() {
    let Some(dir) = samples() else { return };
    // lone-star.copc.laz holds UTM 12N coordinates (515 368 E, 4 918 340 N) but its WKT VLR
    // says GEOCCS (geocentric WGS 84): the file's CRS is wrong, and a file's own CRS is
    // never overridden by the assumed one.
    let f = dir.join("lone-star.copc.laz");
    let info = LasStream::open(&f).unwrap().info().clone();
    assert!(info.compressed && info.point_count == 518_862);
    for assume in [None, Some("EPSG:32612")] {
        let e = scan(std::slice::from_ref(&f), assume).unwrap_err();
        names_file_and(&e, &f, &["is geocentric, not projected"]);
    }
}

/// Two 50 m tiles of a tilted plane around (E0, N0), written with `wkt` by the synthetic
/// tile writer; returns the two files.
fn tiles(dir: &Path, wkt: &str) -> Vec<PathBuf> {
    const E0: f64 = 500_000.0;
    const N0: f64 = 4_400_000.0;
    let mut pts = Vec::new();
    for i in 0..40 {
        for j in 0..20 {
            let (x, y) = (2.5 * i as f64 + 1.0, 2.5 * j as f64 + 1.0);
            pts.push(LidarPoint {
                xyz: [x, y, 0.1 * x + 0.05 * y],
                intensity: 100,
                return_number: 1,
                number_of_returns: 1,
                class: 2,
                scan_angle_deg: 0.0,
                source: 1,
                gps_time: 4.1e8,
            });
        }
    }
    std::fs::create_dir_all(dir).unwrap();
    let written = write_tiles(&pts, [E0, N0, 80.0], 50.0, wkt, false, dir, "").unwrap();
    assert_eq!(written.len(), 2);
    written
        .iter()
        .map(|t| dir.join(t.path.trim_start_matches('/')))
        .collect()
}

#[test]
fn compound_crs_matches_by_its_horizontal_part() {
    let root = tempfile::tempdir().unwrap();
    // WKT1 COMPD_CS as GDAL writes it, and a WKT2 COMPOUNDCRS written by hand.
    let compd = Crs::parse("EPSG:32650+5773").unwrap().to_wkt().unwrap();
    assert!(compd.starts_with("COMPD_CS["), "{compd}");
    let wkt2 = r#"COMPOUNDCRS["WGS 84 / UTM zone 50N + EGM96 height",
        PROJCRS["WGS 84 / UTM zone 50N",
            BASEGEOGCRS["WGS 84", DATUM["World Geodetic System 1984",
                ELLIPSOID["WGS 84",6378137,298.257223563]]],
            CONVERSION["UTM zone 50N", METHOD["Transverse Mercator"],
                PARAMETER["Latitude of natural origin",0],
                PARAMETER["Longitude of natural origin",117],
                PARAMETER["Scale factor at natural origin",0.9996],
                PARAMETER["False easting",500000],
                PARAMETER["False northing",0]],
            CS[Cartesian,2],
                AXIS["easting",east,LENGTHUNIT["metre",1]],
                AXIS["northing",north,LENGTHUNIT["metre",1]],
            ID["EPSG",32650]],
        VERTCRS["EGM96 height", VDATUM["EGM96 geoid"],
            CS[vertical,1], AXIS["gravity-related height",up,LENGTHUNIT["metre",1]],
            ID["EPSG",5773]]]"#;
    let a = tiles(&root.path().join("a"), &compd);
    let b = tiles(&root.path().join("b"), wkt2);
    let plain = tiles(
        &root.path().join("plain"),
        &Crs::from_epsg(32650).unwrap().to_wkt().unwrap(),
    );
    let mut all = a.clone();
    all.extend(b.iter().cloned());
    all.push(plain[0].clone());
    for assume in [None, Some("EPSG:32650"), Some("EPSG:32650+5773")] {
        let cat = scan(&all, assume).unwrap();
        assert_eq!(cat.crs, "EPSG:32650", "{assume:?}");
        assert!(cat.warnings.is_empty(), "{:?}", cat.warnings);
        assert_eq!(cat.point_count, 5 * 400);
        for t in &cat.tiles[..4] {
            assert_eq!(t.vertical_crs.as_deref(), Some("EPSG:5773"), "{:?}", t.file);
            assert_eq!(t.crs_source, CrsSource::File);
        }
        assert_eq!(cat.tiles[4].vertical_crs, None);
        assert!(cat
            .crs()
            .unwrap()
            .same_horizontal(&Crs::from_epsg(32650).unwrap())
            .unwrap());
    }
    // Another horizontal CRS under the same vertical one is a mismatch naming both.
    let other = tiles(
        &root.path().join("other"),
        &Crs::parse("EPSG:32651+5773").unwrap().to_wkt().unwrap(),
    );
    let e = scan(&[a[0].clone(), other[0].clone()], None).unwrap_err();
    assert!(matches!(e, LidarError::CrsMismatch { .. }), "{e}");
    names_file_and(&e, &other[0], &["EPSG:32650", "a/"]);
    let e = scan(std::slice::from_ref(&other[0]), Some("EPSG:32650")).unwrap_err();
    assert!(matches!(e, LidarError::CrsMismatch { .. }), "{e}");
    // Heights in US survey feet under a metric horizontal CRS are refused too.
    let ft = tiles(
        &root.path().join("ft"),
        &Crs::parse("EPSG:32650+6360").unwrap().to_wkt().unwrap(),
    );
    let e = scan(std::slice::from_ref(&ft[0]), None).unwrap_err();
    names_file_and(&e, &ft[0], &["has vertical unit US survey foot"]);
    // Different vertical CRSs over one horizontal CRS: accepted with a warning.
    let egm08 = tiles(
        &root.path().join("egm08"),
        &Crs::parse("EPSG:32650+3855").unwrap().to_wkt().unwrap(),
    );
    let cat = scan(&[a[0].clone(), egm08[0].clone()], None).unwrap();
    assert_eq!(cat.warnings.len(), 1, "{:?}", cat.warnings);
    assert!(
        cat.warnings[0].contains("EPSG:5773") && cat.warnings[0].contains("EPSG:3855"),
        "{:?}",
        cat.warnings
    );
}

#[test]
fn lidar_catalogue_command_reports_assumed_crs_and_refuses_feet() {
    let Some(dir) = samples() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("catalogue.json");
    let warsaw = dir.join("warsaw_small.las");
    let (ok, stdout, stderr) = cli(&[
        "--json",
        "lidar",
        "catalogue",
        warsaw.to_str().unwrap(),
        "--crs",
        "EPSG:2180",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let printed: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for j in [&printed, &saved] {
        assert_eq!(j["crs"], "EPSG:2180");
        assert_eq!(j["tiles"][0]["crs_source"], "assumed");
        assert!(j["warnings"][0]
            .as_str()
            .unwrap()
            .contains("warsaw_small.las"));
    }
    // The saved catalogue reads back with the new fields.
    let back = Catalogue::load(&out).unwrap();
    assert_eq!(back.tiles[0].crs_source, CrsSource::Assumed);

    let mvk = dir.join("mvk-thin.las");
    let (ok, _, stderr) = cli(&["lidar", "catalogue", mvk.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains(mvk.to_str().unwrap()) && stderr.contains("US survey foot"),
        "{stderr}"
    );
}

/// Rewrites a LAS file with its CRS VLRs replaced by `wkt` (none when `None`).
fn recrs(path: &Path, wkt: Option<&str>) {
    let mut reader = las::Reader::from_path(path).unwrap();
    let mut header = reader.header().clone();
    header.remove_crs_vlrs();
    if let Some(w) = wkt {
        header.set_wkt_crs(w.as_bytes().to_vec()).unwrap();
    }
    let points: Vec<las::Point> = reader.points().map(|p| p.unwrap()).collect();
    let tmp = path.with_extension("tmp");
    let mut writer = las::Writer::from_path(&tmp, header).unwrap();
    for p in points {
        writer.write_point(p).unwrap();
    }
    writer.close().unwrap();
    drop(writer);
    std::fs::rename(&tmp, path).unwrap();
}

#[test]
fn run_takes_the_project_crs_for_tiles_without_one() {
    use cloudcontrol::pipeline::{project::Project, run::run_project};
    use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
    let root = tempfile::tempdir().unwrap();
    let block = root.path().join("block");
    let cfg = SynthConfig {
        preset: Preset::Tiny,
        seed: 7,
        change: 0.5,
        pos: PosQuality::Rough,
        laz: false,
    };
    synth::generate(&cfg, &block).unwrap();
    // The project is in EPSG:4547; half the tiles lose their CRS, the others carry it as
    // a compound CRS with EGM96 heights.
    let compound = Crs::parse("EPSG:4547+5773").unwrap().to_wkt().unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(block.join("lidar"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(files.len() >= 2);
    for (i, f) in files.iter().enumerate() {
        recrs(f, (i % 2 == 1).then_some(compound.as_str()));
    }
    let project_path = block.join("project.toml");
    // The project the generator wrote for the block.
    let written = std::fs::read_to_string(&project_path).unwrap();
    let project = Project::load(&project_path).unwrap();
    let e = run_project(&project, &mut |_| {}, Some("sources")).unwrap_err();
    assert!(
        e.to_string().contains("sources"),
        "stopped after sources: {e}"
    );
    let cat = Catalogue::load(&root.path().join("run/sources/catalogue.json")).unwrap();
    assert_eq!(cat.crs, "EPSG:4547");
    for (i, t) in cat.tiles.iter().enumerate() {
        let (source, vertical) = if i % 2 == 1 {
            (CrsSource::File, Some("EPSG:5773"))
        } else {
            (CrsSource::Assumed, None)
        };
        assert_eq!(t.crs_source, source, "{:?}", t.file);
        assert_eq!(t.vertical_crs.as_deref(), vertical, "{:?}", t.file);
    }
    let n = files.len().div_ceil(2);
    assert_eq!(cat.warnings.len(), 1, "{:?}", cat.warnings);
    assert!(
        cat.warnings[0].starts_with(&format!("{n} of {} tiles carry no CRS", files.len())),
        "{:?}",
        cat.warnings
    );
    // The cleaned tiles (CRS VLRs kept as they were) were evaluated against the
    // checkpoints under the same rule.
    assert!(root
        .path()
        .join("run/sources/lidar_checkpoints.json")
        .is_file());

    // A project CRS whose horizontal part differs from the tiles' is refused naming a file.
    std::fs::write(&project_path, written.replace("EPSG:4547", "EPSG:4548")).unwrap();
    let project = Project::load(&project_path).unwrap();
    let e = run_project(&project, &mut |_| {}, Some("sources"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("EPSG:4548") && e.contains(files[1].file_name().unwrap().to_str().unwrap()),
        "{e}"
    );
}
