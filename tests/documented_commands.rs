//! Every command the documentation shows works as written (issue 52): each command of the
//! README's `sh` blocks, in order, from a fresh folder (a `cd` there moves the later ones;
//! a `toml` block whose first line is `# NAME` is written to NAME first), then every
//! `Example:` of every `--help` (the command tree is walked from `cloudcontrol --help`),
//! in the demo's folder (`demo` itself where the README ran it), in the order of a user's
//! workflow ([`WORKFLOW`]). A command
//! passes when it exits 0 and every file it names as an output (`--out`, `--out-dir`,
//! `--report`, `--into`, `> file`, …) exists afterwards.
//!
//! Commands run exactly as written, through `sh -c`, with the binary under test first on
//! the PATH, except the few of [`SUBSTITUTIONS`], each with its reason. The inputs an
//! example names that a user would have (their LiDAR tiles, a camera file, scans, a
//! strips file, …) are made from the demo's block before the examples run
//! ([`prepare_inputs`]); what an example makes (a DEM, a DCP package, …), a later one
//! reads.
//!
//! Besides: the demo's log (stdout and stderr to a file) holds no escape code, no `..` in a
//! path and a line per stage and photo, its warnings name their epoch; `lidar catalogue
//! … | head -1` exits 0 under `pipefail` and still writes its `--out`; `--json` gives
//! JSON for `version`, `run --check` and errors.

mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_cloudcontrol")
}

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Documented commands run otherwise than written: (the command as written without its
/// trailing comment, what runs instead or `None` for not at all, why). Every other
/// documented command runs exactly as written.
const SUBSTITUTIONS: &[(&str, Option<&str>, &str)] = &[
    (
        "./setup.sh && ./target/release/cloudcontrol demo",
        Some("cloudcontrol demo"),
        "setup.sh installs system packages and builds the release binary; the test runs the \
         binary cargo built for it, from the test's folder",
    ),
    (
        "./test.sh",
        None,
        "runs every test of the repository, this one included",
    ),
    (
        "cloudcontrol synth --preset medium --seed 3 --out blk && cloudcontrol run blk/project.toml",
        Some("cloudcontrol synth --preset tiny --seed 3 --out blk && cloudcontrol run --check blk/project.toml"),
        "a medium block is ~100 reference photos and 24 film scans of 32 MP (tens of \
         minutes), a small one three and a half (the demo, the README's first command, is \
         these two steps on it); the tiny block is made and its project checked (its run \
         ends partial: the tiny film is too coarse for the fiducials)",
    ),
    (
        "cloudcontrol synth --out synthetic --preset small --seed 3",
        Some("cloudcontrol synth --out synthetic --preset tiny --seed 3"),
        "the small block takes 80 s to render and the demo rendered one; the tiny one \
         exercises the command in seconds",
    ),
    (
        "cloudcontrol bench accuracy --preset small --seeds 1..10",
        Some("cloudcontrol bench accuracy --preset tiny --seeds 2"),
        "each seed is a whole run (a minute per small block): one tiny block exercises the \
         command (its film epoch, too coarse for the fiducials, is reported as a miss)",
    ),
    (
        "cloudcontrol bench accuracy --preset small --seeds 1..10 --control orthophoto",
        Some("cloudcontrol bench accuracy --preset tiny --seeds 2 --control orthophoto"),
        "as above",
    ),
    (
        "cloudcontrol bench accuracy --preset small --seeds 1..3",
        Some("cloudcontrol bench accuracy --preset tiny --seeds 2"),
        "as above",
    ),
    (
        "cloudcontrol bench patches --out bench_patches",
        Some("cloudcontrol bench patches --out bench_patches --preset tiny --draws 1"),
        "orients both archive epochs of a small block 24 times (about 10 minutes); the tiny \
         block with one draw per group runs the same steps in seconds",
    ),
];

/// The order in which the `--help` examples run: a user's workflow, so that an example
/// finds the files the earlier ones made. Every example's command must be listed.
const WORKFLOW: &[&str] = &[
    "version",
    "demo",
    "run",
    "synth",
    "lidar info",
    "lidar catalogue",
    "lidar eval",
    "lidar clean",
    "lidar dem",
    "icp",
    "dcp generate",
    "dcp export",
    "dcp info",
    "dcp from-orthophoto",
    "dcp merge",
    "dcp import",
    "convert",
    "ortho",
    "dsm",
    "change",
    "adjust",
    "resect",
    "io",
    "match",
    "ties",
    "orient",
    "bench accuracy",
    "bench patches",
];

/// Options whose value is a file or folder the command writes.
const OUTPUT_OPTIONS: &[&str] = &["--out", "--out-dir", "--report", "--into", "--out-block"];

/// One step of the README: a command, or a file to write.
#[derive(Debug)]
enum Step {
    Command(String),
    File(String, String),
}

/// The README's `sh` commands (lines joined at a trailing `\`) and its `toml` blocks that
/// name their file in their first line, in document order.
fn readme_steps(text: &str) -> Vec<Step> {
    let mut steps = Vec::new();
    let mut lines = text.lines();
    while let Some(l) = lines.next() {
        let fence = l.trim_start();
        let Some(lang) = fence.strip_prefix("```") else {
            continue;
        };
        let lang = lang.trim().to_string();
        let mut block = Vec::new();
        for b in lines.by_ref() {
            if b.trim_start().starts_with("```") {
                break;
            }
            block.push(b.to_string());
        }
        match lang.as_str() {
            "sh" => {
                let mut cur = String::new();
                for b in block {
                    let t = b.trim();
                    if let Some(head) = t.strip_suffix('\\') {
                        cur.push_str(head.trim_end());
                        cur.push(' ');
                        continue;
                    }
                    cur.push_str(t);
                    let cmd = std::mem::take(&mut cur);
                    let cmd = cmd.trim();
                    if !cmd.is_empty() && !cmd.starts_with('#') {
                        steps.push(Step::Command(cmd.to_string()));
                    }
                }
            }
            "toml" => {
                if let Some(name) = block
                    .first()
                    .and_then(|f| f.strip_prefix("# "))
                    .map(str::trim)
                    .filter(|n| !n.contains(' '))
                {
                    steps.push(Step::File(name.to_string(), block.join("\n") + "\n"));
                }
            }
            _ => {}
        }
    }
    steps
}

/// A command without its trailing shell comment (`  # …`).
fn without_comment(cmd: &str) -> &str {
    match cmd.find(" #") {
        Some(i) => cmd[..i].trim_end(),
        None => cmd,
    }
}

/// `cloudcontrol --help`'s commands, then theirs, … : every (sub)command path.
fn command_tree() -> Vec<Vec<String>> {
    let mut out = vec![Vec::new()];
    let mut k = 0;
    while k < out.len() {
        let path = out[k].clone();
        for c in subcommands(&help(&path)) {
            let mut p = path.clone();
            p.push(c);
            out.push(p);
        }
        k += 1;
    }
    out
}

fn help(path: &[String]) -> String {
    let o = Command::new(exe())
        .args(path)
        .arg("--help")
        .output()
        .unwrap();
    assert!(o.status.success(), "cloudcontrol {path:?} --help: {o:?}");
    String::from_utf8(o.stdout).unwrap()
}

/// The command names of a help text's `Commands:` section (not `help`).
fn subcommands(help: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut inside = false;
    for l in help.lines() {
        if l.starts_with("Commands:") {
            inside = true;
            continue;
        }
        if inside {
            if !l.starts_with("  ") {
                if l.trim().is_empty() {
                    continue;
                }
                break;
            }
            // An entry starts two spaces in; its description may run on deeper.
            if l.starts_with("   ") {
                continue;
            }
            if let Some(name) = l.split_whitespace().next() {
                if name != "help" {
                    out.push(name.to_string());
                }
            }
        }
    }
    out
}

/// The commands of a help text's `Example:` lines: the text after `Example…:` when it
/// holds the command, else the next non-empty lines (joined at a trailing `\`).
fn examples(help: &str) -> Vec<String> {
    let lines: Vec<&str> = help.lines().collect();
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim();
        if !t.starts_with("Example") {
            continue;
        }
        let Some(colon) = t.find(':') else { continue };
        let rest = t[colon + 1..].trim();
        let mut cmd = String::new();
        let more: Box<dyn Iterator<Item = &str>> = if rest.is_empty() {
            Box::new(
                lines[i + 1..]
                    .iter()
                    .map(|s| s.trim())
                    .filter(|s| !s.is_empty()),
            )
        } else {
            Box::new(std::iter::once(rest))
        };
        for part in more {
            match part.strip_suffix('\\') {
                Some(head) => {
                    cmd.push_str(head.trim_end());
                    cmd.push(' ');
                }
                None => {
                    cmd.push_str(part);
                    break;
                }
            }
        }
        assert!(
            cmd.starts_with("cloudcontrol "),
            "an example is a cloudcontrol command line: {t:?} → {cmd:?}"
        );
        out.push(cmd);
    }
    out
}

/// The subcommand words of a command line (`dcp export`, `orient`), global options left out.
fn subcommand_of(cmd: &str) -> String {
    let words: Vec<&str> = cmd
        .split_whitespace()
        .skip(1)
        .filter(|w| !w.starts_with('-'))
        .take(2)
        .collect();
    for n in [2, 1] {
        let key = words[..n.min(words.len())].join(" ");
        if WORKFLOW.contains(&key.as_str()) {
            return key;
        }
    }
    panic!("the example {cmd:?} is of a command missing from WORKFLOW");
}

/// The files a command names as its outputs, relative to its folder.
fn outputs(cmd: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let words: Vec<&str> = cmd.split_whitespace().collect();
    for (k, w) in words.iter().enumerate() {
        let next = words.get(k + 1).copied();
        if OUTPUT_OPTIONS.contains(w) || *w == ">" {
            if let Some(v) = next {
                out.push(PathBuf::from(v));
            }
        } else if let Some(v) = OUTPUT_OPTIONS
            .iter()
            .find_map(|o| w.strip_prefix(&format!("{o}=")))
        {
            out.push(PathBuf::from(v));
        }
    }
    // `convert IN OUT`: its second operand.
    if let Some(k) = words.iter().position(|w| *w == "convert") {
        let operands: Vec<&&str> = words[k + 1..]
            .iter()
            .take_while(|w| **w != "&&")
            .filter(|w| !w.starts_with('-'))
            .collect();
        if let Some(o) = operands.get(1) {
            out.push(PathBuf::from(**o));
        }
    }
    out
}

/// A command's run: its exit code and its output (stdout and stderr, in one file as
/// `> log 2>&1` gives them).
struct Ran {
    code: Option<i32>,
    log: String,
    seconds: f64,
}

fn path_env() -> std::ffi::OsString {
    let bin = Path::new(exe()).parent().unwrap();
    let mut paths = vec![bin.to_path_buf()];
    paths.extend(std::env::split_paths(
        &std::env::var_os("PATH").unwrap_or_default(),
    ));
    std::env::join_paths(paths).unwrap()
}

/// Runs `cmd` with `shell -c` in `dir`, stdout and stderr into one log file.
fn run_shell(shell: &str, cmd: &str, dir: &Path, log: &Path) -> Ran {
    let file = std::fs::File::create(log).unwrap();
    let t = Instant::now();
    let status = Command::new(shell)
        .arg("-c")
        .arg(cmd)
        .current_dir(dir)
        .env("PATH", path_env())
        .env_remove("CLOUDCONTROL_LOG")
        .stdin(Stdio::null())
        .stdout(file.try_clone().unwrap())
        .stderr(file)
        .status()
        .unwrap();
    Ran {
        code: status.code(),
        log: std::fs::read_to_string(log).unwrap_or_default(),
        seconds: t.elapsed().as_secs_f64(),
    }
}

/// The state of the documented-command run: where the next command runs, what ran.
struct Runner {
    root: PathBuf,
    cwd: PathBuf,
    logs: PathBuf,
    count: usize,
    ran: Vec<(String, f64)>,
    seen: BTreeSet<String>,
}

impl Runner {
    /// Runs a documented command (substituted where [`SUBSTITUTIONS`] says) and asserts
    /// that it worked: exit 0, its output files there. `None` when it is not run at all.
    fn run(&mut self, cmd: &str) -> Option<Ran> {
        if let Some(dir) = cmd.strip_prefix("cd ") {
            self.cwd = self.cwd.join(dir.trim());
            assert!(self.cwd.is_dir(), "{cmd}: no folder {}", self.cwd.display());
            return None;
        }
        let key = without_comment(cmd);
        let actual = match SUBSTITUTIONS.iter().find(|s| s.0 == key) {
            Some((_, None, _)) => return None,
            Some((_, Some(to), _)) => to.to_string(),
            None => cmd.to_string(),
        };
        self.count += 1;
        let log = self.logs.join(format!("{:03}.log", self.count));
        let r = run_shell("sh", &actual, &self.cwd, &log);
        eprintln!(
            "[{:>5.1} s] {} ({})",
            r.seconds,
            actual,
            self.cwd
                .strip_prefix(&self.root)
                .unwrap_or(&self.cwd)
                .display()
        );
        assert_eq!(
            r.code,
            Some(0),
            "documented command failed: {actual}\nin {}\n{}",
            self.cwd.display(),
            r.log
        );
        for o in outputs(&actual) {
            assert!(
                self.cwd.join(&o).exists(),
                "{actual}: its output {} is missing\n{}",
                o.display(),
                r.log
            );
        }
        self.ran.push((actual, r.seconds));
        Some(r)
    }
}

/// Copies the files of `from` (not its folders) into `to`.
fn copy_files(from: &Path, to: &Path, keep: impl Fn(&str) -> bool) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_file() && keep(&name) {
            std::fs::copy(&p, to.join(&name)).unwrap();
        }
    }
}

/// Rows of a CSV file with a header, as maps of column → value (the synthetic block's
/// files: no quoting).
fn csv_rows(path: &Path) -> Vec<std::collections::BTreeMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty());
    let head: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    lines
        .map(|l| {
            head.iter()
                .cloned()
                .zip(l.split(',').map(|s| s.trim().to_string()))
                .collect()
        })
        .collect()
}

/// The inputs the `--help` examples name that a user would have, made in the demo's
/// folder `d` from its block and run: (file, what it stands for).
fn prepare_inputs(d: &Path) -> Vec<(&'static str, &'static str)> {
    let block = d.join("block");
    // LiDAR tiles.
    copy_files(&block.join("lidar"), &d.join("tiles"), |n| {
        n.ends_with(".las")
    });
    // A film camera's calibration certificate, by a bare file name (issue 52, item 1).
    std::fs::copy(
        block.join("epochs/film_1978/camera.json"),
        d.join("rc10.json"),
    )
    .unwrap();
    // Three scans of the first film strip, with the strip's end points from the rough POS
    // (as a flight map gives them).
    let film = block.join("epochs/film_1978");
    copy_files(&film.join("images"), &d.join("scans"), |n| {
        n.starts_with("film_s01_")
    });
    let pos = csv_rows(&film.join("pos.csv"));
    let strip: Vec<_> = pos
        .iter()
        .filter(|r| r["name"].starts_with("film_s01_"))
        .collect();
    // The strip flies north and the scans have image x east (the POS's kappa is about
    // 0): forward along the flight is image up, `-y` (formats/pos/).
    let y = |r: &std::collections::BTreeMap<String, String>| r["y"].parse::<f64>().unwrap();
    assert!(y(strip[strip.len() - 1]) > y(strip[0]) + 1000.0);
    let mut strips = String::from("strip,photo,x,y,z,flight_axis\n");
    for (k, r) in strip.iter().enumerate() {
        if k == 0 || k + 1 == strip.len() {
            strips += &format!("1,{},{},{},{},-y\n", r["name"], r["x"], r["y"], r["z"]);
        } else {
            strips += &format!("1,{},,,,-y\n", r["name"]);
        }
    }
    std::fs::write(d.join("strips.csv"), strips).unwrap();
    // Digital photos.
    copy_files(
        &block.join("epochs/reference_2024/images"),
        &d.join("photos"),
        |_| true,
    );
    // A COLMAP text model of the oriented reference photos.
    let o = Command::new(exe())
        .args([
            "convert",
            "run/outputs-reference_2024/colmap",
            "sparse/0",
            "--text",
        ])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(o.status.success(), "{o:?}");
    // Surveyed points and their image measurements in the reference photos.
    std::fs::copy(block.join("checkpoints.csv"), d.join("gcp.csv")).unwrap();
    let mut img = String::from("id,image_name,x,y\n");
    for r in csv_rows(&block.join("truth/checkpoint_images.csv")) {
        if r["epoch"] == "reference_2024" {
            img += &format!("{},{},{},{}\n", r["id"], r["photo"], r["col"], r["row"]);
        }
    }
    std::fs::write(d.join("gcp_img.csv"), img).unwrap();
    // Control points of one reference photo (pixel, world) from the reference's DCPs.
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(d.join("run/dcp-reference_2024/package/manifest.json")).unwrap(),
    )
    .unwrap();
    let points = manifest["points"].as_array().unwrap();
    let mut per_photo = std::collections::BTreeMap::<u64, Vec<String>>::new();
    for p in points {
        let xyz = &p["xyz"];
        for m in p["measurements"].as_array().unwrap() {
            per_photo
                .entry(m["photo"].as_u64().unwrap())
                .or_default()
                .push(format!(
                    "{},{},{},{},{}",
                    m["pixel"][0], m["pixel"][1], xyz[0], xyz[1], xyz[2]
                ));
        }
    }
    let best = per_photo.values().max_by_key(|v| v.len()).unwrap();
    assert!(best.len() >= 6, "{} control points", best.len());
    std::fs::write(
        d.join("control.csv"),
        format!("x,y,X,Y,Z\n{}\n", best.join("\n")),
    )
    .unwrap();
    // A photo and a chip cut from it, inside the example's search window.
    let photo = block.join("epochs/reference_2024/images/reference_s01_002.png");
    std::fs::copy(&photo, d.join("photo.png")).unwrap();
    let im = image::open(&photo).unwrap();
    im.crop_imm(470, 370, 61, 61)
        .save(d.join("chip.png"))
        .unwrap();
    // Tie points (world X,Y,Z) as CSV and PLY, from the COLMAP model (block-local, its
    // origin in the side file).
    let georef: serde_json::Value = serde_json::from_slice(
        &std::fs::read(d.join("sparse/0/cloudcontrol_georef.json")).unwrap(),
    )
    .unwrap();
    let origin: Vec<f64> = (0..3)
        .map(|i| georef["origin"][i].as_f64().unwrap())
        .collect();
    let mut xyz = Vec::new();
    for l in std::fs::read_to_string(d.join("sparse/0/points3D.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
    {
        let f: Vec<f64> = l
            .split_whitespace()
            .skip(1)
            .take(3)
            .map(|v| v.parse().unwrap())
            .collect();
        if f.len() == 3 {
            xyz.push(format!(
                "{},{},{}",
                f[0] + origin[0],
                f[1] + origin[1],
                f[2] + origin[2]
            ));
        }
    }
    std::fs::write(
        d.join("tie_points.csv"),
        format!("X,Y,Z\n{}\n", xyz.join("\n")),
    )
    .unwrap();
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\n\
         property double z\nend_header\n",
        xyz.len()
    );
    for p in &xyz {
        ply += &p.replace(',', " ");
        ply.push('\n');
    }
    std::fs::write(d.join("tie_points.ply"), ply).unwrap();
    vec![
        ("tiles/", "the user's LiDAR tiles (the demo's)"),
        (
            "rc10.json",
            "a film camera's calibration certificate (the demo's RC10)",
        ),
        ("scans/", "three film scans of one strip"),
        (
            "strips.csv",
            "that strip's end points, from the demo's rough POS",
        ),
        ("photos/", "digital photos (the demo's reference flight)"),
        (
            "sparse/0/",
            "a COLMAP text model (the run's reference epoch)",
        ),
        ("gcp.csv", "surveyed points (the demo's checkpoints)"),
        ("gcp_img.csv", "their measurements in the reference photos"),
        (
            "control.csv",
            "control points of one photo (the reference DCPs)",
        ),
        ("photo.png, chip.png", "a photo and a chip cut from it"),
        ("tie_points.csv, .ply", "tie points (the reference model's)"),
    ]
}

#[test]
fn documented_commands_run_as_written() {
    let t0 = Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().to_path_buf();
    let logs = root.join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    let mut r = Runner {
        root: root.clone(),
        cwd: root.clone(),
        logs,
        count: 0,
        ran: Vec::new(),
        seen: BTreeSet::new(),
    };

    // 1. The README, in order.
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let steps = readme_steps(&readme);
    assert!(steps.len() >= 10, "{steps:?}");
    let mut demo_log = None;
    for s in &steps {
        match s {
            Step::File(name, text) => std::fs::write(r.cwd.join(name), text).unwrap(),
            Step::Command(cmd) => {
                let first_demo =
                    demo_log.is_none() && without_comment(cmd).ends_with("cloudcontrol demo");
                if first_demo {
                    // The demo ran once for the test binaries (150 s on 2 cores; its log
                    // kept): here it runs as written over a copy of it, which finds every
                    // stage done. Its log is checked with the first run's.
                    let shared = common::shared_demo();
                    common::copy_block(&shared, &r.cwd.join("cloudcontrol_demo"));
                    demo_log = Some(std::fs::read_to_string(shared.join("demo.log")).unwrap());
                }
                let ran = r.run(cmd);
                if first_demo {
                    let again = ran.expect("the demo ran").log;
                    assert!(again.contains("skipped"), "{again}");
                    demo_log_is_plain(&again, false);
                }
                r.seen.insert(cmd.clone());
            }
        }
    }
    let readme_count = r.ran.len();

    // The demo's log, stdout and stderr to one file.
    let log = demo_log.expect("the README runs the demo");
    demo_log_is_plain(&log, true);

    // 2. Every `--help` example, in the demo's folder.
    let demo = root.join("cloudcontrol_demo");
    let prepared = prepare_inputs(&demo);
    let mut all = Vec::new();
    for path in command_tree() {
        for e in examples(&help(&path)) {
            if !all.contains(&e) {
                all.push(e);
            }
        }
    }
    assert!(all.len() >= 25, "{all:#?}");
    let rank = |c: &String| WORKFLOW.iter().position(|w| *w == subcommand_of(c));
    all.sort_by_key(rank);
    for e in &all {
        // `demo` where the README ran it (a second run: its block and stages are reused);
        // every other example in the demo's folder.
        r.cwd = if subcommand_of(e) == "demo" {
            root.clone()
        } else {
            demo.clone()
        };
        r.run(e);
    }

    // 3. A closed stdout: the reader's exit ends the output, not the command.
    closed_pipe(&demo);
    json_everywhere(&demo);

    let total = t0.elapsed().as_secs_f64();
    eprintln!(
        "{} README commands and {} help examples ran in {total:.0} s; prepared inputs: {prepared:?}",
        readme_count,
        r.ran.len() - readme_count
    );
}

/// `cloudcontrol demo > log 2>&1`: no escape code, no `..` component in a path, a line per
/// stage and per photo (`ran`: of a demo that ran its stages), and every warning names its
/// epoch.
fn demo_log_is_plain(log: &str, ran: bool) {
    assert!(
        !log.contains('\u{1b}'),
        "escape codes in the demo's log:\n{log}"
    );
    for l in log.lines() {
        assert!(
            !l.contains("/../") && !l.contains(" ../") && !l.ends_with("/.."),
            "a path with `..` in the demo's log: {l}"
        );
    }
    assert!(log.contains("epoch-film_1978"), "{log}");
    // Stage lines `[i/n] name`: numbered up to the count announced, which is the count run.
    let counts: Vec<(usize, usize)> = log
        .lines()
        .filter_map(|l| l.strip_prefix('[')?.split_once(']')?.0.split_once('/'))
        .filter_map(|(i, n)| Some((i.parse().ok()?, n.parse().ok()?)))
        .collect();
    assert!(
        counts.last().is_some_and(|&(i, n)| i == n) && counts.iter().all(|&(i, n)| i <= n),
        "stage numbers {counts:?}"
    );
    assert!(
        !ran || log
            .lines()
            .any(|l| l.contains("epoch-film_1978") && l.contains("film_s01_001")),
        "no per-photo line of the film epoch:\n{log}"
    );
    for l in log.lines().filter(|l| l.contains(" WARN ")) {
        assert!(
            l.contains("epoch{name="),
            "a warning without its epoch: {l}"
        );
    }
}

/// `lidar catalogue … | head -1` exits 0 under pipefail, and a reader that closes the pipe
/// before the first line (`head -n 0`) neither fails the command nor stops its `--out`.
fn closed_pipe(demo: &Path) {
    // Debian's sh (dash) has no pipefail: bash runs these pipelines.
    for (cmd, out) in [
        (
            "set -o pipefail; cloudcontrol lidar catalogue tiles/ | head -1",
            None,
        ),
        (
            "set -o pipefail; cloudcontrol lidar catalogue tiles/ --out piped.json | head -n 0",
            Some("piped.json"),
        ),
        (
            "set -o pipefail; cloudcontrol --json lidar catalogue tiles/ | head -c 10",
            None,
        ),
    ] {
        let r = run_shell("bash", cmd, demo, &demo.join("pipe.log"));
        assert_eq!(r.code, Some(0), "{cmd}: {}", r.log);
        assert!(!r.log.contains("panicked"), "{cmd}: {}", r.log);
        if let Some(o) = out {
            assert!(demo.join(o).is_file(), "{cmd}: no {o}");
        }
    }
}

/// `--json` holds for `version`, `run --check` and errors (with the input and the status).
fn json_everywhere(demo: &Path) {
    let json = |args: &[&str]| {
        let o = Command::new(exe())
            .args(args)
            .current_dir(demo)
            .output()
            .unwrap();
        let v: serde_json::Value = serde_json::from_slice(&o.stdout)
            .unwrap_or_else(|e| panic!("{args:?}: {e}: {}", String::from_utf8_lossy(&o.stdout)));
        (o.status.code(), v)
    };
    let (code, v) = json(&["--json", "version"]);
    assert_eq!(code, Some(0));
    assert_eq!(v["version"], env!("CARGO_PKG_VERSION"));
    let (code, v) = json(&["run", "--check", "--json", "block/project.toml"]);
    assert_eq!(code, Some(0), "{v}");
    assert_eq!(v["valid"], true, "{v}");
    assert_eq!(v["archive"][1], "film_1978", "{v}");
    // The output folder `../run` of block/project.toml, printed without its `..`.
    assert!(!v["output"].as_str().unwrap().contains(".."), "{v}");
    let (code, v) = json(&["--json", "dcp", "info", "no_such.dcp"]);
    assert_eq!(code, Some(1), "{v}");
    assert_eq!(v["error"]["exit_status"], 1, "{v}");
    assert_eq!(v["error"]["input"], "no_such.dcp", "{v}");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("no_such.dcp"),
        "{v}"
    );
    let (code, v) = json(&["--json", "run", "missing.toml"]);
    assert_eq!(code, Some(2), "{v}");
    assert_eq!(v["error"]["command"], "run", "{v}");
    assert_eq!(v["error"]["input"], "missing.toml", "{v}");
    let (code, v) = json(&["--json", "run", "--no-such-option"]);
    assert_eq!(code, Some(2), "{v}");
    assert_eq!(v["error"]["exit_status"], 2, "{v}");
}

/// Every option and argument of every command says what it is (`--help`).
#[test]
fn every_option_has_a_help_line() {
    let mut missing = Vec::new();
    for path in command_tree() {
        let text = help(&path);
        let mut section = "";
        let lines: Vec<&str> = text.lines().collect();
        for (k, l) in lines.iter().enumerate() {
            if !l.starts_with(' ') && l.ends_with(':') {
                section = l;
                continue;
            }
            if section != "Options:" && section != "Arguments:" {
                continue;
            }
            let t = l.trim_start();
            let indent = l.len() - t.len();
            let entry =
                indent == 2 && (t.starts_with('-') || t.starts_with('<') || t.starts_with('['));
            if !entry {
                continue;
            }
            // The description follows the name on its line, or on the next lines, deeper.
            let same_line = t.split("  ").skip(1).any(|s| !s.trim().is_empty());
            let next_line = lines.get(k + 1).is_some_and(|n| {
                let nt = n.trim_start();
                n.len() - nt.len() > 2 && !nt.is_empty() && !nt.starts_with('-')
            });
            if !same_line && !next_line {
                missing.push(format!("cloudcontrol {} {t}", path.join(" ")));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "options without help:\n{}",
        missing.join("\n")
    );
}

/// The help of `bench` reads as one text (issue 52: two doc comments ran together), and
/// no user-facing text names the paper's table.
#[test]
fn bench_help_reads_well() {
    let text = help(&["bench".to_string()]);
    assert!(
        text.contains("accuracy") && text.contains("patches"),
        "{text}"
    );
    for path in command_tree() {
        let h = help(&path);
        assert!(
            !h.contains("table13") && !h.contains("table 1.3") && !h.contains("Table 1.3"),
            "cloudcontrol {}: {h}",
            path.join(" ")
        );
    }
    // The old name still runs, hidden.
    let o = Command::new(exe())
        .args(["bench-table13", "--help"])
        .output()
        .unwrap();
    assert!(o.status.success());
    assert!(!help(&[]).contains("bench-table13"));
}

/// `demo --preset tiny` is refused by the argument parser, saying why (exit 2).
#[test]
fn demo_refuses_the_tiny_preset() {
    let tmp = tempfile::tempdir().unwrap();
    let o = Command::new(exe())
        .args(["demo", "--preset", "tiny", "--out"])
        .arg(tmp.path().join("d"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("tiny") && err.contains("small"), "{err}");
    assert!(!tmp.path().join("d").exists());
}

#[test]
fn paths_are_normalised_lexically() {
    use cloudcontrol::formats::paths::{folder_of, normalise};
    for (p, n) in [
        ("/data/block/../run/x", "/data/run/x"),
        ("/data/./block/./../run", "/data/run"),
        ("block/../../run", "../run"),
        ("../a/./b/..", "../a"),
        ("/..", "/"),
        ("", "."),
        (".", "."),
        ("a/..", "."),
    ] {
        assert_eq!(normalise(Path::new(p)), PathBuf::from(n), "{p}");
    }
    assert_eq!(folder_of(Path::new("rc10.json")), Path::new("."));
    assert_eq!(folder_of(Path::new("cams/rc10.json")), Path::new("cams"));
    assert_eq!(folder_of(Path::new("/rc10.json")), Path::new("/"));
}

/// A film camera file named by a bare file name, as `io` and `orient` take it (issue 52,
/// item 1: its empty folder was refused as `camera folder : No such file or directory`):
/// the camera is read, and the error is the missing scan's.
#[test]
fn a_camera_file_by_its_bare_name() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(
        repo().join("formats/cameras/wild_rc10.json"),
        tmp.path().join("rc10.json"),
    )
    .unwrap();
    // `orient --camera rc10.json` is one of the `--help` examples the long test runs.
    let o = Command::new(exe())
        .args(["io", "--camera", "rc10.json", "missing_scan.png"])
        .current_dir(tmp.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("camera folder"), "{err}");
    assert!(err.contains("missing_scan.png"), "{err}");
}

/// Fields are trimmed (formats/README.md), so a quoted field may follow the comma after a
/// blank: `a, "b, c"` holds `b, c`.
#[test]
fn a_quoted_field_after_a_blank() {
    use cloudcontrol::formats::csv::{parse_records, Extra, Layout};
    #[derive(serde::Deserialize, Debug)]
    struct Row {
        name: String,
        x: f64,
        note: Option<String>,
    }
    let layout = Layout {
        required: &["name", "x"],
        optional: &["note"],
        extra: Extra::Refuse,
    };
    let text = "name, x, note\n  \"ref 001, left.tif\", \"1.5\" , \"a \"\"b\"\"\"\nplain,\t2, \"multi\nline\"\n";
    let t = parse_records::<Row>(Path::new("t.csv"), text, &layout).unwrap();
    assert_eq!(t.rows.len(), 2, "{:?}", t.rows);
    assert_eq!(t.rows[0].1.name, "ref 001, left.tif");
    assert_eq!(t.rows[0].1.x, 1.5);
    assert_eq!(t.rows[0].1.note.as_deref(), Some("a \"b\""));
    assert_eq!(t.rows[1].1.name, "plain");
    assert_eq!(t.rows[1].1.note.as_deref(), Some("multi\nline"));
}
