//! Panics, silent acceptance and failures that exit 0 (issue 51 item 8, issue 52 item 3):
//! every crafted case runs in a child process under RLIMIT_AS 2 GiB (the CLI, or this
//! test binary calling the C ABI) and ends with a clean error or the documented status,
//! its message naming the input, within seconds and 1 GiB, leaving no `.part` file.
//!
//! - a task file (MessagePack, formats/workflow/README.md "Tasks") with NaN or absurd strip
//!   offsets, or noise indices beyond its tile: FORMAT naming the file, nothing written;
//! - a LAS header with a NaN or 0 scale or a NaN offset (formats/lidar/README.md): refused
//!   naming the file and the field, by `lidar info` and by a run given the tile;
//! - a camera JSON with fx 1e-300 or a side of 2³² − 1 px (formats/cameras/README.md):
//!   refused naming the file and the field before anything is written;
//! - a camera of 1500 × 1000 for 400 × 266 photos: refused by `run --check`, `run` and
//!   the C ABI before any stage (exit status 2, INVALID_ARGUMENT; issue 52 item 2), and
//!   `orient` ends partial (exit status 3); photos the run cannot decode end it partial,
//!   saying which epoch, how many and why, and list no empty model;
//! - a photo without a POS row, a checkpoint measurement of an unknown id: refused before
//!   any stage (exit status 2), naming the file (and the line).
//!
//! Every file is written here from the format documents; the project is the tiny
//! synthetic block's (its orthophoto and DEM as the control: a run takes a second).

use crate::common::{self, cli_confined, run_confined, Confined};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;

// ---------------------------------------------------------------------------------------
// The C ABI in a child process
// ---------------------------------------------------------------------------------------

/// What the child test does: `task <json>` (ccp_task_run) or `project <path>`
/// (ccp_project_run).
const CASE: &str = "CLOUDCONTROL_HOSTILE_STATUS_CASE";

/// Runs one C ABI call in a child: this test binary running [`child_call`] with the call in
/// [`CASE`], under the acceptance's limits. The child exits with the call's status and
/// prints the last error.
fn abi_confined(case: &str) -> Confined {
    let exe = std::env::current_exe().unwrap();
    run_confined(
        Command::new(exe)
            .args(["--exact", "hostile_status::child_call", "--nocapture"])
            .args(["--test-threads", "1"])
            .env(CASE, case),
        2 << 30,
        30.0,
    )
}

/// The child side of [`abi_confined`]; does nothing in a normal test run.
#[test]
fn child_call() {
    use cloudcontrol::ffi::{ccp_project_run, ccp_string_free, ccp_task_run};
    let Ok(case) = std::env::var(CASE) else {
        return;
    };
    let (kind, arg) = case.split_once(' ').unwrap();
    let arg = std::ffi::CString::new(arg).unwrap();
    let mut out: *mut std::ffi::c_char = std::ptr::null_mut();
    // SAFETY: a NUL-terminated string and a valid out pointer.
    let status = unsafe {
        match kind {
            "task" => ccp_task_run(arg.as_ptr(), &mut out),
            "project" => ccp_project_run(arg.as_ptr(), &mut out),
            k => panic!("unknown case {k}"),
        }
    };
    let message = common::last_error();
    let json = if out.is_null() {
        String::new()
    } else {
        // SAFETY: a string the library handed out, freed once.
        unsafe {
            let s = std::ffi::CStr::from_ptr(out).to_string_lossy().into_owned();
            ccp_string_free(out);
            s
        }
    };
    eprintln!("STATUS {} MESSAGE {message}", status as i32);
    println!("JSON {json}");
    std::process::exit(status as i32);
}

/// CcpStatus values (include/cloudcontrol.h).
const INVALID_ARGUMENT: i32 = 2;
const FORMAT: i32 = 5;
const PARTIAL: i32 = 12;

// ---------------------------------------------------------------------------------------
// Files written by hand
// ---------------------------------------------------------------------------------------

/// A LAS 1.2 file (ASPRS LAS 1.4 R15 §2.4, 227-byte header, no VLR), point format 0
/// (20-byte records: X, Y, Z as scaled integers, intensity, flags, class 2, scan angle,
/// user data, point source id), with the given scale and offset.
fn las12(points: &[[i32; 3]], source: u16, scale: [f64; 3], offset: [f64; 3]) -> Vec<u8> {
    let mut h = vec![0u8; 227];
    h[0..4].copy_from_slice(b"LASF");
    h[24] = 1;
    h[25] = 2;
    h[94..96].copy_from_slice(&227u16.to_le_bytes()); // header size
    h[96..100].copy_from_slice(&227u32.to_le_bytes()); // offset to point data
    h[104] = 0; // point format
    h[105..107].copy_from_slice(&20u16.to_le_bytes()); // record length
    h[107..111].copy_from_slice(&(points.len() as u32).to_le_bytes());
    h[111..115].copy_from_slice(&(points.len() as u32).to_le_bytes()); // first returns
    for k in 0..3 {
        h[131 + 8 * k..139 + 8 * k].copy_from_slice(&scale[k].to_le_bytes());
        h[155 + 8 * k..163 + 8 * k].copy_from_slice(&offset[k].to_le_bytes());
    }
    // max x, min x, max y, min y, max z, min z
    for k in 0..3 {
        let v = |i: i32| f64::from(i) * scale[k] + offset[k];
        let max = points.iter().map(|p| p[k]).max().unwrap_or(0);
        let min = points.iter().map(|p| p[k]).min().unwrap_or(0);
        h[179 + 16 * k..187 + 16 * k].copy_from_slice(&v(max).to_le_bytes());
        h[187 + 16 * k..195 + 16 * k].copy_from_slice(&v(min).to_le_bytes());
    }
    for p in points {
        for c in p {
            h.extend(c.to_le_bytes());
        }
        h.extend(100u16.to_le_bytes()); // intensity
        h.push(0b0000_1001); // return 1 of 1
        h.push(2); // ground
        h.push(0); // scan angle
        h.push(0); // user data
        h.extend(source.to_le_bytes());
    }
    h
}

/// A 10 × 10 m patch of 100 ground points at 1 m spacing near (500000, 4400000), in
/// centimetres: scale 0.01, offset (500000, 4400000, 0).
fn patch() -> Vec<[i32; 3]> {
    (0..100)
        .map(|i| [100 * (i % 10), 100 * (i / 10), 12_000])
        .collect()
}

const SCALE: [f64; 3] = [0.01; 3];
const OFFSET: [f64; 3] = [500_000.0, 4_400_000.0, 0.0];

/// Files ending in `.part` or holding `.part-` anywhere below `dir`.
fn parts_below(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.to_string_lossy().contains(".part") {
                out.push(p);
            }
        }
    }
    out
}

// The task files of the `sources` stage, as formats/workflow/README.md ("Tasks") gives
// them: field names kept (MessagePack maps).

#[derive(Serialize)]
struct Screen {
    noise: Vec<u64>,
    outliers: Option<()>,
    sample_xyz: Vec<[f64; 3]>,
    sample_src: Vec<u16>,
}

#[derive(Serialize)]
struct ScreenResult {
    tile: String,
    screen: Screen,
}

#[derive(Serialize)]
struct StripOffset {
    source_id: u16,
    points: usize,
    offset_m: [f64; 3],
    sigma_m: [f64; 3],
}

#[derive(Serialize)]
struct StripOffsets {
    model: &'static str,
    reference: Option<u16>,
    strips: Vec<StripOffset>,
    pairs: Vec<()>,
    sigma0_m: f64,
}

/// A `sources` stage's task folder with one tile (`t.las`, 100 points of strip 1): its
/// `plan.json`, the tile's `screen-00000.msgpack` (noise `noise`) and `strip_offsets.msgpack`
/// giving strip 1 `offset`. Returns the folder and the tile's `clean` task (JSON).
fn sources_tasks(root: &Path, noise: Vec<u64>, offset: [f64; 3]) -> (PathBuf, String) {
    std::fs::create_dir_all(root).unwrap();
    let tile = root.join("t.las");
    std::fs::write(&tile, las12(&patch(), 1, SCALE, OFFSET)).unwrap();
    let folder = root.join("run/tasks/sources/0123456789abcdef");
    std::fs::create_dir_all(&folder).unwrap();
    let plan = serde_json::json!({
        "stride": 1,
        "tiles": [{
            "file": tile, "version": "1.2", "point_format": 0, "compressed": false,
            "point_count": 100, "bounds": [500000.0, 4400000.0, 120.0, 500009.0, 4400009.0, 120.0],
            "area_m2": 81.0, "density_pts_m2": 1.23, "classes": {"2": 100},
            "point_sources": {"1": 100}, "gps_time_range": null, "gps_time_type": "week",
            "acquisition_dates": null, "creation_date": null, "crs": "EPSG:4547",
            "crs_source": "assumed", "vertical_crs": null
        }]
    });
    std::fs::write(folder.join("plan.json"), plan.to_string()).unwrap();
    let screen = ScreenResult {
        tile: "t.las".into(),
        screen: Screen {
            noise,
            outliers: None,
            sample_xyz: vec![],
            sample_src: vec![],
        },
    };
    std::fs::write(
        folder.join("screen-00000.msgpack"),
        rmp_serde::to_vec_named(&screen).unwrap(),
    )
    .unwrap();
    let offsets = Some(StripOffsets {
        model: "vertical",
        reference: None,
        strips: vec![StripOffset {
            source_id: 1,
            points: 100,
            offset_m: offset,
            sigma_m: [0.01; 3],
        }],
        pairs: vec![],
        sigma0_m: 0.02,
    });
    std::fs::write(
        folder.join("strip_offsets.msgpack"),
        rmp_serde::to_vec_named(&offsets).unwrap(),
    )
    .unwrap();
    let task = serde_json::json!({
        "kind": "clean", "stage": "sources", "folder": folder, "index": 0, "item": "t.las"
    });
    (folder, task.to_string())
}

// ---------------------------------------------------------------------------------------
// Issue 51 item 8
// ---------------------------------------------------------------------------------------

#[test]
fn task_files_with_nan_or_absurd_values_are_refused_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    // A sane folder first: the clean task writes the tile (the crafted cases differ from
    // it in one value).
    let (folder, task) = sources_tasks(&tmp.path().join("sane"), vec![3, 7], [0.0, 0.0, 0.05]);
    let c = abi_confined(&format!("task {task}"));
    assert_eq!(c.code, Some(0), "{}{}", c.stdout, c.stderr);
    assert!(folder.join("lidar/t.las").is_file() && folder.join("clean-00000.msgpack").is_file());

    // name, noise indices, strip 1's offset, the file refused, what its message says
    type Case = (
        &'static str,
        Vec<u64>,
        [f64; 3],
        &'static str,
        &'static [&'static str],
    );
    let cases: [Case; 4] = [
        (
            "nan",
            vec![],
            [0.0, 0.0, f64::NAN],
            "strip_offsets.msgpack",
            &["strip 1 offset_m[2] = NaN is not finite"],
        ),
        (
            "inf",
            vec![],
            [f64::INFINITY, 0.0, 0.0],
            "strip_offsets.msgpack",
            &["strip 1 offset_m[0] = inf is not finite"],
        ),
        (
            "far",
            vec![],
            [0.0, 1e6, 0.0],
            "strip_offsets.msgpack",
            &["offset_m 1000000 is beyond 100 m"],
        ),
        (
            "noise",
            vec![5, 4_000_000_000],
            [0.0; 3],
            "screen-00000.msgpack",
            &["noise point 4000000000 of tile t.las, which has 100 points"],
        ),
    ];
    for (name, noise, offset, file, words) in cases {
        let (folder, task) = sources_tasks(&tmp.path().join(name), noise, offset);
        let c = abi_confined(&format!("task {task}"));
        let named = folder.join(file).display().to_string();
        c.refused_cleanly(5.0, &[&named, "task file"]);
        c.refused_cleanly(5.0, words);
        assert_eq!(c.code, Some(FORMAT), "{name}: {}", c.stderr);
        assert!(
            !folder.join("lidar/t.las").exists(),
            "{name}: a tile was written"
        );
        assert_eq!(parts_below(tmp.path()), Vec::<PathBuf>::new(), "{name}");
    }
}

/// The LAS writer of the cleaning step: a point its header cannot hold (NaN, or beyond
/// the 32-bit range of its scale and offset) fails the rewrite naming it, and leaves
/// neither the output nor its temporary file.
#[test]
fn a_rewritten_point_the_header_cannot_hold_fails_without_leaving_a_part_file() {
    let tmp = tempfile::tempdir().unwrap();
    let tile = tmp.path().join("t.las");
    std::fs::write(&tile, las12(&patch(), 1, SCALE, OFFSET)).unwrap();
    for (what, shift) in [("NaN", f64::NAN), ("5e7", 5e7)] {
        let out = tmp.path().join("out").join("t.las");
        let e = cloudcontrol::lidar::las::rewrite_las(&tile, &out, |i, mut p| {
            if i == 42 {
                p.z += shift;
            }
            Some(p)
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("point 42") && e.contains("z = ") && e.contains(&tile.display().to_string()),
            "{what}: {e}"
        );
        assert!(!out.exists(), "{what}");
        assert_eq!(parts_below(tmp.path()), Vec::<PathBuf>::new(), "{what}");
    }
}

#[test]
fn a_las_header_with_a_nan_or_zero_scale_or_offset_is_refused_naming_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&str, [f64; 3], [f64; 3], &str); 4] = [
        (
            "nan_scale",
            [f64::NAN, 0.01, 0.01],
            OFFSET,
            "x scale factor NaN",
        ),
        ("zero_scale", [0.01, 0.0, 0.01], OFFSET, "y scale factor 0"),
        (
            "tiny_scale",
            [0.01, 0.01, 1e-300],
            OFFSET,
            "z scale factor 1e-300",
        ),
        (
            "nan_offset",
            SCALE,
            [500_000.0, f64::NAN, 0.0],
            "y offset NaN is not a coordinate offset",
        ),
    ];
    for (name, scale, offset, words) in cases {
        let f = tmp.path().join(format!("{name}.las"));
        std::fs::write(&f, las12(&patch(), 1, scale, offset)).unwrap();
        let c = cli_confined(&["lidar", "info", f.to_str().unwrap()]);
        c.refused_cleanly(5.0, &[&f.display().to_string(), words]);
    }

    // A run given such a tile fails naming it (it used to be dropped from the run: its
    // points had no position, so no footprint ever selected it); through the C ABI, with
    // the status of a malformed file.
    let blk = tmp.path().join("block");
    common::block_copy("tiny", 2, "good", &blk);
    let bad = blk.join("lidar/zz_bad.las");
    std::fs::write(&bad, las12(&patch(), 1, [0.0, 0.01, 0.01], OFFSET)).unwrap();
    let project = blk.join("project.toml");
    let c = cli_confined(&["run", project.to_str().unwrap()]);
    c.refused_cleanly(5.0, &[&bad.display().to_string(), "x scale factor 0"]);
    let c = abi_confined(&format!("project {}", project.display()));
    c.refused_cleanly(5.0, &[&bad.display().to_string(), "x scale factor 0"]);
    assert_eq!(c.code, Some(FORMAT), "{}", c.stderr);
}

/// A frame camera JSON (formats/cameras/README.md) with the given size and focal length.
fn frame_camera(path: &Path, width: u64, height: u64, f: f64) {
    let cam = serde_json::json!({
        "kind": "frame", "width": width, "height": height, "fx": f, "fy": f,
        "cx": width as f64 / 2.0, "cy": height as f64 / 2.0
    });
    std::fs::write(path, cam.to_string()).unwrap();
}

/// `cloudcontrol orient` of the tiny block `blk`'s digital epoch from the package `dcp`
/// with `camera`, into `out`, confined.
fn orient_digital(blk: &Path, dcp: &Path, camera: &Path, out: &Path) -> Confined {
    let epoch = blk.join("epochs/digital_2012");
    cli_confined(&[
        "orient",
        "--dcp",
        dcp.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--images",
        epoch.join("images").to_str().unwrap(),
        "--pos",
        epoch.join("pos.csv").to_str().unwrap(),
        "--name",
        "digital_2012",
        "--crs",
        "EPSG:4547",
        "--dem",
        blk.join("orthophoto/dem.tif").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn orient_refuses_an_implausible_camera_naming_the_file_and_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    common::block_copy("tiny", 2, "good", &blk);
    let cases: [(u64, u64, f64, &str); 3] = [
        (
            (1 << 32) - 1,
            (1 << 32) - 1,
            1e-300,
            "image size 4294967295×4294967295: a side is at most 200000 px",
        ),
        (400, 266, 1e-300, "fx = 1e-300 px is not a focal length"),
        (400, 266, f64::MAX, "fx = 1.7976931348623157e308 px"),
    ];
    for (k, (w, h, f, words)) in cases.into_iter().enumerate() {
        let cam = tmp.path().join(format!("camera_{k}.json"));
        frame_camera(&cam, w, h, f);
        let out = tmp.path().join(format!("out_{k}"));
        let c = orient_digital(&blk, &tmp.path().join("no.dcp"), &cam, &out);
        c.refused_cleanly(5.0, &[&cam.display().to_string(), "invalid camera", words]);
        assert!(!out.exists(), "nothing is written for a refused camera");
    }
}

// ---------------------------------------------------------------------------------------
// Issue 52 item 3
// ---------------------------------------------------------------------------------------

/// [`common::digital_project_toml`] written into `blk` as `project_digital.toml`.
fn digital_project(blk: &Path, camera: &str, checkpoint_images: &str) -> PathBuf {
    let toml = common::digital_project_toml("hostile-status", camera, checkpoint_images);
    let p = blk.join("project_digital.toml");
    std::fs::write(&p, toml).unwrap();
    p
}

#[test]
fn a_camera_of_another_size_than_the_photos_is_refused_by_the_run_and_ends_orient_partial() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    common::block_copy("tiny", 2, "good", &blk);
    // 1500 × 1000 for the epoch's 400 × 266 photos: found from the image headers before
    // any stage (issue 52 item 2), by `run --check`, `run` and the C ABI.
    let camera_1500 = blk.join("camera_1500.json");
    frame_camera(&camera_1500, 1500, 1000, 1800.0);
    let project = digital_project(&blk, "camera_1500.json", "truth/checkpoint_images.csv");
    let p = project.to_str().unwrap();
    let said = [
        camera_1500.display().to_string(),
        "the camera is 1500×1000 px".into(),
        "is 400×266 px".into(),
    ];
    let said: Vec<&str> = said.iter().map(String::as_str).collect();
    for args in [["run", "--check", p], ["--json", "run", p]] {
        let c = cli_confined(&args);
        c.refused_cleanly(5.0, &said);
        assert_eq!(c.code, Some(2), "{args:?}: {}", c.stderr);
        assert!(!blk.join("run/sources").exists(), "a stage ran");
    }
    let c = abi_confined(&format!("project {}", project.display()));
    c.refused_cleanly(5.0, &said);
    assert_eq!(c.code, Some(INVALID_ARGUMENT), "{}", c.stderr);

    // A photo the run finds it cannot decode (its header read, its data cut short) makes
    // the run partial (exit status 3), saying which epoch, how many and why, listing no
    // empty model.
    let images = blk.join("epochs/digital_2012/images");
    let kept = tmp.path().join("images_kept");
    std::fs::create_dir_all(&kept).unwrap();
    for n in ["digital_s01_001.png", "digital_s01_002.png"] {
        let bytes = std::fs::read(images.join(n)).unwrap();
        std::fs::write(kept.join(n), &bytes).unwrap();
        std::fs::write(images.join(n), &bytes[..bytes.len() / 2]).unwrap();
    }
    let cam = blk.join("epochs/digital_2012/camera.json");
    let project = digital_project(&blk, cam.to_str().unwrap(), "truth/checkpoint_images.csv");
    let c = cli_confined(&["--json", "run", project.to_str().unwrap()]);
    assert_eq!(c.code, Some(common::EXIT_PARTIAL), "{}", c.stderr);
    assert!(c.seconds < 30.0 && c.peak_rss <= 1 << 30);
    for w in [
        "cloudcontrol run: partial",
        "epoch digital_2012: 0 of 2 photos oriented",
        "digital_s01_001: image ",
        "result.json",
    ] {
        assert!(c.stderr.contains(w), "says {w:?}: {}", c.stderr);
    }
    let summary: serde_json::Value = serde_json::from_str(&c.stdout).unwrap();
    let p = &summary["partial"][0];
    assert_eq!(
        (p["epoch"].as_str(), p["oriented"].as_u64()),
        (Some("digital_2012"), Some(0))
    );
    assert_eq!(p["total"], 2);
    assert!(
        p["not_oriented"][1]["reason"]
            .as_str()
            .unwrap()
            .contains("digital_s01_002.png"),
        "{p}"
    );
    // The epoch oriented nothing: no empty model is written or listed.
    let listed = summary["products"]["digital_2012"].to_string();
    assert!(
        !listed.contains("colmap") && !listed.contains("blocks_exchange"),
        "{listed}"
    );
    let outputs = blk.join("run/outputs-digital_2012");
    assert!(!outputs.join("colmap").exists() && !outputs.join("blocks_exchange.xml").exists());
    let skipped: serde_json::Value =
        serde_json::from_slice(&std::fs::read(outputs.join("skipped.json")).unwrap()).unwrap();
    assert_eq!(skipped["colmap"], "no photo of the epoch was oriented");

    // Through the C ABI: the status of its own, the summary handed out all the same.
    let c = abi_confined(&format!("project {}", project.display()));
    assert_eq!(c.code, Some(PARTIAL), "{}", c.stderr);
    assert!(
        c.stderr.contains("partial run") && c.stderr.contains("epoch digital_2012: 0 of 2"),
        "{}",
        c.stderr
    );
    // (the harness prints the test's name on the same line)
    let json = c
        .stdout
        .lines()
        .find_map(|l| l.split_once("JSON "))
        .unwrap()
        .1;
    let handed: serde_json::Value = serde_json::from_str(json).unwrap();
    assert_eq!(handed["partial"][0]["epoch"], "digital_2012");
    for n in ["digital_s01_001.png", "digital_s01_002.png"] {
        std::fs::copy(kept.join(n), images.join(n)).unwrap();
    }

    // `orient` (no project, no check before work) with the 1500 × 1000 camera and the
    // run's package: partial, the size found as it orients each photo, no model.
    let why = "is 400×266 px, the camera 1500×1000";
    let out = tmp.path().join("orient");
    let c = orient_digital(
        &blk,
        &blk.join("run/dcp-orthophoto/package"),
        &blk.join("camera_1500.json"),
        &out,
    );
    assert_eq!(
        c.code,
        Some(common::EXIT_PARTIAL),
        "{}{}",
        c.stdout,
        c.stderr
    );
    for w in [
        "cloudcontrol orient: partial",
        "epoch digital_2012: 0 of 2",
        why,
    ] {
        assert!(c.stderr.contains(w), "says {w:?}: {}", c.stderr);
    }
    assert!(out.join("report.json").is_file() && !out.join("colmap").exists());
}

#[test]
fn a_photo_without_a_pos_row_is_refused_before_any_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    common::block_copy("tiny", 2, "good", &blk);
    let pos = blk.join("epochs/digital_2012/pos.csv");
    let text = std::fs::read_to_string(&pos).unwrap();
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with("digital_s01_002"))
        .collect();
    std::fs::write(&pos, kept.join("\n") + "\n").unwrap();
    let cam = blk.join("epochs/digital_2012/camera.json");
    let project = digital_project(&blk, cam.to_str().unwrap(), "truth/checkpoint_images.csv");
    let c = cli_confined(&["run", project.to_str().unwrap()]);
    c.refused_cleanly(
        5.0,
        &[
            &pos.display().to_string(),
            "photo digital_s01_002",
            "has no row",
        ],
    );
    assert_eq!(c.code, Some(2));
    assert!(!blk.join("run/sources").exists(), "a stage ran");
}

#[test]
fn a_checkpoint_measurement_of_an_unknown_id_is_refused_naming_its_line() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    common::block_copy("tiny", 2, "good", &blk);
    let file = blk.join("checkpoint_images.csv");
    let mut text = std::fs::read_to_string(blk.join("truth/checkpoint_images.csv")).unwrap();
    text.push_str("digital_2012,digital_s01_001,CP999,120.5,80.25\n");
    let line = text.lines().count();
    std::fs::write(&file, text).unwrap();
    let cam = blk.join("epochs/digital_2012/camera.json");
    let project = digital_project(&blk, cam.to_str().unwrap(), "checkpoint_images.csv");
    let c = cli_confined(&["run", project.to_str().unwrap()]);
    c.refused_cleanly(
        5.0,
        &[
            &format!("{}:{line}: ", file.display()),
            "\"CP999\"",
            "not among the surveyed checkpoints",
        ],
    );
    assert_eq!(c.code, Some(2));
    assert!(!blk.join("run/sources").exists(), "a stage ran");
}
