//! Camera handles, projection and back-projection.

use super::handles::{free, get, new_handle, read, Handle};
use super::{finite, finite_rows, guard, handle, input, output, CcpStatus, FfiError, FfiResult};
use crate::geometry::{self, Brown, Camera, FrameCamera, Pose};
use nalgebra::{Matrix3, Vector3};

/// Opaque camera handle; create with `ccp_camera_new_frame`, release with `ccp_camera_free`.
/// Thread safety: never changed after creation, so any number of threads may use one
/// camera at once.
pub struct CcpCamera(pub(crate) Camera);

impl Handle for CcpCamera {
    const TAG: usize = 1;
    const NAME: &'static str = "CcpCamera";
}

/// The camera of a handle (a copy: the handle's lock is not held beyond this).
pub(crate) fn camera_arg(h: *const CcpCamera, name: &str) -> FfiResult<Camera> {
    let held = get(h, name)?;
    let camera = read(&held, name)?.0.clone();
    Ok(camera)
}

/// Exterior orientation: `rotation` is the row-major world→camera matrix R and `center`
/// the projection centre C, so that X_cam = R·(X − C) (x right, y down, z forward).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct CcpPose {
    pub rotation: [f64; 9],
    pub center: [f64; 3],
}

impl CcpPose {
    pub(crate) fn to_pose(self) -> FfiResult<Pose> {
        finite(&self.rotation, "pose.rotation")?;
        finite(&self.center, "pose.center")?;
        let pose = Pose::new(
            Matrix3::from_row_slice(&self.rotation),
            Vector3::from(self.center),
        );
        pose.validate(1e-6)
            .map_err(|e| FfiError::invalid(format!("pose: {e}")))?;
        Ok(pose)
    }

    pub(crate) fn from_pose(p: &Pose) -> Self {
        let mut rotation = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                rotation[r * 3 + c] = p.rotation[(r, c)];
            }
        }
        Self {
            rotation,
            center: [p.center.x, p.center.y, p.center.z],
        }
    }
}

/// Creates a digital frame camera. `params` holds `fx, fy, cx, cy` (pinhole, 4 values) or
/// `fx, fy, cx, cy, k1, k2, k3, p1, p2` (Brown, 9 values), in pixels with the origin at
/// the top-left corner of the top-left pixel. The handle goes to `*out_camera`.
#[no_mangle]
pub unsafe extern "C" fn ccp_camera_new_frame(
    width: u32,
    height: u32,
    params: *const f64,
    n_params: usize,
    out_camera: *mut *mut CcpCamera,
) -> CcpStatus {
    guard(|| {
        if out_camera.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_camera is a null pointer",
            ));
        }
        *out_camera = std::ptr::null_mut();
        let p = input(params, n_params, "params", false)?;
        finite(p, "params")?;
        let distortion = match p.len() {
            4 => Brown::default(),
            9 => Brown::from_array([p[4], p[5], p[6], p[7], p[8]]),
            n => {
                return Err(FfiError::invalid(format!(
                    "params: expected 4 (pinhole) or 9 (Brown) values, got {n}"
                )))
            }
        };
        let cam = Camera::Frame(FrameCamera {
            width,
            height,
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
            distortion,
        });
        cam.validate()?;
        *out_camera = new_handle(CcpCamera(cam));
        Ok(())
    })
}

/// Releases a camera handle; NULL is ignored. A handle already freed or of another type
/// is refused with `CCP_STATUS_INVALID_HANDLE` (nothing is freed).
#[no_mangle]
pub unsafe extern "C" fn ccp_camera_free(camera: *mut CcpCamera) -> CcpStatus {
    free(camera, "camera")
}

/// Builds a pose from photogrammetric omega, phi, kappa (radians) and the projection centre.
#[no_mangle]
pub unsafe extern "C" fn ccp_pose_from_opk(
    omega: f64,
    phi: f64,
    kappa: f64,
    center: *const f64,
    out_pose: *mut CcpPose,
) -> CcpStatus {
    guard(|| {
        finite(&[omega, phi, kappa], "omega/phi/kappa")?;
        let c = input(center, 3, "center", false)?;
        finite(c, "center")?;
        let out = output(out_pose, 1, 1, "out_pose")?;
        out[0] = CcpPose::from_pose(&Pose::from_opk(
            omega,
            phi,
            kappa,
            Vector3::new(c[0], c[1], c[2]),
        ));
        Ok(())
    })
}

/// Projects `n_points` object points (`points`: x, y, z interleaved) into pixels
/// (`out_pixels`: x, y interleaved; `out_len` ≥ 2·n_points). Points behind the camera fail
/// the call with the index of the first one.
#[no_mangle]
pub unsafe extern "C" fn ccp_project(
    camera: *const CcpCamera,
    pose: *const CcpPose,
    points: *const f64,
    n_points: usize,
    out_pixels: *mut f64,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let cam = &camera_arg(camera, "camera")?;
        let pose = handle(pose, "pose")?.to_pose()?;
        let n3 = n_points
            .checked_mul(3)
            .ok_or_else(|| FfiError::invalid("n_points overflows"))?;
        let pts = input(points, n3, "points", false)?;
        finite_rows(pts, 3, "points")?;
        let out = output(out_pixels, out_len, 2 * n_points, "out_pixels")?;
        for (i, (x, o)) in pts.chunks_exact(3).zip(out.chunks_exact_mut(2)).enumerate() {
            let p = geometry::project(cam, &pose, &Vector3::new(x[0], x[1], x[2]))
                .map_err(|e| FfiError::from(e).prefixed(&format!("points[{i}]")))?;
            o[0] = p.pixel.x;
            o[1] = p.pixel.y;
        }
        Ok(())
    })
}

/// Back-projects `n_pixels` pixels (x, y interleaved) to unit ray directions in object
/// space (`out_directions`: x, y, z interleaved, `out_len` ≥ 3·n_pixels); every ray starts
/// at the pose's projection centre.
#[no_mangle]
pub unsafe extern "C" fn ccp_back_project(
    camera: *const CcpCamera,
    pose: *const CcpPose,
    pixels: *const f64,
    n_pixels: usize,
    out_directions: *mut f64,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let cam = &camera_arg(camera, "camera")?;
        let pose = handle(pose, "pose")?.to_pose()?;
        let n2 = n_pixels
            .checked_mul(2)
            .ok_or_else(|| FfiError::invalid("n_pixels overflows"))?;
        let px = input(pixels, n2, "pixels", false)?;
        finite_rows(px, 2, "pixels")?;
        let out = output(out_directions, out_len, 3 * n_pixels, "out_directions")?;
        for (i, (p, o)) in px.chunks_exact(2).zip(out.chunks_exact_mut(3)).enumerate() {
            let ray = geometry::back_project(cam, &pose, [p[0], p[1]])
                .map_err(|e| FfiError::from(e).prefixed(&format!("pixels[{i}]")))?;
            o.copy_from_slice(ray.direction.as_slice());
        }
        Ok(())
    })
}

impl FfiError {
    pub(crate) fn prefixed(mut self, what: &str) -> Self {
        self.message = format!("{what}: {}", self.message);
        self
    }
}
