//! DCP packages and patch prediction through the C ABI.

use super::camera::{CcpCamera, CcpPose};
use super::{finite, finite_rows, guard, handle, input, output, CcpStatus, FfiError};
use crate::control::dcp::{DcpIndex, DcpPackage};
use crate::control::predict;
use nalgebra::{Matrix3, SMatrix, Vector3};
use std::ffi::{c_char, CStr};

/// Opaque handle of an opened (verified) DCP package with its spatial index.
pub struct CcpDcp {
    package: DcpPackage,
    index: DcpIndex,
}

fn path_arg<'a>(p: *const c_char, name: &str) -> Result<&'a str, FfiError> {
    if p.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            format!("{name} is a null pointer"),
        ));
    }
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .map_err(|_| FfiError::invalid(format!("{name} is not UTF-8")))
}

/// Opens and verifies a DCP package folder (manifest, CRS, every chip's checksum).
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_open(path: *const c_char, out_dcp: *mut *mut CcpDcp) -> CcpStatus {
    guard(|| {
        if out_dcp.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_dcp is a null pointer",
            ));
        }
        *out_dcp = std::ptr::null_mut();
        let p = path_arg(path, "path")?;
        let package = DcpPackage::open(std::path::Path::new(p)).map_err(|e| {
            let status = match e {
                crate::control::DcpError::Io { .. } => CcpStatus::Io,
                _ => CcpStatus::Format,
            };
            FfiError::new(status, e.to_string())
        })?;
        let index = DcpIndex::new(std::slice::from_ref(&package));
        *out_dcp = Box::into_raw(Box::new(CcpDcp { package, index }));
        Ok(())
    })
}

/// Releases a DCP handle; NULL is ignored.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_free(dcp: *mut CcpDcp) {
    if !dcp.is_null() {
        let _ = std::panic::catch_unwind(|| drop(Box::from_raw(dcp)));
    }
}

/// Number of control points of the package.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_point_count(
    dcp: *const CcpDcp,
    out_count: *mut usize,
) -> CcpStatus {
    guard(|| {
        let d = handle(dcp, "dcp")?;
        output(out_count, 1, 1, "out_count")?[0] = d.package.manifest.points.len();
        Ok(())
    })
}

/// Copies the control points' world coordinates (x, y, z interleaved, `out_len` ≥ 3·count)
/// and their σ (same layout) when `out_sigma` is not NULL.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_points(
    dcp: *const CcpDcp,
    out_xyz: *mut f64,
    out_sigma: *mut f64,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let d = handle(dcp, "dcp")?;
        let pts = &d.package.manifest.points;
        let xyz = output(out_xyz, out_len, 3 * pts.len(), "out_xyz")?;
        for (o, p) in xyz.chunks_exact_mut(3).zip(pts) {
            o.copy_from_slice(&p.xyz);
        }
        if !out_sigma.is_null() {
            let s = output(out_sigma, out_len, 3 * pts.len(), "out_sigma")?;
            for (o, p) in s.chunks_exact_mut(3).zip(pts) {
                o.copy_from_slice(&p.sigma);
            }
        }
        Ok(())
    })
}

/// Indices of the control points inside a polygon (world x, y interleaved, ≥ 3 vertices).
/// Writes at most `capacity` indices and the number found to `*out_count`; when
/// `*out_count` > `capacity` the call fails with CCP_STATUS_BUFFER_TOO_SMALL.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_query_polygon(
    dcp: *const CcpDcp,
    polygon: *const f64,
    n_vertices: usize,
    out_indices: *mut u64,
    capacity: usize,
    out_count: *mut usize,
) -> CcpStatus {
    guard(|| {
        let d = handle(dcp, "dcp")?;
        if n_vertices < 3 {
            return Err(FfiError::invalid(format!(
                "polygon needs at least 3 vertices, got {n_vertices}"
            )));
        }
        let poly = input(polygon, 2 * n_vertices, "polygon", false)?;
        finite_rows(poly, 2, "polygon")?;
        let verts: Vec<[f64; 2]> = poly.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let hits = d.index.query_polygon(&verts);
        output(out_count, 1, 1, "out_count")?[0] = hits.len();
        let out = output(out_indices, capacity, hits.len(), "out_indices")?;
        for (o, (_, i)) in out.iter_mut().zip(hits) {
            *o = i as u64;
        }
        Ok(())
    })
}

/// Predicts object points in a photo with approximate orientation: pixels (x, y
/// interleaved, `out_len` ≥ 2·n) and their 2×2 covariances (row-major, `cov_len` ≥ 4·n)
/// propagated from `eo_covariance` (6×6 row-major; rotation vector rad, then centre m) and
/// the points' σ (x, y, z interleaved, may be NULL for exact points).
#[no_mangle]
pub unsafe extern "C" fn ccp_predict(
    camera: *const CcpCamera,
    pose: *const CcpPose,
    eo_covariance: *const f64,
    points: *const f64,
    point_sigma: *const f64,
    n_points: usize,
    out_pixels: *mut f64,
    out_len: usize,
    out_covariance: *mut f64,
    cov_len: usize,
) -> CcpStatus {
    guard(|| {
        let cam = &handle(camera, "camera")?.0;
        let pose = handle(pose, "pose")?.to_pose()?;
        let cov = input(eo_covariance, 36, "eo_covariance", false)?;
        finite(cov, "eo_covariance")?;
        let eo = SMatrix::<f64, 6, 6>::from_row_slice(cov);
        let n3 = n_points
            .checked_mul(3)
            .ok_or_else(|| FfiError::invalid("n_points overflows"))?;
        let pts = input(points, n3, "points", false)?;
        finite_rows(pts, 3, "points")?;
        let sig = if point_sigma.is_null() {
            None
        } else {
            Some(input(point_sigma, n3, "point_sigma", false)?)
        };
        if let Some(s) = sig {
            finite_rows(s, 3, "point_sigma")?;
        }
        let px = output(out_pixels, out_len, 2 * n_points, "out_pixels")?;
        let pc = output(out_covariance, cov_len, 4 * n_points, "out_covariance")?;
        for i in 0..n_points {
            let x = Vector3::new(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]);
            let pcov = sig.map_or(Matrix3::zeros(), |s| {
                Matrix3::from_diagonal(&Vector3::new(
                    s[3 * i].powi(2),
                    s[3 * i + 1].powi(2),
                    s[3 * i + 2].powi(2),
                ))
            });
            let p = predict::predict(cam, &pose, &eo, &x, &pcov)
                .map_err(|e| FfiError::from(e).prefixed(&format!("points[{i}]")))?;
            px[2 * i] = p.pixel.x;
            px[2 * i + 1] = p.pixel.y;
            pc[4 * i..4 * i + 4].copy_from_slice(&[
                p.covariance[(0, 0)],
                p.covariance[(0, 1)],
                p.covariance[(1, 0)],
                p.covariance[(1, 1)],
            ]);
        }
        Ok(())
    })
}
