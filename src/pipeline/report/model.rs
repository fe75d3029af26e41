//! What `report.json` holds (formats/workflow/README.md, "report.json"): the run's
//! metadata and warnings, the LiDAR's check against the surveyed checkpoints, and one
//! [`EpochReport`] per epoch (its `epoch.json`, with the warnings of the stages after it).

use super::super::tie_statistics::{PhotoTies, TieStatistics};
use crate::adjust::VarianceComponent;
use crate::matching::ScanOrientation;
use serde::{Deserialize, Serialize};

/// Reads a number that JSON may hold as `null` (serde_json writes NaN so): absent
/// statistics (no checkpoints, no adjustment) stay NaN through a round trip.
pub(crate) fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn nan() -> f64 {
    f64::NAN
}

/// One checkpoint's error: adjusted minus surveyed (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointError {
    pub id: String,
    pub x: f64,
    pub y: f64,
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    /// The photos it was intersected from (its measurements kept).
    #[serde(default)]
    pub rays: usize,
}

/// Per-photo summary of the adjustment and of the patch matching.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoSummary {
    pub name: String,
    /// Projection centre, world XY.
    #[serde(deserialize_with = "nan_if_null")]
    pub x: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub y: f64,
    pub oriented: bool,
    /// Why it was not oriented (`result.json`'s reason, in words); `None` when oriented.
    #[serde(default)]
    pub reason: Option<String>,
    /// Mean image residual vector (px) and RMS (px).
    pub mean_residual_px: [f64; 2],
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_px: f64,
    /// Control patches predicted in the photo and matched (accepted).
    pub patches_predicted: usize,
    pub patches_matched: usize,
    /// The photo's tie points and control in the adjusted block.
    #[serde(default)]
    pub ties: PhotoTies,
}

/// Statistics of one ICP iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcpIteration {
    pub iteration: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_m: f64,
    pub inliers: usize,
}

/// A film scan's fiducial interior orientation (`result.json`'s photo `io`), or why it
/// failed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanReport {
    pub photo: String,
    /// The photo was oriented.
    pub oriented: bool,
    /// Why the scan has no interior orientation (unreadable, marks not found); `None`
    /// when it has one.
    #[serde(default)]
    pub failed: Option<String>,
    /// Marks used in the transform, of the camera's marks.
    #[serde(default)]
    pub marks_used: usize,
    #[serde(default)]
    pub marks_total: usize,
    /// RMS residual of the marks after the fit: µm on the film, and scan pixels.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub rmse_um: f64,
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub rmse_px: f64,
    /// Largest residual of a used mark (µm).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub max_residual_um: f64,
    /// Scan pixel size used (µm), where it came from, and what the marks measure.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub pixel_um: f64,
    #[serde(default)]
    pub pixel_source: String,
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub measured_pixel_um: f64,
    /// The scan orientation found, how it was decided, and its margin (cost of the best
    /// other orientation over this one's: below 1 a given orientation fits worse than
    /// another; 1000 when no other orientation measured enough marks).
    #[serde(default)]
    pub orientation: Option<ScanOrientation>,
    #[serde(default)]
    pub orientation_source: String,
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub orientation_margin: f64,
    /// The marks alone did not decide the orientation.
    #[serde(default)]
    pub orientation_ambiguous: bool,
}

/// What a warning is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WarningKind {
    /// The epoch oriented fewer photos than it has.
    PartialEpoch,
    /// A self-calibration parameter was held at its prior value.
    SelfCalibrationHeld,
    /// A self-calibration parameter the block does not determine was left free.
    SelfCalibrationNotDeterminable,
    /// The adjustment changed what it was given (σ scaled, test σ replaced) or did not
    /// converge.
    Adjustment,
    /// Checkpoints not evaluated, or measurements of them rejected.
    Checkpoints,
    /// A film scan's interior orientation: undecided orientation, pixel size contradicted.
    ScanInteriorOrientation,
    /// An input that was given but left out (images not in an existing block, its check
    /// points).
    InputLeftOut,
    /// Something an input does not state was assumed (an existing block's CRS).
    InputAssumed,
    /// The LiDAR: tiles whose CRS was assumed, checkpoints it contradicts.
    Lidar,
    /// A product or DCP package not written.
    Products,
    /// An epoch's surface shifted against the control's beyond the limits, or a shift
    /// the terrain does not determine (`change-<epoch>/`).
    SurfaceShift,
}

/// One comparison of an epoch's own surface (`change-<epoch>/change.json`), in short.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceChange {
    /// `lidar_surface`, `control_dem`, or the younger epoch's name.
    pub against: String,
    /// Nuth & Kääb shift (east, north, up) of the epoch's surface onto it, in the epoch's
    /// ground pixels, and its plan length.
    pub shift_gsd: [f64; 3],
    pub shift_plan_gsd: f64,
    /// Standard error of the plan length (GSD).
    #[serde(default, deserialize_with = "nan_if_null")]
    pub shift_plan_sigma_gsd: f64,
    /// The shift fitted together with a tilt (what the flag judges), when the terrain
    /// determined it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub with_tilt: Option<crate::pipeline::change::ShiftWithTilt>,
    pub converged: bool,
    pub stable_cells: usize,
    /// dh = epoch − `against` on stable terrain.
    #[serde(deserialize_with = "nan_if_null")]
    pub median_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub nmad_m: f64,
    /// Changed areas (`changed_areas.geojson`): how many and their area (m²).
    #[serde(default)]
    pub changed_areas: usize,
    #[serde(default)]
    pub changed_area_m2: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flag: Option<String>,
    /// The dh map (`dh.png` in the comparison's folder, relative to the run's), its colour
    /// range (m: full red that much lower, full blue that much higher than the median).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map: Option<String>,
    #[serde(default)]
    pub map_range_m: f64,
    /// The map's PNG bytes, for the HTML report (not serialised to JSON).
    #[serde(skip)]
    pub map_png: Vec<u8>,
}

/// One thing a user should know about the run, recorded where it was decided.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Warning {
    pub kind: WarningKind,
    pub message: String,
}

impl Warning {
    pub fn new(kind: WarningKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
        }
    }
}

/// Results of one epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochReport {
    pub name: String,
    pub date: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub gsd_m: f64,
    pub photos_total: usize,
    pub photos_oriented: usize,
    /// Of the oriented photos, those oriented through tie points with the epoch's other
    /// photos only (no control patch of their own).
    #[serde(default)]
    pub photos_through_ties: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_rmse_plan_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_rmse_height_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_max_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma0: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_px: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub time_s: f64,
    #[serde(default)]
    pub checkpoints: Vec<CheckpointError>,
    /// Checkpoints whose rays could not be made to agree (not in the RMSE).
    #[serde(default)]
    pub checkpoints_not_evaluated: usize,
    /// Checkpoint measurements left out of the evaluation, and why.
    #[serde(default)]
    pub checkpoint_rejections: Vec<crate::control::checkpoints::RejectedMeasurement>,
    #[serde(default)]
    pub photos: Vec<PhotoSummary>,
    /// Film epochs: each scan's fiducial interior orientation.
    #[serde(default)]
    pub scans: Vec<ScanReport>,
    #[serde(default)]
    pub icp: Vec<IcpIteration>,
    /// What controlled the epoch (LiDAR, an existing block, the DCP packages used).
    #[serde(default)]
    pub control: Vec<String>,
    /// Tie points and control of the adjusted block.
    #[serde(default)]
    pub ties: TieStatistics,
    /// σ0 per observation group of the epoch's adjustment.
    #[serde(default)]
    pub variance_components: Vec<VarianceComponent>,
    /// What a user should know about the epoch: the epoch stage's, then (in
    /// `report.json`) those of its DCP and products stages.
    #[serde(default)]
    pub warnings: Vec<Warning>,
    /// The epoch's own surface against the control's and the next younger epoch's.
    #[serde(default)]
    pub surface_change: Vec<SurfaceChange>,
}

impl EpochReport {
    /// Checkpoint RMSE in plan and height, and the largest 3-D error, from the rows.
    pub fn set_check_statistics(&mut self) {
        let n = self.checkpoints.len();
        if n == 0 {
            (
                self.check_rmse_plan_m,
                self.check_rmse_height_m,
                self.check_max_m,
            ) = (f64::NAN, f64::NAN, f64::NAN);
            return;
        }
        let plan = self
            .checkpoints
            .iter()
            .map(|c| c.dx * c.dx + c.dy * c.dy)
            .sum::<f64>()
            / n as f64;
        let h = self.checkpoints.iter().map(|c| c.dz * c.dz).sum::<f64>() / n as f64;
        self.check_rmse_plan_m = plan.sqrt();
        self.check_rmse_height_m = h.sqrt();
        self.check_max_m = self
            .checkpoints
            .iter()
            .map(|c| (c.dx * c.dx + c.dy * c.dy + c.dz * c.dz).sqrt())
            .fold(0.0, f64::max);
    }
}

/// One checkpoint against the LiDAR, as the LiDAR evaluation gives it: `dz_m` = LiDAR −
/// checkpoint height.
pub use crate::lidar::eval::CheckpointRow as LidarCheckRow;

/// The LiDAR against the surveyed checkpoints (`sources/lidar_checkpoints.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LidarCheck {
    /// Checkpoints with a LiDAR height, and those without.
    pub count: usize,
    pub skipped: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub mean_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub std_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub max_abs_m: f64,
    pub outliers: Vec<String>,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_without_outliers_m: f64,
    /// The local plane's search: ground points within `radius_m`, the `k` nearest, at
    /// least `min_points`.
    pub radius_m: f64,
    pub k: usize,
    pub min_points: usize,
    pub rows: Vec<LidarCheckRow>,
}

impl LidarCheck {
    /// The report's form of the LiDAR evaluation, made with `options`.
    pub fn new(
        r: &crate::lidar::eval::CheckpointReport,
        options: &crate::lidar::CheckpointOptions,
    ) -> Self {
        Self {
            count: r.count,
            skipped: r.skipped,
            mean_m: r.mean_m,
            std_m: r.std_m,
            rmse_m: r.rmse_m,
            max_abs_m: r.max_abs_m,
            outliers: r.outliers.clone(),
            rmse_without_outliers_m: r.rmse_without_outliers_m,
            radius_m: options.radius,
            k: options.k,
            min_points: options.min_points,
            rows: r.rows.clone(),
        }
    }
}

/// An epoch's options as the project gives them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochOptions {
    pub name: String,
    pub date: String,
    /// Scan pixel size given for film scans (µm; from `scan_pixel_um` or `scan_dpi`).
    pub scan_pixel_um: Option<f64>,
    /// Interior parameters self-calibrated, as given; `None`: the default of
    /// [`RunOptions::default_self_calibration`].
    pub self_calibration: Option<Vec<String>>,
}

/// The default self-calibration of an epoch that names none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DefaultSelfCalibration {
    pub reference: Vec<String>,
    pub archive_frame: Vec<String>,
    pub archive_film: Vec<String>,
}

/// The options and thresholds a run used: the project's, with the defaults it left.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunOptions {
    pub thresholds: super::super::project::Thresholds,
    pub outputs: super::super::project::Outputs,
    pub lidar_datum_sigma_m: f64,
    pub orthophoto_sigma_m: Option<f64>,
    pub dem_sigma_m: f64,
    pub checkpoints_crs: Option<String>,
    /// σ (px) a checkpoint measurement is tested with.
    pub checkpoint_measurement_sigma_px: f64,
    pub default_self_calibration: DefaultSelfCalibration,
    pub epochs: Vec<EpochOptions>,
}

/// Who made the report, from what, when.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    pub cloudcontrol_version: String,
    /// SHA-256 of the project file's bytes (hex); `None` for a project not read from a
    /// file.
    pub project_sha256: Option<String>,
    /// When the report was made (UTC, `YYYY-MM-DDThh:mm:ssZ`; `SOURCE_DATE_EPOCH` when
    /// set). A rerun that skips the report keeps the time of the run that made it.
    pub date_utc: String,
    pub options: RunOptions,
}

/// Orthophoto preview for the map: a PNG and its world extent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrthoPreview {
    /// PNG bytes (not serialised to JSON).
    #[serde(skip)]
    pub png: Vec<u8>,
    /// World extent (x_min, y_min, x_max, y_max).
    pub extent: [f64; 4],
}

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub project: String,
    pub crs: String,
    /// Version, project hash, options and date; `None` in reports made without a run.
    #[serde(default)]
    pub run: Option<RunInfo>,
    /// What a user should know about the run as a whole (each epoch's are in its
    /// `warnings`).
    #[serde(default)]
    pub warnings: Vec<Warning>,
    /// The LiDAR against the surveyed checkpoints; `None` without LiDAR or checkpoints.
    #[serde(default)]
    pub lidar_checkpoints: Option<LidarCheck>,
    /// The LiDAR strips' offsets the cleaning removed (`sources/clean.json`); `None`
    /// without LiDAR or with one strip.
    #[serde(default)]
    pub lidar_strips: Option<crate::lidar::StripOffsetReport>,
    pub epochs: Vec<EpochReport>,
    #[serde(skip)]
    pub ortho: Option<OrthoPreview>,
}

/// `secs` since 1970-01-01 UTC as `YYYY-MM-DDThh:mm:ssZ` (proleptic Gregorian).
pub fn utc_iso8601(secs: i64) -> String {
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Days to civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// An ISO 8601 date (`1985`, `1985-06`, `1985-06-12`, or with a time after it) as a
/// decimal year (a year alone is its middle, a month its middle); `None` when it is not
/// one.
pub fn decimal_year(date: &str) -> Option<f64> {
    let date = date.trim();
    let mut it = date.get(..10.min(date.len()))?.split('-');
    let y: i32 = it.next()?.parse().ok()?;
    let Some(m) = it.next() else {
        return Some(y as f64 + 0.5);
    };
    let m: u32 = m.parse().ok().filter(|m| (1..=12).contains(m))?;
    let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let len = |k: u32| match k {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    let before: u32 = (1..m).map(len).sum();
    let day = match it.next() {
        Some(d) => {
            let d: u32 = d.parse().ok().filter(|d| (1..=len(m)).contains(d))?;
            d as f64 - 0.5
        }
        None => len(m) as f64 / 2.0,
    };
    Some(y as f64 + (before as f64 + day) / if leap { 366.0 } else { 365.0 })
}
