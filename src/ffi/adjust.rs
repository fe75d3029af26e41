//! Bundle adjustment and resection over the C ABI: build a block from arrays, add
//! observations of each type, adjust with options, read back orientations, precision and
//! the JSON report; resect one photo.
//!
//! # Safety
//! One contract for every function here: each pointer is NULL (where documented) or
//! valid for the number of elements its length argument states, and handles come from
//! `ccp_block_new` / `ccp_camera_new_frame` and are not used after being freed.
#![allow(clippy::missing_safety_doc)]

use super::camera::camera_arg;
use super::handles::{free, get, new_handle, read, write, Handle};
use super::{finite, guard, handle, input, output, CcpCamera, CcpPose, CcpStatus, FfiError};
use crate::adjust::{
    self, AdjustError, AdjustOptions, AdjustReport, Loss, PlaneConstraint, Rejection,
    ResectionOptions,
};
use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PointKind, PosPrior};
use nalgebra::{Matrix3, Vector3};
use std::ffi::{c_char, CStr};

impl From<AdjustError> for FfiError {
    fn from(e: AdjustError) -> Self {
        let status = match &e {
            AdjustError::NotFinite { .. } => CcpStatus::NotFinite,
            AdjustError::UnknownId { .. } => CcpStatus::NotFound,
            AdjustError::Degenerate(_) | AdjustError::Singular(_) => CcpStatus::Numeric,
            _ => CcpStatus::InvalidArgument,
        };
        Self::new(status, e.to_string())
    }
}

/// Opaque block handle: `ccp_block_new`, `ccp_block_free`.
/// Thread safety: a block may be used from several threads at once. Calls that change it
/// (`ccp_block_add_*`, `ccp_block_set_*`, `ccp_block_adjust`) take it exclusively
/// and run one after the other; reading calls (`ccp_block_get_*`, `ccp_block_report_json`)
/// run together.
pub struct CcpBlock {
    block: Block,
    planes: Vec<PlaneConstraint>,
    /// σ of the LiDAR's datum (m): `ccp_block_set_lidar_datum_sigma`.
    lidar_datum_sigma_m: Option<f64>,
    report: Option<AdjustReport>,
}

impl Handle for CcpBlock {
    const TAG: usize = 2;
    const NAME: &'static str = "CcpBlock";
}

/// Options of `ccp_block_adjust`. `loss`: 0 none, 1 Huber, 2 Cauchy (scale `loss_scale`
/// in σ units); `rejection`: 0 none, 1 k·σ0 threshold, 2 Baarda data snooping (critical
/// value `k`).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct CcpAdjustOptions {
    pub loss: u32,
    pub loss_scale: f64,
    pub rejection: u32,
    pub k: f64,
    pub max_iterations: u32,
    pub max_rounds: u32,
}

/// Summary of `ccp_block_adjust` (the full report: `ccp_block_report_json`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct CcpAdjustSummary {
    pub sigma0: f64,
    pub rmse_px: f64,
    pub iterations: u32,
    pub rounds: u32,
    pub converged: u32,
    pub rejected: u32,
    pub photos: u32,
    pub points: u32,
    pub observations: u64,
    pub time_s: f64,
    pub check_count: u32,
    pub check_rmse_plan_m: f64,
    pub check_rmse_height_m: f64,
    pub check_max_m: f64,
}

/// Creates an empty block with the world coordinates of its local origin (`origin`: 3
/// values; NULL = 0,0,0). All coordinates passed later are block-local.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_new(
    origin: *const f64,
    out_block: *mut *mut CcpBlock,
) -> CcpStatus {
    guard(|| {
        if out_block.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_block is a null pointer",
            ));
        }
        *out_block = std::ptr::null_mut();
        let mut block = Block::new();
        if !origin.is_null() {
            let o = input(origin, 3, "origin", false)?;
            finite(o, "origin")?;
            block.origin = [o[0], o[1], o[2]];
        }
        *out_block = new_handle(CcpBlock {
            block,
            planes: Vec::new(),
            lidar_datum_sigma_m: None,
            report: None,
        });
        Ok(())
    })
}

/// Releases a block; NULL is ignored. A handle already freed or of another type is
/// refused with `CCP_STATUS_INVALID_HANDLE` (nothing is freed).
#[no_mangle]
pub unsafe extern "C" fn ccp_block_free(block: *mut CcpBlock) -> CcpStatus {
    free(block, "block")
}

/// Adds a camera (copied from `camera`). `free_params`: comma-separated names of interior
/// parameters to self-calibrate (fx,fy,cx,cy,k1,k2,k3,p1,p2), or NULL for none.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_add_camera(
    block: *mut CcpBlock,
    camera_id: u32,
    camera: *const CcpCamera,
    free_params: *const c_char,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let cam = camera_arg(camera, "camera")?;
        let free: Vec<String> = if free_params.is_null() {
            Vec::new()
        } else {
            CStr::from_ptr(free_params)
                .to_str()
                .map_err(|_| FfiError::invalid("free_params is not UTF-8"))?
                .split(',')
                .map(|s| s.trim().to_string())
                .filter(|s| !s.is_empty())
                .collect()
        };
        for n in &free {
            if !cam.param_names().contains(&n.as_str()) {
                return Err(FfiError::invalid(format!(
                    "free_params: unknown interior parameter '{n}' (known: {})",
                    cam.param_names().join(", ")
                )));
            }
        }
        b.block.cameras.insert(
            camera_id,
            BlockCamera {
                id: camera_id,
                name: format!("camera {camera_id}"),
                model: cam,
                free_params: free,
                calibration_group: None,
            },
        );
        Ok(())
    })
}

/// Adds a photo with its approximate exterior orientation.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_add_photo(
    block: *mut CcpBlock,
    photo_id: u32,
    camera_id: u32,
    pose: *const CcpPose,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        if !b.block.cameras.contains_key(&camera_id) {
            return Err(FfiError::new(
                CcpStatus::NotFound,
                format!("photo {photo_id}: unknown camera {camera_id}"),
            ));
        }
        let pose = handle(pose, "pose")?.to_pose()?;
        b.block.photos.insert(
            photo_id,
            Photo::new(photo_id, format!("photo {photo_id}"), camera_id, pose),
        );
        Ok(())
    })
}

/// Sets a photo's POS prior: `center` (3) with `center_sigma` (3, m); optional attitude
/// `rotation` (9, row-major world→camera, NULL for none) with σ `rotation_sigma_rad`.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_set_pos_prior(
    block: *mut CcpBlock,
    photo_id: u32,
    center: *const f64,
    center_sigma: *const f64,
    rotation: *const f64,
    rotation_sigma_rad: f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let c = input(center, 3, "center", false)?;
        let s = input(center_sigma, 3, "center_sigma", false)?;
        finite(c, "center")?;
        finite(s, "center_sigma")?;
        if s.iter().any(|v| *v <= 0.0) {
            return Err(FfiError::invalid("center_sigma must be positive"));
        }
        let rot = if rotation.is_null() {
            None
        } else {
            let r = input(rotation, 9, "rotation", false)?;
            finite(r, "rotation")?;
            finite(&[rotation_sigma_rad], "rotation_sigma_rad")?;
            if rotation_sigma_rad <= 0.0 {
                return Err(FfiError::invalid("rotation_sigma_rad must be positive"));
            }
            Some(Matrix3::from_row_slice(r))
        };
        let ph = b.block.photos.get_mut(&photo_id).ok_or_else(|| {
            FfiError::new(CcpStatus::NotFound, format!("unknown photo {photo_id}"))
        })?;
        ph.prior = Some(PosPrior {
            center: Vector3::new(c[0], c[1], c[2]),
            center_sigma: [s[0], s[1], s[2]],
            rotation: rot,
            rotation_sigma_rad,
        });
        Ok(())
    })
}

/// Adds object points: `kinds` (0 tie, 1 control, 2 check), positions `xyz` (3n; for tie
/// points the approximate position), `sigmas` (3n, control σ in m; NULL when there is no
/// control point).
#[no_mangle]
pub unsafe extern "C" fn ccp_block_add_points(
    block: *mut CcpBlock,
    n: usize,
    ids: *const u64,
    kinds: *const u32,
    xyz: *const f64,
    sigmas: *const f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let ids = input(ids, n, "ids", false)?;
        let kinds = input(kinds, n, "kinds", false)?;
        let x = input(xyz, 3 * n, "xyz", false)?;
        finite(x, "xyz")?;
        let s = if sigmas.is_null() {
            None
        } else {
            Some(input(sigmas, 3 * n, "sigmas", false)?)
        };
        for i in 0..n {
            let kind = match kinds[i] {
                0 => PointKind::Tie,
                1 => PointKind::Control,
                2 => PointKind::Check,
                k => {
                    return Err(FfiError::invalid(format!(
                        "kinds[{i}] = {k}: expected 0 (tie), 1 (control) or 2 (check)"
                    )))
                }
            };
            let sigma = match (kind, s) {
                (PointKind::Control, Some(s)) => Some([s[3 * i], s[3 * i + 1], s[3 * i + 2]]),
                (PointKind::Control, None) => {
                    return Err(FfiError::invalid(format!(
                        "point {} is a control point but sigmas is NULL",
                        ids[i]
                    )))
                }
                _ => None,
            };
            b.block.points.insert(
                ids[i],
                ObjectPoint {
                    id: ids[i],
                    name: ids[i].to_string(),
                    kind,
                    position: Vector3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]),
                    sigma,
                    color: [128; 3],
                    observations: Vec::new(),
                },
            );
        }
        Ok(())
    })
}

/// Adds image observations: point `point_ids[i]` measured at `pixels[2i..2i+2]` in photo
/// `photo_ids[i]` with σ `sigma_px[i]`.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_add_observations(
    block: *mut CcpBlock,
    n: usize,
    point_ids: *const u64,
    photo_ids: *const u32,
    pixels: *const f64,
    sigma_px: *const f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let pid = input(point_ids, n, "point_ids", false)?;
        let ph = input(photo_ids, n, "photo_ids", false)?;
        let px = input(pixels, 2 * n, "pixels", false)?;
        let s = input(sigma_px, n, "sigma_px", false)?;
        finite(px, "pixels")?;
        finite(s, "sigma_px")?;
        for i in 0..n {
            if !b.block.photos.contains_key(&ph[i]) {
                return Err(FfiError::new(
                    CcpStatus::NotFound,
                    format!("photo_ids[{i}]: unknown photo {}", ph[i]),
                ));
            }
            if s[i] <= 0.0 {
                return Err(FfiError::invalid(format!("sigma_px[{i}] must be positive")));
            }
            let pt = b.block.points.get_mut(&pid[i]).ok_or_else(|| {
                FfiError::new(
                    CcpStatus::NotFound,
                    format!("point_ids[{i}]: unknown point {}", pid[i]),
                )
            })?;
            pt.observations.push(Observation {
                photo: ph[i],
                pixel: [px[2 * i], px[2 * i + 1]],
                sigma_px: s[i],
                provenance: "ffi".into(),
            });
        }
        Ok(())
    })
}

/// Adds LiDAR point-to-plane constraints n·X = d (block-local) with weights (1/m²).
#[no_mangle]
pub unsafe extern "C" fn ccp_block_add_planes(
    block: *mut CcpBlock,
    n: usize,
    point_ids: *const u64,
    normals: *const f64,
    d: *const f64,
    weights: *const f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let pid = input(point_ids, n, "point_ids", false)?;
        let nr = input(normals, 3 * n, "normals", false)?;
        let d = input(d, n, "d", false)?;
        let w = input(weights, n, "weights", false)?;
        finite(nr, "normals")?;
        finite(d, "d")?;
        finite(w, "weights")?;
        for i in 0..n {
            b.planes.push(PlaneConstraint {
                point: pid[i],
                normal: [nr[3 * i], nr[3 * i + 1], nr[3 * i + 2]],
                d: d[i],
                weight: w[i],
            });
        }
        Ok(())
    })
}

/// Makes the planes' common shift (the LiDAR's datum error) an unknown of the next
/// adjustments, with a zero prior of `sigma_m` per axis (metres, positive and finite);
/// 0 makes the planes the datum as they stand again (the default). The report's
/// `lidar_datum` gives the shift (`ccp_block_report_json`).
#[no_mangle]
pub unsafe extern "C" fn ccp_block_set_lidar_datum_sigma(
    block: *mut CcpBlock,
    sigma_m: f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        if !(sigma_m.is_finite() && sigma_m >= 0.0) {
            return Err(FfiError::invalid(format!(
                "sigma_m = {sigma_m}: expected a finite σ in metres, or 0 for none"
            )));
        }
        b.lidar_datum_sigma_m = (sigma_m > 0.0).then_some(sigma_m);
        Ok(())
    })
}

/// Adjusts the block in place (`options` NULL = defaults) and fills `out_summary`.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_adjust(
    block: *mut CcpBlock,
    options: *const CcpAdjustOptions,
    out_summary: *mut CcpAdjustSummary,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let mut b = write(&held, "block")?;
        let mut o = AdjustOptions::default();
        if let Some(c) = options.as_ref() {
            finite(&[c.loss_scale, c.k], "options")?;
            o.loss = match c.loss {
                0 => Loss::None,
                1 => Loss::Huber(c.loss_scale),
                2 => Loss::Cauchy(c.loss_scale),
                k => {
                    return Err(FfiError::invalid(format!(
                        "options.loss = {k}: expected 0, 1 or 2"
                    )))
                }
            };
            o.rejection = match c.rejection {
                0 => Rejection::None,
                1 => Rejection::Threshold(c.k),
                2 => Rejection::DataSnooping(c.k),
                k => {
                    return Err(FfiError::invalid(format!(
                        "options.rejection = {k}: expected 0, 1 or 2"
                    )))
                }
            };
            o.max_iterations = c.max_iterations as usize;
            o.max_rounds = c.max_rounds as usize;
        }
        o.lidar_datum_sigma_m = b.lidar_datum_sigma_m.map(|s| [s; 3]);
        let out = output(out_summary, 1, 1, "out_summary")?;
        let planes = b.planes.clone();
        let rep = adjust::adjust(&mut b.block, &planes, None, &o)?;
        let ck = rep.check.as_ref();
        out[0] = CcpAdjustSummary {
            sigma0: rep.sigma0,
            rmse_px: rep.rmse_px,
            iterations: rep.iterations as u32,
            rounds: rep.rounds as u32,
            converged: rep.converged as u32,
            rejected: rep.rejected.count as u32,
            photos: rep.photos as u32,
            points: rep.points as u32,
            observations: rep.observations as u64,
            time_s: rep.time_s,
            check_count: ck.map_or(0, |c| c.count as u32),
            check_rmse_plan_m: ck.map_or(f64::NAN, |c| c.rmse_plan_m),
            check_rmse_height_m: ck.map_or(f64::NAN, |c| c.rmse_height_m),
            check_max_m: ck.map_or(f64::NAN, |c| c.max_m),
        };
        b.report = Some(rep);
        Ok(())
    })
}

/// Reads a photo's (adjusted) pose and, after an adjustment, its EO standard deviations
/// (`out_sigma`: 6 values, rotation vector rad then centre m; may be NULL).
#[no_mangle]
pub unsafe extern "C" fn ccp_block_get_photo(
    block: *const CcpBlock,
    photo_id: u32,
    out_pose: *mut CcpPose,
    out_sigma: *mut f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let b = read(&held, "block")?;
        let ph = b.block.photos.get(&photo_id).ok_or_else(|| {
            FfiError::new(CcpStatus::NotFound, format!("unknown photo {photo_id}"))
        })?;
        output(out_pose, 1, 1, "out_pose")?[0] = CcpPose::from_pose(&ph.pose);
        if !out_sigma.is_null() {
            let o = output(out_sigma, 6, 6, "out_sigma")?;
            let pp = b
                .report
                .as_ref()
                .and_then(|r| r.photo_precision.iter().find(|p| p.photo == photo_id));
            match pp {
                Some(p) => {
                    o[..3].copy_from_slice(&p.sigma_rotation_rad);
                    o[3..].copy_from_slice(&p.sigma_center_m);
                }
                None => o.fill(f64::NAN),
            }
        }
        Ok(())
    })
}

/// Reads an object point's (adjusted) block-local position.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_get_point(
    block: *const CcpBlock,
    point_id: u64,
    out_xyz: *mut f64,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let b = read(&held, "block")?;
        let p = b.block.points.get(&point_id).ok_or_else(|| {
            FfiError::new(CcpStatus::NotFound, format!("unknown point {point_id}"))
        })?;
        output(out_xyz, 3, 3, "out_xyz")?.copy_from_slice(p.position.as_slice());
        Ok(())
    })
}

/// Copies the last adjustment's JSON report into `buf` (NUL-terminated) and writes the
/// size it needs (NUL included) to `out_needed`; call with `buf = NULL` to ask the size.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_report_json(
    block: *const CcpBlock,
    buf: *mut c_char,
    buf_len: usize,
    out_needed: *mut usize,
) -> CcpStatus {
    guard(|| {
        let held = get(block, "block")?;
        let b = read(&held, "block")?;
        let rep = b
            .report
            .as_ref()
            .ok_or_else(|| FfiError::invalid("the block has not been adjusted yet"))?;
        let s = serde_json::to_string(rep).map_err(|e| FfiError::invalid(e.to_string()))?;
        output(out_needed, 1, 1, "out_needed")?[0] = s.len() + 1;
        if !buf.is_null() {
            let o = output(buf, buf_len, s.len() + 1, "buf")?;
            for (d, c) in o.iter_mut().zip(s.bytes()) {
                *d = c as c_char;
            }
            o[s.len()] = 0;
        }
        Ok(())
    })
}

/// Resects one photo from `n` control points (`pixels` 2n, `points` 3n block-local, σ
/// `sigma_px`): RANSAC (threshold `threshold_px`) or LMedS (`lmeds` ≠ 0) over P3P, then
/// LM refinement and data snooping. Writes the pose, inlier flags (`out_inliers`, n bytes,
/// may be NULL) and the 6×6 covariance (`out_covariance`, row-major, may be NULL).
#[no_mangle]
pub unsafe extern "C" fn ccp_resect(
    camera: *const CcpCamera,
    n: usize,
    pixels: *const f64,
    points: *const f64,
    sigma_px: f64,
    threshold_px: f64,
    lmeds: u32,
    out_pose: *mut CcpPose,
    out_inliers: *mut u8,
    out_covariance: *mut f64,
) -> CcpStatus {
    guard(|| {
        let cam = &camera_arg(camera, "camera")?;
        let px = input(pixels, 2 * n, "pixels", false)?;
        let xs = input(points, 3 * n, "points", false)?;
        finite(px, "pixels")?;
        finite(xs, "points")?;
        let p: Vec<[f64; 2]> = px.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let x: Vec<[f64; 3]> = xs.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let opts = ResectionOptions {
            threshold_px,
            lmeds: lmeds != 0,
            ..Default::default()
        };
        let r = adjust::resect(cam, &p, &x, sigma_px, &opts)?;
        output(out_pose, 1, 1, "out_pose")?[0] = CcpPose::from_pose(&r.pose);
        if !out_inliers.is_null() {
            let o = output(out_inliers, n, n, "out_inliers")?;
            for (d, &b) in o.iter_mut().zip(&r.inliers) {
                *d = b as u8;
            }
        }
        if !out_covariance.is_null() {
            let o = output(out_covariance, 36, 36, "out_covariance")?;
            for i in 0..6 {
                o[6 * i..6 * i + 6].copy_from_slice(&r.covariance[i]);
            }
        }
        Ok(())
    })
}
