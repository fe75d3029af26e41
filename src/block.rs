//! The block: the one scene model every stage reads and updates (cameras, photos with
//! exterior orientation, object points with their image observations, control and check
//! points), like COLMAP's `Reconstruction`. Coordinates are block-local: world = local +
//! `origin`, so heavy numerics stay well conditioned with projected coordinates of 10⁶ m.

use crate::geometry::{Camera, Pose};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

pub type CameraId = u32;
pub type PhotoId = u32;
pub type PointId = u64;

/// A camera (interior orientation) shared by a group of photos.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BlockCamera {
    pub id: CameraId,
    pub name: String,
    pub model: Camera,
    /// Names of interior parameters that are free in self-calibration (see
    /// [`Camera::param_names`]); empty = all fixed.
    #[serde(default)]
    pub free_params: Vec<String>,
}

/// Prior on a photo's exterior orientation from POS (GNSS/IMU) or an approximate source.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PosPrior {
    /// Measured projection centre (block-local).
    pub center: Vector3<f64>,
    /// Standard deviations of the centre (m): x, y, z.
    pub center_sigma: [f64; 3],
    /// Measured attitude as a world→camera rotation, if the POS has an IMU; JSON: three
    /// rows, or null.
    #[serde(default, with = "crate::geometry::serde_matrix::option_row_major")]
    pub rotation: Option<nalgebra::Matrix3<f64>>,
    /// Standard deviation of each attitude angle (rad).
    pub rotation_sigma_rad: f64,
}

/// A photo with its exterior orientation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Photo {
    pub id: PhotoId,
    /// Image file name, relative to the block's image folder.
    pub name: String,
    pub camera: CameraId,
    pub pose: Pose,
    /// Whether `pose` is an adjusted orientation (false: approximate or unknown).
    #[serde(default)]
    pub oriented: bool,
    #[serde(default)]
    pub prior: Option<PosPrior>,
    /// Acquisition date (ISO 8601), when known.
    #[serde(default)]
    pub date: Option<String>,
}

/// Role of an object point in the adjustment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PointKind {
    /// Unknown position, determined by intersection (tie point).
    #[default]
    Tie,
    /// Known position with a σ, enters the solution as an object-point prior.
    Control,
    /// Known position, never in the solution; compared with its intersection afterwards.
    Check,
}

/// One image measurement of an object point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    pub photo: PhotoId,
    /// Pixel position (x = column, y = row, origin at the top-left corner of the top-left pixel).
    pub pixel: [f64; 2],
    /// A-priori standard deviation (px).
    pub sigma_px: f64,
    /// Which matcher or DCP produced it (free text, for reports).
    #[serde(default)]
    pub provenance: String,
}

/// An object point: tie, control or check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectPoint {
    pub id: PointId,
    /// Name (control/check point label); empty for tie points.
    #[serde(default)]
    pub name: String,
    pub kind: PointKind,
    /// Current (block-local) position: adjusted for tie points, surveyed for control/check.
    pub position: Vector3<f64>,
    /// Standard deviations of a control point's surveyed position (m): x, y, z.
    #[serde(default)]
    pub sigma: Option<[f64; 3]>,
    #[serde(default)]
    pub color: [u8; 3],
    pub observations: Vec<Observation>,
}

/// The scene model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Block {
    /// CRS of world coordinates (`EPSG:n` or WKT); `None` for an arbitrary frame.
    pub crs: Option<String>,
    /// World coordinates of the block-local origin.
    pub origin: [f64; 3],
    pub cameras: BTreeMap<CameraId, BlockCamera>,
    pub photos: BTreeMap<PhotoId, Photo>,
    pub points: BTreeMap<PointId, ObjectPoint>,
    /// Image points not (yet) linked to an object point, per photo (pixels): detected
    /// keypoints that formats such as COLMAP carry alongside the tracks.
    #[serde(default)]
    pub keypoints: BTreeMap<PhotoId, Vec<[f64; 2]>>,
}

/// Errors of block consistency checks.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum BlockError {
    #[error("photo {photo} ({name}) refers to unknown camera {camera}")]
    UnknownCamera {
        photo: PhotoId,
        name: String,
        camera: CameraId,
    },
    #[error("point {point} has an observation in unknown photo {photo}")]
    UnknownPhoto { point: PointId, photo: PhotoId },
    #[error("{what} is not finite")]
    NotFinite { what: String },
    #[error("camera {camera}: {message}")]
    InvalidCamera { camera: CameraId, message: String },
}

impl Block {
    pub fn new() -> Self {
        Self::default()
    }

    /// World coordinates of a block-local position.
    pub fn to_world(&self, local: &Vector3<f64>) -> Vector3<f64> {
        local + Vector3::from(self.origin)
    }

    /// Block-local coordinates of a world position.
    pub fn to_local(&self, world: &Vector3<f64>) -> Vector3<f64> {
        world - Vector3::from(self.origin)
    }

    pub fn camera_of(&self, photo: &Photo) -> Option<&BlockCamera> {
        self.cameras.get(&photo.camera)
    }

    /// Number of image observations over all points.
    pub fn num_observations(&self) -> usize {
        self.points.values().map(|p| p.observations.len()).sum()
    }

    pub fn next_point_id(&self) -> PointId {
        self.points.keys().next_back().map_or(1, |k| k + 1)
    }

    /// Checks references and finiteness; every error names the item.
    pub fn validate(&self) -> Result<(), BlockError> {
        for c in self.cameras.values() {
            c.model.validate().map_err(|e| BlockError::InvalidCamera {
                camera: c.id,
                message: e.to_string(),
            })?;
        }
        for p in self.photos.values() {
            if !self.cameras.contains_key(&p.camera) {
                return Err(BlockError::UnknownCamera {
                    photo: p.id,
                    name: p.name.clone(),
                    camera: p.camera,
                });
            }
            if !p.pose.is_finite() {
                return Err(BlockError::NotFinite {
                    what: format!("pose of photo {} ({})", p.id, p.name),
                });
            }
        }
        for pt in self.points.values() {
            if !pt.position.iter().all(|v| v.is_finite()) {
                return Err(BlockError::NotFinite {
                    what: format!("position of point {}", pt.id),
                });
            }
            for o in &pt.observations {
                if !self.photos.contains_key(&o.photo) {
                    return Err(BlockError::UnknownPhoto {
                        point: pt.id,
                        photo: o.photo,
                    });
                }
                if !o.pixel.iter().all(|v| v.is_finite())
                    || !o.sigma_px.is_finite()
                    || o.sigma_px <= 0.0
                {
                    return Err(BlockError::NotFinite {
                        what: format!("observation of point {} in photo {}", pt.id, o.photo),
                    });
                }
            }
        }
        Ok(())
    }
}
