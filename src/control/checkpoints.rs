//! Checkpoint evaluation, the one for every epoch and every caller: each checkpoint is
//! intersected from its measurements in the oriented photos of a block and compared with
//! its surveyed coordinates, in metres and in ground pixels.

use crate::adjust;
use crate::adjust::rays::Ray;
use crate::block::{Block, Photo};
pub use crate::formats::control_points::CheckpointMeasurement;
use crate::formats::pos::photo_key;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CheckpointError {
    pub id: String,
    /// Intersected minus surveyed (m).
    pub error: [f64; 3],
    pub rays: usize,
}

/// A checkpoint measurement the evaluation left out: its ray disagreed with the
/// checkpoint's other rays beyond chance (data snooping), or the checkpoint's rays
/// disagree and no single ray explains it (then all of them, and the checkpoint is not
/// evaluated).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RejectedMeasurement {
    pub id: String,
    pub photo: String,
    /// 1-based line of the measurement file.
    pub line: usize,
    pub pixel: [f64; 2],
    /// Reprojection error at the intersection of the rays kept (px); None when the
    /// checkpoint has no position.
    pub residual_px: Option<f64>,
    pub reason: String,
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
    /// Checkpoints measured in two or more oriented photos whose rays could not be made
    /// to agree: not in the RMSE, counted here.
    pub not_evaluated: usize,
    pub rejected: Vec<RejectedMeasurement>,
}

/// The σ (px) a checkpoint measurement is tested with: an operator's pointing in an
/// oriented photo, about a pixel.
pub const MEASUREMENT_SIGMA_PX: f64 = 1.0;

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
    /// A measurement names a checkpoint the surveyed points do not hold (a typo, or a
    /// point left out of the survey file): it would be dropped from the evaluation.
    #[error(
        "line {line}: checkpoint {point:?} (measured in photo {photo:?}) is not among the \
         surveyed checkpoints"
    )]
    UnknownPoint {
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
/// an error (a typo must not silently thin out the evaluation), and so is one naming a
/// checkpoint `surveyed` does not hold; one in a photo that is not oriented is left out.
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
    if let Some(m) = unknown_point(measurements, surveyed) {
        return Err(EvaluationError::UnknownPoint {
            line: m.line,
            point: m.id.clone(),
            photo: m.photo.clone(),
        });
    }
    let origin = Vector3::from(block.origin);
    let mut points = Vec::new();
    let mut rejected = Vec::new();
    let mut not_evaluated = 0;
    for (id, xyz) in surveyed {
        let (meas, rays): (Vec<&CheckpointMeasurement>, Vec<Ray<'_>>) = measurements
            .iter()
            .filter(|m| &m.id == id)
            .filter_map(|m| {
                let ph = by_name
                    .get(photo_key(&m.photo))
                    .filter(|p| p.is_oriented())?;
                let cam = &block.cameras.get(&ph.camera)?.model;
                Some((
                    m,
                    Ray {
                        camera: cam,
                        pose: ph.pose,
                        pixel: m.pixel,
                        sigma_px: MEASUREMENT_SIGMA_PX,
                    },
                ))
            })
            .unzip();
        if rays.len() < 2 {
            continue;
        }
        let s = adjust::rays::intersect_snooped(&rays, 1.0, 0.001);
        let reject = |i: usize, residual_px: Option<f64>, reason: String| RejectedMeasurement {
            id: id.clone(),
            photo: meas[i].photo.clone(),
            line: meas[i].line,
            pixel: meas[i].pixel,
            residual_px,
            reason,
        };
        for r in &s.rejected {
            rejected.push(reject(
                r.index,
                Some(r.residual_px).filter(|v| v.is_finite()),
                format!(
                    "data snooping: leaving it out lowers the rays' χ² by {:.1} (> {:.1}, α 0.1 %, σ {MEASUREMENT_SIGMA_PX} px)",
                    r.statistic,
                    adjust::chi2::critical(2, 0.001)
                ),
            ));
        }
        let Some(x) = s.position else {
            not_evaluated += 1;
            let reason = format!(
                "the checkpoint's {} remaining rays disagree (χ² {:.1}, {} degrees of freedom) and no single ray explains it: not evaluated",
                s.kept.len(),
                s.ssr,
                s.dof
            );
            for &i in &s.kept {
                rejected.push(reject(i, None, reason.clone()));
            }
            continue;
        };
        let e = x + origin - Vector3::from(*xyz);
        points.push(CheckpointError {
            id: id.clone(),
            error: [e.x, e.y, e.z],
            rays: s.kept.len(),
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
        not_evaluated,
        rejected,
    })
}

/// The first measurement of a checkpoint that `surveyed` does not hold.
fn unknown_point<'a>(
    measurements: &'a [CheckpointMeasurement],
    surveyed: &[(String, [f64; 3])],
) -> Option<&'a CheckpointMeasurement> {
    let ids: std::collections::BTreeSet<&str> = surveyed.iter().map(|s| s.0.as_str()).collect();
    measurements.iter().find(|m| !ids.contains(m.id.as_str()))
}

/// Refuses, before any work, a measurement (of the file `path`) naming a checkpoint that
/// the surveyed points do not hold: an error naming the file, the line and the id, where
/// it would otherwise be dropped from the evaluation without a word.
pub fn check_measured_points(
    path: &std::path::Path,
    measurements: &[CheckpointMeasurement],
    surveyed: &[(String, [f64; 3])],
) -> Result<(), crate::formats::FormatError> {
    match unknown_point(measurements, surveyed) {
        None => Ok(()),
        Some(m) => Err(crate::formats::FormatError::at(
            path,
            m.line,
            Some("id".into()),
            format!(
                "checkpoint {:?} (measured in photo {:?}) is not among the surveyed checkpoints",
                m.id, m.photo
            ),
        )),
    }
}
