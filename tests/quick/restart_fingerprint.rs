//! Restart fingerprints (issue 52, item 6): a stage's fingerprint names its input files
//! relative to the inputs they were given under, so a project folder copied or moved
//! elsewhere (its output with it) skips every finished stage; a restart takes unchanged
//! files' digests from the output folder's digest cache instead of reading them again;
//! a photo changed in place (same size, its modification time touched or even put back)
//! is read again and its stage redone.
//!
//! The runs are the tiny block's digital epoch controlled by its orthophoto (five stages,
//! under a second), each `cloudcontrol --json run` in a child process (PROJ, which a run
//! loads, is not safe to fork beside: its fork handler can wait on a lock another test's
//! thread holds); the runner's log line `input digests` tells what each run read.

use crate::common;
use cloudcontrol::pipeline::stages::DIGESTS;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

const STAGES: [&str; 8] = [
    "sources",
    "dcp-orthophoto",
    "epoch-digital_2012",
    "surface-digital_2012",
    "change-digital_2012",
    "control",
    "outputs-digital_2012",
    "report",
];
const PHOTO: &str = "epochs/digital_2012/images/digital_s01_001.png";

fn set_mtime(path: &Path, t: SystemTime) {
    std::fs::File::options()
        .write(true)
        .open(path)
        .unwrap()
        .set_modified(t)
        .unwrap();
}

fn mtime(path: &Path) -> SystemTime {
    std::fs::metadata(path).unwrap().modified().unwrap()
}

/// The tiny block at `blk` with its project file; its files last modified an hour ago,
/// as a project's inputs are (a file modified in the last seconds is not cached).
fn tiny_project(blk: &Path) -> PathBuf {
    common::block_copy("tiny", 2, "good", blk);
    let p = blk.join("project_digital.toml");
    std::fs::write(
        &p,
        common::digital_project_toml(
            "restart",
            "epochs/digital_2012/camera.json",
            "truth/checkpoint_images.csv",
        ),
    )
    .unwrap();
    let hour_ago = SystemTime::now() - Duration::from_secs(3600);
    for f in common::files_below(blk) {
        set_mtime(&f, hour_ago);
    }
    p
}

/// The project's input files (what its stages fingerprint outside the output folder).
fn inputs(blk: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = [
        "orthophoto/orthophoto.tif",
        "orthophoto/dem.tif",
        "checkpoints.csv",
        "truth/checkpoint_images.csv",
        "epochs/digital_2012/camera.json",
        "epochs/digital_2012/pos.csv",
    ]
    .iter()
    .map(|f| blk.join(f))
    .collect();
    v.extend(common::files_below(&blk.join("epochs/digital_2012/images")));
    v
}

struct Ran {
    ran: Vec<String>,
    skipped: Vec<String>,
    /// Bytes streamed through SHA-256 by the run.
    hashed: u64,
    seconds: f64,
}

/// `value` of `key=value` in a log line.
fn field(line: &str, key: &str) -> Option<u64> {
    let at = line.find(&format!("{key}="))? + key.len() + 1;
    let digits: String = line[at..]
        .chars()
        .take_while(|c| c.is_ascii_digit())
        .collect();
    digits.parse().ok()
}

fn run(project: &Path) -> Ran {
    let t = std::time::Instant::now();
    let o = std::process::Command::new(common::exe())
        .env("CLOUDCONTROL_LOG", "cloudcontrol::pipeline::stages=info")
        .args(["--json", "run"])
        .arg(project)
        .output()
        .unwrap();
    let seconds = t.elapsed().as_secs_f64();
    let stderr = String::from_utf8_lossy(&o.stderr);
    // Done, or partial: the tiny block's two photos are not oriented by this project.
    assert!(
        matches!(o.status.code(), Some(0 | common::EXIT_PARTIAL)),
        "{:?}: {stderr}",
        o.status
    );
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let names = |k: &str| -> Vec<String> {
        summary[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_string())
            .collect()
    };
    let line = stderr
        .lines()
        .find(|l| l.contains("input digests"))
        .unwrap_or_else(|| panic!("no input digests line: {stderr}"));
    Ran {
        ran: names("ran"),
        skipped: names("skipped"),
        hashed: field(line, "bytes_read").unwrap_or_else(|| panic!("{line}")),
        seconds,
    }
}

/// The files of a run that name input files (an epoch's block and images, the LiDAR
/// cleaning report, the film frames' report) are free of `project`'s absolute path.
/// Descriptions for people (report, `epoch.json`'s control, a DCP's source) name the
/// inputs as the project gave them, and the LiDAR catalogue keeps its own rule (tiles
/// outside its folder absolute, formats/lidar).
fn assert_names_no_absolute_input(run: &Path, project: &Path) {
    const NAMING: [&str; 4] = ["images.json", "block.json", "clean.json", "frames.json"];
    let names = [
        project.to_string_lossy().into_owned(),
        project
            .canonicalize()
            .unwrap()
            .to_string_lossy()
            .into_owned(),
    ];
    let (mut read, mut naming) = (0, Vec::new());
    for f in common::files_below(run) {
        if !f
            .file_name()
            .is_some_and(|n| NAMING.iter().any(|m| n == *m))
        {
            continue;
        }
        let text = String::from_utf8_lossy(&std::fs::read(&f).unwrap()).into_owned();
        if names.iter().any(|n| text.contains(n.as_str())) {
            naming.push(f.display().to_string());
        }
        read += 1;
    }
    assert!(read >= 2, "{read} files below {}", run.display());
    assert!(naming.is_empty(), "{naming:#?} name {}", names[0]);
}

#[test]
fn a_project_folder_copied_or_moved_elsewhere_skips_every_finished_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("a/block");
    let project = tiny_project(&blk);
    let first = run(&project);
    assert_eq!(first.ran, STAGES, "skipped {:?}", first.skipped);
    // No file that names inputs to read them again names the project's folder: they are
    // named relative to the file, so that they are found wherever the project goes.
    assert_names_no_absolute_input(&blk.join("run"), &blk);
    // The project folder, inputs and output together, copied to another path (new
    // inodes, new times: the digest cache has none of its files) …
    let copy = tmp.path().join("elsewhere/deeper/block");
    common::copy_block(&blk, &copy);
    let copied = run(&copy.join("project_digital.toml"));
    assert!(copied.ran.is_empty(), "ran {:?}", copied.ran);
    assert_eq!(copied.skipped, STAGES);
    // … and that copy moved once more (same inodes, another canonical path).
    let moved = tmp.path().join("moved");
    std::fs::rename(&copy, &moved).unwrap();
    let again = run(&moved.join("project_digital.toml"));
    assert!(again.ran.is_empty(), "ran {:?}", again.ran);
    assert_eq!(again.skipped, STAGES);
    // Its skipped epoch stage names the photos where they are now, read as the DCP
    // export and the outputs read it, and the copy that was moved away is gone.
    let epoch = moved.join("run/epoch-digital_2012");
    let images: std::collections::BTreeMap<u32, PathBuf> =
        serde_json::from_slice(&std::fs::read(epoch.join("images.json")).unwrap()).unwrap();
    assert_eq!(images.len(), 2);
    let here = moved.canonicalize().unwrap();
    for path in images.values() {
        assert!(path.is_relative(), "{}", path.display());
        let found = epoch.join(path).canonicalize().unwrap();
        assert!(found.starts_with(&here), "{}", found.display());
    }
    assert!(!copy.exists());
    let block = cloudcontrol::pipeline::epoch_files::load_block(&epoch).unwrap();
    for p in block.photos.values() {
        let image = p.image.as_ref().unwrap();
        assert!(image.is_file(), "{}", image.display());
        assert!(image.canonicalize().unwrap().starts_with(&here));
    }
    // The original is untouched by all this.
    let original = run(&project);
    assert!(original.ran.is_empty(), "ran {:?}", original.ran);
}

#[test]
fn a_restart_reads_no_unchanged_input_again() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    let project = tiny_project(&blk);
    let input_bytes: u64 = inputs(&blk)
        .iter()
        .map(|f| std::fs::metadata(f).unwrap().len())
        .sum();
    let first = run(&project);
    assert_eq!(first.ran, STAGES);
    assert!(
        first.hashed >= input_bytes,
        "{} bytes hashed, the inputs hold {input_bytes}",
        first.hashed
    );
    // The cache is the run's: in its ledger, and its temporaries are the run's too.
    let out = blk.join("run");
    assert!(out.join(DIGESTS).is_file());
    let ledger: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
    assert_eq!(ledger["files"], serde_json::json!([DIGESTS]));
    let cache: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join(DIGESTS)).unwrap()).unwrap();
    for f in inputs(&blk) {
        let key = std::fs::canonicalize(&f).unwrap();
        let entry = &cache["files"][key.to_str().unwrap()];
        assert_eq!(entry["stat"]["size"], std::fs::metadata(&f).unwrap().len());
        assert_eq!(
            entry["sha256"].as_str().unwrap().len(),
            64,
            "{}",
            f.display()
        );
    }
    // The outputs the first run wrote were hashed as they were written, too fresh to be
    // cached: past the racy window the restart reads them once, and none of the inputs.
    std::thread::sleep(Duration::from_millis(2100));
    let second = run(&project);
    assert_eq!(second.skipped, STAGES);
    assert!(
        second.hashed + input_bytes <= first.hashed,
        "restart hashed {} bytes, the first run {} with {input_bytes} of inputs",
        second.hashed,
        first.hashed
    );
    let third = run(&project);
    assert_eq!(third.skipped, STAGES);
    assert_eq!(
        third.hashed, 0,
        "a restart with every digest cached reads nothing"
    );
    eprintln!(
        "first run {:.3} s, {} bytes hashed; restart {:.3} s, {} bytes; restart with \
         every digest cached {:.3} s, {} bytes",
        first.seconds, first.hashed, second.seconds, second.hashed, third.seconds, third.hashed
    );
    // A file of the cache's name that the ledger does not list is a user's: neither
    // read nor replaced, and the run goes on reading its inputs.
    let mut ledger: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
    ledger.as_object_mut().unwrap().remove("files");
    std::fs::write(out.join("stages.json"), ledger.to_string()).unwrap();
    std::fs::write(out.join(DIGESTS), "mine").unwrap();
    let fourth = run(&project);
    assert_eq!(fourth.skipped, STAGES);
    assert!(fourth.hashed >= input_bytes);
    assert_eq!(std::fs::read(out.join(DIGESTS)).unwrap(), b"mine");
}

/// The PNG of `img` with the pixel byte `flip` (if any) changed.
fn png(img: &image::DynamicImage, flip: Option<usize>) -> Vec<u8> {
    use image::ImageEncoder;
    let mut px = img.as_bytes().to_vec();
    if let Some(i) = flip {
        px[i] ^= 1;
    }
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&px, img.width(), img.height(), img.color().into())
        .unwrap();
    out
}

/// Rewrites the PNG `path` (written by [`png`]) with one byte of its pixels changed so
/// that the file keeps its size: a change that size alone does not show.
fn same_size_edit(path: &Path, nth: usize) {
    let old = std::fs::read(path).unwrap();
    let img = image::load_from_memory(&old).unwrap();
    let mut found = 0;
    for i in 0..img.as_bytes().len() {
        let new = png(&img, Some(i));
        if new.len() == old.len() && new != old {
            if found == nth {
                std::fs::write(path, new).unwrap();
                return;
            }
            found += 1;
        }
    }
    panic!("no same-size edit of {}", path.display());
}

#[test]
fn a_photo_changed_in_place_reruns_its_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    let project = tiny_project(&blk);
    // The photo as this test's encoder writes it, so that an edit can keep its size.
    let photo = blk.join(PHOTO);
    let img = image::open(&photo).unwrap();
    std::fs::write(&photo, png(&img, None)).unwrap();
    set_mtime(&photo, SystemTime::now() - Duration::from_secs(3600));
    assert_eq!(run(&project).ran, STAGES);
    let size = std::fs::metadata(&photo).unwrap().len();
    // Same size, another modification time.
    same_size_edit(&photo, 0);
    assert_eq!(std::fs::metadata(&photo).unwrap().len(), size);
    let touched = SystemTime::now() - Duration::from_secs(1800);
    set_mtime(&photo, touched);
    // What the photo feeds reruns; the change stage's inputs (the surface stage's folder:
    // the digital epoch has no stereo pair here, so the same skipped.json) are unchanged,
    // and the control's surfaces (the LiDAR's) owe nothing to a photo.
    let unchanged = ["change-digital_2012", "control"];
    let downstream: Vec<&str> = STAGES[2..]
        .iter()
        .copied()
        .filter(|s| !unchanged.contains(s))
        .collect();
    let r = run(&project);
    assert_eq!(r.ran, downstream, "skipped {:?}", r.skipped);
    assert_eq!(r.skipped, [&STAGES[..2], &unchanged].concat());
    // Changed again, same size, its modification time put back as it was (`touch -r`,
    // a copy that keeps times): the change time tells.
    same_size_edit(&photo, 1);
    set_mtime(&photo, touched);
    assert_eq!(mtime(&photo), touched);
    assert_eq!(std::fs::metadata(&photo).unwrap().len(), size);
    let r = run(&project);
    assert_eq!(r.ran, downstream, "skipped {:?}", r.skipped);
    // Unchanged since: skipped.
    assert!(run(&project).ran.is_empty());
}
