//! Robust bundle adjustment with self-calibration, and single-photo resection.
//!
//! [`adjust`] reads a [`Block`], assembles one residual block per observation (image
//! points of tie and control points, control-point priors, POS centre/attitude priors,
//! LiDAR point-to-plane constraints), solves by Levenberg–Marquardt on the reduced camera
//! system, removes gross errors (IRLS with Huber/Cauchy, then Baarda data snooping
//! against the a-priori σ, or elimination of observations whose standardised residual
//! exceeds k·σ0), writes the adjusted orientations back into the block and reports the
//! precision with variance components per observation group.
//! Check points never enter the solution: they are intersected afterwards with the
//! adjusted orientations and compared with their surveyed coordinates.

#[doc(hidden)]
pub mod chi2;
#[doc(hidden)]
pub mod datum;
mod evaluated;
pub mod georef;
mod precision;
mod problem;
mod ragged;
pub mod rays;
mod report;
pub mod resection;
mod residual;
mod robust;
#[doc(hidden)]
pub mod selinv;
mod solver;
pub mod support;
pub mod synthetic;
#[doc(hidden)]
pub mod tie_prior;

pub use precision::intersect;
pub use problem::{adjust, adjust_with_rejected};
pub use report::checkpoint_rmse;
pub use resection::{resect, ResectionOptions, ResectionResult};
pub use residual::Loss;
pub use tie_prior::TiePrior;

use crate::block::{Block, PhotoId, PointId};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Errors of the adjustment and the resection; each names the photo, point or option.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum AdjustError {
    #[error("invalid block: {0}")]
    InvalidBlock(String),
    #[error("invalid option {name}: {message}")]
    InvalidOption { name: String, message: String },
    #[error("degenerate geometry: {0}")]
    Degenerate(String),
    #[error("too few observations: {0}")]
    TooFewObservations(String),
    #[error("unknown {what} {id}")]
    UnknownId { what: String, id: String },
    #[error("{what} is not finite")]
    NotFinite { what: String },
    #[error("the normal equations are singular: {0}")]
    Singular(String),
}

/// A LiDAR plane n·X = d (block-local, |n| = 1) that tie point `point` should lie on,
/// with the plane's coplanarity weight (1/σ² of the point-to-plane distance, 1/m²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneConstraint {
    pub point: PointId,
    pub normal: [f64; 3],
    pub d: f64,
    pub weight: f64,
}

/// Re-fits the LiDAR planes of tie points between adjustment rounds (the LiDAR module
/// implements it: nearest neighbours around the current object position, PCA plane,
/// coplanarity weight). Returning an empty list drops all plane constraints.
pub trait PlaneRefitter {
    fn refit(&mut self, points: &[(PointId, Vector3<f64>)]) -> Vec<PlaneConstraint>;
}

/// How gross errors are removed after each robust solution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rejection {
    /// Keep every observation (IRLS only).
    None,
    /// Remove every observation whose standardised residual component exceeds `k` (in
    /// units of the robust σ0, re-estimated each round), re-solve, repeat. The σ0 shrinks
    /// as the tails go, so on clean data this erodes good observations; kept for the
    /// archive epochs' few resection rays, not the default.
    Threshold(f64),
    /// Baarda data snooping (the default): each observation is tested with its own
    /// dimension against the a-priori σ (variance factor 1, never re-normalised), an image
    /// point as w² = vᵀQ_vv⁻¹v ~ χ²(2), a control prior ~ χ²(d) with d its known axes, a
    /// LiDAR plane ~ χ²(1). `k` is the critical value of the one-dimensional test and so
    /// fixes α0 = P(|N(0,1)| > k) for every dimension (k = 3.29: α0 = 0.1 %, χ²(2)
    /// critical 13.82 — w = 3.72 —, χ²(3) 16.27); [`Rejection::data_snooping`] builds it
    /// from α0. Per object point and round only the worst observation goes.
    DataSnooping(f64),
}

impl Rejection {
    /// Data snooping at significance level `alpha` (α0 of each single test; 0.001 usual).
    pub fn data_snooping(alpha: f64) -> Self {
        if alpha > 0.0 && alpha < 1.0 {
            Rejection::DataSnooping(chi2::k_of_alpha(alpha))
        } else {
            Rejection::DataSnooping(f64::NAN)
        }
    }

    /// α0 of data snooping (`None` for the other rules).
    pub fn alpha(&self) -> Option<f64> {
        match *self {
            Rejection::DataSnooping(k) => Some(chi2::alpha_of_k(k)),
            _ => None,
        }
    }
}

/// Options of [`adjust`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AdjustOptions {
    pub loss: Loss,
    pub rejection: Rejection,
    /// Largest number of solve–reject rounds.
    pub max_rounds: usize,
    pub max_iterations: usize,
    pub function_tolerance: f64,
    pub parameter_tolerance: f64,
    /// Correlation above which a self-calibrated parameter is flagged as not determinable.
    pub max_correlation: f64,
    /// Compute per-photo EO standard deviations (one multi-right-hand-side solve).
    pub covariance: bool,
    /// σ (m, per axis) of the LiDAR's datum. With LiDAR planes and a σ the adjustment
    /// estimates one shift b common to every plane (the LiDAR surface is the true one
    /// displaced by b), with a zero prior of that σ: the planes then fix the block's
    /// shape, scale and orientation as before, and its position only as far as the LiDAR's
    /// datum is known against the POS. None: the planes are the datum as they stand.
    #[serde(default)]
    pub lidar_datum_sigma_m: Option<[f64; 3]>,
}

impl Default for AdjustOptions {
    fn default() -> Self {
        Self {
            loss: Loss::Huber(2.0),
            rejection: Rejection::data_snooping(0.001),
            max_rounds: 10,
            max_iterations: 50,
            function_tolerance: 1e-6,
            parameter_tolerance: 1e-10,
            max_correlation: 0.98,
            covariance: true,
            lidar_datum_sigma_m: None,
        }
    }
}

/// Which observation a report entry refers to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ObservationRef {
    Image {
        point: PointId,
        photo: PhotoId,
    },
    ControlPrior {
        point: PointId,
    },
    PosCenter {
        photo: PhotoId,
    },
    PosAttitude {
        photo: PhotoId,
    },
    Plane {
        point: PointId,
    },
    /// The zero prior of the LiDAR datum shift.
    LidarDatum,
}

/// A rejected observation and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rejected {
    pub observation: ObservationRef,
    pub round: usize,
    /// The test statistic that failed: data snooping w = √(vᵀQ_vv⁻¹v) against the σ the
    /// test used (`reason` names the χ² critical value), the threshold rule the largest
    /// standardised component in units of the round's robust σ0.
    pub standardized_residual: f64,
    pub reason: String,
    /// The observation went with its whole tie point: the point's rays disagree but have
    /// no redundancy to tell which one is wrong (two rays, or three along one base line),
    /// so the point leaves the block; this observation is not itself claimed wrong.
    #[serde(default)]
    pub with_point: bool,
}

/// Residual of one observation after the adjustment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualReport {
    pub observation: ObservationRef,
    /// Residual in the observation's units (px, m, rad), up to three components; on a
    /// control axis with σ = ∞ the adjusted minus the given coordinate.
    pub residual: Vec<f64>,
    /// Largest standardised residual component (units of σ0·σ_l·√r).
    pub standardized: f64,
    /// Redundancy number (local estimate, see `precision`).
    pub redundancy: f64,
}

/// Exterior-orientation precision of a photo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoPrecision {
    pub photo: PhotoId,
    pub name: String,
    /// σ of the rotation vector components (rad, camera-frame left perturbation).
    pub sigma_rotation_rad: [f64; 3],
    /// σ of the projection centre (m).
    pub sigma_center_m: [f64; 3],
    /// RMS image residual of the photo (px).
    pub rmse_px: f64,
    pub observations: usize,
}

/// Result of self-calibration for one interior parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    pub camera: u32,
    pub param: String,
    pub value: f64,
    pub sigma: f64,
    /// Largest |correlation| with any other unknown of the reduced system.
    pub max_correlation: f64,
    /// Name of the unknown it correlates most with.
    pub correlated_with: String,
    /// False when the block geometry does not determine the parameter (correlation
    /// above the limit): the value is then not trustworthy.
    pub determinable: bool,
    /// Held at its prior value after it was found not determinable or not significant
    /// (`value` is that prior, `sigma` 0; `held_because` says which).
    #[serde(default)]
    pub fixed: bool,
    /// Why [`adjust_determinable`] held it: [`HeldBecause`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_because: Option<HeldBecause>,
    /// Its estimate's distance from the prior value in standard deviations, on the
    /// solution that tested it ([`adjust_determinable`]; `None` from a plain [`adjust`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub t_prior: Option<f64>,
}

/// Why a self-calibration parameter was held at its prior value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HeldBecause {
    /// Its correlation with another unknown is above the limit: the block geometry does
    /// not separate it from the exterior orientation.
    NotDeterminable,
    /// Its estimate is within the two-sided 5 % test of its prior value: the data do
    /// not show it differs, and a free parameter with that σ only adds noise.
    NotSignificant,
}

/// Check point comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckPointReport {
    pub point: PointId,
    pub name: String,
    /// Intersected minus surveyed (m): x, y, z.
    pub error: [f64; 3],
    pub rays: usize,
}

/// A check point measurement left out of the check point's intersection by data snooping
/// ([`rays::intersect_snooped`]), or a measurement of a check point whose rays disagree
/// in a way no test can localise (the point is then not evaluated).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedCheckRay {
    pub point: PointId,
    pub name: String,
    pub photo: PhotoId,
    pub pixel: [f64; 2],
    /// Reprojection error at the intersection of the point's kept rays (px); None when
    /// the point has no position.
    pub residual_px: Option<f64>,
    pub reason: String,
}

/// Check point comparison: RMSE over the check points whose rays agree (after their
/// gross measurement errors are rejected); `not_evaluated` counts those whose rays could
/// not be made to agree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckSummary {
    pub count: usize,
    pub rmse_plan_m: f64,
    pub rmse_height_m: f64,
    pub max_m: f64,
    pub points: Vec<CheckPointReport>,
    #[serde(default)]
    pub not_evaluated: usize,
    #[serde(default)]
    pub rejected: Vec<RejectedCheckRay>,
}

/// The reduced camera system as the last solution factorised it: its size, how it was
/// ordered and how much the factor filled in (archive-scale blocks: strips make the
/// system banded, cross strips and long tracks widen the band).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReducedSystemReport {
    /// Unknowns of the photos and cameras (the points eliminated).
    pub unknowns: usize,
    /// "AMD" (sparse Cholesky with approximate minimum degree) or "dense".
    pub ordering: String,
    /// Non-zero entries of its upper triangle.
    pub nonzeros: usize,
    /// Entries the Cholesky factor stores (supernodes' dense blocks included).
    pub factor_nonzeros: usize,
}

/// The adjusted shift of the LiDAR's datum from the block's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LidarDatumReport {
    /// LiDAR minus block (m, block CRS axes): the LiDAR surface lies this far from the
    /// adjusted block's surface.
    pub shift_m: [f64; 3],
    /// Its a-posteriori σ (m).
    pub sigma_m: [f64; 3],
    /// The a-priori σ it was given (m).
    pub prior_sigma_m: [f64; 3],
}

/// Variance component of one observation group: σ0_g = √(Σ_g vᵀPv / Σ_g r) over the
/// group's active observations. Redundancy numbers of image points and LiDAR planes are
/// local (their point's own normal block, orientations held; see `precision`), slightly
/// high; those of control priors are exact (the point's full cofactor through the reduced
/// camera system), those of POS priors exact when EO covariances are computed, else 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VarianceComponent {
    /// "image", "control", "pos_center", "pos_attitude", "plane" or "lidar_datum".
    pub group: String,
    /// Active observations of the group (an image point counts once).
    pub observations: usize,
    /// Their scalar observation equations (a control axis with σ = ∞ is none).
    pub components: usize,
    /// Σ vᵀPv (weighted with the a-priori σ).
    pub vtpv: f64,
    /// Σ r, the group's share of the redundancy.
    pub redundancy: f64,
    /// σ0 of the group in units of its a-priori σ (1 when the a-priori σ is right);
    /// `None` without redundancy.
    pub sigma0: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedSummary {
    pub count: usize,
    pub list: Vec<Rejected>,
}

/// The adjustment report (serialised as the JSON report, see formats/adjust/).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdjustReport {
    /// A-posteriori standard deviation of unit weight.
    pub sigma0: f64,
    /// The gross-error test used, e.g. "baarda_data_snooping alpha=0.001 sigma=a_priori",
    /// "baarda_data_snooping alpha=0.001 sigma=first_round 1.83" (the a-priori image σ was
    /// too optimistic: the test used the first solution's robust σ0, fixed for all rounds),
    /// "threshold k=3 sigma=max(robust_sigma0, 1)" or "none"; ", control sigma x4.2" when the
    /// control group's σ were scaled (see `control_sigma_scale`); ", final sweep n" when
    /// the rounds ran out and n remaining exceedances were rejected at once.
    #[serde(default)]
    pub rejection_test: String,
    /// Factor every control σ was scaled by on the first solution, when the control as a
    /// whole fitted its rays significantly worse than its stated σ (data snooping; the
    /// control group's residuals and variance component refer to the scaled σ).
    #[serde(default)]
    pub control_sigma_scale: Option<f64>,
    /// The tie points' precision prior, when they differ in precision beyond chance
    /// (data snooping): each tie ray was then tested against its own point's other rays
    /// (leave-one-out, F test with the prior's d0 and s0²), not against one σ.
    #[serde(default)]
    pub tie_point_prior: Option<TiePrior>,
    /// σ0 per observation group.
    #[serde(default)]
    pub variance_components: Vec<VarianceComponent>,
    /// Tie points removed from the block because fewer than two image observations were
    /// left to intersect them (their remaining observations are not in `rejected`).
    #[serde(default)]
    pub removed_tie_points: usize,
    /// RMS of the image residuals (px), active observations.
    pub rmse_px: f64,
    pub iterations: usize,
    pub rounds: usize,
    pub converged: bool,
    /// How the datum is defined: "control" (control with plan and height coordinates),
    /// "control_plan" (only 2-D control, σ_z = ∞), "control_height" (only height
    /// control), "pos", "lidar_planes", combinations joined by "+", or "free_network"
    /// (first photo and one centre coordinate of a second held fixed).
    pub datum: String,
    pub photos: usize,
    pub points: usize,
    pub observations: usize,
    pub redundancy: usize,
    pub rejected: RejectedSummary,
    pub time_s: f64,
    pub photo_precision: Vec<PhotoPrecision>,
    pub calibration: Vec<CalibrationReport>,
    /// The LiDAR datum shift, when adjusted (`lidar_datum_sigma_m`).
    #[serde(default)]
    pub lidar_datum: Option<LidarDatumReport>,
    /// None when the system was singular at the solution.
    #[serde(default)]
    pub reduced_system: Option<ReducedSystemReport>,
    pub check: Option<CheckSummary>,
    /// Residuals of every observation (image residuals can be many; omit from JSON by
    /// clearing when not wanted).
    pub residuals: Vec<ResidualReport>,
}

/// Significance level of the test of a self-calibration parameter against its prior
/// value (two-sided): Grün's test of additional parameters, which keeps only those the
/// data show to differ from what the camera file says.
pub const CALIBRATION_SIGNIFICANCE: f64 = 0.05;

/// [`adjust`] with self-calibration of only what the block determines and shows:
/// an interior parameter the geometry cannot separate from the exterior orientation
/// (correlation above the limit), or whose estimate is not significantly different from
/// its prior value ([`CALIBRATION_SIGNIFICANCE`]), is held at its prior value and the
/// block adjusted again.
///
/// A 6-photo digital epoch with control on gentle relief ties the focal length to the
/// flying heights (correlation 0.998, σ 1 %): left free, it came out 0.85, 0.98 and
/// 1.25 % from the truth where the prior was 0.16, 0.19 and 0.36 % off (small block,
/// seeds 4, 6, 8), and the checkpoints away from the control's mean height followed it:
/// held, their height RMSE went from 1.72 to 1.50, 1.48 to 0.37 and 0.62 to 0.51 GSD.
/// Seed 10's k2 came out 0.037 ± 0.031 (1.2 σ from its prior 0, truth 0.005): free, it
/// bent the frame corners by a pixel and the checkpoint heights to 1.43 GSD.
pub fn adjust_determinable(
    block: &mut Block,
    opts: &AdjustOptions,
) -> Result<AdjustReport, AdjustError> {
    let prior = block.clone();
    // Every camera's parameters before the adjustment: what each free one is tested
    // against and held at.
    let start: std::collections::BTreeMap<_, (&[&str], Vec<f64>)> = prior
        .cameras
        .iter()
        .map(|(id, c)| (*id, (c.model.param_names(), c.model.params())))
        .collect();
    let prior_value = |c: &CalibrationReport| -> Option<f64> {
        let (names, values) = start.get(&c.camera)?;
        Some(values[names.iter().position(|n| *n == c.param)?])
    };
    let mut first = adjust(block, &[], None, opts)?;
    let t_limit = chi2::critical(1, CALIBRATION_SIGNIFICANCE).sqrt();
    for c in &mut first.calibration {
        c.t_prior = prior_value(c)
            .filter(|_| c.sigma > 0.0 && c.sigma.is_finite())
            .map(|p| (c.value - p).abs() / c.sigma);
    }
    let held_because = |c: &CalibrationReport| {
        if !c.determinable {
            Some(HeldBecause::NotDeterminable)
        } else if c.t_prior.is_some_and(|t| t < t_limit) {
            Some(HeldBecause::NotSignificant)
        } else {
            None
        }
    };
    let weak: Vec<(CalibrationReport, HeldBecause)> = first
        .calibration
        .iter()
        .filter_map(|c| held_because(c).map(|why| (c.clone(), why)))
        .collect();
    if weak.is_empty() {
        return Ok(first);
    }
    *block = prior;
    let mut held = Vec::with_capacity(weak.len());
    for (mut c, why) in weak {
        let Some(cam) = block.cameras.get(&c.camera) else {
            continue;
        };
        if let Some(v) = prior_value(&c) {
            c.value = v;
        }
        // Held for the whole calibration group: its cameras keep one list of free
        // parameters.
        let group = cam.calibration_group.clone();
        for other in block.cameras.values_mut() {
            if other.id == c.camera || (group.is_some() && other.calibration_group == group) {
                other.free_params.retain(|p| *p != c.param);
            }
        }
        tracing::info!(
            camera = c.camera,
            param = %c.param,
            ?why,
            correlation = c.max_correlation,
            with = %c.correlated_with,
            t = c.t_prior,
            "self-calibration parameter held at its prior value"
        );
        (c.sigma, c.fixed, c.held_because) = (0.0, true, Some(why));
        held.push(c);
    }
    let mut rep = adjust(block, &[], None, opts)?;
    let tested: Vec<_> = first.calibration;
    for c in &mut rep.calibration {
        c.t_prior = tested
            .iter()
            .find(|t| t.camera == c.camera && t.param == c.param)
            .and_then(|t| t.t_prior);
    }
    rep.calibration.extend(held);
    Ok(rep)
}
