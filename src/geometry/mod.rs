//! Geometry core: camera models with Brown distortion, film interior orientation,
//! rotation conventions, collinearity with analytic Jacobians, 7-parameter similarity
//! transforms and ray–DEM intersection.
//!
//! Conventions (design overview §2): camera frame x right, y down, z forward;
//! exterior orientation is `R` (world→camera) and the projection centre `C`, so
//! `X_cam = R (X − C)`; pixel origin at the top-left corner of the top-left pixel.

mod camera;
mod collinearity;
mod dem;
mod hartley;
mod interior;
pub mod lattice;
pub mod region;
mod rotation;
pub mod serde_matrix;
mod similarity;

pub use camera::{Brown, Camera, FilmCamera, FrameCamera};
pub use collinearity::{project, project_with_jacobians, Projection, ProjectionJacobians};
pub use dem::{Dem, GeoTransform};
pub(crate) use hartley::{dlt_null_matrix, hartley_normalisation};
pub use interior::{InteriorOrientation, InteriorTransformKind};
pub use lattice::{Lattice, LatticeGrid};
pub use rotation::{
    matrix_from_opk, matrix_from_quaternion_wxyz, matrix_from_ypr, opk_from_matrix, orthonormalize,
    quaternion_wxyz_from_matrix, rotation_from_vector, skew, ypr_from_matrix,
};
pub use similarity::Similarity;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Errors of the geometry core. Each names the quantity that was wrong.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GeometryError {
    #[error("{what} is not finite")]
    NotFinite { what: String },
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
    #[error("point lies behind the camera (z = {z:.6})")]
    BehindCamera { z: f64 },
    #[error("degenerate configuration: {0}")]
    Degenerate(String),
    #[error("{what} did not converge after {iterations} iterations")]
    NotConverged { what: String, iterations: usize },
    #[error("the ray does not meet the DEM: {0}")]
    NoIntersection(String),
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

pub type Result<T> = std::result::Result<T, GeometryError>;

/// Exterior orientation of a photo: `X_cam = rotation · (X − center)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// World→camera rotation (rows are the camera axes in world coordinates); JSON: three
    /// rows.
    #[serde(with = "serde_matrix::row_major")]
    pub rotation: Matrix3<f64>,
    /// Projection centre in world (block-local) coordinates.
    pub center: Vector3<f64>,
}

impl Pose {
    pub fn new(rotation: Matrix3<f64>, center: Vector3<f64>) -> Self {
        Self { rotation, center }
    }

    /// Pose from photogrammetric omega/phi/kappa (radians) and the projection centre.
    pub fn from_opk(omega: f64, phi: f64, kappa: f64, center: Vector3<f64>) -> Self {
        Self::new(matrix_from_opk(omega, phi, kappa), center)
    }

    /// Camera-frame coordinates of a world point.
    #[inline]
    pub fn to_camera(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * (x - self.center)
    }

    /// World direction of a camera-frame direction.
    #[inline]
    pub fn direction_to_world(&self, d: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.transpose() * d
    }

    /// COLMAP translation `t = −R·C`.
    pub fn translation(&self) -> Vector3<f64> {
        -(self.rotation * self.center)
    }

    /// From COLMAP's `cam_from_world` rotation and translation.
    pub fn from_rotation_translation(rotation: Matrix3<f64>, t: Vector3<f64>) -> Self {
        Self::new(rotation, -(rotation.transpose() * t))
    }

    /// Applies a local update: rotation vector `dtheta` (left-multiplied) and centre shift `dc`.
    /// This is the parameterisation the collinearity Jacobians are taken in.
    pub fn perturbed(&self, dtheta: &Vector3<f64>, dc: &Vector3<f64>) -> Self {
        Self::new(
            rotation_from_vector(dtheta) * self.rotation,
            self.center + dc,
        )
    }

    pub fn is_finite(&self) -> bool {
        self.rotation.iter().all(|v| v.is_finite()) && self.center.iter().all(|v| v.is_finite())
    }

    /// Checks that the rotation is orthonormal with determinant +1 (to `tol`).
    pub fn validate(&self, tol: f64) -> Result<()> {
        if !self.is_finite() {
            return Err(GeometryError::NotFinite {
                what: "pose".into(),
            });
        }
        let e = (self.rotation * self.rotation.transpose() - Matrix3::identity())
            .abs()
            .max();
        let det = self.rotation.determinant();
        if e > tol || (det - 1.0).abs() > tol {
            return Err(GeometryError::InvalidArgument(format!(
                "pose rotation is not a proper rotation (|RRᵀ−I| = {e:.2e}, det = {det:.6})"
            )));
        }
        Ok(())
    }
}

/// A ray in world coordinates: `origin + t·direction`, direction of unit length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: Vector3<f64>,
    pub direction: Vector3<f64>,
}

impl Ray {
    pub fn at(&self, t: f64) -> Vector3<f64> {
        self.origin + self.direction * t
    }
}

/// Back-projects an image point (pixels) to a world ray through the projection centre.
pub fn back_project(camera: &Camera, pose: &Pose, pixel: [f64; 2]) -> Result<Ray> {
    let d_cam = camera.unproject(pixel)?;
    let d = pose.direction_to_world(&d_cam).normalize();
    Ok(Ray {
        origin: pose.center,
        direction: d,
    })
}

pub(crate) fn check_finite(values: &[f64], what: &str) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(GeometryError::NotFinite {
            what: what.to_string(),
        })
    }
}
