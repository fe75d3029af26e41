//! DCP packages: write, verify, refuse corruption, merge, footprint queries.

use cloudcontrol::control::dcp::*;
use cloudcontrol::geometry::{self, Camera, FrameCamera, Pose};
use image::{DynamicImage, GrayImage, Luma};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::Path;

const ORIGIN: [f64; 3] = [500_000.0, 4_400_000.0, 0.0];

/// A small package: two nadir photos over flat ground, a grid of control points, chips
/// cut from a procedural texture at the projected positions.
fn sample(epoch: &str, n: usize) -> (Manifest, BTreeMap<String, DynamicImage>) {
    let cam = Camera::Frame(FrameCamera::pinhole(2000, 1500, 2000.0));
    let mut m = Manifest::new(
        "EPSG:4547",
        EpochInfo {
            name: epoch.into(),
            date: Some("2019-05-04".into()),
        },
        "synthetic reference photos oriented against LiDAR",
        0.1,
        Accuracy {
            plan_m: 0.05,
            height_m: 0.08,
        },
    );
    let poses: Vec<Pose> = (0..2)
        .map(|i| {
            Pose::from_opk(
                0.0,
                0.0,
                0.0,
                Vector3::new(ORIGIN[0] + 80.0 * i as f64, ORIGIN[1], 200.0),
            )
        })
        .collect();
    for (i, p) in poses.iter().enumerate() {
        let r = p.rotation;
        m.photos.push(DcpPhoto {
            id: i as u32 + 1,
            name: format!("ref_{i:03}.tif"),
            camera: cam.clone(),
            rotation: [
                r[(0, 0)],
                r[(0, 1)],
                r[(0, 2)],
                r[(1, 0)],
                r[(1, 1)],
                r[(1, 2)],
                r[(2, 0)],
                r[(2, 1)],
                r[(2, 2)],
            ],
            center: [p.center.x, p.center.y, p.center.z],
            date: None,
        });
    }
    let mut chips = BTreeMap::new();
    let half = 16u32;
    for k in 0..n {
        let xyz = [
            ORIGIN[0] + 10.0 + 12.0 * (k % 6) as f64,
            ORIGIN[1] - 30.0 + 12.0 * (k / 6) as f64,
            0.0,
        ];
        let mut pt = DcpPoint {
            id: k as u64 + 1,
            name: format!("C{k}"),
            xyz,
            sigma: [0.05, 0.05, 0.08],
            normal: Some([0.0, 0.0, 1.0]),
            quality: PointQuality {
                interest: 1.0,
                coplanarity: 0.001,
                class: "ground".into(),
            },
            measurements: vec![],
        };
        for (i, p) in poses.iter().enumerate() {
            let px = geometry::project(&cam, p, &Vector3::from(xyz))
                .unwrap()
                .pixel;
            let (x0, y0) = (px.x.floor() as u32 - half, px.y.floor() as u32 - half);
            let file = format!("chips/p{}_{}.png", pt.id, i + 1);
            let img = GrayImage::from_fn(2 * half, 2 * half, |x, y| {
                Luma([((x0 + x) * 7 + (y0 + y) * 13 + k as u32 * 31) as u8])
            });
            chips.insert(file.clone(), DynamicImage::ImageLuma8(img));
            pt.measurements.push(DcpMeasurement {
                photo: i as u32 + 1,
                pixel: [px.x, px.y],
                chip: ChipRef {
                    file,
                    x0,
                    y0,
                    width: 2 * half,
                    height: 2 * half,
                },
            });
        }
        m.points.push(pt);
    }
    (m, chips)
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = crate::common::files_below(dir)
        .into_iter()
        .map(|p| p.strip_prefix(dir).unwrap().display().to_string())
        .collect();
    v.sort();
    v
}

#[test]
fn package_round_trips_and_chips_read_back_equal() {
    let dir = tempfile::tempdir().unwrap();
    let pkg_dir = dir.path().join("epoch2019.dcp");
    let (m, chips) = sample("2019", 12);
    let written = DcpPackage::write(&pkg_dir, m.clone(), &chips).unwrap();
    assert_eq!(written.manifest.files.len(), 24);
    let pkg = DcpPackage::open(&pkg_dir).unwrap();
    assert_eq!(pkg.manifest, written.manifest);
    assert_eq!(pkg.manifest.points, m.points);
    for pt in &pkg.manifest.points {
        for ms in &pt.measurements {
            let img = pkg.chip(&ms.chip).unwrap();
            assert_eq!(img.to_luma8(), chips[&ms.chip.file].to_luma8());
        }
    }
    // Only the package folder exists: no temporary folder left.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // The manifest is plain JSON with the documented top-level keys.
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(pkg_dir.join("manifest.json")).unwrap()).unwrap();
    for key in [
        "format", "version", "crs", "epoch", "source", "gsd_m", "accuracy", "photos", "points",
        "files",
    ] {
        assert!(v.get(key).is_some(), "{key}");
    }
    assert_eq!(v["format"], "cloudcontrol-dcp");
}

fn expect_refused(dir: &Path, needle: &str) {
    let before = listing(dir);
    let e = DcpPackage::open(dir).unwrap_err().to_string();
    assert!(e.contains(needle), "error {e:?} should mention {needle:?}");
    assert!(
        e.contains(&dir.display().to_string()),
        "error names the package: {e}"
    );
    assert_eq!(listing(dir), before, "opening changes nothing");
}

#[test]
fn corrupted_packages_are_refused_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let (m, chips) = sample("2019", 6);
    let make = |name: &str| {
        let d = dir.path().join(name);
        DcpPackage::write(&d, m.clone(), &chips).unwrap();
        d
    };
    // An edited chip: same size, one pixel changed.
    let d = make("edited");
    let chip = d.join("chips/p1_1.png");
    let mut img = image::open(&chip).unwrap().to_luma8();
    img.put_pixel(3, 3, Luma([255]));
    img.save(&chip).unwrap();
    expect_refused(&d, "checksum mismatch");
    // A wrong checksum in the manifest.
    let d = make("wrongsum");
    let mpath = d.join("manifest.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&mpath).unwrap()).unwrap();
    v["files"]["chips/p2_2.png"] = serde_json::Value::String("00".repeat(32));
    std::fs::write(&mpath, serde_json::to_vec(&v).unwrap()).unwrap();
    expect_refused(&d, "chips/p2_2.png");
    // A missing chip.
    let d = make("missing");
    std::fs::remove_file(d.join("chips/p3_1.png")).unwrap();
    expect_refused(&d, "chips/p3_1.png");
    // A newer version, an unknown key, an unknown CRS, a geographic CRS, a missing manifest.
    for (name, edit, needle) in [
        (
            "newer",
            ("version", serde_json::json!(7)),
            "newer than this library",
        ),
        (
            "unknown",
            ("surprise", serde_json::json!(1)),
            "unknown field",
        ),
        (
            "badcrs",
            ("crs", serde_json::json!("EPSG:999999")),
            "EPSG:999999",
        ),
        (
            "geographic",
            ("crs", serde_json::json!("EPSG:4326")),
            "not projected",
        ),
    ] {
        let d = make(name);
        let mpath = d.join("manifest.json");
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&mpath).unwrap()).unwrap();
        v[edit.0] = edit.1;
        std::fs::write(&mpath, serde_json::to_vec(&v).unwrap()).unwrap();
        expect_refused(&d, needle);
    }
    let d = make("nomanifest");
    std::fs::remove_file(d.join("manifest.json")).unwrap();
    expect_refused(&d, "manifest.json");
    // A chip path that leaves the package is refused when writing, and nothing is written.
    let (mut m2, mut chips2) = sample("2019", 1);
    let img = chips2.remove("chips/p1_1.png").unwrap();
    chips2.insert("../escape.png".into(), img);
    m2.points[0].measurements[0].chip.file = "../escape.png".into();
    let out = dir.path().join("escape");
    assert!(DcpPackage::write(&out, m2, &chips2).is_err());
    assert!(!out.exists() && !dir.path().join("escape.png").exists());
}

#[test]
fn packages_merge_and_footprint_queries_find_their_points() {
    let dir = tempfile::tempdir().unwrap();
    let (a, ca) = sample("2019", 12);
    let (b, cb) = sample("2015", 6);
    let pa = DcpPackage::write(&dir.path().join("a"), a, &ca).unwrap();
    let pb = DcpPackage::write(&dir.path().join("b"), b, &cb).unwrap();
    let merged = DcpPackage::merge(&[pa.clone(), pb.clone()], &dir.path().join("ab")).unwrap();
    let reopened = DcpPackage::open(&merged.dir).unwrap();
    assert_eq!(reopened.manifest.points.len(), 18);
    assert_eq!(reopened.manifest.photos.len(), 4);
    assert_eq!(reopened.manifest.epoch.name, "2019+2015");
    let ids: std::collections::BTreeSet<u64> =
        reopened.manifest.points.iter().map(|p| p.id).collect();
    assert_eq!(ids.len(), 18);
    // Chips survive the merge bit for bit (as images).
    let p = &reopened.manifest.points[13];
    let orig = &pb.manifest.points[1];
    assert_eq!(
        reopened.chip(&p.measurements[0].chip).unwrap().to_luma8(),
        pb.chip(&orig.measurements[0].chip).unwrap().to_luma8()
    );

    // Index: a rotated square footprint around the first row of points.
    let index = DcpIndex::new(std::slice::from_ref(&pa));
    assert_eq!(index.len(), 12);
    let (cx, cy) = (ORIGIN[0] + 40.0, ORIGIN[1] - 30.0);
    let poly: Vec<[f64; 2]> = (0..4)
        .map(|i| {
            let a = std::f64::consts::FRAC_PI_4 + i as f64 * std::f64::consts::FRAC_PI_2;
            [cx + 45.0 * a.cos(), cy + 8.0 * a.sin()]
        })
        .collect();
    let hits = index.query_polygon(&poly);
    let expected: Vec<(usize, usize)> = pa
        .manifest
        .points
        .iter()
        .enumerate()
        .filter(|(_, p)| point_in_polygon([p.xyz[0], p.xyz[1]], &poly))
        .map(|(i, _)| (0, i))
        .collect();
    assert!(!expected.is_empty());
    assert_eq!(hits, expected);

    // Packages in different CRSs do not merge.
    let (mut c, cc) = sample("utm", 2);
    c.crs = "EPSG:32650".into();
    let pc = DcpPackage::write(&dir.path().join("c"), c, &cc).unwrap();
    let e = DcpPackage::merge(&[pa, pc], &dir.path().join("ac"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("differs"), "{e}");
    assert!(!dir.path().join("ac").exists());
}

#[test]
fn import_copies_verified_packages_into_a_store_of_one_crs() {
    let dir = tempfile::tempdir().unwrap();
    let (a, ca) = sample("2019", 6);
    let (b, cb) = sample("2015", 3);
    let pa = DcpPackage::write(&dir.path().join("src/a.dcp"), a, &ca).unwrap();
    let pb = DcpPackage::write(&dir.path().join("src/b.dcp"), b.clone(), &cb).unwrap();
    let store = dir.path().join("store");
    // A batch with one damaged package writes nothing, not even the store folder.
    let bad = DcpPackage::write(&dir.path().join("bad/c.dcp"), b.clone(), &cb).unwrap();
    std::fs::write(bad.dir.join("chips/p1_1.png"), b"not a png").unwrap();
    let e = DcpPackage::import(&[pa.dir.clone(), bad.dir.clone()], &store)
        .unwrap_err()
        .to_string();
    assert!(e.contains("c.dcp") && e.contains("chips/p1_1.png"), "{e}");
    assert!(!store.exists());
    // Two valid packages: copied file for file, verified, under their folder names.
    let got = DcpPackage::import(&[pa.dir.clone(), pb.dir.clone()], &store).unwrap();
    assert_eq!(got.len(), 2);
    assert_eq!(got[0].dir, store.join("a.dcp"));
    assert_eq!(got[1].manifest, pb.manifest);
    assert_eq!(listing(&store.join("a.dcp")), listing(&pa.dir));
    for f in listing(&pa.dir) {
        assert_eq!(
            std::fs::read(pa.dir.join(&f)).unwrap(),
            std::fs::read(store.join("a.dcp").join(&f)).unwrap(),
            "{f}"
        );
    }
    // Importing the same package again leaves it; another package of that name is refused.
    DcpPackage::import(std::slice::from_ref(&pa.dir), &store).unwrap();
    let other = DcpPackage::write(&dir.path().join("other/a.dcp"), b.clone(), &cb).unwrap();
    let e = DcpPackage::import(&[other.dir], &store)
        .unwrap_err()
        .to_string();
    assert!(e.contains("already holds a different package"), "{e}");
    // Another CRS is refused by the store, as is a batch that mixes CRSs.
    let (mut u, cu) = sample("utm", 2);
    u.crs = "EPSG:32650".into();
    let pu = DcpPackage::write(&dir.path().join("src/utm.dcp"), u, &cu).unwrap();
    let e = DcpPackage::import(std::slice::from_ref(&pu.dir), &store)
        .unwrap_err()
        .to_string();
    assert!(e.contains("EPSG:32650") && e.contains("EPSG:4547"), "{e}");
    let fresh = dir.path().join("fresh");
    assert!(DcpPackage::import(&[pa.dir.clone(), pu.dir.clone()], &fresh).is_err());
    assert!(!fresh.exists());
    let mut names: Vec<String> = std::fs::read_dir(&store)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["a.dcp", "b.dcp"], "no temporary folder is left");
}

/// The committed sample in formats/dcp/sample opens and verifies (regenerate with
/// CLOUDCONTROL_UPDATE_SAMPLES=1).
#[test]
fn committed_sample_package_verifies() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/dcp/sample.dcp");
    if std::env::var_os("CLOUDCONTROL_UPDATE_SAMPLES").is_some() {
        let (m, chips) = sample("2019", 4);
        DcpPackage::write(&dir, m, &chips).unwrap();
    }
    let pkg = DcpPackage::open(&dir).unwrap();
    assert_eq!(pkg.manifest.points.len(), 4);
}
