//! Fuzz target bodies: each feeds the input bytes to the library's own reading entry point
//! for one format. Errors are the expected outcome for most inputs; a panic, abort, OOM or
//! hang is a bug. The fuzz_targets/*.rs files only wrap these for libFuzzer, and
//! the root crate's tests/fuzz_replay.rs replays fuzz/corpus/ through them on stable, so
//! the glue cannot rot.
//!
//! Readers that take a path get the bytes as files in a scratch folder of this process
//! and thread (reused between inputs, so a run measures the reader, not mkdir). Inputs of
//! several files are split by [`members`].

use cloudcontrol::control::dcp::DcpPackage;
use cloudcontrol::control::epoch::EpochCamera;
use cloudcontrol::formats::odm_gcp::{read_odm_gcp, GcpOptions};
use cloudcontrol::formats::{blocks_exchange, colmap, image_open};
use cloudcontrol::geometry::{Camera, FilmCamera, InteriorOrientation, InteriorTransformKind};
use cloudcontrol::lidar::{points_io, LasStream, PointBatch};
use cloudcontrol::matching::fiducial::{
    check_scan_pixel_um, interior_orientation_file, render_template, CameraDefinition,
    FiducialFrame, IoOptions, ScanOrientation,
};
use cloudcontrol::matching::GreyImage;
use cloudcontrol::pipeline::project::Project;
use cloudcontrol::pipeline::run::check_output;
use cloudcontrol::pipeline::stages::MARKER;
use cloudcontrol::pipeline::tasks::read_task_file;
use nalgebra::{Matrix2, Vector2};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// The member files of a COLMAP model, in the order [`members`] splits them.
const COLMAP_STEMS: [&str; 5] = ["cameras", "images", "points3D", "rigs", "frames"];

/// Stands for the SHA-256 of the chip in a `dcp_package` input's manifest, so mutated
/// chips still pass the checksum and reach the image header reader.
pub const CHIP_SHA256: &str = "@CHIP_SHA256@";

/// Where `dcp_package` writes its chip, relative to the package.
pub const CHIP_FILE: &str = "chips/chip.png";

/// Splits an input into up to `n` members, each a little-endian `u32` length then that
/// many bytes (fewer when the input ends first). A member is absent when fewer than four
/// bytes are left for its length, so inputs also reach the "file missing" paths.
pub fn members(mut data: &[u8], n: usize) -> Vec<Option<&[u8]>> {
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        if data.len() < 4 {
            out.push(None);
            continue;
        }
        let len = u32::from_le_bytes([data[0], data[1], data[2], data[3]]) as usize;
        let len = len.min(data.len() - 4);
        out.push(Some(&data[4..4 + len]));
        data = &data[4 + len..];
    }
    out
}

/// The inverse of [`members`]: how corpus files are made from real files.
pub fn join_members(parts: &[Option<&[u8]>]) -> Vec<u8> {
    let mut out = Vec::new();
    for p in parts.iter().flatten() {
        out.extend_from_slice(&(p.len() as u32).to_le_bytes());
        out.extend_from_slice(p);
    }
    out
}

/// The scratch folder for `target`, private to this process and thread, made on first
/// use. It lives in /dev/shm where there is one: on a disk, writing and removing the
/// member files costs milliseconds and would set the pace of the whole run.
fn scratch(target: &str) -> PathBuf {
    let shm = Path::new("/dev/shm");
    let base = if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!(
        "cloudcontrol-fuzz-{}-{:?}-{target}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&dir).expect("scratch folder can be made");
    dir
}

/// Removes the files a previous input left, so each input sees only its own members.
fn clear(dir: &Path, names: &[&str]) {
    for n in names {
        let _ = std::fs::remove_file(dir.join(n));
    }
}

fn put(path: &Path, bytes: &[u8]) {
    if let Some(p) = path.parent() {
        std::fs::create_dir_all(p).expect("scratch sub-folder can be made");
    }
    std::fs::write(path, bytes).expect("scratch file can be written");
}

fn colmap(data: &[u8], ext: &str, target: &str) -> bool {
    let dir = scratch(target);
    let names = COLMAP_STEMS.map(|stem| format!("{stem}.{ext}"));
    clear(&dir, &names.each_ref().map(String::as_str));
    for (stem, bytes) in COLMAP_STEMS.iter().zip(members(data, COLMAP_STEMS.len())) {
        if let Some(b) = bytes {
            put(&dir.join(format!("{stem}.{ext}")), b);
        }
    }
    colmap::read(&dir).is_ok()
}

/// A binary COLMAP model: cameras, images, points3D, rigs, frames `.bin` by [`members`].
fn colmap_bin_reads(data: &[u8]) -> bool {
    colmap(data, "bin", "colmap_bin")
}

/// A text COLMAP model: cameras, images, points3D, rigs, frames `.txt` by [`members`].
fn colmap_txt_reads(data: &[u8]) -> bool {
    colmap(data, "txt", "colmap_txt")
}

/// A BlocksExchange XML file.
fn blocks_exchange_reads(data: &[u8]) -> bool {
    let dir = scratch("blocks_exchange");
    let path = dir.join("block.xml");
    put(&path, data);
    blocks_exchange::read(&path).is_ok()
}

/// The sample package's chips, so a mutated manifest meets real, correctly summed files.
const SAMPLE_CHIPS: [(&str, &[u8]); 8] = [
    (
        "chips/p1_1.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p1_1.png"),
    ),
    (
        "chips/p1_2.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p1_2.png"),
    ),
    (
        "chips/p2_1.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p2_1.png"),
    ),
    (
        "chips/p2_2.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p2_2.png"),
    ),
    (
        "chips/p3_1.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p3_1.png"),
    ),
    (
        "chips/p3_2.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p3_2.png"),
    ),
    (
        "chips/p4_1.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p4_1.png"),
    ),
    (
        "chips/p4_2.png",
        include_bytes!("../../formats/dcp/sample.dcp/chips/p4_2.png"),
    ),
];

/// A DCP manifest (`manifest.json`) in a package holding the sample package's chips.
fn dcp_manifest_reads(data: &[u8]) -> bool {
    let dir = scratch("dcp_manifest");
    for (name, bytes) in SAMPLE_CHIPS {
        if !dir.join(name).is_file() {
            put(&dir.join(name), bytes);
        }
    }
    put(&dir.join("manifest.json"), data);
    DcpPackage::open(&dir).is_ok()
}

/// A DCP package: manifest then one chip by [`members`]; the chip is [`CHIP_FILE`] and
/// [`CHIP_SHA256`] in the manifest is replaced by the chip's checksum.
fn dcp_package_reads(data: &[u8]) -> bool {
    let dir = scratch("dcp_package");
    clear(&dir, &["manifest.json", CHIP_FILE]);
    let parts = members(data, 2);
    let chip = parts[1].unwrap_or_default();
    if let Some(manifest) = parts[0] {
        let sum: String = Sha256::digest(chip)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        put(
            &dir.join("manifest.json"),
            &replace(manifest, CHIP_SHA256.as_bytes(), sum.as_bytes()),
        );
    }
    if parts[1].is_some() {
        put(&dir.join(CHIP_FILE), chip);
    }
    DcpPackage::open(&dir).is_ok()
}

fn replace(haystack: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(haystack.len());
    let mut i = 0;
    while i < haystack.len() {
        if haystack[i..].starts_with(from) {
            out.extend_from_slice(to);
            i += from.len();
        } else {
            out.push(haystack[i]);
            i += 1;
        }
    }
    out
}

/// A LAS or LAZ file (the header says which): header, VLRs and every point.
fn las_reads(data: &[u8]) -> bool {
    let dir = scratch("las");
    let path = dir.join("tile.las");
    put(&path, data);
    // Opening a LAZ file already decompresses its first points.
    let read = std::panic::AssertUnwindSafe(|| {
        let Ok(mut s) = LasStream::open(&path) else {
            return false;
        };
        if s.crs().is_err() {
            return false;
        }
        let mut batch = PointBatch::default();
        loop {
            match s.read_batch(1 << 16, &mut batch) {
                Ok(0) => return true,
                Ok(_) => {}
                Err(_) => return false,
            }
        }
    });
    pass_known_laz_assertion();
    std::panic::catch_unwind(read).unwrap_or(false)
}

/// laz 0.12 has checks that only builds with debug assertions make: its arithmetic
/// decoder `debug_assert!`s the width of a decoded symbol (src/decoders.rs), and its
/// integer arithmetic (e.g. the GPS time predictor, src/las/gps.rs) is overflow-checked.
/// Corrupt point data breaks both within a few thousand inputs. The fuzz build has debug
/// assertions and overflow checks on; the library's release build has neither, and there
/// the same inputs end in an error or in wrong point values, never a panic
/// (tests/fuzz_regressions.rs, tests/fuzz_replay.rs). So exactly those panics raised
/// inside laz are let unwind to the `catch_unwind` in [`las_reads`]; every other panic
/// still reaches libFuzzer's hook (an abort, a crash report).
fn pass_known_laz_assertion() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            // The registry's laz, or the vendored copy that replaces it (vendor/README.md).
            let in_laz = info
                .location()
                .map(|l| l.file())
                .filter(|f| f.contains("/laz-0.12.") || f.contains("vendor/laz/src/"));
            let p = info.payload();
            let message = p
                .downcast_ref::<&str>()
                .copied()
                .or(p.downcast_ref::<String>().map(String::as_str))
                .unwrap_or("");
            let known = in_laz.is_some_and(|f| {
                (f.ends_with("src/decoders.rs") && message.contains("sym < (1 << 16)"))
                    || (message.starts_with("attempt to ") && message.ends_with("with overflow"))
            });
            if !known {
                previous(info);
            }
        }));
    });
}

/// A PLY point file (ascii or binary little endian).
fn ply_points_reads(data: &[u8]) -> bool {
    let dir = scratch("ply_points");
    let path = dir.join("points.ply");
    put(&path, data);
    points_io::read_xyz(&path).is_ok()
}

/// A CSV/text XYZ point file.
fn csv_points_reads(data: &[u8]) -> bool {
    let dir = scratch("csv_points");
    let path = dir.join("points.csv");
    put(&path, data);
    points_io::read_xyz(&path).is_ok()
}

/// An OpenDroneMap GCP file (`gcp_list.txt`).
fn odm_gcp_reads(data: &[u8]) -> bool {
    let dir = scratch("odm_gcp");
    let path = dir.join("gcp_list.txt");
    put(&path, data);
    read_odm_gcp(&path, &GcpOptions::default()).is_ok()
}

/// The paths formats/project/example.toml names, so a project can pass the existence
/// checks and reach the epoch, date and threshold checks behind them.
const PROJECT_DIRS: [&str; 4] = [
    "lidar",
    "epochs/reference/images",
    "epochs/digital/images",
    "epochs/film/images",
];
const PROJECT_FILES: [&str; 9] = [
    "checkpoints.csv",
    "checkpoint_images.csv",
    "epochs/reference/camera.json",
    "epochs/reference/pos.csv",
    "epochs/digital/camera.json",
    "epochs/digital/pos.csv",
    "epochs/film/camera.json",
    "epochs/film/strips.csv",
    "lidar/tile.las",
];

/// A project TOML file (its relative paths resolve inside the scratch folder, which holds
/// the example's files, empty).
fn project_toml_reads(data: &[u8]) -> bool {
    let dir = scratch("project_toml");
    for d in PROJECT_DIRS {
        std::fs::create_dir_all(dir.join(d)).expect("scratch sub-folder can be made");
    }
    for f in PROJECT_FILES {
        if !dir.join(f).is_file() {
            put(&dir.join(f), b"");
        }
    }
    let path = dir.join("project.toml");
    put(&path, data);
    Project::load(&path).is_ok()
}

/// The template image a film camera's `template` marks may name (`"file":
/// "template.png"` or `"marks/L.png"`, as formats/cameras/README.md's example), beside
/// the camera file of the `camera_json` target: a 32 × 32 grey crop.
const TEMPLATE_PNG: &[u8] = include_bytes!("../../formats/dcp/sample.dcp/chips/p1_1.png");

/// A camera JSON file: a frame camera or a film camera's certificate, read, validated
/// and then built into what the workflow uses (see [`use_camera`]).
fn camera_json_reads(data: &[u8]) -> bool {
    let dir = scratch("camera_json");
    for name in ["template.png", "marks/L.png"] {
        if !dir.join(name).is_file() {
            put(&dir.join(name), TEMPLATE_PNG);
        }
    }
    let path = dir.join("camera.json");
    put(&path, data);
    match EpochCamera::load(&path) {
        Ok(cam) => {
            use_camera(&cam);
            true
        }
        Err(_) => false,
    }
}

/// Side (pixels) of the nominal scan a film camera is built for in [`use_camera`]: the
/// scan pixel is the film format over it (clamped to the plausible scan pixels), so the
/// templates drawn stay small whatever the camera says.
const NOMINAL_SCAN_SIDE: f64 = 256.0;

/// What the workflow does with a camera once read: a frame camera's projections (pixel
/// to ray and back over a grid of the image, its parameter vector); a film camera's mark
/// templates drawn in every scan orientation, its fiducial frame and frame camera, and
/// the film camera of a nominal scan projected like a frame camera's.
fn use_camera(cam: &EpochCamera) {
    match cam {
        EpochCamera::Frame(f) => project_grid(&Camera::Frame(f.clone())),
        EpochCamera::Film(def) => {
            let [fw, fh] = def.format_mm;
            let s = (fw.max(fh) / NOMINAL_SCAN_SIDE).clamp(0.003, 0.2);
            let margin = 0.5
                * def
                    .fiducials
                    .iter()
                    .map(|f| f.shape.extent_mm())
                    .fold(0.0, f64::max);
            for o in ScanOrientation::all() {
                for f in &def.fiducials {
                    let _ = render_template(&f.shape, &o.linear(s), margin);
                }
            }
            let (w, h) = ((fw / s).round(), (fh / s).round());
            let Ok(interior) = InteriorOrientation::affine(
                &Matrix2::new(s, 0.0, 0.0, -s),
                &Vector2::new(-s * w / 2.0, s * h / 2.0),
            ) else {
                return;
            };
            let d = &def.distortion;
            let film = FilmCamera {
                width: w as u32,
                height: h as u32,
                focal_mm: def.focal_mm,
                principal_point_mm: def.principal_point_mm,
                distortion: cloudcontrol::geometry::Brown::from_array([
                    d.k1, d.k2, d.k3, d.p1, d.p2,
                ]),
                interior,
            };
            if let Ok(frame) = FiducialFrame::new(def.format_mm, s) {
                let _ = frame.sensor_size_mm();
                project_grid(&Camera::Frame(frame.frame_camera(&film)));
            }
            project_grid(&Camera::Film(film));
        }
    }
}

/// A camera validated, then a 5 × 5 grid of its image (edges included) taken to rays and
/// projected back, and its parameters read and set again.
fn project_grid(cam: &Camera) {
    if cam.validate().is_err() {
        return;
    }
    let (w, h) = cam.image_size();
    let _ = cam.focal_px();
    for i in 0..5 {
        for j in 0..5 {
            let px = [w as f64 * i as f64 / 4.0, h as f64 * j as f64 / 4.0];
            if let Ok(ray) = cam.unproject(px) {
                let _ = cam.project(&ray);
            }
        }
    }
    let mut c = cam.clone();
    let p = c.params();
    let _ = c.set_params(&p);
}

/// Largest side (pixels) of the scan the `fiducial_io` target orients: larger scans are
/// skipped (by their header) to keep the target fast; the marks of a small camera (a
/// 23 mm format, 2 mm marks) on such a scan are ~20 pixels, as on a real scan.
pub const FIDUCIAL_MAX_SCAN_SIDE: u32 = 256;

/// Fiducial interior orientation, the whole path of `cloudcontrol io --camera camera.json
/// [--pixel-um U] [--orientation O] [--projective] scan` (src/bin/cloudcontrol/matching.rs):
/// camera definition, scan, options and a template image by [`members`]. The options
/// member is text, the CLI's flags as `pixel_um=U`, `orientation=O` and `projective`
/// separated by white space. The scan must be an image whose header the `image` crate
/// reads and at most [`FIDUCIAL_MAX_SCAN_SIDE`] a side.
fn fiducial_io_reads(data: &[u8]) -> bool {
    let dir = scratch("fiducial_io");
    clear(&dir, &["camera.json", "scan", "template.png"]);
    let parts = members(data, 4);
    let (Some(camera), Some(scan)) = (parts[0], parts[1]) else {
        return false;
    };
    match image_open::image_size_bytes(Path::new("scan"), scan) {
        Ok((w, h)) if w <= FIDUCIAL_MAX_SCAN_SIDE && h <= FIDUCIAL_MAX_SCAN_SIDE => {}
        _ => return false,
    }
    let (camera_path, scan_path) = (dir.join("camera.json"), dir.join("scan"));
    put(&camera_path, camera);
    put(&scan_path, scan);
    if let Some(t) = parts[3] {
        put(&dir.join("template.png"), t);
    }
    // The CLI's flags.
    let (mut pixel_um, mut orientation, mut projective) = (None, None, false);
    for word in String::from_utf8_lossy(parts[2].unwrap_or_default()).split_whitespace() {
        match word.split_once('=') {
            Some(("pixel_um", v)) => match v.parse::<f64>() {
                Ok(v) => pixel_um = Some(v),
                Err(_) => return false,
            },
            Some(("orientation", v)) => orientation = Some(v.to_string()),
            None if word == "projective" => projective = true,
            _ => return false,
        }
    }
    // As `matching::io` does.
    if let Some(um) = pixel_um {
        if check_scan_pixel_um(um).is_err() {
            return false;
        }
    }
    let cam = match CameraDefinition::load(&camera_path) {
        Ok(c) => c,
        Err(e) => return verdict(Err::<(), _>(e)),
    };
    let Ok(orientation) = orientation.as_deref().map(str::parse).transpose() else {
        return false;
    };
    let opts = IoOptions {
        pixel_mm: pixel_um.map(|u| u / 1000.0),
        orientation,
        kind: if projective {
            InteriorTransformKind::Projective
        } else {
            InteriorTransformKind::Affine
        },
        ..IoOptions::default()
    };
    match interior_orientation_file(&cam, &scan_path, &opts) {
        Ok(io) => {
            let text = serde_json::to_string_pretty(&io.to_json()).expect("io.json serialises");
            !text.is_empty()
        }
        Err(e) => verdict(Err::<(), _>(e)),
    }
}

/// An image decoded whole, as DCP chips (`decode_image_bytes`, in memory) and photos and
/// scans (`GreyImage::load` of a file: `decode_image`, the reduction to grey, GDAL for
/// what the `image` crate cannot read) are, within the decoders' memory limits.
fn image_decode_reads(data: &[u8]) -> bool {
    let chip = image_open::decode_image_bytes(Path::new("chip"), data).is_ok();
    let dir = scratch("image_decode");
    let path = dir.join("photo");
    put(&path, data);
    let photo = GreyImage::load(&path).is_ok();
    chip || photo
}

/// The task files a `task_files` input may be, by its first byte (modulo their number):
/// every kind's result, a round's result, a round's file and a photo's part of it, the
/// strip offsets, a stereo pair's samples (src/pipeline/tasks/).
pub const TASK_FILES: [&str; 17] = [
    "screen-00000.msgpack",
    "clean-00000.msgpack",
    "strip_offsets.msgpack",
    "scan-00000.msgpack",
    "orient-00000.msgpack",
    "cut-000-00000.msgpack",
    "match-000-00000.msgpack",
    "reorient-000-00000.msgpack",
    "round-000-cut.msgpack",
    "round-000-match.msgpack",
    "round-000-reorient.msgpack",
    "round-000-match-00000.msgpack",
    "pairs-00000.msgpack",
    "chips-00000.msgpack",
    "resample-00000.msgpack",
    "ortho-00000.msgpack",
    "stereo-00000.msgpack",
];

/// A task file (MessagePack) read as its stage reads it back
/// (`pipeline::tasks::read_task_file`): the first byte picks its name from
/// [`TASK_FILES`], the rest is the file.
fn task_files_reads(data: &[u8]) -> bool {
    let Some((&k, body)) = data.split_first() else {
        return false;
    };
    let dir = scratch("task_files");
    let path = dir.join(TASK_FILES[k as usize % TASK_FILES.len()]);
    put(&path, body);
    let ok = verdict(read_task_file(&path));
    let _ = std::fs::remove_file(&path);
    ok
}

/// Whether `r` is Ok; with CLOUDCONTROL_FUZZ_VERBOSE set, the error is printed (to see
/// why a seed is refused: `CLOUDCONTROL_FUZZ_VERBOSE=1 cargo test --release --test
/// fuzz_replay -- --nocapture`).
fn verdict<T, E: std::fmt::Display>(r: Result<T, E>) -> bool {
    match r {
        Ok(_) => true,
        Err(e) => {
            if std::env::var_os("CLOUDCONTROL_FUZZ_VERBOSE").is_some() {
                eprintln!("refused: {e}");
            }
            false
        }
    }
}

/// What a path a project names is in a `project_check` input's folder (the layout
/// member's byte for it, modulo 10).
#[derive(Clone, Copy, PartialEq)]
enum Entry {
    /// What the example project expects there (its folders a folder, files a file with the
    /// content member, the output folder absent).
    Expected,
    Absent,
    File,
    EmptyDir,
    /// A folder holding a file (for the output folder: a user's folder).
    FullDir,
    /// A symbolic link to a regular file of the content member.
    LinkToFile,
    /// A symbolic link to itself.
    LinkLoop,
    /// A symbolic link to nothing.
    Dangling,
    Fifo,
    /// A folder a run made: its marker file (`pipeline::stages::MARKER`) holding the
    /// content member.
    RunDir,
}

const ENTRIES: [Entry; 10] = [
    Entry::Expected,
    Entry::Absent,
    Entry::File,
    Entry::EmptyDir,
    Entry::FullDir,
    Entry::LinkToFile,
    Entry::LinkLoop,
    Entry::Dangling,
    Entry::Fifo,
    Entry::RunDir,
];

/// The paths a project may name in `project_check`'s folder (formats/project/example.toml
/// and its commented keys), parents first, with what each is when expected: a folder
/// (`true`), a file, or for `out` (the output), nothing.
pub const CHECK_PATHS: [(&str, Option<bool>); 17] = [
    ("lidar", Some(true)),
    ("lidar/tile.las", Some(false)),
    ("checkpoints.csv", Some(false)),
    ("checkpoint_images.csv", Some(false)),
    ("epochs/reference/images", Some(true)),
    ("epochs/reference/camera.json", Some(false)),
    ("epochs/reference/pos.csv", Some(false)),
    ("epochs/digital/images", Some(true)),
    ("epochs/digital/camera.json", Some(false)),
    ("epochs/digital/pos.csv", Some(false)),
    ("epochs/film/images", Some(true)),
    ("epochs/film/camera.json", Some(false)),
    ("epochs/film/strips.csv", Some(false)),
    ("ortho/orthophoto.tif", Some(false)),
    ("ortho/dem.tif", Some(false)),
    ("at/blocks_exchange.xml", Some(false)),
    ("out", None),
];

/// Top-level names [`CHECK_PATHS`] and the target's own files use, removed before each input.
const CHECK_ROOTS: [&str; 10] = [
    "lidar",
    "checkpoints.csv",
    "checkpoint_images.csv",
    "epochs",
    "ortho",
    "at",
    "out",
    "project.toml",
    "content",
    "nothing",
];

/// Lays out `project_check`'s folder: each of [`CHECK_PATHS`] as its byte of `layout`
/// says ([`Entry`]; [`Entry::Expected`] where the layout ends), files holding `content`.
pub fn lay_out_project(dir: &Path, layout: &[u8], content: &[u8]) {
    for name in CHECK_ROOTS {
        let p = dir.join(name);
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(&p).expect("scratch folder removed"),
            Ok(_) => std::fs::remove_file(&p).expect("scratch file removed"),
            Err(_) => {}
        }
    }
    put(&dir.join("content"), content);
    for (k, (rel, expected)) in CHECK_PATHS.iter().enumerate() {
        let p = dir.join(rel);
        // A child of something that is not a folder cannot be made.
        match p.parent().map(std::fs::symlink_metadata) {
            Some(Ok(m)) if m.is_dir() => {}
            Some(Ok(_)) => continue,
            _ => std::fs::create_dir_all(p.parent().expect("relative path"))
                .expect("scratch sub-folder can be made"),
        }
        let entry = match layout.get(k) {
            Some(&b) => ENTRIES[b as usize % ENTRIES.len()],
            None => Entry::Expected,
        };
        let entry = match (entry, expected) {
            (Entry::Expected, Some(true)) => Entry::EmptyDir,
            (Entry::Expected, Some(false)) => Entry::File,
            (Entry::Expected, None) => Entry::Absent,
            (e, _) => e,
        };
        match entry {
            Entry::Expected | Entry::Absent => {}
            Entry::File => put(&p, content),
            Entry::EmptyDir => std::fs::create_dir(&p).expect("scratch folder made"),
            Entry::FullDir => {
                std::fs::create_dir(&p).expect("scratch folder made");
                put(&p.join("notes.txt"), content);
            }
            Entry::RunDir => {
                std::fs::create_dir(&p).expect("scratch folder made");
                put(&p.join(MARKER), content);
            }
            Entry::LinkToFile => link(&dir.join("content"), &p),
            Entry::LinkLoop => link(&p, &p),
            Entry::Dangling => link(&dir.join("nothing"), &p),
            Entry::Fifo => {
                let c = std::ffi::CString::new(p.as_os_str().as_encoded_bytes())
                    .expect("scratch path without NUL");
                // SAFETY: a NUL-terminated path.
                let rc = unsafe { libc::mkfifo(c.as_ptr(), 0o600) };
                assert_eq!(rc, 0, "mkfifo {}", p.display());
            }
        }
    }
}

fn link(target: &Path, at: &Path) {
    std::os::unix::fs::symlink(target, at).expect("scratch link made");
}

/// A project file through the checks `cloudcontrol run --check` makes (src/bin/cloudcontrol/
/// run.rs: `Project::load`, its parse, paths and validation, then `check_output`, whether
/// a run may write its output folder, then `validate::check_inputs`, every epoch's
/// inputs and the checkpoint files read), in a folder where each path the project may name
/// is present or not, a file, a folder, a link, a FIFO or a run's output folder:
/// project.toml, the layout and the files' content by [`members`] ([`lay_out_project`]).
/// tests/fuzz_replay.rs checks that the CLI accepts exactly the seeds this target does.
fn project_check_reads(data: &[u8]) -> bool {
    let dir = scratch("project_check");
    let parts = members(data, 3);
    lay_out_project(
        &dir,
        parts[1].unwrap_or_default(),
        parts[2].unwrap_or_default(),
    );
    let Some(toml) = parts[0] else {
        return false;
    };
    let path = dir.join("project.toml");
    put(&path, toml);
    match Project::load(&path) {
        Ok(project) => {
            check_output(&project).is_ok()
                && cloudcontrol::pipeline::validate::check_inputs(&project).is_ok()
        }
        Err(_) => false,
    }
}

/// An image header (PNG, TIFF, JPEG): the size query DCP chips and photos go through.
fn image_header_reads(data: &[u8]) -> bool {
    image_open::image_size_bytes(Path::new("image"), data).is_ok()
}

/// The photo memory budget of every target: 256 MiB, not the library's default 1 GiB.
/// libFuzzer's limit (2 GB RSS) has to hold what it holds before any decode (0.9 GB once
/// the image corpus is loaded: the corpus, ASan's quarantine and shadow) beside one decode,
/// so a decode that kept to a 1 GiB budget reached 2.4 GB (CI, 2026-11-29); at 256 MiB a reader that exceeds the budget by
/// fourfold is still caught, which is what the targets are there to find.
const FUZZ_PHOTO_MEMORY: u64 = 256 << 20;

fn harness() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        image_open::set_photo_memory(Some(FUZZ_PHOTO_MEMORY))
            .expect("the fuzz photo memory budget is above the smallest");
    });
}

/// Declares each target `pub fn <target>(data: &[u8])` (what libFuzzer runs) over its
/// `<target>_reads` body, and [`reads`], which tells whether a target's reader accepted an
/// input (the replay checks that the seeds reach past the first error).
macro_rules! targets {
    ($($t:ident => $body:ident),* $(,)?) => {
        $(
            pub fn $t(data: &[u8]) {
                harness();
                let _ = $body(data);
            }
        )*

        /// The fuzz targets, by name.
        pub const TARGETS: &[&str] = &[$(stringify!($t)),*];

        /// Whether `target`'s reader accepts `data`; `None` for an unknown target.
        pub fn reads(target: &str, data: &[u8]) -> Option<bool> {
            match target {
                $(stringify!($t) => {
                    harness();
                    Some($body(data))
                })*
                _ => None,
            }
        }
    };
}

targets!(
    colmap_bin => colmap_bin_reads,
    colmap_txt => colmap_txt_reads,
    blocks_exchange => blocks_exchange_reads,
    dcp_manifest => dcp_manifest_reads,
    dcp_package => dcp_package_reads,
    las => las_reads,
    ply_points => ply_points_reads,
    csv_points => csv_points_reads,
    odm_gcp => odm_gcp_reads,
    project_toml => project_toml_reads,
    camera_json => camera_json_reads,
    image_header => image_header_reads,
    fiducial_io => fiducial_io_reads,
    image_decode => image_decode_reads,
    task_files => task_files_reads,
    project_check => project_check_reads,
);
