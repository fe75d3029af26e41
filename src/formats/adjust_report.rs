//! The adjustment's report as files (formats/adjust/README.md): a JSON summary whose size
//! does not grow with the block, and the per-observation and per-photo listings as CSV
//! side files written only on request.
//!
//! Why bounded: the whole [`AdjustReport`] of a 3,200-photo block (6.4 M observations) was
//! a 908 MB JSON file, nearly all of it per-observation residuals; a reader that only
//! wants σ0 and the check points then parses a gigabyte. The summary keeps every figure
//! of the block as a whole, the largest rejections and the weakest photos (at most
//! [`LISTED`] of each) and says how many there are; the CSV files, streamed row by row,
//! hold the rest.

use super::{write_atomically, FormatError, Result};
use crate::adjust::{AdjustReport, ObservationRef, PhotoPrecision, Rejected, RejectedSummary};
use crate::block::{Block, PhotoId, PointId};
use serde::Serialize;
use std::io::Write;
use std::path::Path;

/// Most rejected observations and photos the JSON summary lists by name.
pub const LISTED: usize = 100;

/// The rejected observations in the summary: the [`LISTED`] largest test statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RejectedListing {
    pub count: usize,
    /// How many `list` holds (all of them when `count` ≤ [`LISTED`]).
    pub listed: usize,
    /// By decreasing standardised residual.
    pub list: Vec<Rejected>,
}

/// The exterior-orientation precision of the block in the summary.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PrecisionSummary {
    pub photos: usize,
    /// Per component, over the photos.
    pub median_sigma_center_m: [f64; 3],
    pub max_sigma_center_m: [f64; 3],
    pub median_sigma_rotation_rad: [f64; 3],
    pub max_sigma_rotation_rad: [f64; 3],
    /// How many `weakest` holds.
    pub listed: usize,
    /// The photos of largest centre σ (largest component first), at most [`LISTED`].
    pub weakest: Vec<PhotoPrecision>,
}

/// The summary written as the JSON report: the report without its per-observation
/// residuals, with the rejected observations and the photos' precision bounded.
#[derive(Debug, Clone, Serialize)]
pub struct ReportSummary<'a> {
    #[serde(flatten)]
    report: ReportCore<'a>,
    pub rejected: RejectedListing,
    pub photo_precision: PrecisionSummary,
}

/// The report's fields that are bounded by themselves (serialised as they are).
#[derive(Debug, Clone, Serialize)]
struct ReportCore<'a> {
    sigma0: f64,
    rejection_test: &'a str,
    control_sigma_scale: Option<f64>,
    tie_point_prior: &'a Option<crate::adjust::TiePrior>,
    variance_components: &'a [crate::adjust::VarianceComponent],
    removed_tie_points: usize,
    rmse_px: f64,
    iterations: usize,
    rounds: usize,
    converged: bool,
    datum: &'a str,
    photos: usize,
    points: usize,
    observations: usize,
    redundancy: usize,
    time_s: f64,
    calibration: &'a [crate::adjust::CalibrationReport],
    lidar_datum: &'a Option<crate::adjust::LidarDatumReport>,
    reduced_system: &'a Option<crate::adjust::ReducedSystemReport>,
    check: &'a Option<crate::adjust::CheckSummary>,
}

/// The bounded summary of `rep`.
pub fn summary(rep: &AdjustReport) -> ReportSummary<'_> {
    ReportSummary {
        report: ReportCore {
            sigma0: rep.sigma0,
            rejection_test: &rep.rejection_test,
            control_sigma_scale: rep.control_sigma_scale,
            tie_point_prior: &rep.tie_point_prior,
            variance_components: &rep.variance_components,
            removed_tie_points: rep.removed_tie_points,
            rmse_px: rep.rmse_px,
            iterations: rep.iterations,
            rounds: rep.rounds,
            converged: rep.converged,
            datum: &rep.datum,
            photos: rep.photos,
            points: rep.points,
            observations: rep.observations,
            redundancy: rep.redundancy,
            time_s: rep.time_s,
            calibration: &rep.calibration,
            lidar_datum: &rep.lidar_datum,
            reduced_system: &rep.reduced_system,
            check: &rep.check,
        },
        rejected: rejected_listing(&rep.rejected),
        photo_precision: precision_summary(&rep.photo_precision),
    }
}

fn rejected_listing(r: &RejectedSummary) -> RejectedListing {
    let mut order: Vec<&Rejected> = r.list.iter().collect();
    // Stable: equal statistics keep the order of rejection.
    order.sort_by(|a, b| b.standardized_residual.total_cmp(&a.standardized_residual));
    let list: Vec<Rejected> = order.into_iter().take(LISTED).cloned().collect();
    RejectedListing {
        count: r.count,
        listed: list.len(),
        list,
    }
}

fn precision_summary(p: &[PhotoPrecision]) -> PrecisionSummary {
    let per_axis = |f: &dyn Fn(&PhotoPrecision) -> [f64; 3]| {
        let mut med = [f64::NAN; 3];
        let mut max = [f64::NAN; 3];
        for k in 0..3 {
            let mut v: Vec<f64> = p
                .iter()
                .map(|x| f(x)[k])
                .filter(|v| v.is_finite())
                .collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(f64::total_cmp);
            med[k] = v[v.len() / 2];
            max[k] = v[v.len() - 1];
        }
        (med, max)
    };
    let (median_sigma_center_m, max_sigma_center_m) = per_axis(&|x| x.sigma_center_m);
    let (median_sigma_rotation_rad, max_sigma_rotation_rad) = per_axis(&|x| x.sigma_rotation_rad);
    let worst = |x: &PhotoPrecision| x.sigma_center_m.iter().copied().fold(f64::NAN, f64::max);
    let mut order: Vec<&PhotoPrecision> = p.iter().collect();
    order.sort_by(|a, b| worst(b).total_cmp(&worst(a)));
    let weakest: Vec<PhotoPrecision> = order.into_iter().take(LISTED).cloned().collect();
    PrecisionSummary {
        photos: p.len(),
        median_sigma_center_m,
        max_sigma_center_m,
        median_sigma_rotation_rad,
        max_sigma_rotation_rad,
        listed: weakest.len(),
        weakest,
    }
}

/// Writes the summary of `rep` as pretty JSON, atomically, with `extra` fields (the
/// command's own: wall time, origin, georeference) merged at the top level.
pub fn write_summary(
    path: &Path,
    rep: &AdjustReport,
    extra: serde_json::Map<String, serde_json::Value>,
) -> Result<serde_json::Value> {
    let mut v = serde_json::to_value(summary(rep)).map_err(|e| invalid(path, e))?;
    if let Some(o) = v.as_object_mut() {
        o.extend(extra);
    }
    let bytes = serde_json::to_vec_pretty(&v).map_err(|e| invalid(path, e))?;
    super::write_bytes_atomically(path, &bytes)?;
    Ok(v)
}

fn invalid(path: &Path, e: impl std::fmt::Display) -> FormatError {
    FormatError::Invalid {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// The identifiers of an observation as CSV fields: type, photo id, point id.
fn ids(o: &ObservationRef) -> (&'static str, Option<PhotoId>, Option<PointId>) {
    match *o {
        ObservationRef::Image { point, photo } => ("image", Some(photo), Some(point)),
        ObservationRef::ControlPrior { point } => ("control_prior", None, Some(point)),
        ObservationRef::PosCenter { photo } => ("pos_center", Some(photo), None),
        ObservationRef::PosAttitude { photo } => ("pos_attitude", Some(photo), None),
        ObservationRef::Plane { point } => ("plane", None, Some(point)),
        ObservationRef::LidarDatum => ("lidar_datum", None, None),
    }
}

/// One row of the observation listing.
#[derive(Serialize)]
struct ObservationRow<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    photo: Option<PhotoId>,
    photo_name: &'a str,
    point: Option<PointId>,
    point_name: &'a str,
    status: &'static str,
    round: Option<usize>,
    residual_1: Option<f64>,
    residual_2: Option<f64>,
    residual_3: Option<f64>,
    standardized: f64,
    redundancy: Option<f64>,
    with_point: Option<bool>,
    reason: &'a str,
}

/// Writes every observation of the adjustment to `path` as CSV, streamed: the ones kept
/// (`status` = used, their residuals, standardised residual and redundancy number) and
/// the rejected ones (`status` = rejected, the round, the statistic that failed, why).
/// Photo and point names come from `block` (a point that left the block has none).
/// Returns the rows written.
pub fn write_observations_csv(path: &Path, rep: &AdjustReport, block: &Block) -> Result<usize> {
    let photo_name = |id: Option<PhotoId>| {
        id.and_then(|i| block.photos.get(&i))
            .map_or("", |p| p.name.as_str())
    };
    let point_name = |id: Option<PointId>| {
        id.and_then(|i| block.points.get(&i))
            .map_or("", |p| p.name.as_str())
    };
    // The fields every row has: which observation it is.
    let row = |o: &ObservationRef| {
        let (kind, photo, point) = ids(o);
        ObservationRow {
            kind,
            photo,
            photo_name: photo_name(photo),
            point,
            point_name: point_name(point),
            status: "used",
            round: None,
            residual_1: None,
            residual_2: None,
            residual_3: None,
            standardized: f64::NAN,
            redundancy: None,
            with_point: None,
            reason: "",
        }
    };
    write_csv(path, |w| {
        let mut rows = 0;
        for r in &rep.residuals {
            let c = |k: usize| r.residual.get(k).copied();
            w.serialize(ObservationRow {
                residual_1: c(0),
                residual_2: c(1),
                residual_3: c(2),
                standardized: r.standardized,
                redundancy: Some(r.redundancy),
                ..row(&r.observation)
            })?;
            rows += 1;
        }
        for r in &rep.rejected.list {
            w.serialize(ObservationRow {
                status: "rejected",
                round: Some(r.round),
                standardized: r.standardized_residual,
                with_point: Some(r.with_point),
                reason: &r.reason,
                ..row(&r.observation)
            })?;
            rows += 1;
        }
        Ok(rows)
    })
}

/// One row of the photo listing.
#[derive(Serialize)]
struct PhotoRow<'a> {
    photo: PhotoId,
    name: &'a str,
    sigma_rotation_1_rad: f64,
    sigma_rotation_2_rad: f64,
    sigma_rotation_3_rad: f64,
    sigma_x_m: f64,
    sigma_y_m: f64,
    sigma_z_m: f64,
    rmse_px: f64,
    observations: usize,
}

/// Writes every photo's exterior-orientation precision to `path` as CSV. Returns the rows.
pub fn write_photos_csv(path: &Path, rep: &AdjustReport) -> Result<usize> {
    write_csv(path, |w| {
        for p in &rep.photo_precision {
            let [r1, r2, r3] = p.sigma_rotation_rad;
            let [x, y, z] = p.sigma_center_m;
            w.serialize(PhotoRow {
                photo: p.photo,
                name: &p.name,
                sigma_rotation_1_rad: r1,
                sigma_rotation_2_rad: r2,
                sigma_rotation_3_rad: r3,
                sigma_x_m: x,
                sigma_y_m: y,
                sigma_z_m: z,
                rmse_px: p.rmse_px,
                observations: p.observations,
            })?;
        }
        Ok(rep.photo_precision.len())
    })
}

/// A CSV file written atomically through a buffered writer.
fn write_csv(
    path: &Path,
    rows: impl FnOnce(&mut csv::Writer<std::io::BufWriter<std::fs::File>>) -> csv::Result<usize>,
) -> Result<usize> {
    write_atomically(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| FormatError::io(path, e))?;
        let mut w = csv::Writer::from_writer(std::io::BufWriter::new(file));
        let n = rows(&mut w).map_err(|e| invalid(path, e))?;
        let mut inner = w.into_inner().map_err(|e| invalid(path, e))?;
        inner.flush().map_err(|e| FormatError::io(path, e))?;
        inner
            .into_inner()
            .map_err(|e| FormatError::io(path, e.into_error()))?
            .sync_all()
            .map_err(|e| FormatError::io(path, e))?;
        Ok(n)
    })
}
