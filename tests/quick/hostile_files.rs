//! Inputs that are not what a file name promises (issue 51, items 5 and 6): FIFOs,
//! devices, symbolic link cycles, and text files far beyond any real input of their kind.
//! Each case runs the CLI in a child process under an address-space limit of 2 GiB
//! ([`common::cli_confined`]): a clean error naming the file (and the project key that
//! named it), within 1 GiB of resident memory and 5 s. The one mechanism under test is
//! `cloudcontrol::formats::input` (formats/README.md, "Input files").

use crate::common;
use common::{cli_confined, exe, run_confined, Confined};
use std::path::{Path, PathBuf};

/// Makes a FIFO at `path`.
fn fifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a NUL-terminated path that lives for the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

fn link(target: impl AsRef<Path>, at: &Path) {
    std::os::unix::fs::symlink(target, at).unwrap();
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A project whose every input is a small regular file: LiDAR (not read before work), a
/// camera, a POS, checkpoints, a photos folder with one photo; those `run --check` reads
/// (the epoch's and the checkpoint files, the photo's header) are valid, so that it gets
/// to the end. `change` replaces inputs before the project is written.
struct Project {
    dir: PathBuf,
    file: PathBuf,
}

impl Project {
    fn new(dir: &Path) -> Self {
        for (f, text) in [
            ("lidar.las", "x\n"),
            (
                "camera.json",
                r#"{"kind": "frame", "width": 64, "height": 64, "fx": 64, "fy": 64, "cx": 32, "cy": 32}"#,
            ),
            (
                "pos.csv",
                "name,x,y,z,omega,phi,kappa\np1,500000,4400000,400,0,0,0\n",
            ),
            ("cp.csv", "id,x,y,z\nCP1,500000,4400000,100\n"),
            (
                "cp_images.csv",
                "epoch,photo,id,col,row\nref,p1,CP1,10,10\n",
            ),
        ] {
            std::fs::write(dir.join(f), text).unwrap();
        }
        std::fs::create_dir_all(dir.join("photos")).unwrap();
        image::GrayImage::new(64, 64)
            .save(dir.join("photos/p1.png"))
            .unwrap();
        let file = dir.join("project.toml");
        std::fs::write(
            &file,
            r#"name = "hostile"
crs = "EPSG:32650"
output = "out"

[control]
lidar = ["lidar.las"]
checkpoints = "cp.csv"
checkpoint_images = "cp_images.csv"

[reference]
name = "ref"
date = "2024"
photos = "photos"
camera = "camera.json"
pos = "pos.csv"
"#,
        )
        .unwrap();
        Self {
            dir: dir.to_path_buf(),
            file,
        }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Replaces the input `name` (removed first) by what `make` makes there.
    fn replace(&self, name: &str, make: impl FnOnce(&Path)) -> PathBuf {
        let p = self.path(name);
        let _ = std::fs::remove_file(&p);
        make(&p);
        p
    }

    fn check(&self) -> Confined {
        cli_confined(&["run", "--check", s(&self.file)])
    }

    fn run(&self) -> Confined {
        cli_confined(&["-q", "run", s(&self.file)])
    }
}

#[test]
fn the_unchanged_project_passes_check() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let r = p.check();
    assert_eq!(r.code, Some(0), "{}{}", r.stdout, r.stderr);
}

// ---------------------------------------------------------------------------------------
// Item 5: FIFOs, devices, link cycles
// ---------------------------------------------------------------------------------------

#[test]
fn a_photo_that_is_a_fifo_is_refused_naming_it_and_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let photo = p.replace("photos/p2.png", fifo);
    for r in [p.check(), p.run()] {
        r.refused_cleanly(5.0, &["reference.photos", s(&photo), "is a FIFO"]);
    }
    // The photo reader itself, through a command that takes the photo directly.
    let chip = p.path("photos/p1.png");
    cli_confined(&["match", s(&photo), s(&chip)])
        .refused_cleanly(5.0, &[s(&photo), "is a FIFO, not a regular file"]);
}

#[test]
fn a_photo_that_links_to_dev_zero_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let photo = p.replace("photos/p2.png", |at| link("/dev/zero", at));
    for r in [p.check(), p.run()] {
        r.refused_cleanly(
            5.0,
            &[
                "reference.photos",
                s(&photo),
                "links to /dev/zero, a device",
            ],
        );
    }
    let chip = p.path("photos/p1.png");
    cli_confined(&["match", s(&photo), s(&chip)])
        .refused_cleanly(5.0, &[s(&photo), "/dev/zero", "not a regular file"]);
}

#[test]
fn a_checkpoint_file_that_is_a_fifo_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let cp = p.replace("cp.csv", fifo);
    for r in [p.check(), p.run()] {
        r.refused_cleanly(5.0, &["control.checkpoints", s(&cp), "is a FIFO"]);
    }
    // The CSV reader itself (`adjust --control` reads it as control points).
    let model = empty_colmap_model(tmp.path());
    let out = tmp.path().join("adjusted");
    cli_confined(&[
        "adjust",
        "--model",
        s(&model),
        "--out",
        s(&out),
        "--control",
        s(&cp),
    ])
    .refused_cleanly(5.0, &[s(&cp), "is a FIFO, not a regular file"]);
}

#[test]
fn a_project_file_that_is_a_fifo_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let f = p.replace("project.toml", fifo);
    p.check().refused_cleanly(5.0, &[s(&f), "is a FIFO"]);
}

#[test]
fn a_las_file_that_is_a_fifo_or_a_device_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let las = tmp.path().join("tile.las");
    fifo(&las);
    cli_confined(&["lidar", "info", s(&las)])
        .refused_cleanly(5.0, &[s(&las), "is a FIFO, not a regular file"]);
    let zero = tmp.path().join("zero.las");
    link("/dev/zero", &zero);
    cli_confined(&["lidar", "info", s(&zero)])
        .refused_cleanly(5.0, &[s(&zero), "/dev/zero, a device"]);
    // In a project's LiDAR folder.
    let p = Project::new(tmp.path());
    std::fs::create_dir_all(p.path("tiles")).unwrap();
    let tile = p.replace("tiles/a.las", fifo);
    let text = std::fs::read_to_string(&p.file)
        .unwrap()
        .replace(r#"lidar = ["lidar.las"]"#, r#"lidar = ["tiles"]"#);
    std::fs::write(&p.file, text).unwrap();
    p.check()
        .refused_cleanly(5.0, &["control.lidar[0]", s(&tile), "is a FIFO"]);
}

#[test]
fn a_photos_folder_with_two_self_links_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    link(".", &p.path("photos/a"));
    link(".", &p.path("photos/b"));
    for r in [p.check(), p.run()] {
        r.refused_cleanly(
            5.0,
            &[
                "reference.photos",
                s(&p.path("photos/a")),
                "symbolic link cycle",
            ],
        );
    }
}

#[test]
fn a_link_cycle_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    // Two links naming each other.
    link("b.png", &p.path("photos/a.png"));
    link("a.png", &p.path("photos/b.png"));
    p.check().refused_cleanly(
        5.0,
        &[
            "reference.photos",
            s(&p.path("photos/a.png")),
            "symbolic link cycle",
        ],
    );
    // Folders through each other: photos/x → other, other/y → photos.
    std::fs::remove_file(p.path("photos/a.png")).unwrap();
    std::fs::remove_file(p.path("photos/b.png")).unwrap();
    std::fs::create_dir_all(p.path("other")).unwrap();
    link("../other", &p.path("photos/x"));
    link("../photos", &p.path("other/y"));
    p.check().refused_cleanly(
        5.0,
        &["reference.photos", "photos/x/y", "symbolic link cycle"],
    );
    // A camera file that is a link cycle.
    let cam = p.replace("camera.json", |at| link("camera.json", at));
    std::fs::remove_file(p.path("photos/x")).unwrap();
    p.check()
        .refused_cleanly(5.0, &["reference.camera", s(&cam), "symbolic link cycle"]);
}

/// The stage fingerprint, which hashes every input file, never waits on a FIFO and never
/// walks round a link cycle: the library's `Runner` refuses both (in this process, under
/// a watchdog, as no command reaches it past the project check).
#[test]
fn the_stage_fingerprint_refuses_fifos_and_cycles() {
    use cloudcontrol::pipeline::stages::{Inputs, Runner};
    let tmp = tempfile::tempdir().unwrap();
    let photos = tmp.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    std::fs::write(photos.join("p1.png"), "x").unwrap();
    let out = tmp.path().join("out");
    let run = |inputs: Inputs| {
        let out = out.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut r = Runner::new(&out).unwrap();
            let e = r.stage("x", &inputs, |_| Ok(())).map(|_| ());
            drop(r); // the run's lock, before the next run takes it
            let _ = tx.send(e.map_err(|e| e.to_string()));
        });
        rx.recv_timeout(std::time::Duration::from_secs(5))
            .expect("the fingerprint returned within 5 s")
    };
    assert!(run(Inputs::new().file(&photos)).is_ok());
    fifo(&photos.join("p2.png"));
    let e = run(Inputs::new().file(&photos)).unwrap_err();
    assert!(e.contains("p2.png") && e.contains("is a FIFO"), "{e}");
    std::fs::remove_file(photos.join("p2.png")).unwrap();
    link(".", &photos.join("a"));
    link(".", &photos.join("b"));
    let e = run(Inputs::new().file(&photos)).unwrap_err();
    assert!(e.contains("photos/a") && e.contains("cycle"), "{e}");
}

// ---------------------------------------------------------------------------------------
// Item 6: text inputs without a size cap
// ---------------------------------------------------------------------------------------

/// An empty COLMAP model (no camera, photo or point), for `adjust --control`.
fn empty_colmap_model(dir: &Path) -> PathBuf {
    let m = dir.join("model");
    std::fs::create_dir_all(&m).unwrap();
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        std::fs::write(m.join(f), 0u64.to_le_bytes()).unwrap();
    }
    m
}

/// A CSV of `len` bytes: a control point header, then one line without an end (a sparse
/// file: nothing of it is written to disk).
fn sparse_csv(path: &Path, len: u64) {
    use std::io::Write;
    let mut f = std::fs::File::create(path).unwrap();
    f.write_all(b"id,x,y,z\n").unwrap();
    f.set_len(len).unwrap();
}

/// `cloudcontrol adjust --control csv` with `limits` in `CLOUDCONTROL_INPUT_LIMITS`.
fn adjust_control(dir: &Path, csv: &Path, limits: Option<&str>) -> Confined {
    let model = empty_colmap_model(dir);
    let mut cmd = std::process::Command::new(exe());
    let out = dir.join("adjusted");
    cmd.args([
        "adjust",
        "--model",
        s(&model),
        "--out",
        s(&out),
        "--control",
        s(csv),
    ]);
    if let Some(l) = limits {
        cmd.env("CLOUDCONTROL_INPUT_LIMITS", l);
    }
    run_confined(&cmd, 2 << 30, 30.0)
}

#[test]
fn a_two_gigabyte_csv_line_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("control.csv");
    sparse_csv(&csv, 2 << 30);
    // By its size, before a byte is read: 2 GiB > 256 MiB, the CSV cap.
    adjust_control(tmp.path(), &csv, None).refused_cleanly(
        5.0,
        &[
            s(&csv),
            "size in bytes: 2147483648 exceeds 268435456",
            "csv",
        ],
    );
    // With the file cap raised (configuration, formats/README.md), by the line cap after
    // 1 MiB of the line has been read.
    adjust_control(tmp.path(), &csv, Some("csv=4G"))
        .refused_cleanly(5.0, &[s(&csv), "line 2", "exceeds 1048576", "csv_line"]);
    // And by a lower line cap set the same way.
    adjust_control(tmp.path(), &csv, Some("csv=4G,csv_line=64K"))
        .refused_cleanly(5.0, &[s(&csv), "line 2", "exceeds 65536"]);
    // A project naming it: at the check, by the key.
    let p = Project::new(tmp.path());
    let cp = p.replace("cp.csv", |at| sparse_csv(at, 2 << 30));
    p.check()
        .refused_cleanly(5.0, &["control.checkpoints", s(&cp), "exceeds 268435456"]);
}

#[test]
fn a_ten_million_column_header_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("control.csv");
    let mut header = "c,".repeat(10_000_000);
    header.push_str("\n1,2\n");
    std::fs::write(&csv, header).unwrap();
    // Its 20 MB header line is beyond the line cap.
    adjust_control(tmp.path(), &csv, None)
        .refused_cleanly(5.0, &[s(&csv), "line 1", "exceeds 1048576"]);
    // With the line cap raised, by the column cap.
    adjust_control(tmp.path(), &csv, Some("csv_line=64M")).refused_cleanly(
        5.0,
        &[s(&csv), "columns of the header: 10000001 exceeds 1024"],
    );
    // A header within the line cap but over the column cap.
    std::fs::write(&csv, format!("{}z\n", "c,".repeat(2000))).unwrap();
    adjust_control(tmp.path(), &csv, None).refused_cleanly(
        5.0,
        &[
            s(&csv),
            "columns of the header: 2001 exceeds 1024",
            "csv_columns",
        ],
    );
}

#[test]
fn a_79_megabyte_project_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let mut text = std::fs::read_to_string(&p.file).unwrap();
    text.push_str("# ");
    text.push_str(&"x".repeat(79_000_000));
    text.push('\n');
    std::fs::write(&p.file, text).unwrap();
    p.check().refused_cleanly(
        5.0,
        &[
            s(&p.file),
            "exceeds 1048576",
            "project",
            "CLOUDCONTROL_INPUT_LIMITS",
        ],
    );
}

#[test]
fn a_camera_file_beyond_its_cap_is_refused_by_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let p = Project::new(tmp.path());
    let cam = p.replace("camera.json", |at| {
        std::fs::File::create(at).unwrap().set_len(5 << 20).unwrap()
    });
    p.check()
        .refused_cleanly(5.0, &["reference.camera", s(&cam), "exceeds 4194304"]);
}
