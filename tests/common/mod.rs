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

/// `cloudcontrol synth --preset PRESET --seed SEED --out DIR`, asserting it succeeded.
pub fn synth_block(dir: &std::path::Path, preset: &str, seed: u64) {
    let o = std::process::Command::new(exe())
        .args([
            "synth",
            "--preset",
            preset,
            "--seed",
            &seed.to_string(),
            "--out",
        ])
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
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
