//! Hostile and careless outputs (issue 51, items 1, 7 and 8): a run never writes into a
//! folder it did not make and never removes a name it did not write; temporary names are
//! unique per process, thread and call, so concurrent calls on one destination do not
//! collide; a run held by another comes back as `CCP_STATUS_BUSY`; a killed `ortho` leaves
//! nothing the next one does not remove. The CLI cases run in a child process under an
//! RLIMIT_AS of 2 GiB (common::run_confined); every case checks that the user's files are
//! still there byte for byte and that no `.part-` name is left behind.

use crate::common;
// The project tree of formats/project/example.toml with empty input files.
use crate::pipeline_project::example_tree;
use cloudcontrol::ffi::*;
use cloudcontrol::pipeline::stages::{Inputs, Runner, StageError, WorkError, MARKER};
use common::{cli_confined, exe, last_error, run_confined, Confined};
use std::collections::BTreeMap;
use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::process::Command;

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

/// Every name below `dir` (not following links), with a file's bytes (`None` for a
/// folder): what "nothing of the user's was touched" compares.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let m = std::fs::symlink_metadata(&p).unwrap();
            if m.is_dir() {
                stack.push(p.clone());
                out.insert(p, None);
            } else {
                out.insert(p.clone(), Some(std::fs::read(&p).unwrap_or_default()));
            }
        }
    }
    out
}

/// Asserts that no name below `dir` is a temporary of the product.
fn no_part_below(dir: &Path) {
    let left: Vec<PathBuf> = snapshot(dir)
        .into_keys()
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| cloudcontrol::formats::parse_temporary(n).is_some())
        })
        .collect();
    assert!(left.is_empty(), "temporaries left behind: {left:?}");
}

/// Asserts that every entry of `before` is still there with the same bytes.
fn kept(before: &BTreeMap<PathBuf, Option<Vec<u8>>>, root: &Path) {
    let now = snapshot(root);
    for (p, bytes) in before {
        match now.get(p) {
            None => panic!("{} was removed", p.display()),
            Some(b) => assert!(b == bytes, "{} changed", p.display()),
        }
    }
}

/// A child that ended by itself with exit 0 within the acceptance's limits.
fn succeeded(c: &Confined, seconds: f64) {
    assert!(
        c.code == Some(0) && !c.timed_out,
        "exit {:?} / signal {:?}: {}{}",
        c.code,
        c.signal,
        c.stdout,
        c.stderr
    );
    assert!(c.peak_rss <= 1 << 30, "peak RSS {} MiB", c.peak_rss >> 20);
    assert!(c.seconds <= seconds, "{:.1} s", c.seconds);
}

/// `text` with its `output = "out"` line replaced by `output = "{output}"`.
fn with_output(text: &str, output: &str) -> String {
    assert!(text.contains("output = \"out\""));
    text.replace("output = \"out\"", &format!("output = {output:?}"))
}

fn write_project(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// `run --check` and `run` of `project` are both refused with exit code 2 and a message
/// holding each of `words`.
fn both_refused(project: &str, words: &[&str]) {
    for check in [true, false] {
        let mut args = vec!["run", project];
        if check {
            args.push("--check");
        }
        let c = cli_confined(&args);
        c.refused_cleanly(5.0, words);
        assert_eq!(c.code, Some(2), "{args:?}: {}", c.stderr);
    }
}

// ---------------------------------------------------------------------------------------
// Item 1: the output folder is the product's
// ---------------------------------------------------------------------------------------

/// The reported case: `output` names a folder of the user's that holds `report/`,
/// `sources/`, `epoch-*` folders and `.X.part-N` files of the same names a run writes.
/// `run --check` and `run` refuse it, naming the folder; nothing in it changes.
#[test]
fn a_run_into_a_users_folder_is_refused_and_removes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let text = example_tree(root);
    let out = root.join("out");
    for (f, bytes) in [
        ("report/thesis.docx", &b"PK\x03\x04 the thesis"[..]),
        ("sources/field_notes.csv", b"id,x\n1,2\n"),
        ("epoch-digital_2012/photo.tif", b"II*\0"),
        (".report.part-12", b"mine"),
        (".sources.part-1-2-3", b"mine too"),
        ("stages.json", b"{}"),
    ] {
        std::fs::create_dir_all(out.join(f).parent().unwrap()).unwrap();
        std::fs::write(out.join(f), bytes).unwrap();
    }
    let project = write_project(root, "project.toml", &text);
    let before = snapshot(root);
    both_refused(
        &project,
        &[
            &out.display().to_string(),
            "did not make",
            ".report.part-12",
        ],
    );
    kept(&before, root);
    assert_eq!(snapshot(root).len(), before.len(), "nothing added");
    assert!(!out.join(MARKER).exists());
}

/// `/`, the home folder, a file, an input folder, a folder inside an input folder and a
/// folder holding an input: each refused by `run --check` and by `run` with exit code 2,
/// naming the output (and the input's key), and nothing made or removed.
#[test]
fn outputs_that_are_not_a_folder_of_their_own_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let text = example_tree(root);
    std::fs::write(root.join("notes.txt"), "mine").unwrap();
    // An owned output folder (made by a run) that holds an input.
    let owned = root.join("owned");
    std::fs::create_dir_all(owned.join("pos")).unwrap();
    std::fs::write(owned.join(MARKER), r#"{"cloudcontrol_output":1}"#).unwrap();
    std::fs::write(owned.join("pos/pos.csv"), "").unwrap();
    let text_owned = text.replace(
        "pos = \"epochs/reference/pos.csv\"",
        "pos = \"owned/pos/pos.csv\"",
    );
    assert_ne!(text_owned, text);
    let before = snapshot(root);
    let cases: Vec<(String, String, Vec<String>)> = vec![
        (
            with_output(&text, "/"),
            "/".into(),
            vec!["root folder".into()],
        ),
        (
            with_output(&text, "notes.txt"),
            root.join("notes.txt").display().to_string(),
            vec!["not a folder".into()],
        ),
        (
            with_output(&text, "epochs/reference/images"),
            root.join("epochs/reference/images").display().to_string(),
            vec!["is the input reference.photos".into()],
        ),
        (
            with_output(&text, "lidar/run"),
            root.join("lidar/run").display().to_string(),
            vec!["lies inside the input control.lidar[0]".into()],
        ),
        (
            with_output(&text_owned, "owned"),
            owned.display().to_string(),
            vec!["holds the input reference.pos".into()],
        ),
    ];
    for (i, (t, named, words)) in cases.iter().enumerate() {
        let project = write_project(root, &format!("p{i}.toml"), t);
        let mut w: Vec<&str> = vec![named.as_str()];
        w.extend(words.iter().map(String::as_str));
        both_refused(&project, &w);
    }
    // The home folder (HOME pointed at a folder of its own for the child).
    let home = root.join("home");
    std::fs::create_dir_all(&home).unwrap();
    std::fs::write(home.join(".bashrc"), "# mine").unwrap();
    let project = write_project(
        root,
        "home.toml",
        &with_output(&text, home.to_str().unwrap()),
    );
    for check in [true, false] {
        let mut cmd = Command::new(exe());
        cmd.env("HOME", &home).args(["run", &project]);
        if check {
            cmd.arg("--check");
        }
        let c = run_confined(&cmd, 2 << 30, 30.0);
        c.refused_cleanly(5.0, &[&home.display().to_string(), "home folder"]);
        assert_eq!(c.code, Some(2));
    }
    let mut before = before;
    before.extend(snapshot(&home));
    kept(&before, root);
    assert!(!root.join("lidar/run").exists(), "nothing made");
    for d in [&owned, &home, &root.join("epochs/reference/images")] {
        assert!(!d.join("stages.json").exists());
    }
    assert!(!home.join(MARKER).exists());
}

/// A project whose `sources` stage finishes in a second (two LiDAR tiles of two strips
/// under one POS centre), and whose reference epoch of one small photo then ends as it may (one
/// photo orients nothing): a real run that writes stage folders.
fn sources_project(root: &Path, centre_x: f64) -> String {
    std::fs::create_dir_all(root.join("lidar")).unwrap();
    std::fs::create_dir_all(root.join("photos")).unwrap();
    if !root.join("lidar/a.las").exists() {
        use crate::lidar_synth::{two_strips, write_las, CrsVlr, E0, EPSG};
        let (pts, _) = two_strips(2.0, 0.0, 0.0, 5);
        let (a, b): (Vec<_>, Vec<_>) = pts.iter().partition(|p| p.x - E0 < 100.0);
        write_las(&root.join("lidar/a.las"), &a, 4, CrsVlr::Wkt(EPSG), false);
        write_las(&root.join("lidar/b.las"), &b, 4, CrsVlr::Wkt(EPSG), false);
    }
    std::fs::write(
        root.join("camera.json"),
        r#"{"kind": "frame", "width": 64, "height": 64, "fx": 64, "fy": 64, "cx": 32, "cy": 32}"#,
    )
    .unwrap();
    image::GrayImage::from_fn(64, 64, |c, r| image::Luma([((c * 13 + r * 7) % 256) as u8]))
        .save(root.join("photos/ref_000.png"))
        .unwrap();
    std::fs::write(
        root.join("pos.csv"),
        format!(
            "name,x,y,z,omega,phi,kappa\nref_000.png,{centre_x},{},400,0,0,0\n",
            crate::lidar_synth::N0 + 50.0
        ),
    )
    .unwrap();
    write_project(
        root,
        "project.toml",
        "name = \"t\"\ncrs = \"EPSG:32650\"\noutput = \"out\"\n[control]\nlidar = [\"lidar\"]\n\
         [reference]\nname = \"ref\"\ndate = \"2024-05-01\"\nphotos = \"photos\"\n\
         camera = \"camera.json\"\npos = \"pos.csv\"\n",
    )
}

/// A child that ended by itself (exit 0, 1 or 3: done, failed, partial — not refused, not
/// a panic) within the acceptance's limits; its exit code.
fn ended(c: &Confined, seconds: f64) -> i32 {
    assert!(
        !c.timed_out && c.signal.is_none() && matches!(c.code, Some(0 | 1 | 3)),
        "exit {:?} / signal {:?} after {:.1} s: {}{}",
        c.code,
        c.signal,
        c.seconds,
        c.stdout,
        c.stderr
    );
    assert!(c.peak_rss <= 1 << 30, "peak RSS {} MiB", c.peak_rss >> 20);
    assert!(c.seconds <= seconds, "{:.1} s: {}", c.seconds, c.stderr);
    c.code.unwrap()
}

/// A file of the user's in a folder the product owns survives every rerun: a rerun whose
/// stage is unchanged skips it (the file is not the stage's), and a stage that must be
/// redone refuses, naming the file, before any work — its folder untouched; once the file
/// is moved out, the stage is redone. A file beside the stage folders is never touched.
#[test]
fn a_users_file_in_an_owned_folder_survives_reruns_and_stops_a_redo() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let project = sources_project(root, 500_100.0);
    let out = root.join("out");
    let ledger = || std::fs::read_to_string(out.join("stages.json")).unwrap();
    // First run: the sources stage is written.
    let c = cli_confined(&["run", &project]);
    ended(&c, 5.0);
    assert!(
        out.join(MARKER).is_file() && out.join("sources/origin.json").is_file(),
        "{}",
        c.stderr
    );
    no_part_below(&out);
    // The user's files: one in the stage folder, one in a folder of theirs inside one of
    // the stage's, one beside the stage folders.
    std::fs::write(out.join("sources/notes.txt"), "keep me").unwrap();
    std::fs::create_dir_all(out.join("sources/lidar/mine")).unwrap();
    std::fs::write(out.join("sources/lidar/mine/x.las"), "mine").unwrap();
    std::fs::write(out.join("thesis.docx"), "the thesis").unwrap();
    let sources = snapshot(&out.join("sources"));
    let ledger_before = ledger();
    // Rerun, same inputs: sources skipped (the ledger's record of it unchanged), all kept.
    ended(&cli_confined(&["run", &project]), 5.0);
    kept(&sources, &out.join("sources"));
    assert_eq!(snapshot(&out.join("sources")).len(), sources.len());
    assert_eq!(
        std::fs::read(out.join("thesis.docx")).unwrap(),
        b"the thesis"
    );
    let record = |l: &str| {
        let v: serde_json::Value = serde_json::from_str(l).unwrap();
        v["stages"]["sources"].clone()
    };
    assert_eq!(record(&ledger()), record(&ledger_before));
    no_part_below(&out);
    // Changed navigation: sources must be redone, and is refused naming a user's file.
    sources_project(root, 500_102.0);
    let before = snapshot(&out);
    let c = cli_confined(&["run", &project]);
    c.refused_cleanly(
        5.0,
        &[
            &out.join("sources").display().to_string(),
            "was not written by cloudcontrol",
            "move it out",
        ],
    );
    assert_eq!(c.code, Some(2), "{}", c.stderr);
    assert!(
        c.stderr.contains("notes.txt") || c.stderr.contains("mine/x.las"),
        "{}",
        c.stderr
    );
    kept(&before, &out);
    no_part_below(&out);
    // Moved out: the stage is redone, the file beside kept.
    std::fs::remove_file(out.join("sources/notes.txt")).unwrap();
    std::fs::remove_dir_all(out.join("sources/lidar/mine")).unwrap();
    ended(&cli_confined(&["run", &project]), 5.0);
    assert_eq!(
        std::fs::read(out.join("thesis.docx")).unwrap(),
        b"the thesis"
    );
    assert_ne!(record(&ledger()), record(&ledger_before), "sources redone");
    assert!(out.join("sources/origin.json").is_file());
    no_part_below(&out);
}

/// The same rules through the library's stage runner: a stage folder the ledger does not
/// list is refused (a user's `report/` in an owned folder), a user's file in a stage's
/// folder keeps the stage skipped and stops its redo, and a folder of the user's inside
/// the stage folder is named.
#[test]
fn the_stage_runner_removes_only_what_it_wrote() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let input = tmp.path().join("in.txt");
    std::fs::write(&input, "a").unwrap();
    let write = |dir: &Path| -> Result<(), WorkError> {
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        std::fs::write(dir.join("sub/plot.svg"), "<svg/>").unwrap();
        Ok(())
    };
    // A folder of the user's named like a stage, in a folder the product owns.
    drop(Runner::new(&out).unwrap());
    std::fs::create_dir_all(out.join("report")).unwrap();
    std::fs::write(out.join("report/thesis.docx"), "thesis").unwrap();
    let mut r = Runner::new(&out).unwrap();
    let e = r
        .stage("report", &Inputs::new().file(&input), write)
        .unwrap_err();
    assert!(matches!(e, StageError::Output { .. }), "{e}");
    let m = e.to_string();
    assert!(
        m.contains(&out.join("report").display().to_string()) && m.contains("does not list it"),
        "{m}"
    );
    assert_eq!(
        std::fs::read(out.join("report/thesis.docx")).unwrap(),
        b"thesis"
    );
    std::fs::remove_dir_all(out.join("report")).unwrap();
    r.stage("report", &Inputs::new().file(&input), write)
        .unwrap();
    // A user's file in it: the unchanged stage is skipped, the file kept.
    std::fs::write(out.join("report/notes.txt"), "notes").unwrap();
    std::fs::create_dir_all(out.join("report/sub/old")).unwrap();
    drop(r);
    let mut r = Runner::new(&out).unwrap();
    r.stage("report", &Inputs::new().file(&input), write)
        .unwrap();
    assert_eq!(r.skipped, ["report"]);
    // Changed input: refused before any work, naming the first foreign name.
    std::fs::write(&input, "b").unwrap();
    let before = snapshot(&out);
    let e = r
        .stage("report", &Inputs::new().file(&input), |_| {
            panic!("no work before the folder is known to be replaceable")
        })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&out.join("report/notes.txt").display().to_string())
            && e.contains("1 other name"),
        "{e}"
    );
    kept(&before, &out);
    no_part_below(&out);
    // Moved out: redone.
    std::fs::remove_file(out.join("report/notes.txt")).unwrap();
    std::fs::remove_dir(out.join("report/sub/old")).unwrap();
    r.stage("report", &Inputs::new().file(&input), write)
        .unwrap();
    assert_eq!(r.ran, ["report"]);
    no_part_below(&out);
}

// ---------------------------------------------------------------------------------------
// Item 7: temporary names per process, thread and call
// ---------------------------------------------------------------------------------------

fn c_path(p: &Path) -> CString {
    CString::new(p.to_str().unwrap()).unwrap()
}

/// Runs `f(i)` on `n` threads released together.
fn together(n: usize, f: impl Fn(usize) + Sync) {
    let start = std::sync::Barrier::new(n);
    std::thread::scope(|s| {
        for i in 0..n {
            let (f, start) = (&f, &start);
            s.spawn(move || {
                start.wait();
                f(i)
            });
        }
    });
}

/// Eight threads import into one store at once, five rounds: the same package (each
/// call succeeds and the store holds it once, whole) and eight packages of different
/// names (all eight stored). Imports into one store serialise on its lock.
#[test]
fn parallel_dcp_imports_into_one_store_all_succeed() {
    let tmp = tempfile::tempdir().unwrap();
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/dcp/sample.dcp");
    let mut named = Vec::new();
    for k in 0..8 {
        let d = tmp.path().join(format!("src/pkg{k}.dcp"));
        common::copy_block(&sample, &d);
        named.push(c_path(&d));
    }
    let same = c_path(&sample);
    for round in 0..5 {
        for (kind, store) in [("same", "same"), ("named", "named")] {
            let store_dir = tmp.path().join(format!("{store}{round}"));
            let store_c = c_path(&store_dir);
            let statuses = std::sync::Mutex::new(Vec::new());
            together(8, |i| {
                let pkg = if kind == "same" { &same } else { &named[i] };
                let mut dcp = std::ptr::null_mut();
                let st = unsafe { ccp_dcp_import(pkg.as_ptr(), store_c.as_ptr(), &mut dcp) };
                let msg = last_error();
                if !dcp.is_null() {
                    unsafe { ccp_dcp_free(dcp) };
                }
                statuses.lock().unwrap().push((st, msg));
            });
            for (st, msg) in statuses.into_inner().unwrap() {
                assert_eq!(st, CcpStatus::Ok, "{kind} round {round}: {msg}");
            }
            let held: Vec<String> = std::fs::read_dir(&store_dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            let want = if kind == "same" { 1 } else { 8 };
            assert_eq!(held.len(), want, "{kind} round {round}: {held:?}");
            for h in held {
                cloudcontrol::control::dcp::DcpPackage::open(&store_dir.join(&h))
                    .unwrap_or_else(|e| panic!("{kind} round {round}: {h}: {e}"));
            }
        }
    }
    no_part_below(tmp.path());
}

/// Eight threads convert one block to one output at once (a COLMAP folder, a
/// BlocksExchange file), five rounds: every call succeeds and the output reads back
/// whole; sixteen threads writing one file atomically each write their own temporary.
#[test]
fn parallel_conversions_to_one_output_all_succeed() {
    let tmp = tempfile::tempdir().unwrap();
    let input = c_path(&Path::new(env!("CARGO_MANIFEST_DIR")).join(
        "formats/blocks-exchange/synthetic_historical_with_dcp/synthetic_historical_with_dcp.xml",
    ));
    let want = cloudcontrol::formats::convert::read_block(Path::new(input.to_str().unwrap()), None)
        .unwrap();
    for round in 0..5 {
        let model = tmp.path().join(format!("model{round}"));
        let xml = tmp.path().join(format!("x{round}/block.xml"));
        for out in [&model, &xml] {
            let out_c = c_path(out);
            let statuses = std::sync::Mutex::new(Vec::new());
            together(8, |_| {
                let st = unsafe { ccp_convert(input.as_ptr(), out_c.as_ptr(), 0, 0) };
                statuses.lock().unwrap().push((st, last_error()));
            });
            for (st, msg) in statuses.into_inner().unwrap() {
                assert_eq!(st, CcpStatus::Ok, "{}: {msg}", out.display());
            }
            let back = cloudcontrol::formats::convert::read_block(out, None).unwrap();
            assert_eq!(back.photos.len(), want.photos.len());
            assert_eq!(back.points.len(), want.points.len());
        }
    }
    let file = tmp.path().join("one.json");
    together(16, |i| {
        cloudcontrol::formats::write_bytes_atomically(&file, format!("{i:04}").as_bytes()).unwrap();
    });
    assert_eq!(std::fs::read(&file).unwrap().len(), 4);
    no_part_below(tmp.path());
}

/// The temporary names: unique per call, recognised exactly.
#[test]
fn temporary_names_are_unique_and_recognised_exactly() {
    use cloudcontrol::formats::{parse_temporary, temporary_sibling};
    let names = std::sync::Mutex::new(std::collections::BTreeSet::new());
    together(8, |_| {
        for _ in 0..100 {
            let n = temporary_sibling(Path::new("/x/ortho.tif"));
            let n = n.file_name().unwrap().to_str().unwrap().to_string();
            let t = parse_temporary(&n).unwrap();
            assert_eq!(
                (t.stem, t.rest, t.pid),
                ("ortho", "tif", std::process::id())
            );
            assert!(names.lock().unwrap().insert(n));
        }
    });
    assert_eq!(names.into_inner().unwrap().len(), 800);
    for (name, ok) in [
        (".stages.part-1-2-3.json", true),
        (".epoch-a.b.part-1-0-9", true),
        (".ortho.part-7-1-2.tif.aux.xml", true),
        (".x.part-12", false),
        (".x.part-1-2", false),
        (".x.part-1-2-3-4", false),
        (".x.part-1-2-a", false),
        ("x.part-1-2-3", false),
        (".part-1-2-3", false),
        (".x.part-1-2-3.", false),
        (".thesis.docx", false),
    ] {
        assert_eq!(parse_temporary(name).is_some(), ok, "{name}");
    }
}

// ---------------------------------------------------------------------------------------
// Item 8: a lock conflict has a status of its own; a killed ortho leaves nothing
// ---------------------------------------------------------------------------------------

/// While a run holds an output folder, `ccp_project_run` and `ccp_project_plan` on it
/// return `CCP_STATUS_BUSY` (not NUMERIC) naming the folder, and the CLI's `run` fails
/// with exit code 1 and the same message; once it is released, the folder is free.
#[test]
fn a_run_on_a_held_output_folder_is_busy() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let text = example_tree(root);
    let project = write_project(root, "project.toml", &text);
    let out = root.join("out");
    let held = Runner::new(&out).unwrap();
    let before = snapshot(root);
    let p = CString::new(project.as_str()).unwrap();
    for plan in [false, true] {
        let mut json = std::ptr::null_mut();
        let st = unsafe {
            if plan {
                ccp_project_plan(p.as_ptr(), &mut json)
            } else {
                ccp_project_run(p.as_ptr(), &mut json)
            }
        };
        assert_eq!(st, CcpStatus::Busy, "{}", last_error());
        assert!(json.is_null());
        let e = last_error();
        assert!(
            e.contains(&out.display().to_string()) && e.contains("another cloudcontrol run"),
            "{e}"
        );
    }
    let c = cli_confined(&["run", &project]);
    c.refused_cleanly(
        5.0,
        &[&out.display().to_string(), "another cloudcontrol run"],
    );
    assert_eq!(c.code, Some(1));
    kept(&before, root);
    assert_eq!(snapshot(root).len(), before.len());
    drop(held);
    // Free again: the run gets past the lock (and fails on the empty example inputs).
    let mut json = std::ptr::null_mut();
    let st = unsafe { ccp_project_run(p.as_ptr(), &mut json) };
    assert_ne!(st, CcpStatus::Busy, "{}", last_error());
    assert_ne!(st, CcpStatus::Ok);
}

/// A DEM over a textured plane and a COLMAP block of two nadir photos of it (PNG files
/// beside the model): the inputs of `cloudcontrol ortho`.
fn ortho_inputs(dir: &Path) -> (PathBuf, PathBuf) {
    use cloudcontrol::block::{Block, BlockCamera, Photo};
    use cloudcontrol::geometry::{Camera, Dem, FrameCamera, Pose};
    use nalgebra::{Matrix3, Vector3};
    let (e0, n0) = (500_000.0, 4_000_000.0);
    let dem = Dem::from_fn(e0 - 200.0, n0 + 200.0, 2.0, 200, 200, |_, _| 100.0).unwrap();
    let dem_path = dir.join("dem.tif");
    cloudcontrol::formats::raster::write_dem(
        &dem_path,
        &dem,
        &cloudcontrol::formats::crs::Crs::from_epsg(32650).unwrap(),
        &Default::default(),
    )
    .unwrap();
    let model = dir.join("model");
    std::fs::create_dir_all(&model).unwrap();
    let mut block = Block::new();
    block.origin = [e0, n0, 0.0];
    let size = 400u32;
    let cam = FrameCamera::pinhole(size, size, 400.0);
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "cam".into(),
            model: Camera::Frame(cam),
            free_params: vec![],
            calibration_group: None,
        },
    );
    let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    for (id, x) in [(1u32, -40.0), (2, 40.0)] {
        let name = format!("p{id}.png");
        let img = image::RgbImage::from_fn(size, size, |c, r| {
            image::Rgb([
                (c * 7 % 251) as u8,
                (r * 5 % 241) as u8,
                ((c + r) % 256) as u8,
            ])
        });
        img.save(model.join(&name)).unwrap();
        block.photos.insert(
            id,
            Photo {
                id,
                name,
                camera: 1,
                pose: Pose::new(nadir, Vector3::new(x, 0.0, 400.0)),
                status: cloudcontrol::block::PhotoStatus::Oriented,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    cloudcontrol::formats::colmap::write(&model, &block, &Default::default()).unwrap();
    (model, dem_path)
}

/// `cloudcontrol ortho` removes what a killed `ortho` into the same place left — its
/// temporary GeoTIFF, the COG's scratch file, GDAL's side file — and nothing else: a live
/// writer's temporary (locked by this process), names that only look like temporaries,
/// another output's temporaries and the user's files stay. Then a real `ortho` is killed
/// mid-write and the next one leaves no `.part` file.
#[test]
fn a_killed_ortho_leaves_nothing_the_next_one_does_not_remove() {
    let tmp = tempfile::tempdir().unwrap();
    let (model, dem) = ortho_inputs(tmp.path());
    let outdir = tmp.path().join("out");
    std::fs::create_dir_all(&outdir).unwrap();
    let out = outdir.join("ortho.tif");
    let args = |out: &Path| -> Vec<String> {
        [
            "ortho",
            "--block",
            model.to_str().unwrap(),
            "--dem",
            dem.to_str().unwrap(),
            "--gsd",
            "0.1",
            "--extent",
            "499900",
            "3999900",
            "500100",
            "4000100",
            "--cog",
            "--out",
            out.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    // What a writer killed by the pid of no live process left (pid 2^22 + 1 is beyond
    // Linux's pid_max default and never a live process here).
    let dead = 4_194_305u32;
    let left = [
        format!(".ortho.part-{dead}-0-0.tif"),
        format!(".ortho.part-{dead}-0-0.scratch.tif"),
        format!(".ortho.part-{dead}-3-9.tif.aux.xml"),
    ];
    for n in &left {
        std::fs::write(outdir.join(n), "half a GeoTIFF").unwrap();
    }
    // A live writer's temporary: locked by this process.
    let live = outdir.join(format!(".ortho.part-{}-77-1.tif", std::process::id()));
    std::fs::write(&live, "being written").unwrap();
    let lock = cloudcontrol::formats::Lock::exclusive(&live, false)
        .unwrap()
        .unwrap();
    let live_side = outdir.join(format!(
        ".ortho.part-{}-77-1.tif.ovr.tmp",
        std::process::id()
    ));
    std::fs::write(&live_side, "overviews").unwrap();
    // Not the product's temporaries of this output.
    for n in [
        "notes.txt",
        ".ortho.part-1-2.tif",
        "ortho.part-1-2-3.tif",
        ".other.part-1-2-3.tif",
        ".ortho.part-1-2-3-4.tif",
    ] {
        std::fs::write(outdir.join(n), "mine").unwrap();
    }
    std::fs::create_dir_all(outdir.join(".ortho.part-5-5-5.tif")).unwrap();
    let before: BTreeMap<_, _> = snapshot(&outdir)
        .into_iter()
        .filter(|(p, _)| !left.iter().any(|n| p.ends_with(n)))
        .collect();
    let a = args(&out);
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    let c = cli_confined(&a);
    succeeded(&c, 5.0);
    for n in &left {
        assert!(!outdir.join(n).exists(), "{n} left");
    }
    kept(&before, &outdir);
    assert!(out.is_file());
    drop(lock);
    for p in before.keys() {
        if p.is_file() {
            std::fs::remove_file(p).unwrap();
        } else if p.is_dir() {
            std::fs::remove_dir(p).unwrap();
        }
    }

    // A real kill: SIGKILL once the temporary is there, under the same address-space
    // limit; the next run into the same place removes what it left.
    let mut saw = false;
    for _ in 0..5 {
        let mut cmd = common::under_rlimit_as(Command::new(exe()).args(&a), 2 << 30);
        let mut child = cmd
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let t = std::time::Instant::now();
        while t.elapsed().as_secs_f64() < 10.0 {
            let part = std::fs::read_dir(&outdir).unwrap().any(|e| {
                e.unwrap()
                    .file_name()
                    .to_str()
                    .is_some_and(|n| n.starts_with(".ortho.part-"))
            });
            if part {
                saw = true;
                break;
            }
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let _ = child.kill();
        child.wait().unwrap();
        if saw {
            break;
        }
    }
    assert!(saw, "the ortho child never showed its temporary file");
    let c = cli_confined(&a);
    succeeded(&c, 5.0);
    no_part_below(&outdir);
    let names: Vec<String> = std::fs::read_dir(&outdir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["ortho.tif"]);
}
