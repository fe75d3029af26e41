//! The records the text and binary readers share, before they are assembled into a
//! block, and the conversion of COLMAP's `cam_from_world` (quaternion, translation) to
//! our [`Pose`].

use crate::block::{CameraId, ObjectPoint, PhotoId};
use crate::geometry::{
    matrix_from_quaternion_wxyz, quaternion_wxyz_from_matrix, FrameCamera, Pose,
};
use nalgebra::{Matrix3, Vector3};
use std::collections::{BTreeMap, HashMap};

/// Frame cameras by id: the `cameras` file (and, one trivial rig each, `rigs`).
pub(super) type Cameras = BTreeMap<CameraId, FrameCamera>;

/// One image's POINTS2D in order: (pixel, point id or `INVALID_POINT3D`).
pub(super) type Points2d = Vec<([f64; 2], u64)>;

/// What `points3D` holds beyond the block's points.
pub(super) struct PointsTable<'a> {
    pub points: Vec<&'a ObjectPoint>,
    /// COLMAP's ERROR column: mean reprojection error per point (px).
    pub errors: Vec<f64>,
    /// POINT2D_IDX of every observation, flat over the points in order.
    pub idx: &'a [u32],
}

/// A parsed image record before its 2-D points are attached to object points.
pub(super) struct Image {
    pub id: PhotoId,
    pub pose: Pose,
    pub camera: CameraId,
    pub name: String,
    pub points2d: Points2d,
}

/// One image as both encodings write it (the images file, and the frames file of the
/// rig layout): `cam_from_world` as COLMAP's quaternion and translation.
pub(super) struct ImageRow<'a> {
    pub id: PhotoId,
    pub q: [f64; 4],
    pub t: [f64; 3],
    pub camera: CameraId,
    pub name: &'a str,
    pub points2d: &'a Points2d,
}

/// Sensor poses of one rig: camera id → `sensor_from_rig` (None for the reference sensor).
pub(super) type RigSensors = HashMap<u32, Option<Pose>>;

pub(super) fn pose_from_qt(q: [f64; 4], t: [f64; 3]) -> std::result::Result<Pose, String> {
    let n = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
    if !n.is_finite() || (n - 1.0).abs() > 1e-3 || t.iter().any(|v| !v.is_finite()) {
        return Err(format!(
            "pose is not a unit quaternion with a finite translation (|q| = {n})"
        ));
    }
    let r = matrix_from_quaternion_wxyz([q[0] / n, q[1] / n, q[2] / n, q[3] / n]);
    Ok(Pose::from_rotation_translation(r, Vector3::from(t)))
}

pub(super) fn qt_from_pose(p: &Pose) -> ([f64; 4], [f64; 3]) {
    let t = p.translation();
    (quaternion_wxyz_from_matrix(&p.rotation), [t.x, t.y, t.z])
}

/// `a ∘ b` for cam_from_world style poses: x ↦ a(b(x)).
pub(super) fn compose(a: &Pose, b: &Pose) -> Pose {
    let r: Matrix3<f64> = a.rotation * b.rotation;
    let t = a.rotation * b.translation() + a.translation();
    Pose::from_rotation_translation(r, t)
}

/// A parsed frame: (frame id, rig id, `rig_from_world`, data as (sensor type, sensor id,
/// data id)).
pub(super) type FrameRecord = (u32, u32, Pose, Vec<(i32, u32, u64)>);

/// Receives each parsed 3-D point: (id, xyz, rgb, track as (image id, POINT2D_IDX)).
pub(super) type PointSink<'a> =
    dyn FnMut(u64, [f64; 3], [u8; 3], &[(u32, u32)]) -> std::result::Result<(), String> + 'a;
