//! Collinearity equations: object point → pixel through exterior and interior orientation,
//! with analytic Jacobians for the bundle adjustment and resection.

use super::camera::IntrinsicsJacobian;
use super::{skew, Camera, Pose, Result};
use nalgebra::{SMatrix, Vector2, Vector3};

/// A projected point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    pub pixel: Vector2<f64>,
    /// Depth along the optical axis (m).
    pub depth: f64,
}

/// Partial derivatives of a pixel.
///
/// Exterior orientation is perturbed locally as in [`Pose::perturbed`]: the first three
/// columns of `pose` belong to a rotation vector applied on the left of `R`, the last three
/// to the projection centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectionJacobians {
    pub pose: SMatrix<f64, 2, 6>,
    pub point: SMatrix<f64, 2, 3>,
    pub intrinsics: IntrinsicsJacobian,
}

/// Projects a world point into a photo.
#[inline]
pub fn project(camera: &Camera, pose: &Pose, x: &Vector3<f64>) -> Result<Projection> {
    let xc = pose.to_camera(x);
    let pixel = camera.project(&xc)?;
    Ok(Projection { pixel, depth: xc.z })
}

/// Projects a world point and returns the Jacobians with respect to exterior orientation,
/// the object point and the interior parameters.
#[inline]
pub fn project_with_jacobians(
    camera: &Camera,
    pose: &Pose,
    x: &Vector3<f64>,
) -> Result<(Projection, ProjectionJacobians)> {
    let xc = pose.to_camera(x);
    let (pixel, j_xc, j_int) = camera.project_with_jacobian(&xc)?;
    // X_cam = R (X − C): ∂/∂δθ = −[X_cam]×, ∂/∂C = −R, ∂/∂X = R.
    let j_rot = j_xc * (-skew(&xc));
    let j_point = j_xc * pose.rotation;
    let mut j_pose = SMatrix::<f64, 2, 6>::zeros();
    j_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&j_rot);
    j_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&(-j_point));
    Ok((
        Projection { pixel, depth: xc.z },
        ProjectionJacobians {
            pose: j_pose,
            point: j_point,
            intrinsics: j_int,
        },
    ))
}
