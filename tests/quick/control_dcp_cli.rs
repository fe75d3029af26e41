//! `cloudcontrol dcp generate|export|import` and their library functions on the tiny
//! synthetic block: the reference epoch's true orientation written as the workflow's
//! block.json / images.json, its LiDAR tiles as the control surface. Points are checked
//! against the truth (reprojection through the true orientation, LiDAR ground heights),
//! `generate` against `export`, and import against damaged and foreign packages.

use cloudcontrol::control::cloud::CloudOptions;
use cloudcontrol::control::dcp::{DcpPackage, EpochInfo};
use cloudcontrol::control::export::{ControlPointSet, DcpExportOptions, OrientedBlock};
use cloudcontrol::geometry;
use cloudcontrol::lidar::LIDAR_CELL_M;
use cloudcontrol::synth::reading::synth_truth_block;
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

struct Setup {
    root: PathBuf,
    block_json: PathBuf,
    images_json: PathBuf,
    lidar: PathBuf,
    truth: cloudcontrol::block::Block,
}

/// The tiny block and its reference epoch as an oriented block on disk, shared by the
/// tests of this file.
fn setup() -> &'static Setup {
    static S: OnceLock<Setup> = OnceLock::new();
    S.get_or_init(|| {
        let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("control_dcp_cli");
        let _ = std::fs::remove_dir_all(&root);
        let dir = root.join("block");
        synth::generate(
            &SynthConfig {
                preset: Preset::Tiny,
                seed: 2,
                change: 0.5,
                pos: PosQuality::Good,
                laz: false,
            },
            &dir,
        )
        .unwrap();
        let block = synth_truth_block(&dir, "reference_2024").unwrap();
        let images: std::collections::BTreeMap<u32, PathBuf> = block
            .photos
            .values()
            .filter_map(|p| Some((p.id, p.image.clone()?)))
            .collect();
        let epoch = root.join("epoch-reference_2024");
        std::fs::create_dir_all(&epoch).unwrap();
        let block_json = epoch.join("block.json");
        let images_json = epoch.join("images.json");
        std::fs::write(&block_json, serde_json::to_vec_pretty(&block).unwrap()).unwrap();
        std::fs::write(&images_json, serde_json::to_vec_pretty(&images).unwrap()).unwrap();
        Setup {
            block_json,
            images_json,
            lidar: dir.join("lidar"),
            truth: block,
            root,
        }
    })
}

/// Settings for the tiny block's 600×400 photos at 0.15 m (as tests/control_archive_cli).
fn options() -> DcpExportOptions {
    DcpExportOptions {
        cloud: CloudOptions {
            interval_px: 40.0,
            max_coplanarity: 0.02,
            ..CloudOptions::default()
        },
        chip_size: 129,
        interest_level: 1,
        ..DcpExportOptions::default()
    }
}

const CLI_OPTIONS: [&str; 8] = [
    "--interval-px",
    "40",
    "--chip-size",
    "129",
    "--interest-level",
    "1",
    "--max-coplanarity",
    "0.02",
];

fn cli(args: &[&str], paths: &[(&str, &Path)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cloudcontrol"));
    c.args(args);
    for (flag, p) in paths {
        if !flag.is_empty() {
            c.arg(flag);
        }
        c.arg(p);
    }
    c.output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Height of the LiDAR ground (class 2 returns) at (x, y): a least-squares plane through
/// the returns within 1.5 m, independent of the gridded surface the selection used.
fn lidar_ground(ground: &[[f64; 3]], x: f64, y: f64) -> Option<f64> {
    let near: Vec<&[f64; 3]> = ground
        .iter()
        .filter(|p| (p[0] - x).powi(2) + (p[1] - y).powi(2) <= 1.5f64.powi(2))
        .collect();
    if near.len() < 6 {
        return None;
    }
    let mut n = nalgebra::Matrix3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    for p in &near {
        let a = Vector3::new(1.0, p[0] - x, p[1] - y);
        n += a * a.transpose();
        b += a * p[2];
    }
    n.lu().solve(&b).map(|s| s[0])
}

fn ground_points(lidar: &Path) -> Vec<[f64; 3]> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(lidar).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "las") {
            v.extend(
                cloudcontrol::lidar::las::read_points(&p, None, Some(&[2]))
                    .unwrap()
                    .xyz,
            );
        }
    }
    v
}

/// Every measurement reprojects through the true orientation, every height is the
/// LiDAR ground's; returns the largest reprojection error (px) and height error (m).
fn check_against_truth(s: &Setup, set: &ControlPointSet) -> (f64, f64) {
    let ground = ground_points(&s.lidar);
    let origin = Vector3::from(s.truth.origin);
    let (mut max_px, mut max_dz) = (0.0f64, 0.0f64);
    for p in &set.points {
        let local = Vector3::from(p.xyz) - origin;
        assert!(p.measurements.len() >= 2, "point {} seen once", p.id);
        for m in &p.measurements {
            let ph = &s.truth.photos[&m.photo];
            let cam = &s.truth.cameras[&ph.camera].model;
            let px = geometry::project(cam, &ph.pose, &local).unwrap().pixel;
            let e = ((px.x - m.pixel[0]).powi(2) + (px.y - m.pixel[1]).powi(2)).sqrt();
            assert!(e <= 0.5, "point {} in photo {}: {e} px", p.id, m.photo);
            assert_eq!(m.name, ph.name);
            max_px = max_px.max(e);
        }
        let z = lidar_ground(&ground, p.xyz[0], p.xyz[1])
            .unwrap_or_else(|| panic!("no LiDAR ground near point {}", p.id));
        let dz = (p.xyz[2] - z).abs();
        assert!(dz <= 0.2, "point {}: {dz} m from the LiDAR ground", p.id);
        max_dz = max_dz.max(dz);
        assert_eq!(p.quality.class, "ground");
        assert!(p.quality.coplanarity <= 0.02);
    }
    (max_px, max_dz)
}

/// The package holds exactly the listed points, with the same measurements.
fn assert_same_points(set: &ControlPointSet, pkg: &DcpPackage) {
    let m = &pkg.manifest;
    assert_eq!(m.crs, set.crs);
    assert_eq!(m.points.len(), set.points.len());
    for (a, b) in set.points.iter().zip(&m.points) {
        assert_eq!(
            (a.id, &a.name, a.xyz, a.sigma),
            (b.id, &b.name, b.xyz, b.sigma)
        );
        assert_eq!(Some(a.normal), b.normal);
        assert_eq!(a.quality, b.quality);
        let pa: Vec<(u32, [f64; 2])> = a.measurements.iter().map(|m| (m.photo, m.pixel)).collect();
        let pb: Vec<(u32, [f64; 2])> = b.measurements.iter().map(|m| (m.photo, m.pixel)).collect();
        assert_eq!(pa, pb, "point {}", a.id);
    }
}

#[test]
fn exported_points_agree_with_the_truth_and_with_generate() {
    let s = setup();
    let b = OrientedBlock::load(
        &s.block_json,
        &s.images_json,
        std::slice::from_ref(&s.lidar),
        LIDAR_CELL_M,
    )
    .unwrap();
    let t = std::time::Instant::now();
    let set = b.select(&options()).unwrap();
    let select_s = t.elapsed().as_secs_f64();
    let out = s.root.join("lib").join("reference.dcp");
    let pkg = b
        .export(
            EpochInfo {
                name: "reference_2024".into(),
                date: Some("2024-05-29".into()),
            },
            &out,
            &options(),
        )
        .unwrap();
    let pkg = DcpPackage::open(&pkg.dir).unwrap();
    let (max_px, max_dz) = check_against_truth(s, &set);
    let measurements: usize = set.points.iter().map(|p| p.measurements.len()).sum();
    println!(
        "{} points, {measurements} measurements, selection {select_s:.2} s; max reprojection \
         through the truth {max_px:.2e} px, max |z − LiDAR ground| {max_dz:.3} m",
        set.points.len()
    );
    assert!(set.points.len() >= 15, "{} points", set.points.len());
    assert_same_points(&set, &pkg);
    // Every chip is the photo's pixels around the measurement.
    let ms = &pkg.manifest.points[0].measurements[0];
    let chip = pkg.chip(&ms.chip).unwrap().to_luma8();
    let path = b.block.photos[&ms.photo].image.clone().unwrap();
    let photo = image::open(path).unwrap().to_luma8();
    assert_eq!(
        chip.get_pixel(64, 64),
        photo.get_pixel(ms.chip.x0 + 64, ms.chip.y0 + 64)
    );
    assert_eq!(
        (
            ms.pixel[0].floor() as u32 - ms.chip.x0,
            ms.pixel[1].floor() as u32 - ms.chip.y0
        ),
        (64, 64)
    );
}

#[test]
fn cli_generate_export_import_and_refusals() {
    let s = setup();
    let work = s.root.join("cli");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let inputs: [(&str, &Path); 3] = [
        ("--block", &s.block_json),
        ("--images", &s.images_json),
        ("--lidar", &s.lidar),
    ];

    // generate → points.json
    let points = work.join("points.json");
    let o = cli(
        &[&["dcp", "generate"][..], &CLI_OPTIONS].concat(),
        &[&inputs[..], &[("--out", points.as_path())]].concat(),
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("control points"), "{}", text(&o));
    let set: ControlPointSet = serde_json::from_slice(&std::fs::read(&points).unwrap()).unwrap();
    let (max_px, max_dz) = check_against_truth(s, &set);
    println!(
        "generate: {} points, max reprojection {max_px:.2e} px, max dz {max_dz:.3} m",
        set.points.len()
    );
    // Without --out the listing goes to stdout.
    let o = cli(&[&["dcp", "generate"][..], &CLI_OPTIONS].concat(), &inputs);
    assert!(o.status.success(), "{}", text(&o));
    let printed: ControlPointSet = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(printed, set);

    // export → the same points, with chips
    let pkg_dir = work.join("reference.dcp");
    let o = cli(
        &[
            &["--json", "dcp", "export"][..],
            &CLI_OPTIONS,
            &["--name", "reference_2024", "--date", "2024-05-29"],
        ]
        .concat(),
        &[&inputs[..], &[("--out", pkg_dir.as_path())]].concat(),
    );
    assert!(o.status.success(), "{}", text(&o));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["points"], set.points.len());
    assert_eq!(summary["epoch"]["name"], "reference_2024");
    let pkg = DcpPackage::open(&pkg_dir).unwrap();
    assert_same_points(&set, &pkg);
    assert_eq!(pkg.manifest.epoch.date.as_deref(), Some("2024-05-29"));

    // import → STORE/reference.dcp, verified; importing it again changes nothing
    let store = work.join("store");
    let o = cli(
        &["--json", "dcp", "import"],
        &[("", pkg_dir.as_path()), ("--into", store.as_path())],
    );
    assert!(o.status.success(), "{}", text(&o));
    let stored = DcpPackage::open(&store.join("reference.dcp")).unwrap();
    assert_eq!(stored.manifest, pkg.manifest);
    let o = cli(
        &["dcp", "import"],
        &[("", pkg_dir.as_path()), ("--into", store.as_path())],
    );
    assert!(o.status.success(), "{}", text(&o));
    let listing = |d: &Path| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    assert_eq!(listing(&store), ["reference.dcp"]);

    // A package with an edited chip is refused, naming the chip; the store is unchanged
    // and a new store is not even created.
    let bad = work.join("bad").join("edited.dcp");
    copy_dir(&pkg_dir, &bad);
    let chip = pkg.manifest.points[0].measurements[0].chip.file.clone();
    let mut img = image::open(bad.join(&chip)).unwrap().to_luma8();
    let v = img.get_pixel(3, 3).0[0];
    img.put_pixel(3, 3, image::Luma([v.wrapping_add(40)]));
    img.save(bad.join(&chip)).unwrap();
    for target in [store.clone(), work.join("new_store")] {
        let o = cli(
            &["dcp", "import"],
            &[("", bad.as_path()), ("--into", target.as_path())],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert!(
            err.contains("checksum mismatch") && err.contains(&chip) && err.contains("edited.dcp"),
            "{err}"
        );
    }
    assert_eq!(listing(&store), ["reference.dcp"]);
    assert!(!work.join("new_store").exists());
    // A valid package of another CRS is refused by a store of EPSG:4547; nothing written.
    let foreign = work.join("foreign").join("utm.dcp");
    copy_dir(&pkg_dir, &foreign);
    let mpath = foreign.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&mpath).unwrap()).unwrap();
    m["crs"] = "EPSG:32650".into();
    std::fs::write(&mpath, serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    DcpPackage::open(&foreign).unwrap();
    let o = cli(
        &["dcp", "import"],
        &[("", foreign.as_path()), ("--into", store.as_path())],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("EPSG:32650") && err.contains("EPSG:4547") && err.contains("utm.dcp"),
        "{err}"
    );
    assert_eq!(listing(&store), ["reference.dcp"]);

    // An images.json that names a missing image is refused, naming the file and photo.
    let images_bad = work.join("images_bad.json");
    let mut im: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&s.images_json).unwrap()).unwrap();
    im["1"] = "nowhere/ref_001.png".into();
    std::fs::write(&images_bad, serde_json::to_vec(&im).unwrap()).unwrap();
    let o = cli(
        &["dcp", "generate"],
        &[
            ("--block", s.block_json.as_path()),
            ("--images", images_bad.as_path()),
            ("--lidar", s.lidar.as_path()),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("images_bad.json") && err.contains("photo 1") && err.contains("nowhere"),
        "{err}"
    );

    // Every subcommand's help carries an example.
    for sub in ["generate", "export", "import"] {
        let h = cli(&["dcp", sub, "--help"], &[]);
        let help = String::from_utf8_lossy(&h.stdout);
        assert!(
            help.contains("Example") && help.contains(&format!("cloudcontrol dcp {sub}")),
            "{sub}: {help}"
        );
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}
