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
use cloudcontrol::lidar::{points_io, LasStream, PointBatch};
use cloudcontrol::pipeline::project::Project;
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
            let in_laz = info
                .location()
                .map(|l| l.file())
                .filter(|f| f.contains("/laz-0.12."));
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

/// A camera JSON file: a frame camera or a film camera's certificate.
fn camera_json_reads(data: &[u8]) -> bool {
    let dir = scratch("camera_json");
    let path = dir.join("camera.json");
    put(&path, data);
    EpochCamera::load(&path).is_ok()
}

/// An image header (PNG, TIFF, JPEG): the size query DCP chips and photos go through.
fn image_header_reads(data: &[u8]) -> bool {
    image_open::image_size_bytes(Path::new("image"), data).is_ok()
}

/// Declares each target `pub fn <target>(data: &[u8])` (what libFuzzer runs) over its
/// `<target>_reads` body, and [`reads`], which tells whether a target's reader accepted an
/// input (the replay checks that the seeds reach past the first error).
macro_rules! targets {
    ($($t:ident => $body:ident),* $(,)?) => {
        $(
            pub fn $t(data: &[u8]) {
                let _ = $body(data);
            }
        )*

        /// The fuzz targets, by name.
        pub const TARGETS: &[&str] = &[$(stringify!($t)),*];

        /// Whether `target`'s reader accepts `data`; `None` for an unknown target.
        pub fn reads(target: &str, data: &[u8]) -> Option<bool> {
            match target {
                $(stringify!($t) => Some($body(data)),)*
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
);
