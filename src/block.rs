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
    /// Cameras with the same group are one physical camera whose free parameters take one
    /// value: the film camera behind scans that each have their own interior orientation
    /// (focal length and principal point in mm are the camera's, the scan's affine
    /// transformation is not). They must be of one kind with the same `free_params`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_group: Option<String>,
}

/// Prior on a photo's exterior orientation from POS (GNSS/IMU) or an approximate source
/// (strip interpolation): the approximate orientation with its covariance.
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

impl PosPrior {
    /// The prior as an approximate pose (the identity attitude when the POS has no IMU).
    pub fn pose(&self) -> Pose {
        Pose::new(
            self.rotation.unwrap_or_else(nalgebra::Matrix3::identity),
            self.center,
        )
    }

    /// 6×6 covariance in the local parameterisation of [`Pose::perturbed`] (rotation
    /// vector, then centre).
    pub fn covariance(&self) -> nalgebra::SMatrix<f64, 6, 6> {
        let mut c = nalgebra::SMatrix::<f64, 6, 6>::zeros();
        for i in 0..3 {
            c[(i, i)] = self.rotation_sigma_rad.powi(2);
            c[(i + 3, i + 3)] = self.center_sigma[i].powi(2);
        }
        c
    }
}

/// Why a photo could not be oriented: what the report shows and the C ABI returns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, thiserror::Error)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PhotoFailure {
    #[error("no approximate orientation (the photo is not in the POS or strip file)")]
    NoNavigation,
    #[error("image {path}: {message}")]
    Image { path: String, message: String },
    #[error("image {path} is {width}×{height} px, the camera {camera_width}×{camera_height}")]
    ImageSize {
        path: String,
        width: usize,
        height: usize,
        camera_width: u32,
        camera_height: u32,
    },
    #[error("fiducial interior orientation failed: {message}")]
    InteriorOrientation { message: String },
    #[error("footprint on the DEM: {message}")]
    Footprint { message: String },
    #[error("no control point predicted inside the photo ({in_footprint} in the footprint)")]
    NoControlInView { in_footprint: usize },
    #[error(
        "{matched} of {predicted} control patches matched; a resection with at least \
         {needed} inliers was not possible"
    )]
    TooFewMatches {
        matched: usize,
        predicted: usize,
        needed: usize,
    },
    /// A resected pose that its own predictions did not confirm: matched again in narrow
    /// windows around where it puts the patches, they no longer support a resection.
    #[error(
        "the resected pose was not confirmed: round {round} matched {matched} of \
         {predicted} patches at its predictions and {message}"
    )]
    Unconfirmed {
        round: usize,
        matched: usize,
        predicted: usize,
        message: String,
    },
    #[error("{kept} tie observations kept, fewer than {needed}")]
    TooFewTieObservations { kept: usize, needed: usize },
    /// The orientation found lies `sigmas` standard deviations of the navigation from it
    /// (the largest over the centre coordinates and the attitude), beyond `limit`: a
    /// wrong solution on repeated texture, or navigation with a wrong σ.
    #[error("the resected pose lies {sigmas:.1} σ from the navigation (at most {limit} accepted)")]
    FarFromPrior { sigmas: f64, limit: f64 },
    /// Left out of the block adjustment: too few of its points are seen by other photos
    /// (tie points) or are control.
    #[error("observes {points} adjustable point(s) of the block; the adjustment needs {needed}")]
    LostSupport { points: usize, needed: usize },
    #[error("control chip unusable: {message}")]
    Chip { message: String },
    #[error("{first}; with the epoch's own oriented photos as control: {second}")]
    SecondPass {
        first: Box<PhotoFailure>,
        second: Box<PhotoFailure>,
    },
    /// Not oriented from control (`before`), nor through tie points with the epoch's
    /// oriented photos (`ties`).
    #[error("{before}; through tie points with the epoch's oriented photos: {ties}")]
    TiePass {
        before: Box<PhotoFailure>,
        ties: Box<PhotoFailure>,
    },
}

/// Where a photo stands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PhotoStatus {
    /// The pose is approximate (navigation) or not known yet.
    #[default]
    Approximate,
    /// The pose is a resected or adjusted orientation.
    Oriented,
    /// Orientation was tried and failed.
    Failed(PhotoFailure),
}

/// A photo with its exterior orientation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Photo {
    pub id: PhotoId,
    /// Photo name (the image file's name or stem).
    pub name: String,
    pub camera: CameraId,
    pub pose: Pose,
    #[serde(default)]
    pub status: PhotoStatus,
    /// The approximate orientation with its σ (POS, strip interpolation).
    #[serde(default)]
    pub prior: Option<PosPrior>,
    /// Acquisition date (ISO 8601), when known.
    #[serde(default)]
    pub date: Option<String>,
    /// Image file, when the block knows it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<std::path::PathBuf>,
    /// How `pose` was obtained (free text for reports: "POS", "resection from 14 control
    /// patches", "block adjustment", …).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub provenance: String,
}

impl Photo {
    /// A photo with an approximate (or unknown) pose and nothing else known.
    pub fn new(id: PhotoId, name: impl Into<String>, camera: CameraId, pose: Pose) -> Self {
        Self {
            id,
            name: name.into(),
            camera,
            pose,
            status: PhotoStatus::Approximate,
            prior: None,
            date: None,
            image: None,
            provenance: String::new(),
        }
    }

    /// Whether `pose` is a resected or adjusted orientation.
    pub fn is_oriented(&self) -> bool {
        self.status == PhotoStatus::Oriented
    }

    /// The same photo marked oriented.
    pub fn oriented(mut self) -> Self {
        self.status = PhotoStatus::Oriented;
        self
    }
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

    /// The block without its photos that are not oriented (what products such as COLMAP
    /// models and BlocksExchange files hold).
    pub fn oriented_only(&self) -> Block {
        Block {
            photos: self
                .photos
                .iter()
                .filter(|(_, p)| p.is_oriented())
                .map(|(k, p)| (*k, p.clone()))
                .collect(),
            ..self.clone()
        }
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
