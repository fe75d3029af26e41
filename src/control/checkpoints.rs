//! Checkpoint evaluation, the one for every epoch and every caller: each checkpoint is
//! intersected from its measurements in the oriented photos of a block and compared with
//! its surveyed coordinates, in metres and in ground pixels.

use crate::adjust;
use crate::block::{Block, Photo};
pub use crate::formats::control_points::CheckpointMeasurement;
use crate::formats::pos::photo_key;
use crate::geometry::{Camera, Pose};
use nalgebra::Vector3;
use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CheckpointError {
    pub id: String,
    /// Intersected minus surveyed (m).
    pub error: [f64; 3],
    pub rays: usize,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CheckpointEvaluation {
    pub count: usize,
    pub rmse_plan_m: f64,
    pub rmse_height_m: f64,
    pub max_m: f64,
    pub gsd_m: f64,
    pub rmse_plan_px: f64,
    pub rmse_height_px: f64,
    pub max_px: f64,
    pub points: Vec<CheckpointError>,
}

/// Why checkpoints could not be evaluated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvaluationError {
    #[error("ground pixel {0} must be positive")]
    Gsd(f64),
    /// A measurement names a photo the epoch does not have (a naming mistake).
    #[error(
        "line {line}: checkpoint {point} is measured in photo {photo:?}, which is not a photo of the epoch"
    )]
    UnknownPhoto {
        line: usize,
        point: String,
        photo: String,
    },
    /// Too few oriented photos see a checkpoint (a result, not an input error).
    #[error("no checkpoint is measured in two or more oriented photos")]
    TooFewRays,
}

/// Intersects every checkpoint measured in at least two oriented photos of `block` (least
/// squares on the reprojection error with the full camera model) and compares it with its
/// surveyed coordinates (world, the block's CRS); errors are also given in ground pixels of
/// `gsd_m`. Measurements name photos by file name or stem; one naming a photo the block does not hold at all is
/// an error (a typo must not silently thin out the evaluation), one in a photo that is
/// not oriented is left out.
pub fn evaluate_checkpoints(
    block: &Block,
    measurements: &[CheckpointMeasurement],
    surveyed: &[(String, [f64; 3])],
    gsd_m: f64,
) -> Result<CheckpointEvaluation, EvaluationError> {
    if !(gsd_m.is_finite() && gsd_m > 0.0) {
        return Err(EvaluationError::Gsd(gsd_m));
    }
    let by_name: BTreeMap<&str, &Photo> = block
        .photos
        .values()
        .map(|p| (photo_key(&p.name), p))
        .collect();
    if let Some(m) = measurements
        .iter()
        .find(|m| !by_name.contains_key(photo_key(&m.photo)))
    {
        return Err(EvaluationError::UnknownPhoto {
            line: m.line,
            point: m.id.clone(),
            photo: m.photo.clone(),
        });
    }
    let origin = Vector3::from(block.origin);
    let mut points = Vec::new();
    for (id, xyz) in surveyed {
        let rays: Vec<(&Camera, &Pose, [f64; 2], f64)> = measurements
            .iter()
            .filter(|m| &m.id == id)
            .filter_map(|m| {
                let ph = by_name
                    .get(photo_key(&m.photo))
                    .filter(|p| p.is_oriented())?;
                let cam = &block.cameras.get(&ph.camera)?.model;
                Some((cam, &ph.pose, m.pixel, 1.0))
            })
            .collect();
        let Some(x) = adjust::intersect(&rays) else {
            continue;
        };
        let e = x + origin - Vector3::from(*xyz);
        points.push(CheckpointError {
            id: id.clone(),
            error: [e.x, e.y, e.z],
            rays: rays.len(),
        });
    }
    if points.is_empty() {
        return Err(EvaluationError::TooFewRays);
    }
    let [plan, height, max] = adjust::checkpoint_rmse(points.iter().map(|p| p.error));
    Ok(CheckpointEvaluation {
        count: points.len(),
        rmse_plan_m: plan,
        rmse_height_m: height,
        max_m: max,
        gsd_m,
        rmse_plan_px: plan / gsd_m,
        rmse_height_px: height / gsd_m,
        max_px: max / gsd_m,
        points,
    })
}
