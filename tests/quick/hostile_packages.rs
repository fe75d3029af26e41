//! DCP package members that are not what the manifest says (formats/dcp/README.md,
//! "Validation on import"): a chip that is a symbolic link (out of the package, to
//! /dev/zero), a chip folder that is a link, a device, a FIFO, a manifest that is a link,
//! and a chip whose pixel size differs from the manifest's are refused, naming the package
//! and the chip, on open, on `dcp import` and through the C ABI — within seconds, without
//! following the link, reading the device or waiting on the FIFO.

use crate::common;
use cloudcontrol::control::dcp::DcpPackage;
use common::{cli, last_error};
use sha2::{Digest, Sha256};
use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const CHIP: &str = "chips/p1_1.png";

/// A copy of formats/dcp/sample.dcp (4 points in 2 photos, 32 × 32 chips) in `dir`.
fn sample(dir: &Path, name: &str) -> PathBuf {
    let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/dcp/sample.dcp");
    let to = dir.join(name);
    std::fs::create_dir_all(to.join("chips")).unwrap();
    for e in std::fs::read_dir(from.join("chips")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join("chips").join(e.file_name())).unwrap();
    }
    std::fs::copy(from.join("manifest.json"), to.join("manifest.json")).unwrap();
    DcpPackage::open(&to).expect("the sample opens");
    to
}

fn says(message: &str, words: &[&str]) {
    for w in words {
        assert!(message.contains(w), "says {w:?}: {message}");
    }
}

/// `DcpPackage::open`, `dcp import` and `ccp_dcp_open` all refuse `pkg`, each within a few
/// seconds (run on a thread, so a hang fails the test instead of stalling it), with an
/// error holding `words`; the store is not created.
fn refused_everywhere(pkg: &Path, words: &[&str]) {
    let name = pkg.display().to_string();
    let mut words = words.to_vec();
    words.push(&name);
    let (tx, rx) = std::sync::mpsc::channel();
    let p = pkg.to_path_buf();
    std::thread::spawn(move || {
        let t = Instant::now();
        let e = DcpPackage::open(&p).err().map(|e| e.to_string());
        tx.send((e, t.elapsed())).unwrap();
    });
    let (e, took) = rx
        .recv_timeout(Duration::from_secs(10))
        .expect("DcpPackage::open returns within 10 s");
    says(&e.expect("refused"), &words);
    assert!(took < Duration::from_secs(3), "open took {took:?}");

    let store = pkg.with_extension("store");
    let t = Instant::now();
    let (ok, out, err) = cli(&[
        "dcp",
        "import",
        pkg.to_str().unwrap(),
        "--into",
        store.to_str().unwrap(),
    ]);
    assert!(!ok, "import succeeded: {out}");
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    says(&err, &words);
    assert!(!store.exists(), "a refused import created the store");

    let c = CString::new(pkg.to_str().unwrap()).unwrap();
    let mut h = std::ptr::null_mut();
    let st = unsafe { cloudcontrol::ffi::ccp_dcp_open(c.as_ptr(), &mut h) };
    assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
    assert!(h.is_null());
    says(&last_error(), &words);
}

#[test]
fn chip_links_are_refused_even_with_the_right_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    // A link out of the package to a file with the chip's own bytes: the checksum matches,
    // the link is refused for what it is.
    let pkg = sample(tmp.path(), "outside.dcp");
    let outside = tmp.path().join("elsewhere.png");
    std::fs::rename(pkg.join(CHIP), &outside).unwrap();
    std::os::unix::fs::symlink(&outside, pkg.join(CHIP)).unwrap();
    refused_everywhere(&pkg, &[CHIP, "symbolic link", "elsewhere.png"]);

    let pkg = sample(tmp.path(), "zero.dcp");
    std::fs::remove_file(pkg.join(CHIP)).unwrap();
    std::os::unix::fs::symlink("/dev/zero", pkg.join(CHIP)).unwrap();
    refused_everywhere(&pkg, &[CHIP, "symbolic link", "/dev/zero"]);

    // The chip folder itself a link to a copy of the chips.
    let pkg = sample(tmp.path(), "folder.dcp");
    let copy = tmp.path().join("chips-copy");
    std::fs::rename(pkg.join("chips"), &copy).unwrap();
    std::os::unix::fs::symlink(&copy, pkg.join("chips")).unwrap();
    refused_everywhere(&pkg, &["lies in chips, a symbolic link"]);

    // The manifest a link to the manifest of another package.
    let pkg = sample(tmp.path(), "manifest.dcp");
    let other = sample(tmp.path(), "other.dcp");
    std::fs::remove_file(pkg.join("manifest.json")).unwrap();
    std::os::unix::fs::symlink(other.join("manifest.json"), pkg.join("manifest.json")).unwrap();
    refused_everywhere(&pkg, &["manifest.json is a symbolic link"]);
}

#[test]
fn fifo_and_device_chips_are_refused_without_reading() {
    let tmp = tempfile::tempdir().unwrap();
    let pkg = sample(tmp.path(), "fifo.dcp");
    std::fs::remove_file(pkg.join(CHIP)).unwrap();
    let c = CString::new(pkg.join(CHIP).to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    refused_everywhere(&pkg, &[CHIP, "is a FIFO"]);

    // /dev/zero's device (1, 5) inside the package; making it needs CAP_MKNOD.
    let pkg = sample(tmp.path(), "device.dcp");
    std::fs::remove_file(pkg.join(CHIP)).unwrap();
    let c = CString::new(pkg.join(CHIP).to_str().unwrap()).unwrap();
    let dev = libc::makedev(1, 5);
    if unsafe { libc::mknod(c.as_ptr(), libc::S_IFCHR | 0o644, dev) } == 0 {
        refused_everywhere(&pkg, &[CHIP, "is a device"]);
    } else {
        println!("device case skipped: mknod needs CAP_MKNOD");
    }
}

#[test]
fn a_chip_of_another_size_than_the_manifest_says_is_refused_on_import() {
    let tmp = tempfile::tempdir().unwrap();
    let pkg = sample(tmp.path(), "size.dcp");
    // 40 × 24 pixels instead of 32 × 32, listed with its own checksum: only the size
    // tells.
    let img = image::GrayImage::from_fn(40, 24, |x, y| image::Luma([(x * 5 + y) as u8]));
    img.save(pkg.join(CHIP)).unwrap();
    let sum: String = Sha256::digest(std::fs::read(pkg.join(CHIP)).unwrap())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let mpath = pkg.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&mpath).unwrap()).unwrap();
    m["files"][CHIP] = sum.into();
    std::fs::write(&mpath, serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    refused_everywhere(&pkg, &[CHIP, "is 40×24 pixels, the manifest says 32×32"]);
}

#[test]
fn peak_memory_of_the_refusals_stays_small() {
    // The CLI imports above run as children; their peak RSS is what a host would see.
    chip_links_are_refused_even_with_the_right_bytes();
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(
        unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) },
        0
    );
    let kib = ru.ru_maxrss;
    println!("peak RSS of a refusing `dcp import`: {} MiB", kib / 1024);
    assert!(kib < 1 << 20, "{kib} KiB");
}
