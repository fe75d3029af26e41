//! The C ABI refuses bad arguments with a status and a message, never a crash.

use crate::common;
use cloudcontrol::ffi::*;
use common::last_error;
use std::ffi::CStr;
use std::path::Path;
use std::ptr::{null, null_mut};

fn camera() -> *mut CcpCamera {
    let params = [1000.0, 1000.0, 500.0, 400.0, -0.1, 0.01, 0.0, 1e-4, -1e-4];
    let mut cam = null_mut();
    let st = unsafe { ccp_camera_new_frame(1000, 800, params.as_ptr(), params.len(), &mut cam) };
    assert_eq!(st, CcpStatus::Ok);
    assert!(!cam.is_null());
    cam
}

fn nadir_pose() -> CcpPose {
    let mut pose = CcpPose {
        rotation: [0.0; 9],
        center: [0.0; 3],
    };
    let c = [0.0, 0.0, 1000.0];
    assert_eq!(
        unsafe { ccp_pose_from_opk(0.0, 0.0, 0.0, c.as_ptr(), &mut pose) },
        CcpStatus::Ok
    );
    pose
}

#[test]
fn version_is_the_crate_version() {
    let v = unsafe { CStr::from_ptr(ccp_version()) }.to_str().unwrap();
    assert_eq!(v, env!("CARGO_PKG_VERSION"));
}

#[test]
fn projection_through_the_abi_matches_the_known_value() {
    let cam = camera();
    let pose = nadir_pose();
    // Nadir photo 1000 m above the origin: a point 100 m east and 50 m north lies at
    // normalised (0.1, −0.05); Brown distortion and pixel mapping by hand.
    let (x, y): (f64, f64) = (0.1, -0.05);
    let r2 = x * x + y * y;
    let radial = 1.0 - 0.1 * r2 + 0.01 * r2 * r2;
    let xd = x * radial + 2.0 * 1e-4 * x * y + -1e-4 * (r2 + 2.0 * x * x);
    let yd = y * radial + 1e-4 * (r2 + 2.0 * y * y) + 2.0 * -1e-4 * x * y;
    let expected = [1000.0 * xd + 500.0, 1000.0 * yd + 400.0];
    let pts = [100.0, 50.0, 0.0];
    let mut px = [0.0; 2];
    let st = unsafe { ccp_project(cam, &pose, pts.as_ptr(), 1, px.as_mut_ptr(), 2) };
    assert_eq!(st, CcpStatus::Ok, "{}", last_error());
    assert!(
        (px[0] - expected[0]).abs() < 1e-9 && (px[1] - expected[1]).abs() < 1e-9,
        "{px:?} vs {expected:?}"
    );
    let mut dir = [0.0; 3];
    let st = unsafe { ccp_back_project(cam, &pose, px.as_ptr(), 1, dir.as_mut_ptr(), 3) };
    assert_eq!(st, CcpStatus::Ok);
    // The ray from (0, 0, 1000) through the pixel reaches the point at t = |P − C|.
    let len = (100.0f64 * 100.0 + 50.0 * 50.0 + 1000.0 * 1000.0).sqrt();
    let hit = [dir[0] * len, dir[1] * len, 1000.0 + dir[2] * len];
    assert!(
        (hit[0] - 100.0).abs() < 1e-6 && (hit[1] - 50.0).abs() < 1e-6 && hit[2].abs() < 1e-6,
        "{hit:?}"
    );
    unsafe { ccp_camera_free(cam) };
}

#[test]
fn bad_arguments_give_a_status_and_a_message() {
    let cam = camera();
    let pose = nadir_pose();
    let pts = [100.0, 50.0, 0.0, 1.0, 2.0, 3.0];
    let mut px = [0.0; 4];
    unsafe {
        // Null handle, null pose, null arrays.
        assert_eq!(
            ccp_project(null(), &pose, pts.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("camera"), "{}", last_error());
        assert_eq!(
            ccp_project(cam, null(), pts.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("pose"));
        assert_eq!(
            ccp_project(cam, &pose, null(), 1, px.as_mut_ptr(), 2),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("points"));
        assert_eq!(
            ccp_project(cam, &pose, pts.as_ptr(), 1, null_mut(), 2),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("out_pixels"));
        // Zero length, a negative length passed as size_t, a too small output.
        assert_eq!(
            ccp_project(cam, &pose, pts.as_ptr(), 0, px.as_mut_ptr(), 2),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("zero"), "{}", last_error());
        assert_eq!(
            ccp_project(
                cam,
                &pose,
                pts.as_ptr(),
                (-1isize) as usize,
                px.as_mut_ptr(),
                2
            ),
            CcpStatus::InvalidArgument
        );
        assert!(!last_error().is_empty());
        assert_eq!(
            ccp_project(cam, &pose, pts.as_ptr(), 2, px.as_mut_ptr(), 3),
            CcpStatus::BufferTooSmall
        );
        assert!(
            last_error().contains("out_pixels holds 3"),
            "{}",
            last_error()
        );
        // NaN coordinates, NaN pose, a point behind the camera, a non-rotation.
        let nan = [f64::NAN, 0.0, 0.0];
        assert_eq!(
            ccp_project(cam, &pose, nan.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::NotFinite
        );
        assert!(last_error().contains("points[0]"), "{}", last_error());
        let mut bad_pose = pose;
        bad_pose.center[2] = f64::INFINITY;
        assert_eq!(
            ccp_project(cam, &bad_pose, pts.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::NotFinite
        );
        let above = [0.0, 0.0, 2000.0];
        assert_ne!(
            ccp_project(cam, &pose, above.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::Ok
        );
        assert!(
            last_error().contains("behind the camera"),
            "{}",
            last_error()
        );
        let mut skew = pose;
        skew.rotation[0] = 2.0;
        assert_eq!(
            ccp_project(cam, &skew, pts.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::InvalidArgument
        );
        let nan_px = [f64::NAN, 1.0];
        let mut dir = [0.0; 3];
        assert_eq!(
            ccp_back_project(cam, &pose, nan_px.as_ptr(), 1, dir.as_mut_ptr(), 3),
            CcpStatus::NotFinite
        );

        // Bad cameras: wrong parameter count, negative focal length, NaN, empty image, null out.
        let mut out = null_mut();
        let p3 = [1.0, 2.0, 3.0];
        assert_eq!(
            ccp_camera_new_frame(100, 100, p3.as_ptr(), 3, &mut out),
            CcpStatus::InvalidArgument
        );
        assert!(out.is_null() && last_error().contains("4 (pinhole) or 9 (Brown)"));
        let neg = [-1000.0, 1000.0, 50.0, 50.0];
        assert_eq!(
            ccp_camera_new_frame(100, 100, neg.as_ptr(), 4, &mut out),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("focal length"), "{}", last_error());
        let nanp = [f64::NAN, 1000.0, 50.0, 50.0];
        assert_eq!(
            ccp_camera_new_frame(100, 100, nanp.as_ptr(), 4, &mut out),
            CcpStatus::NotFinite
        );
        let ok = [1000.0, 1000.0, 50.0, 50.0];
        assert_eq!(
            ccp_camera_new_frame(0, 100, ok.as_ptr(), 4, &mut out),
            CcpStatus::InvalidArgument
        );
        assert_eq!(
            ccp_camera_new_frame(100, 100, ok.as_ptr(), 4, null_mut()),
            CcpStatus::NullPointer
        );
        assert_eq!(
            ccp_camera_new_frame(100, 100, null(), 4, &mut out),
            CcpStatus::NullPointer
        );

        // A success clears the message; freeing NULL is harmless.
        assert_eq!(
            ccp_project(cam, &pose, pts.as_ptr(), 1, px.as_mut_ptr(), 2),
            CcpStatus::Ok
        );
        assert_eq!(last_error(), "");
        ccp_camera_free(null_mut());

        // A free that succeeds leaves the message of the failed call before it: a
        // destructor (a Python object collected right then) must not erase it.
        let mut other: *mut CcpCamera = null_mut();
        let k = [1000.0, 1000.0, 50.0, 50.0];
        assert_eq!(
            ccp_camera_new_frame(100, 100, k.as_ptr(), 4, &mut other),
            CcpStatus::Ok
        );
        assert_eq!(
            ccp_camera_new_frame(100, 100, null(), 4, &mut out),
            CcpStatus::NullPointer
        );
        let message = last_error();
        assert!(!message.is_empty());
        assert_eq!(ccp_camera_free(other), CcpStatus::Ok);
        let s = std::ffi::CString::new("x").unwrap();
        // A string the library did not hand out: refused, and that failure is the message.
        assert_eq!(
            ccp_string_free(s.as_ptr() as *mut _),
            CcpStatus::InvalidHandle
        );
        assert_ne!(last_error(), message);
        assert_eq!(ccp_camera_free(cam), CcpStatus::Ok);
        assert!(!last_error().is_empty(), "the free kept the message");
    }
}

#[test]
fn last_error_truncates_into_small_buffers() {
    unsafe {
        let _ = ccp_project(null(), null(), null(), 0, null_mut(), 0);
        let full = last_error();
        let mut small = [1 as std::ffi::c_char; 8];
        let needed = ccp_last_error(small.as_mut_ptr(), small.len());
        assert_eq!(needed, full.len() + 1);
        let got = CStr::from_ptr(small.as_ptr()).to_str().unwrap();
        assert_eq!(got, &full[..7]);
    }
}

#[test]
fn dcp_export_and_import_refuse_bad_arguments_and_import_the_sample() {
    let dir = tempfile::tempdir().unwrap();
    let c = |s: &str| std::ffi::CString::new(s).unwrap();
    let missing = c(dir.path().join("nowhere/block.json").to_str().unwrap());
    let images = c(dir.path().join("images.json").to_str().unwrap());
    let out = c(dir.path().join("out.dcp").to_str().unwrap());
    let tile = c(dir.path().join("tiles").to_str().unwrap());
    let lidar = [tile.as_ptr()];
    unsafe {
        let mut dcp = null_mut();
        let export = |block: *const std::ffi::c_char,
                      n: usize,
                      opts: *const CcpDcpExportOptions,
                      dcp: &mut *mut CcpDcp| {
            ccp_dcp_export(
                block,
                images.as_ptr(),
                lidar.as_ptr(),
                n,
                out.as_ptr(),
                opts,
                dcp,
            )
        };
        assert_eq!(
            export(missing.as_ptr(), 1, null(), &mut dcp),
            CcpStatus::NotFound
        );
        assert!(
            last_error().contains("nowhere/block.json"),
            "{}",
            last_error()
        );
        assert!(dcp.is_null());
        assert_eq!(export(null(), 1, null(), &mut dcp), CcpStatus::NullPointer);
        assert!(last_error().contains("block_json"), "{}", last_error());
        assert_eq!(
            export(missing.as_ptr(), 0, null(), &mut dcp),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("lidar_paths"), "{}", last_error());
        let mut opts = std::mem::zeroed::<CcpDcpExportOptions>();
        assert_eq!(ccp_dcp_export_options_default(&mut opts), CcpStatus::Ok);
        assert_eq!((opts.chip_size, opts.interval_px), (193, 250.0));
        opts.chip_size = 100;
        assert_eq!(
            export(missing.as_ptr(), 1, &opts, &mut dcp),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("chip_size 100"), "{}", last_error());
        assert_eq!(
            ccp_dcp_export(
                missing.as_ptr(),
                images.as_ptr(),
                lidar.as_ptr(),
                1,
                out.as_ptr(),
                null(),
                null_mut()
            ),
            CcpStatus::NullPointer
        );
        assert!(!dir.path().join("out.dcp").exists());

        // Import: a folder that is not a package is refused; the sample is stored.
        let store = c(dir.path().join("store").to_str().unwrap());
        let not_pkg = c(dir.path().to_str().unwrap());
        assert_eq!(
            ccp_dcp_import(not_pkg.as_ptr(), store.as_ptr(), &mut dcp),
            CcpStatus::Format
        );
        assert!(
            last_error().contains("not a DCP package"),
            "{}",
            last_error()
        );
        assert!(!dir.path().join("store").exists());
        let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/dcp/sample.dcp");
        let sample = c(sample.to_str().unwrap());
        assert_eq!(
            ccp_dcp_import(sample.as_ptr(), store.as_ptr(), &mut dcp),
            CcpStatus::Ok,
            "{}",
            last_error()
        );
        let mut n = 0usize;
        assert_eq!(ccp_dcp_point_count(dcp, &mut n), CcpStatus::Ok);
        assert_eq!(n, 4);
        let mut path = null_mut();
        assert_eq!(ccp_dcp_path(dcp, &mut path), CcpStatus::Ok);
        let stored = CStr::from_ptr(path).to_str().unwrap().to_string();
        ccp_string_free(path);
        assert_eq!(Path::new(&stored), dir.path().join("store/sample.dcp"));
        ccp_dcp_free(dcp);
        assert_eq!(ccp_dcp_path(null(), &mut path), CcpStatus::NullPointer);
    }
}

/// `ccp_match_pair`: NULL photos and outputs, an image of another size than its camera, a
/// huge claimed size, NaN heights, an inverted height range and a pair with one centre are
/// refused with a status and a message naming the argument; nothing is allocated then.
#[test]
fn match_pair_refuses_bad_arguments() {
    let cam = camera();
    let pose = nadir_pose();
    let pixels = vec![100f32; 1000 * 800];
    let photo = |pose: CcpPose, px: &[f32], w: u32, h: u32| CcpPairPhoto {
        camera: cam,
        pose,
        pixels: px.as_ptr(),
        width: w,
        height: h,
    };
    let mut right_pose = pose;
    right_pose.center[0] += 300.0;
    let (l, r) = (
        photo(pose, &pixels, 1000, 800),
        photo(right_pose, &pixels, 1000, 800),
    );
    let (mut pts, mut n) = (null_mut(), 0usize);
    unsafe {
        assert_eq!(
            ccp_match_pair(null(), &r, 0.0, 1.0, &mut pts, &mut n),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("left"), "{}", last_error());
        assert_eq!(
            ccp_match_pair(&l, &r, 0.0, 1.0, null_mut(), &mut n),
            CcpStatus::NullPointer
        );
        assert!(last_error().contains("out_points"), "{}", last_error());
        assert_eq!(
            ccp_match_pair(&l, &r, f64::NAN, 1.0, &mut pts, &mut n),
            CcpStatus::NotFinite
        );
        assert_eq!(
            ccp_match_pair(&l, &r, 2.0, 1.0, &mut pts, &mut n),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("z_min"), "{}", last_error());
        let small = photo(pose, &pixels, 500, 400);
        assert_eq!(
            ccp_match_pair(&small, &r, 0.0, 1.0, &mut pts, &mut n),
            CcpStatus::InvalidArgument
        );
        assert!(
            last_error().contains("left: image of 500×400 px for a camera of 1000×800"),
            "{}",
            last_error()
        );
        // A size far beyond the photo memory budget: refused before reading the pixels.
        let huge = photo(pose, &pixels, 200_000, 200_000);
        assert_eq!(
            ccp_match_pair(&huge, &r, 0.0, 1.0, &mut pts, &mut n),
            CcpStatus::InvalidArgument
        );
        assert!(last_error().contains("left.pixels"), "{}", last_error());
        let same = photo(pose, &pixels, 1000, 800);
        assert_eq!(
            ccp_match_pair(&l, &same, 0.0, 1.0, &mut pts, &mut n),
            CcpStatus::Numeric
        );
        assert!(
            last_error().contains("centres coincide"),
            "{}",
            last_error()
        );
        assert!(pts.is_null() && n == 0);
        // A flat grey pair matches nothing: no array, no error.
        assert_eq!(
            ccp_match_pair(&l, &r, -10.0, 10.0, &mut pts, &mut n),
            CcpStatus::Ok
        );
        assert!(pts.is_null() && n == 0);
        assert_eq!(ccp_points_free(null_mut(), 0), CcpStatus::Ok);
        ccp_camera_free(cam);
    }
}
