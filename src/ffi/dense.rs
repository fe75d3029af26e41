//! Dense matching over the C ABI: one stereo pair to object points, and the errors of
//! `crate::dense` as statuses.

use super::camera::{camera_arg, CcpCamera, CcpPose};
use super::matching::image_from;
use super::{finite, guard, handle, output, CcpStatus, FfiError, FfiResult};
use crate::dense::epoch::{match_stereo, DsmOptions};
use crate::dense::{DenseError, RectifiedPair};
use crate::geometry::{Camera, Pose};
use crate::matching::oriented::Surface;
use crate::matching::GreyImage;

/// Invalid inputs (sizes, options, a block without photos) are INVALID_ARGUMENT, a pair
/// that cannot be rectified (coinciding centres, a baseline along the view) NUMERIC, and
/// geometry and file errors as everywhere.
impl From<DenseError> for FfiError {
    fn from(e: DenseError) -> Self {
        match e {
            DenseError::Geometry(g) => g.into(),
            DenseError::Format(f) => f.into(),
            DenseError::Rectification(_) | DenseError::NoSurface(_) => {
                FfiError::new(CcpStatus::Numeric, e.to_string())
            }
            DenseError::InvalidInput { .. } => FfiError::invalid(e.to_string()),
        }
    }
}

/// One photo of a pair: its camera handle, exterior orientation and grey values
/// (row-major f32, `width × height`, the camera's size).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct CcpPairPhoto {
    pub camera: *const CcpCamera,
    pub pose: CcpPose,
    pub pixels: *const f32,
    pub width: u32,
    pub height: u32,
}

/// The camera, pose and image of one photo of a pair, checked.
unsafe fn pair_photo(p: *const CcpPairPhoto, name: &str) -> FfiResult<(Camera, Pose, GreyImage)> {
    let p = handle(p, name)?;
    let camera = camera_arg(p.camera, &format!("{name}.camera"))?;
    let pose = p.pose.to_pose()?;
    let image = image_from(p.pixels, p.width, p.height, &format!("{name}.pixels"))?;
    let (w, h) = camera.image_size();
    if (w, h) != (p.width, p.height) {
        return Err(FfiError::invalid(format!(
            "{name}: image of {}×{} px for a camera of {w}×{h} px",
            p.width, p.height
        )));
    }
    Ok((camera, pose, image))
}

/// Dense matching of one stereo pair: the pair is rectified, matched by semi-global
/// matching for object heights between `z_min` and `z_max` (the poses' frame), and every
/// matched pixel of the left photo triangulated. The object points (x, y, z interleaved,
/// the poses' frame) go to `*out_points`, an array the library allocates and
/// `ccp_points_free` releases; `*out_count` receives their number (0 with a NULL array
/// when nothing matched). Memory: one tile of about 2²⁰ rectified pixels is matched at a
/// time, beside the two images.
///
/// # Safety
/// Pointers must be null or valid: photos' `pixels` of `width·height` values, the outputs
/// writable.
#[no_mangle]
pub unsafe extern "C" fn ccp_match_pair(
    left: *const CcpPairPhoto,
    right: *const CcpPairPhoto,
    z_min: f64,
    z_max: f64,
    out_points: *mut *mut f64,
    out_count: *mut usize,
) -> CcpStatus {
    guard(|| {
        let points_out = output(out_points, 1, 1, "out_points")?;
        let count_out = output(out_count, 1, 1, "out_count")?;
        points_out[0] = std::ptr::null_mut();
        count_out[0] = 0;
        finite(&[z_min, z_max], "z_min/z_max")?;
        if z_min > z_max {
            return Err(FfiError::invalid(format!(
                "z_min {z_min} is above z_max {z_max}"
            )));
        }
        let (lc, lp, li) = pair_photo(left, "left")?;
        let (rc, rp, ri) = pair_photo(right, "right")?;
        let pair = RectifiedPair::new((&lc, &lp), (&rc, &rp))?;
        let half = 0.5 * (z_max - z_min);
        let prior = Surface::Plane {
            height: z_min + half,
            sigma_m: 0.0,
        };
        let mut xyz: Vec<f64> = Vec::new();
        match_stereo(
            &pair,
            &li,
            &ri,
            &prior,
            half,
            &DsmOptions::default(),
            |pts| xyz.extend(pts.iter().flat_map(|p| [p.x, p.y, p.z])),
        )?;
        if xyz.is_empty() {
            return Ok(());
        }
        count_out[0] = xyz.len() / 3;
        points_out[0] = Box::into_raw(xyz.into_boxed_slice()).cast::<f64>();
        Ok(())
    })
}

/// Releases an array of `count` points from `ccp_match_pair` (NULL is fine).
///
/// # Safety
/// `points` must be NULL or exactly what `ccp_match_pair` returned with this `count`, not
/// yet released.
#[no_mangle]
pub unsafe extern "C" fn ccp_points_free(points: *mut f64, count: usize) -> CcpStatus {
    guard(|| {
        if points.is_null() {
            return Ok(());
        }
        let n = count
            .checked_mul(3)
            .ok_or_else(|| FfiError::invalid("count overflows"))?;
        drop(Box::from_raw(std::ptr::slice_from_raw_parts_mut(points, n)));
        Ok(())
    })
}
