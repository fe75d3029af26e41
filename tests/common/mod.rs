//! Helpers shared by the end-to-end tests that run the `cloudcontrol` binary and read its
//! JSON (each test binary uses the part it needs).
#![allow(dead_code)]

use serde_json::Value;

pub fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_cloudcontrol")
}

/// Exit status of a run that finished with an epoch orienting fewer photos than it has
/// (README.md, "Exit statuses").
pub const EXIT_PARTIAL: i32 = 3;

/// Whether a command finished: exit 0, or [`EXIT_PARTIAL`] (its products and summary are
/// written; the tests then look at what was oriented).
pub fn finished(out: &std::process::Output) -> bool {
    matches!(out.status.code(), Some(0 | EXIT_PARTIAL))
}

/// The JSON a command that finished ([`finished`]) printed on stdout (the command's stderr
/// when it failed).
pub fn json_of(out: &std::process::Output) -> Value {
    assert!(
        finished(out),
        "exit {:?}: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

/// Epoch `name` of a run report.
pub fn epoch<'a>(report: &'a Value, name: &str) -> &'a Value {
    report["epochs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == name)
        .unwrap_or_else(|| panic!("no epoch {name}"))
}

/// A length of an epoch report (`key`, metres; NaN when null) in the epoch's ground pixels.
pub fn px(e: &Value, key: &str) -> f64 {
    e[key].as_f64().unwrap_or(f64::NAN) / e["gsd_m"].as_f64().unwrap()
}

/// Runs the binary with `args`: success, stdout, stderr.
pub fn cli(args: &[&str]) -> (bool, String, String) {
    cli_in(std::path::Path::new("."), args)
}

/// [`cli`] run from the folder `dir`.
pub fn cli_in(dir: &std::path::Path, args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(exe())
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A folder made once per build of the binary by `make` and shared by every test binary
/// and the Python tests (`CARGO_TARGET_TMPDIR/blocks/<key>`). A stamp of the binary (size
/// and modification time) written beside it once it is complete makes a rebuilt binary
/// make it again. It is made in a private folder and renamed into place, or (`in_place`:
/// a run's products name their inputs by absolute paths, which must stay valid) made
/// where it stays, its stamp removed first. Tests take a [`copy_block`] of it, never the
/// shared folder itself.
///
/// The check and the making happen under an exclusive `flock` of `<key>.lock` beside it:
/// test.sh runs the Python tests beside the Rust tests, and both share these folders
/// (bindings/python/tests/conftest.py takes the same lock). Once stamped, a folder is not
/// touched again by this build, so copies need no lock. The lock is the library's
/// (`formats::Lock`), which also keeps this binary's threads apart.
fn shared_folder(
    key: &str,
    in_place: bool,
    make: impl FnOnce(&std::path::Path),
) -> std::path::PathBuf {
    let root = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("blocks");
    std::fs::create_dir_all(&root).unwrap();
    let lock_file = root.join(format!("{key}.lock"));
    std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock_file)
        .unwrap();
    let held = cloudcontrol::formats::Lock::exclusive(&lock_file, true).unwrap();
    let dir = root.join(key);
    let stamp_file = root.join(format!("{key}.stamp"));
    let meta = std::fs::metadata(exe()).unwrap();
    let modified = meta
        .modified()
        .unwrap()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    let stamp = format!("{}-{}", meta.len(), modified.as_nanos());
    if dir.is_dir() && std::fs::read_to_string(&stamp_file).is_ok_and(|s| s.trim() == stamp) {
        return dir;
    }
    let _ = std::fs::remove_file(&stamp_file);
    if in_place {
        let _ = std::fs::remove_dir_all(&dir);
        make(&dir);
    } else {
        let tmp = root.join(format!(".{key}.{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        make(&tmp);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::rename(&tmp, &dir).unwrap();
    }
    std::fs::write(&stamp_file, stamp).unwrap();
    drop(held);
    dir
}

/// A synthetic block (`<preset>-<seed>-<pos>`, a [`shared_folder`]): a small block costs
/// 66 CPU s to render (37 s on 2 cores, 2026-11-30; 120–140 CPU s on slower days), and
/// the Rust and Python tests use eight of them, most more than once.
pub fn shared_block(preset: &str, seed: u64, pos: &str) -> std::path::PathBuf {
    shared_folder(&format!("{preset}-{seed}-{pos}"), false, |tmp| {
        let o = std::process::Command::new(exe())
            .args(["synth", "-q", "--preset", preset, "--pos", pos])
            .args(["--seed", &seed.to_string(), "--out"])
            .arg(tmp)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    })
}

/// `cloudcontrol demo > demo.log 2>&1` run once (a [`shared_folder`] `demo`: the demo's
/// block and run, and its log `demo.log` beside them), from the shared block the demo makes
/// (small, seed 7, rough POS). The README's first command and `pipeline_run` both need a
/// finished demo, which takes 150 s on 2 cores; a copy of this one is a demo whose every
/// stage is done, as a second `cloudcontrol demo` finds it; its products name the photos
/// in this folder by their absolute paths.
pub fn shared_demo() -> std::path::PathBuf {
    let block = shared_block("small", 7, "rough");
    shared_folder("demo", true, |tmp| {
        copy_block(&block, &tmp.join("block"));
        let log = std::fs::File::create(tmp.join("demo.log")).unwrap();
        let status = std::process::Command::new(exe())
            .arg("demo")
            .arg("--out")
            .arg(tmp)
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .status()
            .unwrap();
        assert!(
            status.success(),
            "demo: {status}\n{}",
            std::fs::read_to_string(tmp.join("demo.log")).unwrap_or_default()
        );
    })
}

/// A private copy of `src` (a [`shared_block`]) at `dest`, which is replaced.
pub fn copy_block(src: &std::path::Path, dest: &std::path::Path) {
    let _ = std::fs::remove_dir_all(dest);
    let mut stack = vec![(src.to_path_buf(), dest.to_path_buf())];
    while let Some((from, to)) = stack.pop() {
        std::fs::create_dir_all(&to).unwrap();
        for e in std::fs::read_dir(&from).unwrap() {
            let e = e.unwrap();
            let target = to.join(e.file_name());
            if e.file_type().unwrap().is_dir() {
                stack.push((e.path(), target));
            } else {
                std::fs::copy(e.path(), &target).unwrap();
            }
        }
    }
}

/// Turns the epochs' surfaces and their changes off in the project file `path`
/// (`Project::without_surfaces`, as `bench accuracy --no-surfaces` does), for a test of
/// orientation: dense matching and the change analysis are half of a small block's run,
/// and `pipeline_run` and the dense tests check them.
pub fn without_surfaces(path: &std::path::Path) {
    let text = cloudcontrol::pipeline::project::Project::without_surfaces(path).unwrap();
    std::fs::write(path, text).unwrap();
}

/// Every regular file below `dir`, sorted.
pub fn files_below(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The project file of a tiny block's digital epoch controlled by its orthophoto and DEM
/// (no LiDAR, no reference: a run takes about a second), named `name`, with `camera` and
/// the checkpoint measurements `checkpoint_images` (paths relative to the block).
pub fn digital_project_toml(name: &str, camera: &str, checkpoint_images: &str) -> String {
    format!(
        r#"name = "{name}"
crs = "EPSG:4547"
output = "run"

[control]
orthophoto = "orthophoto/orthophoto.tif"
dem = "orthophoto/dem.tif"
dem_sigma_m = 0.1
checkpoints = "checkpoints.csv"
checkpoint_images = "{checkpoint_images}"

[[archive]]
name = "digital_2012"
date = "2012-08-14"
photos = "epochs/digital_2012/images"
camera = "{camera}"
pos = "epochs/digital_2012/pos.csv"

[thresholds]
control_interval_px = 60
chip_size_px = 193
"#
    )
}

/// [`copy_block`] of [`shared_block`]`(preset, seed, pos)` at `dest`.
pub fn block_copy(preset: &str, seed: u64, pos: &str, dest: &std::path::Path) {
    copy_block(&shared_block(preset, seed, pos), dest);
}

/// A synthetic block's checkpoints as an evaluation takes them: the image measurements of
/// `epoch` (`truth/checkpoint_images.csv`, standing for an operator's) and the surveyed
/// points (`checkpoints.csv`, world).
pub fn synth_checkpoints(
    dir: &std::path::Path,
    epoch: &str,
) -> (
    Vec<cloudcontrol::formats::control_points::CheckpointMeasurement>,
    Vec<(String, [f64; 3])>,
) {
    use cloudcontrol::formats::control_points;
    let measured = control_points::read_checkpoint_measurements(
        &dir.join("truth/checkpoint_images.csv"),
        epoch,
    )
    .unwrap();
    let surveyed = control_points::read_points(&dir.join("checkpoints.csv"))
        .unwrap()
        .into_iter()
        .map(|p| (p.id, p.xyz))
        .collect();
    (measured, surveyed)
}

/// Asserts that `message` names `file` and holds each of `words`.
pub fn says(message: &str, file: &std::path::Path, words: &[&str]) {
    assert!(
        message.contains(&file.display().to_string()),
        "names the file {}: {message}",
        file.display()
    );
    for w in words {
        assert!(message.contains(w), "says {w:?}: {message}");
    }
}

/// Runs the CLI, which must fail within a few seconds, and returns its stderr.
pub fn cli_fails(args: &[&str]) -> String {
    let t = std::time::Instant::now();
    let (ok, out, err) = cli(args);
    assert!(!ok, "succeeded: {out}");
    assert!(
        t.elapsed() < std::time::Duration::from_secs(5),
        "{args:?}: {:?}",
        t.elapsed()
    );
    err
}

/// The C ABI's thread-local last-error message.
pub fn last_error() -> String {
    use cloudcontrol::ffi::ccp_last_error;
    unsafe {
        let n = ccp_last_error(std::ptr::null_mut(), 0);
        let mut buf = vec![0 as std::ffi::c_char; n];
        ccp_last_error(buf.as_mut_ptr(), n);
        std::ffi::CStr::from_ptr(buf.as_ptr())
            .to_string_lossy()
            .into_owned()
    }
}

/// What a confined child process did ([`run_confined`]).
#[derive(Debug)]
pub struct Confined {
    /// The exit code, or `None` when a signal ended it (killed at the time limit, or
    /// aborted).
    pub code: Option<i32>,
    pub signal: Option<i32>,
    pub stdout: String,
    pub stderr: String,
    /// Peak resident memory of the child (`ru_maxrss`), bytes.
    pub peak_rss: u64,
    pub seconds: f64,
    /// Killed because it ran past the time limit.
    pub timed_out: bool,
}

impl Confined {
    /// Asserts the hostile-input contract (issue 51): the child ended by itself with a
    /// non-zero exit status (no signal, no abort), within `seconds` and 1 GiB of resident
    /// memory, and its message holds each of `words`.
    pub fn refused_cleanly(&self, seconds: f64, words: &[&str]) {
        assert!(
            !self.timed_out && self.signal.is_none(),
            "ended by signal {:?} after {:.1} s (timed out: {}): {}",
            self.signal,
            self.seconds,
            self.timed_out,
            self.stderr
        );
        assert!(
            self.code.is_some_and(|c| c != 0 && c != 101),
            "exit {:?} (101 is a panic): {}{}",
            self.code,
            self.stdout,
            self.stderr
        );
        assert!(
            self.peak_rss <= 1 << 30,
            "peak RSS {} MiB: {}",
            self.peak_rss >> 20,
            self.stderr
        );
        assert!(
            self.seconds <= seconds,
            "{:.1} s: {}",
            self.seconds,
            self.stderr
        );
        let all = format!("{}{}", self.stdout, self.stderr);
        for w in words {
            assert!(all.contains(w), "says {w:?}: {all}");
        }
    }
}

/// `cmd` run through util-linux's `prlimit --as`, which sets RLIMIT_AS on itself and
/// execs the command in the same process (same pid, so wait4's peak RSS is the
/// command's). Not a `pre_exec` hook: that makes std fork the multi-threaded test
/// process, and the child then runs the libraries' atfork handlers, one of which (PROJ's,
/// through GDAL) waited forever on a lock another test thread held: a test hung in 1 of 2
/// runs. Without `pre_exec` std spawns by posix_spawn, which runs no atfork handler.
pub fn under_rlimit_as(cmd: &std::process::Command, rlimit_as: u64) -> std::process::Command {
    let mut c = std::process::Command::new("prlimit");
    c.arg(format!("--as={rlimit_as}"))
        .arg("--")
        .arg(cmd.get_program())
        .args(cmd.get_args());
    for (k, v) in cmd.get_envs() {
        match v {
            Some(v) => c.env(k, v),
            None => c.env_remove(k),
        };
    }
    if let Some(d) = cmd.get_current_dir() {
        c.current_dir(d);
    }
    c
}

/// Runs `cmd` in a child process under an address-space limit of `rlimit_as` bytes
/// (RLIMIT_AS: an allocation beyond it fails in the child instead of taking the machine),
/// killed after `limit_s` seconds, and reports its exit, output, peak RSS and time. The
/// hostile-input tests run each crafted case this way so that a regression shows as a
/// failed assertion, never as a hung or out-of-memory test run.
pub fn run_confined(cmd: &std::process::Command, rlimit_as: u64, limit_s: f64) -> Confined {
    use std::process::Stdio;
    let mut cmd = under_rlimit_as(cmd, rlimit_as);
    let out = tempfile::NamedTempFile::new().unwrap();
    let err = tempfile::NamedTempFile::new().unwrap();
    cmd.stdin(Stdio::null())
        .stdout(out.reopen().unwrap())
        .stderr(err.reopen().unwrap());
    let t = std::time::Instant::now();
    let child = cmd.spawn().expect("child starts");
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value for wait4 to fill.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let mut timed_out = false;
    loop {
        // SAFETY: waits for our own child; the pointers are to live locals.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        assert!(r == 0, "wait4: {}", std::io::Error::last_os_error());
        if t.elapsed().as_secs_f64() > limit_s && !timed_out {
            timed_out = true;
            // SAFETY: signals our own child, which has not been reaped yet.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let seconds = t.elapsed().as_secs_f64();
    drop(child); // reaped above by wait4; dropping neither waits nor kills
    let read = |f: &tempfile::NamedTempFile| std::fs::read_to_string(f.path()).unwrap_or_default();
    Confined {
        code: libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status)),
        signal: libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status)),
        stdout: read(&out),
        stderr: read(&err),
        peak_rss: usage.ru_maxrss as u64 * 1024,
        seconds,
        timed_out,
    }
}

/// [`run_confined`] on the CLI with the acceptance's limits: 2 GiB of address space,
/// killed after 30 s (the assertions then ask for much less).
pub fn cli_confined(args: &[&str]) -> Confined {
    run_confined(std::process::Command::new(exe()).args(args), 2 << 30, 30.0)
}

/// `gdalinfo -json` of a raster: the independent reader of every GeoTIFF we write.
pub fn gdalinfo(path: &std::path::Path) -> serde_json::Value {
    let out = std::process::Command::new("gdalinfo")
        .arg("-json")
        .arg(path)
        .output()
        .expect("gdalinfo runs");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("gdalinfo JSON of {path:?}: {e}"))
}
