//! Every input of every epoch is checked before work starts, every problem at once (issue
//! 52, items 2 and 3; `pipeline::validate::check_inputs`): a hand-written project with a
//! misspelt key in an archive camera (`"fxx"`), a photo without its POS row, a checkpoint
//! CSV with a wrong header, `checkpoints_crs = "WGS84"` (no CRS syntax: PROJ names are not
//! taken, formats/README.md "CRS definitions"), a camera of 1500 × 1000 for 1000 × 666
//! photos and a measurement of an unknown checkpoint: `run --check` lists them with their
//! files and lines in a second, exit status 2, writing nothing; `run` refuses the project
//! before any stage; fixed one by one, the project passes.

use crate::common::{self, cli_confined, Confined};
use std::path::{Path, PathBuf};

/// A frame camera file, one key a line (so that a key has a line to point at).
fn camera(width: u32, height: u32, focal_key: &str) -> String {
    format!(
        "{{\n  \"kind\": \"frame\",\n  \"width\": {width},\n  \"height\": {height},\n  \
         \"{focal_key}\": 1200,\n  \"fy\": 1200,\n  \"cx\": {},\n  \"cy\": {}\n}}\n",
        width / 2,
        height / 2
    )
}

fn pos(photos: &[&str]) -> String {
    let mut s = String::from("name,x,y,z,omega,phi,kappa\n");
    for (i, p) in photos.iter().enumerate() {
        s.push_str(&format!("{p},{},4400000,1200,0,0,0\n", 500_000 + 300 * i));
    }
    s
}

const GOOD_CHECKPOINTS: &str = "id,x,y,z,sigma_xy,sigma_z\nCP1,500100,4400010,100,0.02,0.03\n";
const GOOD_MEASUREMENTS: &str = "epoch,photo,id,col,row\nref_2020,ref_001,CP1,500.5,300.25\n";

/// The project, with every input right, in `dir`: LiDAR (not read before work), the
/// reference and three archive epochs of two 1000 × 666 photos each, checkpoints and
/// their measurements. Returns the project file.
fn project(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir.join("lidar")).unwrap();
    std::fs::write(dir.join("lidar/tile.las"), "not read before work").unwrap();
    let photo = image::GrayImage::from_fn(1000, 666, |c, r| image::Luma([((c ^ r) & 255) as u8]));
    for e in ["ref", "a2010", "a2000", "a1990"] {
        let d = dir.join(e);
        std::fs::create_dir_all(d.join("images")).unwrap();
        let names = [format!("{e}_001"), format!("{e}_002")];
        for n in &names {
            photo.save(d.join(format!("images/{n}.png"))).unwrap();
        }
        std::fs::write(d.join("camera.json"), camera(1000, 666, "fx")).unwrap();
        std::fs::write(
            d.join("pos.csv"),
            pos(&[names[0].as_str(), names[1].as_str()]),
        )
        .unwrap();
    }
    std::fs::write(dir.join("checkpoints.csv"), GOOD_CHECKPOINTS).unwrap();
    std::fs::write(dir.join("checkpoint_images.csv"), GOOD_MEASUREMENTS).unwrap();
    let file = dir.join("project.toml");
    std::fs::write(&file, toml("")).unwrap();
    file
}

/// The project file; `checkpoints_crs` is a line of `[control]` (or empty).
fn toml(checkpoints_crs: &str) -> String {
    let mut s = format!(
        "name = \"check-inputs\"\ncrs = \"EPSG:32650\"\noutput = \"out\"\n\n[control]\n\
         lidar = [\"lidar\"]\ncheckpoints = \"checkpoints.csv\"\n{checkpoints_crs}\
         checkpoint_images = \"checkpoint_images.csv\"\n"
    );
    for (table, name, date, dir) in [
        ("[reference]", "ref_2020", "2020", "ref"),
        ("[[archive]]", "a_2010", "2010", "a2010"),
        ("[[archive]]", "a_2000", "2000", "a2000"),
        ("[[archive]]", "a_1990", "1990", "a1990"),
    ] {
        s.push_str(&format!(
            "\n{table}\nname = \"{name}\"\ndate = \"{date}\"\nphotos = \"{dir}/images\"\n\
             camera = \"{dir}/camera.json\"\npos = \"{dir}/pos.csv\"\n"
        ));
    }
    s
}

/// The six mistakes, each as a file to write with its wrong content and its right one,
/// and what `run --check` must say of it: the file's path and line, and words.
struct Mistake {
    file: &'static str,
    wrong: String,
    right: String,
    /// `path:line` (or `path:` where the mistake has no line: a row that is missing).
    at: Option<usize>,
    words: &'static [&'static str],
}

fn mistakes() -> Vec<Mistake> {
    let crs_line = toml("checkpoints_crs = \"WGS84\"\n")
        .lines()
        .position(|l| l.starts_with("checkpoints_crs"))
        .unwrap()
        + 1;
    vec![
        Mistake {
            file: "a2010/camera.json",
            wrong: camera(1000, 666, "fxx"),
            right: camera(1000, 666, "fx"),
            at: Some(5),
            words: &["missing field `fx`", "\"fxx\""],
        },
        Mistake {
            file: "a2000/pos.csv",
            wrong: pos(&["a2000_001"]),
            right: pos(&["a2000_001", "a2000_002"]),
            at: None,
            words: &["photo a2000_002", "has no row"],
        },
        Mistake {
            file: "checkpoints.csv",
            wrong: GOOD_CHECKPOINTS.replace("id,x,y", "id,east,north"),
            right: GOOD_CHECKPOINTS.into(),
            at: Some(1),
            words: &["\"east\""],
        },
        Mistake {
            file: "project.toml",
            wrong: toml("checkpoints_crs = \"WGS84\"\n"),
            right: toml(""),
            at: Some(crs_line),
            words: &["WGS84", "control.checkpoints_crs"],
        },
        Mistake {
            file: "a1990/camera.json",
            wrong: camera(1500, 1000, "fx"),
            right: camera(1000, 666, "fx"),
            at: Some(3),
            words: &["1500×1000", "1000×666", "a1990_001.png"],
        },
        Mistake {
            file: "checkpoint_images.csv",
            wrong: format!("{GOOD_MEASUREMENTS}a_2010,a2010_002,CP9,10,20\n"),
            right: GOOD_MEASUREMENTS.into(),
            at: Some(3),
            words: &["\"CP9\"", "not among the surveyed checkpoints"],
        },
    ]
}

fn check(file: &Path) -> Confined {
    cli_confined(&["run", "--check", file.to_str().unwrap()])
}

/// `c` lists mistake `m` of the project in `dir`: its file with its line, and its words,
/// on one line of the message.
fn lists(c: &Confined, dir: &Path, m: &Mistake) {
    let path = dir.join(m.file).display().to_string();
    let at = match m.at {
        Some(l) => format!("{path}:{l}: "),
        None => format!("{path}: "),
    };
    let line = c
        .stderr
        .lines()
        .find(|l| l.starts_with(&at) && m.words.iter().all(|w| l.contains(w)))
        .unwrap_or_else(|| panic!("no line `{at}…` saying {:?}: {}", m.words, c.stderr));
    assert!(!line.is_empty());
}

fn no_output(dir: &Path) {
    assert!(!dir.join("out").exists(), "run --check wrote its output");
}

#[test]
fn run_check_lists_every_mistake_with_its_file_and_line_and_each_fix_passes() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let file = project(dir);
    let ok = check(&file);
    assert_eq!(ok.code, Some(0), "the right project: {}", ok.stderr);
    no_output(dir);

    let all = mistakes();
    for m in &all {
        std::fs::write(dir.join(m.file), &m.wrong).unwrap();
    }
    let c = check(&file);
    c.refused_cleanly(5.0, &["problem(s) in the project's inputs"]);
    assert_eq!(c.code, Some(2), "{}", c.stderr);
    no_output(dir);
    // A checkpoint file whose header is wrong has no ids to check the measurements
    // against: the unknown id is found once the header is right. Every other mistake is
    // listed at once.
    let (unknown_id, rest) = all.split_last().unwrap();
    for m in rest {
        lists(&c, dir, m);
    }
    // With --json: the same problems as an array, each with its file and line.
    let j = cli_confined(&["--json", "run", "--check", file.to_str().unwrap()]);
    assert_eq!(j.code, Some(2), "{}", j.stderr);
    let doc: serde_json::Value = serde_json::from_str(&j.stdout).unwrap();
    let problems = doc["problems"].as_array().unwrap();
    assert_eq!(problems.len(), rest.len(), "{doc:#}");
    for m in rest {
        let file = dir.join(m.file).display().to_string();
        let p = problems
            .iter()
            .find(|p| p["file"] == file.as_str())
            .unwrap_or_else(|| panic!("{file} not listed: {doc:#}"));
        assert_eq!(p["line"].as_u64(), m.at.map(|l| l as u64), "{p}");
    }
    assert_eq!(doc["error"]["exit_status"], 2);
    assert_eq!(doc["error"]["input"], problems[0]["file"]);
    assert_eq!(doc["valid"], false);

    // The header right: the unknown id is listed with the rest.
    std::fs::write(dir.join(rest[2].file), &rest[2].right).unwrap();
    let c = check(&file);
    assert_eq!(c.code, Some(2), "{}", c.stderr);
    lists(&c, dir, unknown_id);
    for m in rest.iter().filter(|m| m.file != rest[2].file) {
        lists(&c, dir, m);
    }

    // Each fixed in turn: it is no longer listed, the others still are; all fixed passes.
    let mut left: Vec<&Mistake> = all.iter().filter(|m| m.file != rest[2].file).collect();
    while let Some(m) = left.pop() {
        std::fs::write(dir.join(m.file), &m.right).unwrap();
        let c = check(&file);
        let path = dir.join(m.file).display().to_string();
        if left.is_empty() {
            assert_eq!(c.code, Some(0), "all fixed: {}", c.stderr);
        } else {
            assert_eq!(c.code, Some(2), "{}", c.stderr);
            assert!(
                !c.stderr
                    .lines()
                    .any(|l| l.starts_with(&format!("{path}:"))
                        && m.words.iter().all(|w| l.contains(w))),
                "{} fixed, still listed: {}",
                m.file,
                c.stderr
            );
            for o in &left {
                lists(&c, dir, o);
            }
        }
        no_output(dir);
    }
}

#[test]
fn run_refuses_the_mistakes_before_any_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let file = project(dir);
    let all = mistakes();
    for m in &all {
        std::fs::write(dir.join(m.file), &m.wrong).unwrap();
    }
    let c = cli_confined(&["run", file.to_str().unwrap()]);
    c.refused_cleanly(5.0, &["problem(s) in the project's inputs"]);
    assert_eq!(c.code, Some(2), "{}", c.stderr);
    for m in &all[..5] {
        lists(&c, dir, m);
    }
    let stages: Vec<_> = std::fs::read_dir(dir.join("out"))
        .map(|d| d.flatten().map(|e| e.file_name()).collect())
        .unwrap_or_default();
    assert!(
        stages
            .iter()
            .all(|n| n.to_string_lossy().starts_with('.') || n == "stages.json"),
        "a stage ran: {stages:?}"
    );
    // Through the C ABI: INVALID_ARGUMENT, every problem in the message.
    let p = std::ffi::CString::new(file.to_str().unwrap()).unwrap();
    let mut json = std::ptr::null_mut();
    // SAFETY: a NUL-terminated path and a valid out pointer.
    let st = unsafe { cloudcontrol::ffi::ccp_project_run(p.as_ptr(), &mut json) };
    assert_eq!(st, cloudcontrol::ffi::CcpStatus::InvalidArgument);
    assert!(json.is_null());
    let e = common::last_error();
    for m in &all[..5] {
        assert!(e.contains(&dir.join(m.file).display().to_string()), "{e}");
    }
}
