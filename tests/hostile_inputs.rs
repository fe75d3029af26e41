//! Small crafted files whose counts or sizes claim far more than they hold: each is refused
//! with a typed error naming the file and the limit, before anything is allocated from
//! the claim, through the library and through the CLI. Every file is written here, byte
//! by byte, from the format documents (formats/colmap, formats/lidar, ...).

mod common;
use common::cli;
use std::path::Path;

/// Asserts that `message` names `file` and holds each of `words`.
fn says(message: &str, file: &Path, words: &[&str]) {
    assert!(
        message.contains(&file.display().to_string()),
        "names the file {}: {message}",
        file.display()
    );
    for w in words {
        assert!(message.contains(w), "says {w:?}: {message}");
    }
}

/// Runs the CLI, which must fail, and returns its stderr.
fn cli_fails(args: &[&str]) -> String {
    let (ok, out, err) = cli(args);
    assert!(!ok, "succeeded: {out}");
    err
}

// ---------------------------------------------------------------------------------------
// COLMAP frames
// ---------------------------------------------------------------------------------------

/// An empty COLMAP 4 model (no camera, image, point or rig) whose `frames.bin` holds one
/// frame claiming 2³² − 1 data ids (formats/colmap/README.md, `frames.bin`).
fn colmap_frames_bin(dir: &Path) -> std::path::PathBuf {
    for f in ["cameras.bin", "images.bin", "points3D.bin", "rigs.bin"] {
        std::fs::write(dir.join(f), 0u64.to_le_bytes()).unwrap();
    }
    let mut b = Vec::new();
    b.extend(1u64.to_le_bytes()); // frames
    b.extend(1u32.to_le_bytes()); // frame id
    b.extend(1u32.to_le_bytes()); // rig id
    for v in [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] {
        b.extend(v.to_le_bytes());
    }
    b.extend(u32::MAX.to_le_bytes()); // data ids
    b.extend(0i32.to_le_bytes());
    b.extend(1u32.to_le_bytes());
    b.extend(1u64.to_le_bytes());
    let f = dir.join("frames.bin");
    std::fs::write(&f, b).unwrap();
    f
}

fn colmap_frames_txt(dir: &Path) -> std::path::PathBuf {
    for f in ["cameras.txt", "images.txt", "points3D.txt", "rigs.txt"] {
        std::fs::write(dir.join(f), "# empty\n").unwrap();
    }
    let f = dir.join("frames.txt");
    std::fs::write(&f, "# frames\n1 1 1 0 0 0 0 0 0 4294967295 CAMERA 1 1\n").unwrap();
    f
}

#[test]
fn colmap_frame_data_id_count_beyond_the_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let bin = tmp.path().join("bin");
    let txt = tmp.path().join("txt");
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::create_dir_all(&txt).unwrap();
    let fb = colmap_frames_bin(&bin);
    let ft = colmap_frames_txt(&txt);
    let len = std::fs::metadata(&fb).unwrap().len();

    let e = cloudcontrol::formats::colmap::read(&bin)
        .unwrap_err()
        .to_string();
    says(
        &e,
        &fb,
        &[
            "data id count",
            "4294967295",
            &format!("file of {len} bytes"),
        ],
    );
    let e = cloudcontrol::formats::colmap::read(&txt)
        .unwrap_err()
        .to_string();
    says(
        &e,
        &ft,
        &["line 2", "NUM_DATA_IDS 4294967295", "holds 3 more"],
    );

    for (dir, f) in [(&bin, &fb), (&txt, &ft)] {
        let out = tmp.path().join("out.xml");
        let err = cli_fails(&["convert", dir.to_str().unwrap(), out.to_str().unwrap()]);
        says(&err, f, &["4294967295"]);
    }
}
