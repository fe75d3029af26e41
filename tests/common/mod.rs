//! Helpers shared by the end-to-end tests that run the `cloudcontrol` binary and read its
//! JSON (each test binary uses the part it needs).
#![allow(dead_code)]

use serde_json::Value;

pub fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_cloudcontrol")
}

/// The JSON a successful command printed on stdout (the command's stderr when it failed).
pub fn json_of(out: &std::process::Output) -> Value {
    assert!(
        out.status.success(),
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

/// A synthetic block made once per build of the binary and shared by every test binary
/// and the Python tests (`CARGO_TARGET_TMPDIR/blocks/<preset>-<seed>-<pos>`): the small
/// blocks cost 120–140 CPU s each to render, and six tests used three of them twice over.
/// The block is generated into a private folder and renamed into place, so no test ever
/// sees a half-written one; a stamp of the binary (size and modification time) beside it
/// makes a rebuilt binary generate it again. Tests take a [`copy_block`] of it, never the
/// shared folder itself.
pub fn shared_block(preset: &str, seed: u64, pos: &str) -> std::path::PathBuf {
    use std::sync::Mutex;
    static LOCK: Mutex<()> = Mutex::new(());
    let _held = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let root = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("blocks");
    let key = format!("{preset}-{seed}-{pos}");
    let dir = root.join(&key);
    let stamp_file = root.join(format!("{key}.stamp"));
    let meta = std::fs::metadata(exe()).unwrap();
    let modified = meta
        .modified()
        .unwrap()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    let stamp = format!("{}-{}", meta.len(), modified.as_nanos());
    if dir.join("manifest.json").is_file()
        && std::fs::read_to_string(&stamp_file).is_ok_and(|s| s.trim() == stamp)
    {
        return dir;
    }
    let tmp = root.join(format!(".{key}.{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let o = std::process::Command::new(exe())
        .args(["synth", "-q", "--preset", preset, "--pos", pos])
        .args(["--seed", &seed.to_string(), "--out"])
        .arg(&tmp)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::rename(&tmp, &dir).unwrap();
    std::fs::write(&stamp_file, stamp).unwrap();
    dir
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
