//! Handles at the C ABI carry their type and liveness: a double free, a freed handle, a
//! handle of another type or a pointer that never was a handle is refused with
//! `CCP_STATUS_INVALID_HANDLE` and a message, never a crash; one block adjusted from 8
//! threads at once gives the single-threaded result; freeing a block while other threads
//! adjust it is safe.

use crate::common;
use cloudcontrol::ffi::*;
use common::last_error;
use std::ptr::{null, null_mut};

const W: u32 = 4000;
const H: u32 = 3000;
const F: f64 = 3500.0;

fn camera() -> *mut CcpCamera {
    let params = [F, F, W as f64 / 2.0, H as f64 / 2.0];
    let mut cam = null_mut();
    let st = unsafe { ccp_camera_new_frame(W, H, params.as_ptr(), 4, &mut cam) };
    assert_eq!(st, CcpStatus::Ok, "{}", last_error());
    cam
}

fn nadir(c: [f64; 3]) -> CcpPose {
    let mut pose = CcpPose {
        rotation: [0.0; 9],
        center: [0.0; 3],
    };
    assert_eq!(
        unsafe { ccp_pose_from_opk(0.0, 0.0, 0.0, c.as_ptr(), &mut pose) },
        CcpStatus::Ok
    );
    pose
}

/// A deterministic stream in [-1, 1) (no dependency on the rand crate's versions).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

const PHOTOS: usize = 14;

/// 14 nadir photos 800 m above 600 points, 12 of them control; observations with uniform
/// noise of ±0.5 px; starting centres up to 2 m off.
fn block(cam: *mut CcpCamera) -> *mut CcpBlock {
    let mut rng = Lcg(4);
    let mut b = null_mut();
    unsafe {
        assert_eq!(ccp_block_new(null(), &mut b), CcpStatus::Ok);
        assert_eq!(ccp_block_add_camera(b, 1, cam, null()), CcpStatus::Ok);
        let poses: Vec<CcpPose> = (0..PHOTOS)
            .map(|j| nadir([(j % 7) as f64 * 190.0, (j / 7) as f64 * 450.0, 800.0]))
            .collect();
        for (j, p) in poses.iter().enumerate() {
            let mut start = *p;
            for c in &mut start.center {
                *c += 2.0 * rng.next();
            }
            assert_eq!(
                ccp_block_add_photo(b, j as u32 + 1, 1, &start),
                CcpStatus::Ok
            );
        }
        let n = 600;
        let xyz: Vec<f64> = (0..n)
            .flat_map(|_| {
                let r = [rng.next(), rng.next(), rng.next()];
                [
                    650.0 + 700.0 * r[0],
                    225.0 + 400.0 * r[1],
                    10.0 + 20.0 * r[2],
                ]
            })
            .collect();
        let ids: Vec<u64> = (1..=n as u64).collect();
        let kinds: Vec<u32> = (0..n).map(|i| u32::from(i < 12)).collect();
        let sig = vec![0.02; 3 * n];
        assert_eq!(
            ccp_block_add_points(
                b,
                n,
                ids.as_ptr(),
                kinds.as_ptr(),
                xyz.as_ptr(),
                sig.as_ptr()
            ),
            CcpStatus::Ok,
            "{}",
            last_error()
        );
        let (mut pid, mut phid, mut px) = (Vec::new(), Vec::new(), Vec::new());
        for (j, p) in poses.iter().enumerate() {
            for i in 0..n {
                let mut uv = [0.0; 2];
                let st = ccp_project(cam, p, xyz[3 * i..].as_ptr(), 1, uv.as_mut_ptr(), 2);
                if st != CcpStatus::Ok
                    || !(10.0..W as f64 - 10.0).contains(&uv[0])
                    || !(10.0..H as f64 - 10.0).contains(&uv[1])
                {
                    continue;
                }
                pid.push(i as u64 + 1);
                phid.push(j as u32 + 1);
                px.extend([uv[0] + 0.5 * rng.next(), uv[1] + 0.5 * rng.next()]);
            }
        }
        let s = vec![1.0; pid.len()];
        assert_eq!(
            ccp_block_add_observations(
                b,
                pid.len(),
                pid.as_ptr(),
                phid.as_ptr(),
                px.as_ptr(),
                s.as_ptr()
            ),
            CcpStatus::Ok,
            "{}",
            last_error()
        );
    }
    b
}

/// Plain least squares: adjusting an adjusted block again returns it unchanged.
fn options() -> CcpAdjustOptions {
    CcpAdjustOptions {
        loss: 0,
        loss_scale: 1.0,
        rejection: 0,
        k: 3.0,
        max_iterations: 50,
        max_rounds: 1,
    }
}

fn centres(b: *const CcpBlock) -> Vec<[f64; 3]> {
    (1..=PHOTOS as u32)
        .map(|id| {
            let mut p = nadir([0.0; 3]);
            assert_eq!(
                unsafe { ccp_block_get_photo(b, id, &mut p, null_mut()) },
                CcpStatus::Ok
            );
            p.center
        })
        .collect()
}

#[test]
fn double_free_freed_and_foreign_handles_are_refused() {
    let cam = camera();
    let b = block(cam);
    let pose = nadir([0.0, 0.0, 800.0]);
    unsafe {
        // A camera handed in as a block: refused, and nothing happened to the camera.
        let st = ccp_block_add_photo(cam as *mut CcpBlock, 99, 1, &pose);
        assert_eq!(st, CcpStatus::InvalidHandle);
        assert!(
            last_error().contains("block is a CcpCamera handle, not a CcpBlock"),
            "{}",
            last_error()
        );
        assert_eq!(
            ccp_block_free(cam as *mut CcpBlock),
            CcpStatus::InvalidHandle
        );
        let mut uv = [0.0; 2];
        let x = [0.0, 0.0, 0.0];
        assert_eq!(
            ccp_project(cam, &pose, x.as_ptr(), 1, uv.as_mut_ptr(), 2),
            CcpStatus::Ok
        );
        assert_eq!(uv, [2000.0, 1500.0]);
        // A block handed in as a camera.
        let st = ccp_project(
            b as *const CcpCamera,
            &pose,
            x.as_ptr(),
            1,
            uv.as_mut_ptr(),
            2,
        );
        assert_eq!(st, CcpStatus::InvalidHandle);
        assert!(last_error().contains("CcpBlock handle, not a CcpCamera"));
        // A pointer that never was a handle (the address of a local).
        let stray = &pose as *const CcpPose as *const CcpBlock;
        assert_eq!(
            ccp_block_get_photo(stray, 1, &mut nadir([0.0; 3]), null_mut()),
            CcpStatus::InvalidHandle
        );
        assert!(last_error().contains("not a CcpBlock handle made by this library"));

        // Free, then use, then free again.
        assert_eq!(ccp_block_free(b), CcpStatus::Ok);
        let st = ccp_block_adjust(b, &options(), &mut CcpAdjustSummary::default());
        assert_eq!(st, CcpStatus::InvalidHandle);
        assert!(last_error().contains("was freed"), "{}", last_error());
        assert_eq!(ccp_block_free(b), CcpStatus::InvalidHandle);
        assert!(last_error().contains("freed twice"), "{}", last_error());
        assert_eq!(ccp_camera_free(cam), CcpStatus::Ok);
        assert_eq!(ccp_camera_free(cam), CcpStatus::InvalidHandle);
        assert_eq!(ccp_camera_free(null_mut()), CcpStatus::Ok);

        // Strings: freed once; a pointer the library did not return is refused.
        let sample = std::ffi::CString::new(
            concat!(env!("CARGO_MANIFEST_DIR"), "/formats/dcp/sample.dcp").to_string(),
        )
        .unwrap();
        let mut dcp = null_mut();
        assert_eq!(ccp_dcp_open(sample.as_ptr(), &mut dcp), CcpStatus::Ok);
        let mut path = null_mut();
        assert_eq!(ccp_dcp_path(dcp, &mut path), CcpStatus::Ok);
        assert_eq!(ccp_string_free(path), CcpStatus::Ok);
        assert_eq!(ccp_string_free(path), CcpStatus::InvalidHandle);
        let mine = sample.as_ptr() as *mut std::ffi::c_char;
        assert_eq!(ccp_string_free(mine), CcpStatus::InvalidHandle);
        assert_eq!(ccp_dcp_free(dcp), CcpStatus::Ok);
    }
}

#[test]
fn eight_threads_adjusting_one_block_get_the_single_threaded_result() {
    let cam = camera();
    let reference = block(cam);
    let mut s0 = CcpAdjustSummary::default();
    assert_eq!(
        unsafe { ccp_block_adjust(reference, &options(), &mut s0) },
        CcpStatus::Ok,
        "{}",
        last_error()
    );
    assert_eq!(s0.converged, 1);
    // Uniform noise of ±0.5 px has σ 0.5/√3 px, the observations are weighted with 1 px.
    let sigma = 0.5 / 3f64.sqrt();
    assert!((s0.sigma0 / sigma - 1.0).abs() < 0.1, "σ0 {}", s0.sigma0);
    let first = centres(reference);
    // Each adjustment starts where the one before stopped: eight in a row, one thread.
    for _ in 1..8 {
        let mut s = CcpAdjustSummary::default();
        assert_eq!(
            unsafe { ccp_block_adjust(reference, &options(), &mut s) },
            CcpStatus::Ok
        );
    }
    let want = centres(reference);

    let shared = block(cam) as usize;
    let t = std::time::Instant::now();
    let summaries: Vec<(CcpStatus, CcpAdjustSummary, Vec<[f64; 3]>)> = std::thread::scope(|s| {
        let threads: Vec<_> = (0..8)
            .map(|_| {
                s.spawn(move || {
                    let b = shared as *mut CcpBlock;
                    let mut sum = CcpAdjustSummary::default();
                    let st = unsafe { ccp_block_adjust(b, &options(), &mut sum) };
                    (st, sum, centres(b))
                })
            })
            .collect();
        threads.into_iter().map(|t| t.join().unwrap()).collect()
    });
    println!("8 concurrent adjustments of one block: {:?}", t.elapsed());
    let close = |a: &[[f64; 3]], b: &[[f64; 3]], tol: f64| {
        a.iter()
            .zip(b)
            .all(|(p, q)| (0..3).all(|k| (p[k] - q[k]).abs() < tol))
    };
    // Every call saw a whole block: the same σ0 and centres as the first adjustment up
    // to its convergence tolerance (a later adjustment moves it by < 0.1 mm).
    for (st, sum, got) in &summaries {
        assert_eq!(*st, CcpStatus::Ok);
        assert_eq!(sum.converged, 1);
        assert!(
            (sum.sigma0 - s0.sigma0).abs() < 1e-6 * s0.sigma0,
            "{sum:?} vs {s0:?}"
        );
        assert!(close(got, &first, 1e-4), "{got:?} vs {first:?}");
    }
    // One after the other: the block ends where eight adjustments in a row end.
    let end = centres(shared as *const CcpBlock);
    assert!(close(&end, &want, 1e-9), "{end:?} vs {want:?}");
    unsafe {
        assert_eq!(ccp_block_free(shared as *mut CcpBlock), CcpStatus::Ok);
        assert_eq!(ccp_block_free(reference), CcpStatus::Ok);
        assert_eq!(ccp_camera_free(cam), CcpStatus::Ok);
    }
}

#[test]
fn freeing_a_block_while_threads_adjust_it_is_safe() {
    let cam = camera();
    let shared = block(cam) as usize;
    // Each thread adjusts until the block is gone: the calls in flight when it is freed
    // finish, every later call is refused.
    let runs: Vec<Vec<CcpStatus>> = std::thread::scope(|s| {
        let threads: Vec<_> = (0..8)
            .map(|_| {
                s.spawn(move || {
                    let mut seen = Vec::new();
                    for _ in 0..1000 {
                        let mut sum = CcpAdjustSummary::default();
                        let b = shared as *mut CcpBlock;
                        let st = unsafe { ccp_block_adjust(b, &options(), &mut sum) };
                        seen.push(st);
                        if st != CcpStatus::Ok {
                            break;
                        }
                    }
                    seen
                })
            })
            .collect();
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert_eq!(
            unsafe { ccp_block_free(shared as *mut CcpBlock) },
            CcpStatus::Ok
        );
        threads.into_iter().map(|t| t.join().unwrap()).collect()
    });
    let ok: usize = runs.iter().map(|r| r.len() - 1).sum();
    println!("adjustments before the free: {ok}");
    for r in &runs {
        let (last, before) = r.split_last().unwrap();
        assert_eq!(*last, CcpStatus::InvalidHandle, "{r:?}");
        assert!(before.iter().all(|s| *s == CcpStatus::Ok), "{r:?}");
    }
    assert!(ok >= 1);
    unsafe { ccp_camera_free(cam) };
}
