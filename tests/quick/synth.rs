//! Acceptance tests of the synthetic block generator on the `tiny` preset: rendered
//! checkpoint targets and fiducial marks against their truth, determinism, LAS/LAZ read back.

use cloudcontrol::formats::crs::Crs;
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig, SynthManifest};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn config(seed: u64) -> SynthConfig {
    SynthConfig {
        preset: Preset::Tiny,
        seed,
        change: 0.5,
        pos: PosQuality::Rough,
        laz: false,
    }
}

struct Shared {
    _dir: tempfile::TempDir,
    path: PathBuf,
    manifest: SynthManifest,
}

fn shared() -> &'static Shared {
    static S: OnceLock<Shared> = OnceLock::new();
    S.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("block");
        let manifest = synth::generate(&config(11), &path).expect("generate tiny block");
        Shared {
            _dir: dir,
            path,
            manifest,
        }
    })
}

fn csv(path: &Path) -> Vec<BTreeMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(String::from))
                .collect()
        })
        .collect()
}

fn gray(path: &Path) -> image::GrayImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_luma8()
}

/// Intensity-weighted centroid (pixel-centre convention: centre of pixel (i, j) is
/// (i + 0.5, j + 0.5)) of the signal above the window's background level.
fn centroid(img: &image::GrayImage, cx: f64, cy: f64, half: f64, floor: f64) -> (f64, f64) {
    let (w, h) = img.dimensions();
    let x0 = ((cx - half).floor().max(0.0)) as u32;
    let y0 = ((cy - half).floor().max(0.0)) as u32;
    let x1 = ((cx + half).ceil() as u32).min(w - 1);
    let y1 = ((cy + half).ceil() as u32).min(h - 1);
    let mut vals = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            vals.push(img.get_pixel(x, y)[0] as f64);
        }
    }
    vals.sort_by(f64::total_cmp);
    let bg = vals[vals.len() / 10] + floor;
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for y in y0..=y1 {
        for x in x0..=x1 {
            // Circular window: only what lies around the mark counts.
            if (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) > half {
                continue;
            }
            let v = (img.get_pixel(x, y)[0] as f64 - bg).max(0.0);
            sw += v;
            sx += v * (x as f64 + 0.5);
            sy += v * (y as f64 + 0.5);
        }
    }
    (sx / sw, sy / sw)
}

#[test]
fn checkpoint_targets_are_rendered_where_the_true_orientation_projects_them() {
    let s = shared();
    let rows = csv(&s.path.join("truth/checkpoint_images.csv"));
    let mut per_epoch: BTreeMap<String, (usize, f64)> = BTreeMap::new();
    for r in &rows {
        let epoch = s
            .manifest
            .epochs
            .iter()
            .find(|e| e.name == r["epoch"])
            .unwrap();
        let img = gray(
            &s.path
                .join(&epoch.images_dir)
                .join(format!("{}.png", r["photo"])),
        );
        let (col, row): (f64, f64) = (r["col"].parse().unwrap(), r["row"].parse().unwrap());
        // Circular window: the white disc plus 1.5 px of its black surround.
        let half = synth::TARGET_DISC_RADIUS / epoch.gsd_m + 1.5;
        // Start from a point 0.7 px off so the window does not inherit the truth exactly.
        let (mx, my) = centroid(&img, col + 0.7, row - 0.7, half, 3.0);
        let (mx, my) = centroid(&img, mx, my, half, 3.0);
        let err = (mx - col).hypot(my - row);
        let e = per_epoch.entry(r["epoch"].clone()).or_default();
        e.0 += 1;
        e.1 = e.1.max(err);
    }
    eprintln!("checkpoint target centre vs projection, max error per epoch: {per_epoch:?}");
    assert_eq!(
        per_epoch.len(),
        3,
        "every epoch sees checkpoints: {per_epoch:?}"
    );
    for (epoch, (n, max)) in &per_epoch {
        assert!(*n >= 2, "{epoch}: only {n} checkpoint observations");
        assert!(
            *max <= 0.5,
            "{epoch}: checkpoint target {max:.3} px from its projection"
        );
    }
}

/// Mean scan pixel size (mm) of a photo from the true scan affine.
fn scan_pixel_mm(truth: &Path, photo: &str) -> f64 {
    let rows = csv(&truth.join("scan_affine.csv"));
    let r = rows.iter().find(|r| r["photo"] == photo).unwrap();
    let a: Vec<f64> = ["a11", "a12", "a21", "a22"]
        .iter()
        .map(|k| r[*k].parse().unwrap())
        .collect();
    (a[0] * a[3] - a[1] * a[2]).abs().sqrt()
}

#[test]
fn fiducial_marks_are_rendered_at_their_true_scan_positions() {
    let s = shared();
    let film = s.manifest.epochs.iter().find(|e| e.kind == "film").unwrap();
    let def: synth::FilmCameraDef =
        serde_json::from_slice(&std::fs::read(s.path.join(&film.camera)).unwrap()).unwrap();
    let rows = csv(&s.path.join(&film.truth_dir).join("fiducials.csv"));
    assert_eq!(rows.len(), film.photos.len() * def.fiducials.len());
    let mut worst: f64 = 0.0;
    for r in &rows {
        let img = gray(
            &s.path
                .join(&film.images_dir)
                .join(format!("{}.png", r["photo"])),
        );
        let f = def
            .fiducials
            .iter()
            .find(|f| f.id == r["fiducial"])
            .unwrap();
        let (col, row): (f64, f64) = (r["col"].parse().unwrap(), r["row"].parse().unwrap());
        let pixel_mm = scan_pixel_mm(&s.path.join(&film.truth_dir), &r["photo"]);
        let half = (f.shape.size_mm / 2.0 + 0.3) * std::f64::consts::SQRT_2 / pixel_mm;
        let (mx, my) = centroid(&img, col + 0.6, row + 0.4, half, 6.0);
        let (mx, my) = centroid(&img, mx, my, half, 6.0);
        worst = worst.max((mx - col).hypot(my - row));
    }
    eprintln!("fiducial mark centre vs truth: max {worst:.3} px");
    assert!(worst <= 0.2, "fiducial mark {worst:.3} px from its truth");
}

#[test]
fn same_seed_is_byte_identical_and_another_seed_differs() {
    let s = shared();
    let dir = tempfile::tempdir().unwrap();
    // The second run on a single thread: parallel rendering must not change a byte.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let again = pool
        .install(|| synth::generate(&config(11), &dir.path().join("a")))
        .unwrap();
    let a = synth::hash_tree(&s.path).unwrap();
    let b = synth::hash_tree(&dir.path().join("a")).unwrap();
    assert!(a.len() > 20);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(
            (&x.path, &x.sha256),
            (&y.path, &y.sha256),
            "{} differs between runs",
            x.path
        );
    }
    assert_eq!(
        std::fs::read(s.path.join("manifest.json")).unwrap(),
        std::fs::read(dir.path().join("a/manifest.json")).unwrap()
    );
    assert_eq!(again.files.len(), s.manifest.files.len());
    let other = synth::generate(&config(12), &dir.path().join("b")).unwrap();
    // Camera definitions and the project files do not depend on the seed; everything else
    // must.
    let same: Vec<&String> = other
        .files
        .iter()
        .filter(|f| {
            !f.path.ends_with("camera.json")
                && f.path != "project.toml"
                && f.path != "project_orthophoto.toml"
        })
        .filter(|f| a.iter().any(|g| g.path == f.path && g.sha256 == f.sha256))
        .map(|f| &f.path)
        .collect();
    assert!(same.is_empty(), "identical across seeds: {same:?}");
}

fn read_las(path: &Path) -> (las::Header, Vec<las::Point>) {
    let mut r = las::Reader::from_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let header = r.header().clone();
    let pts: Vec<las::Point> = r.points().map(|p| p.unwrap()).collect();
    (header, pts)
}

#[test]
fn las_tiles_read_back_equal_to_the_generated_points_with_their_crs() {
    let s = shared();
    let cfg = config(11);
    let scene = synth::Scene::generate(cfg.seed, synth::scene_extent(cfg.preset));
    let (strips, generated) = synth::simulate_lidar(&cfg, &scene);
    let mut read = Vec::new();
    for tile in &s.manifest.lidar.tiles {
        let (h, pts) = read_las(&s.path.join(&tile.path));
        assert_eq!(h.version(), las::Version::new(1, 4));
        assert_eq!(h.point_format().to_u8().unwrap(), 6);
        assert_eq!(h.transforms().x.scale, 0.001);
        assert_eq!(pts.len() as u64, tile.points);
        let wkt = String::from_utf8(h.get_wkt_crs_bytes().expect("WKT CRS VLR").to_vec()).unwrap();
        let crs = Crs::parse(wkt.trim_end_matches('\0')).unwrap();
        assert_eq!(crs.epsg(), Some(4547), "{}", tile.path);
        read.extend(pts);
    }
    assert_eq!(read.len(), generated.len());
    let key = |t: f64, x: f64, r: u8| (t.to_bits(), r, (x * 1000.0).round() as i64);
    let mut by_key: BTreeMap<_, &las::Point> = BTreeMap::new();
    for p in &read {
        by_key.insert(
            key(p.gps_time.unwrap(), p.x - synth::ORIGIN[0], p.return_number),
            p,
        );
    }
    let mut max_err: f64 = 0.0;
    let mut classes = std::collections::BTreeSet::new();
    for g in &generated {
        let p = by_key
            .get(&key(g.gps_time, g.xyz[0], g.return_number))
            .or_else(|| by_key.get(&key(g.gps_time, g.xyz[0] + 0.0005, g.return_number)))
            .or_else(|| by_key.get(&key(g.gps_time, g.xyz[0] - 0.0005, g.return_number)))
            .expect("generated point present in the tiles");
        max_err = max_err
            .max((p.x - synth::ORIGIN[0] - g.xyz[0]).abs())
            .max((p.y - synth::ORIGIN[1] - g.xyz[1]).abs())
            .max((p.z - g.xyz[2]).abs());
        assert_eq!(u8::from(p.classification), g.class);
        assert_eq!(p.point_source_id, g.source);
        assert_eq!(p.intensity, g.intensity);
        assert_eq!(
            (p.return_number, p.number_of_returns),
            (g.return_number, g.number_of_returns)
        );
        classes.insert(g.class);
    }
    assert!(max_err <= 0.0005 + 1e-9, "coordinates differ by {max_err}");
    for c in [2u8, 5, 6, 7, 18] {
        assert!(classes.contains(&c), "class {c} missing: {classes:?}");
    }
    assert_eq!(strips.len(), s.manifest.lidar.strips);

    // The same points written as LAZ read back identically.
    let dir = tempfile::tempdir().unwrap();
    let wkt = Crs::from_epsg(4547).unwrap().to_wkt().unwrap();
    let laz = synth::lidar::write_tiles(
        &generated,
        synth::ORIGIN,
        100.0,
        &wkt,
        true,
        dir.path(),
        ".",
    )
    .unwrap();
    for (a, b) in laz.iter().zip(&s.manifest.lidar.tiles) {
        let (_, pa) = read_las(&dir.path().join(a.path.trim_start_matches("./")));
        let (_, pb) = read_las(&s.path.join(&b.path));
        assert_eq!(pa, pb, "{} LAZ differs from LAS", a.path);
    }
}

#[test]
fn invalid_change_fraction_is_rejected_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = config(1);
    c.change = f64::NAN;
    let e = synth::generate(&c, dir.path()).unwrap_err().to_string();
    assert!(e.contains("change"), "{e}");
}

#[test]
fn unwritable_output_folder_is_reported_with_its_path() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not_a_folder");
    std::fs::write(&file, b"x").unwrap();
    let e = synth::generate(&config(1), &file).unwrap_err().to_string();
    assert!(e.contains("not_a_folder"), "{e}");
}

/// The navigation the generator writes is the documented POS CSV (formats/pos/): read by
/// the project's reader, each record names its image file and lies within its stated σ of
/// the truth (read by the truth readers, checked against this file's own CSV split).
#[test]
fn navigation_is_the_documented_pos_within_its_sigma_of_the_truth() {
    use cloudcontrol::formats::pos::read_pos;
    use cloudcontrol::synth::truth::{read_scan_affine, read_truth_eo};
    let s = shared();
    for e in &s.manifest.epochs {
        let pos = read_pos(&s.path.join(&e.navigation)).unwrap();
        let truth = read_truth_eo(&s.path.join(&e.truth_dir).join("eo.csv")).unwrap();
        assert_eq!(pos.len(), e.photos.len());
        assert_eq!(truth.len(), e.photos.len());
        for ((r, (name, rot, centre)), photo) in pos.iter().zip(&truth).zip(&e.photos) {
            assert_eq!(r.name, format!("{photo}.png"));
            assert_eq!(name, photo);
            assert!(s.path.join(&e.images_dir).join(&r.name).is_file());
            let (sc, sa) = (r.sigma_xyz.unwrap(), r.sigma_angle.unwrap());
            let d = (0..3)
                .map(|i| (r.center[i] - centre[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(d < 5.0 * sc, "{}: centre {d:.3} m off, σ {sc}", r.name);
            let q = cloudcontrol::geometry::matrix_from_opk(r.opk[0], r.opk[1], r.opk[2]);
            let angle = ((q * rot.transpose()).trace() - 1.0).clamp(-2.0, 2.0) / 2.0;
            let angle = angle.clamp(-1.0, 1.0).acos();
            assert!(
                angle < 5.0 * 3f64.sqrt() * sa,
                "{}: attitude {angle} rad off, σ {sa}",
                r.name
            );
        }
        // The truth reader agrees with this file's independent split of eo.csv.
        let rows = csv(&s.path.join(&e.truth_dir).join("eo.csv"));
        for (row, (name, rot, centre)) in rows.iter().zip(&truth) {
            assert_eq!(&row["photo"], name);
            assert_eq!(row["x"].parse::<f64>().unwrap(), centre[0]);
            assert_eq!(row["r23"].parse::<f64>().unwrap(), rot[(1, 2)]);
        }
        if e.kind == "film" {
            let affine =
                read_scan_affine(&s.path.join(&e.truth_dir).join("scan_affine.csv")).unwrap();
            for r in csv(&s.path.join(&e.truth_dir).join("scan_affine.csv")) {
                let m = &affine[&r["photo"]].pixel_to_mm;
                assert_eq!(r["a12"].parse::<f64>().unwrap(), m[(0, 1)]);
                assert_eq!(r["a23"].parse::<f64>().unwrap(), m[(1, 2)]);
            }
        }
    }
}

/// Each epoch's true surface (`truth/epochs/<epoch>/dsm.tif`), read with GDAL: on the
/// block's area at the epoch's ground pixel in the block's CRS; the reference epoch's is
/// the present scene's heights; an older epoch's differs where the scene changed
/// (buildings built or demolished since) and nowhere else.
#[test]
fn every_epoch_has_its_true_surface_at_its_ground_pixel() {
    let s = shared();
    let cfg = config(11);
    let area = synth::scene_extent(cfg.preset);
    let scene = synth::Scene::generate(cfg.seed, area);
    let read = |epoch: &synth::EpochInfo| {
        let path = s.path.join(&epoch.truth_dir).join("dsm.tif");
        let ds = gdal::Dataset::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let gt = ds.geo_transform().unwrap();
        let srs = ds.spatial_ref().unwrap();
        assert_eq!(srs.auth_code().unwrap(), 4547, "{}", path.display());
        let (w, h) = ds.raster_size();
        let band = ds.rasterband(1).unwrap();
        let z = band
            .read_as::<f32>((0, 0), (w, h), (w, h), None)
            .unwrap()
            .data()
            .to_vec();
        (gt, w, h, z)
    };
    let reference = &s.manifest.epochs[0];
    let (gt, w, h, z_ref) = read(reference);
    let g = reference.gsd_m;
    assert_eq!((gt[1], gt[5]), (g, -g));
    assert_eq!(
        (gt[0], gt[3]),
        (area[0] + synth::ORIGIN[0], area[3] + synth::ORIGIN[1])
    );
    assert_eq!(
        (w, h),
        (
            ((area[2] - area[0]) / g) as usize,
            ((area[3] - area[1]) / g) as usize
        )
    );
    let mut worst: f64 = 0.0;
    for k in (0..w * h).step_by(97) {
        let (c, r) = ((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
        let (x, y) = (gt[0] + c * gt[1], gt[3] + r * gt[5]);
        let truth = scene.height_at(x - synth::ORIGIN[0], y - synth::ORIGIN[1]) + synth::ORIGIN[2];
        worst = worst.max((z_ref[k] as f64 - truth).abs());
    }
    assert!(worst < 1e-3, "reference DSM off the scene by {worst} m");
    for epoch in &s.manifest.epochs[1..] {
        let (gt, w, h, z) = read(epoch);
        assert_eq!(
            (gt[1], gt[5]),
            (epoch.gsd_m, -epoch.gsd_m),
            "{}",
            epoch.name
        );
        // The reference surface at this grid's cell centres, from its own grid.
        let (mut same, mut changed, mut n) = (0usize, 0usize, 0usize);
        for k in (0..w * h).step_by(7) {
            let (c, r) = ((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            let (x, y) = (gt[0] + c * gt[1], gt[3] + r * gt[5]);
            let truth = scene.height_at(x - synth::ORIGIN[0], y - synth::ORIGIN[1]);
            let dz = (z[k] as f64 - truth).abs();
            n += 1;
            same += (dz < 1e-3) as usize;
            changed += (dz > 2.0) as usize;
        }
        let (same, changed) = (same as f64 / n as f64, changed as f64 / n as f64);
        eprintln!(
            "{}: {same:.3} of the cells as today, {changed:.3} changed by > 2 m",
            epoch.name
        );
        assert!(
            same > 0.7 && changed > 0.005,
            "{}: same {same}, changed {changed}",
            epoch.name
        );
        assert!(
            same + changed > 0.97,
            "{}: heights changed without an object",
            epoch.name
        );
    }
}

/// `truth/epochs/<epoch>/buildings.csv` against the epoch's own true surface (GDAL): a
/// building listed for an epoch stands at its footprint's centre (the surface at least
/// its eave above its base), one listed for today and not for the epoch does not stand
/// there then (the surface below half its eave height), and the ids listed
/// in one epoch and not the other are the changed buildings both ways.
#[test]
fn each_epoch_lists_the_buildings_standing_then() {
    use cloudcontrol::synth::truth::read_buildings;
    let s = shared();
    // Each epoch's true surface read once with GDAL; its height at a point by its cell.
    let surface = |epoch: &synth::EpochInfo| {
        let ds = gdal::Dataset::open(s.path.join(&epoch.truth_dir).join("dsm.tif")).unwrap();
        let gt = ds.geo_transform().unwrap();
        let (w, h) = ds.raster_size();
        let band = ds.rasterband(1).unwrap();
        let z = band.read_as::<f32>((0, 0), (w, h), (w, h), None).unwrap();
        move |x: f64, y: f64| -> f64 {
            let (c, r) = (
                ((x - gt[0]) / gt[1]) as usize,
                ((y - gt[3]) / gt[5]) as usize,
            );
            z.data()[r * w + c] as f64
        }
    };
    let today = &s.manifest.epochs[0];
    let now = read_buildings(&s.path.join(&today.truth_dir).join("buildings.csv")).unwrap();
    assert!(!now.is_empty());
    for epoch in &s.manifest.epochs {
        let then = read_buildings(&s.path.join(&epoch.truth_dir).join("buildings.csv")).unwrap();
        let height = surface(epoch);
        for b in &then {
            assert!(
                b.contains(b.x, b.y)
                    && !b.contains(b.x + 2.0 * b.half_length, b.y + 2.0 * b.half_length)
            );
            let z = height(b.x, b.y);
            assert!(
                z >= b.base + b.eave - 0.01,
                "{} building {}: surface {z} below its eave {}",
                epoch.name,
                b.id,
                b.base + b.eave
            );
        }
        let gone: Vec<_> = now
            .iter()
            .filter(|b| then.iter().all(|t| t.id != b.id))
            .collect();
        let built_over = |b: &&cloudcontrol::synth::truth::TrueBuilding| {
            then.iter().any(|t| t.contains(b.x, b.y))
        };
        for b in gone.iter().filter(|b| !built_over(b)) {
            let z = height(b.x, b.y);
            assert!(
                z < b.base + 0.5 * b.eave,
                "{}: building {} of today stands then ({z} m over a base of {})",
                epoch.name,
                b.id,
                b.base
            );
        }
        if epoch.name != today.name {
            let added = then
                .iter()
                .filter(|t| now.iter().all(|b| b.id != t.id))
                .count();
            eprintln!(
                "{}: {} buildings, {} of today's not yet standing, {added} gone since",
                epoch.name,
                then.len(),
                gone.len()
            );
            assert!(
                !gone.is_empty() || added > 0,
                "{}: no changed building",
                epoch.name
            );
        }
    }
}
