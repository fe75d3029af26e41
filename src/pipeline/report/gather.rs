//! What the report is made of, taken where it was decided: an epoch's warnings and film
//! scans from its result (the adjustment's held parameters, the photos not oriented, the
//! fiducial interior orientations), the existing block's left-out inputs, and at the end
//! of a run the warnings of the stages after the epochs (`skipped.json` of a DCP or
//! products stage, the LiDAR catalogue's), the LiDAR's checkpoint evaluation and the
//! run's metadata.

use super::model::*;
use crate::adjust::{AdjustReport, HeldBecause};
use crate::block::{Block, PhotoFailure};
use crate::control::archive::{ArchiveOptions, EpochResult};
use crate::control::existing::ExistingReport;
use crate::formats::FormatError;
use crate::pipeline::epoch_files::read_json;
use crate::pipeline::project::Project;
use crate::pipeline::stages::Inputs;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Photos named in a warning; the rest are counted.
const LISTED: usize = 8;

/// `names` joined, the first [`LISTED`] of them, then how many more.
fn listed(names: &[String]) -> String {
    let mut s = names
        .iter()
        .take(LISTED)
        .cloned()
        .collect::<Vec<_>>()
        .join("; ");
    if names.len() > LISTED {
        s.push_str(&format!("; … and {} more", names.len() - LISTED));
    }
    s
}

/// Each film scan's fiducial interior orientation (`io` of the photo results), and the
/// scans that have none because it failed or the scan could not be read. Empty for an
/// epoch of frame photos.
pub fn scan_rows(result: &EpochResult) -> Vec<ScanReport> {
    let film = result.photos.iter().any(|p| {
        p.io.is_some() || matches!(p.reason, Some(PhotoFailure::InteriorOrientation { .. }))
    });
    if !film {
        return Vec::new();
    }
    result
        .photos
        .iter()
        .filter_map(|p| {
            let mut row = ScanReport {
                photo: p.name.clone(),
                oriented: p.oriented,
                failed: None,
                marks_used: 0,
                marks_total: 0,
                rmse_um: f64::NAN,
                rmse_px: f64::NAN,
                max_residual_um: f64::NAN,
                pixel_um: f64::NAN,
                pixel_source: String::new(),
                measured_pixel_um: f64::NAN,
                orientation: None,
                orientation_source: String::new(),
                orientation_margin: f64::NAN,
                orientation_ambiguous: false,
            };
            match (&p.io, &p.reason) {
                (Some(io), _) => {
                    row.marks_used = io.marks_used;
                    row.marks_total = io.marks_total;
                    row.rmse_um = io.rmse_um;
                    row.rmse_px = io.rmse_um / io.pixel_um;
                    row.max_residual_um = io.max_residual_um.unwrap_or(f64::NAN);
                    row.pixel_um = io.pixel_um;
                    row.pixel_source = io.pixel_source.clone();
                    row.measured_pixel_um = io.measured_pixel_um.unwrap_or(f64::NAN);
                    row.orientation = io.orientation;
                    row.orientation_source = io.orientation_source.clone();
                    row.orientation_margin = io.orientation_margin.unwrap_or(f64::NAN);
                    row.orientation_ambiguous = io.orientation_ambiguous;
                }
                (
                    None,
                    Some(
                        f @ (PhotoFailure::InteriorOrientation { .. } | PhotoFailure::Image { .. }),
                    ),
                ) => {
                    row.failed = Some(f.to_string());
                }
                _ => return None,
            }
            Some(row)
        })
        .collect()
}

/// The warnings of an epoch's result: photos not oriented, self-calibration parameters
/// held or not determinable, what the adjustment changed, the film scans' interior
/// orientation, and the checkpoints of `rep` not evaluated or rejected.
pub fn epoch_warnings(result: &EpochResult, rep: &EpochReport) -> Vec<Warning> {
    let mut w = Vec::new();
    let not: Vec<String> = result
        .photos
        .iter()
        .filter(|p| !p.oriented)
        .map(|p| match &p.reason {
            Some(r) => format!("{}: {r}", p.name),
            None => p.name.clone(),
        })
        .collect();
    if !not.is_empty() {
        w.push(Warning::new(
            WarningKind::PartialEpoch,
            format!(
                "{} of {} photos oriented; not oriented: {}",
                result.photos.len() - not.len(),
                result.photos.len(),
                listed(&not)
            ),
        ));
    }
    if let Some(a) = &result.adjustment {
        w.extend(adjustment_warnings(a, &result.block));
    }
    for p in &result.photos {
        let Some(io) = &p.io else { continue };
        if io.orientation_ambiguous {
            w.push(Warning::new(
                WarningKind::ScanInteriorOrientation,
                format!(
                    "scan {}: the fiducial marks alone do not decide its orientation (margin {}); {} was taken ({})",
                    p.name,
                    io.orientation_margin
                        .map_or("–".into(), |m| format!("{m:.2}")),
                    io.orientation.map_or("–".into(), |o| o.to_string()),
                    io.orientation_source
                ),
            ));
        }
        for m in &io.warnings {
            w.push(Warning::new(
                WarningKind::ScanInteriorOrientation,
                format!("scan {}: {m}", p.name),
            ));
        }
    }
    if rep.checkpoints_not_evaluated > 0 {
        w.push(Warning::new(
            WarningKind::Checkpoints,
            format!(
                "{} checkpoint(s) not evaluated: their rays disagree and no single ray explains it",
                rep.checkpoints_not_evaluated
            ),
        ));
    }
    if !rep.checkpoint_rejections.is_empty() {
        let mut photos: Vec<&str> = rep
            .checkpoint_rejections
            .iter()
            .map(|r| r.photo.as_str())
            .collect();
        photos.sort_unstable();
        photos.dedup();
        w.push(Warning::new(
            WarningKind::Checkpoints,
            format!(
                "{} checkpoint measurement(s) rejected (photos {}): check them in the checkpoint image file",
                rep.checkpoint_rejections.len(),
                photos.join(", ")
            ),
        ));
    }
    w
}

/// Held or undetermined self-calibration parameters, a replaced test σ, scaled control σ,
/// a final sweep and no convergence, from the adjustment's report.
fn adjustment_warnings(a: &AdjustReport, block: &Block) -> Vec<Warning> {
    let mut w = Vec::new();
    let camera = |id: u32| match block.cameras.get(&id) {
        Some(c) if !c.name.is_empty() => format!("camera {id} ({})", c.name),
        _ => format!("camera {id}"),
    };
    for c in &a.calibration {
        if c.fixed {
            let why = match c.held_because {
                Some(HeldBecause::NotDeterminable) => format!(
                    "the block does not determine it (correlation {:.3} with {})",
                    c.max_correlation, c.correlated_with
                ),
                Some(HeldBecause::NotSignificant) => match c.t_prior {
                    Some(t) => {
                        format!("its estimate was {t:.1} σ from the prior: not significant at 5 %")
                    }
                    None => "its estimate did not differ significantly from the prior".into(),
                },
                None => "held".into(),
            };
            w.push(Warning::new(
                WarningKind::SelfCalibrationHeld,
                format!(
                    "{}: {} held at its prior value {}: {why}",
                    camera(c.camera),
                    c.param,
                    c.value
                ),
            ));
        } else if !c.determinable {
            w.push(Warning::new(
                WarningKind::SelfCalibrationNotDeterminable,
                format!(
                    "{}: {} = {} is not determinable by this block (correlation {:.3} with {}): not trustworthy",
                    camera(c.camera),
                    c.param,
                    c.value,
                    c.max_correlation,
                    c.correlated_with
                ),
            ));
        }
    }
    if let Some(rest) = a.rejection_test.split("sigma=first_round").nth(1) {
        let s0 = rest.split([' ', ',']).find(|t| !t.is_empty()).unwrap_or("");
        w.push(Warning::new(
            WarningKind::Adjustment,
            format!(
                "the a-priori image σ was too optimistic: gross errors were tested against the first solution's σ0 {s0}"
            ),
        ));
    }
    if let Some(s) = a.control_sigma_scale {
        w.push(Warning::new(
            WarningKind::Adjustment,
            format!(
                "the control σ was too optimistic for the control as a whole: every control σ was scaled ×{s:.2}"
            ),
        ));
    }
    if let Some(rest) = a.rejection_test.split("final sweep").nth(1) {
        w.push(Warning::new(
            WarningKind::Adjustment,
            format!(
                "{} observation(s) still failed the rejection test when the rounds ran out and were rejected at once",
                rest.trim().split([' ', ',']).next().unwrap_or("")
            ),
        ));
    }
    if !a.converged {
        w.push(Warning::new(
            WarningKind::Adjustment,
            format!(
                "the adjustment did not converge in {} iterations",
                a.iterations
            ),
        ));
    }
    w
}

/// What an existing block left out of the epoch: images it does not hold, its check
/// points, and a CRS it does not state.
pub fn existing_warnings(r: &ExistingReport) -> Vec<Warning> {
    let mut w = Vec::new();
    if !r.images_not_in_block.is_empty() {
        w.push(Warning::new(
            WarningKind::InputLeftOut,
            format!(
                "{} image(s) of the photo folder are not in the existing block {} and are not in the epoch: {}",
                r.images_not_in_block.len(),
                r.source,
                listed(&r.images_not_in_block)
            ),
        ));
    }
    if r.check_points_dropped > 0 {
        w.push(Warning::new(
            WarningKind::InputLeftOut,
            format!(
                "{} check point(s) of the existing block left out: the project's checkpoints evaluate the epoch",
                r.check_points_dropped
            ),
        ));
    }
    if r.crs.is_none() {
        w.push(Warning::new(
            WarningKind::InputAssumed,
            format!(
                "the existing block {} states no CRS: taken to be the project's",
                r.source
            ),
        ));
    }
    w
}

/// Folders of one epoch's stages.
pub struct EpochFolders {
    pub name: String,
    /// `epoch-<name>/`, `dcp-<name>/`, `outputs-<name>/`, `change-<name>/` (the last
    /// three need not exist).
    pub epoch: PathBuf,
    pub dcp: PathBuf,
    pub outputs: PathBuf,
    pub change: PathBuf,
}

/// The folders of a run the report reads.
pub struct RunFolders {
    /// `sources/`.
    pub sources: PathBuf,
    /// In run order.
    pub epochs: Vec<EpochFolders>,
}

impl RunFolders {
    /// Every file the report reads that exists, in a fixed order (the report stage's
    /// input files).
    pub fn files(&self) -> Vec<PathBuf> {
        let mut f = vec![
            self.sources.join("catalogue.json"),
            self.sources.join("lidar_checkpoints.json"),
        ];
        for e in &self.epochs {
            f.push(e.epoch.join("epoch.json"));
            f.push(e.dcp.join("skipped.json"));
            f.push(e.outputs.join("skipped.json"));
            f.push(e.change.join(crate::change::compare::CHANGE_REPORT_FILE));
            f.push(e.change.join(crate::change::compare::DH_MAP_FILE));
        }
        f.retain(|p| p.is_file());
        f
    }
}

/// The options and thresholds of `project`, with the defaults it leaves.
pub fn run_options(project: &Project) -> RunOptions {
    let archive = ArchiveOptions::default();
    let c = &project.control;
    RunOptions {
        thresholds: project.thresholds.clone(),
        outputs: project.outputs.clone(),
        lidar_datum_sigma_m: c.lidar_datum_sigma_m,
        orthophoto_sigma_m: c.orthophoto_sigma_m,
        dem_sigma_m: c.dem_sigma_m,
        checkpoints_crs: c.checkpoints_crs.clone(),
        checkpoint_measurement_sigma_px: crate::control::checkpoints::MEASUREMENT_SIGMA_PX,
        default_self_calibration: DefaultSelfCalibration {
            reference: crate::control::reference::ReferenceOptions::default().self_calibration,
            archive_frame: archive.self_calibration,
            archive_film: archive.film_self_calibration,
        },
        epochs: project
            .epochs()
            .map(|e| EpochOptions {
                name: e.name.clone(),
                date: e.date.clone(),
                scan_pixel_um: e.scan_pixel_mm().map(|mm| mm * 1000.0),
                self_calibration: e.self_calibration.clone(),
            })
            .collect(),
    }
}

/// The report stage's inputs: the project's name, CRS, hash and options, this
/// cloudcontrol's version, and the files of `folders`.
pub fn report_inputs(project: &Project, folders: &RunFolders) -> Inputs {
    let mut i = Inputs::new()
        .param("name", &project.name)
        .param("crs", &project.crs)
        .param("version", &crate::VERSION)
        .param("project_sha256", &project.file_sha256)
        .param("options", &run_options(project));
    for f in folders.files() {
        i = i.file(f);
    }
    i
}

/// Now, UTC, as [`utc_iso8601`]; `SOURCE_DATE_EPOCH` (seconds) when set, for a report
/// made to be byte-identical.
fn now_utc() -> String {
    let secs = std::env::var("SOURCE_DATE_EPOCH")
        .ok()
        .and_then(|s| s.trim().parse::<i64>().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs() as i64)
        });
    utc_iso8601(secs)
}

fn read_if_file<T: for<'de> serde::Deserialize<'de>>(
    path: PathBuf,
) -> Result<Option<T>, FormatError> {
    if path.is_file() {
        read_json(&path).map(Some)
    } else {
        Ok(None)
    }
}

/// The run's report from its folders: each epoch's `epoch.json` with the warnings of its
/// DCP and products stages added, the LiDAR catalogue's warnings and checkpoint
/// evaluation, and the run's metadata.
pub fn make_report(
    project: &Project,
    folders: &RunFolders,
    ortho: Option<OrthoPreview>,
) -> Result<Report, FormatError> {
    let mut epochs = Vec::new();
    for f in &folders.epochs {
        let mut e: EpochReport = read_json(&f.epoch.join("epoch.json"))?;
        if let Some(s) = read_if_file::<serde_json::Value>(f.dcp.join("skipped.json"))? {
            let reason = s["reason"].as_str().unwrap_or("no reason given");
            e.warnings.push(Warning::new(
                WarningKind::Products,
                format!("no DCP package made from this epoch: {reason}; older epochs are not controlled by it"),
            ));
        }
        if let Some(s) = read_if_file::<BTreeMap<String, String>>(f.outputs.join("skipped.json"))? {
            for (product, reason) in s {
                e.warnings.push(Warning::new(
                    WarningKind::Products,
                    format!("{product} not written: {reason}"),
                ));
            }
        }
        if let Some(c) = read_if_file::<crate::pipeline::change::EpochChange>(
            f.change.join(crate::change::compare::CHANGE_REPORT_FILE),
        )? {
            let younger = c
                .younger
                .as_ref()
                .map(|y| crate::pipeline::change::younger_dir(&f.change, &y.against));
            let dirs = std::iter::once(f.change.clone()).chain(younger);
            for (cmp, dir) in std::iter::once(&c.control)
                .chain(c.younger.as_ref())
                .zip(dirs)
            {
                let r = &cmp.change;
                let map_path = dir.join(crate::change::compare::DH_MAP_FILE);
                let map_png = std::fs::read(&map_path).unwrap_or_default();
                let map = (!map_png.is_empty()).then(|| {
                    map_path
                        .strip_prefix(f.change.parent().unwrap_or(&f.change))
                        .unwrap_or(&map_path)
                        .display()
                        .to_string()
                });
                if let Some(flag) = &cmp.flag {
                    e.warnings.push(Warning::new(
                        WarningKind::SurfaceShift,
                        format!("surface against {}: {flag}", cmp.against),
                    ));
                }
                e.surface_change.push(SurfaceChange {
                    against: cmp.against.clone(),
                    shift_gsd: cmp.shift_gsd,
                    shift_plan_gsd: cmp.shift_plan_gsd,
                    shift_plan_sigma_gsd: cmp.shift_plan_sigma_gsd,
                    with_tilt: cmp.with_tilt.clone(),
                    converged: r.nuth_kaab.converged,
                    stable_cells: r.stable_cells,
                    median_m: r.statistics.median_m,
                    nmad_m: r.statistics.nmad_m,
                    changed_areas: r.changed_areas,
                    changed_area_m2: r.changed_area_m2,
                    flag: cmp.flag.clone(),
                    map,
                    map_range_m: r.map_range_m,
                    map_png,
                });
            }
        }
        epochs.push(e);
    }
    let mut warnings = Vec::new();
    if let Some(c) =
        read_if_file::<crate::lidar::Catalogue>(folders.sources.join("catalogue.json"))?
    {
        warnings.extend(
            c.warnings
                .into_iter()
                .map(|m| Warning::new(WarningKind::Lidar, m)),
        );
    }
    let lidar = read_if_file::<crate::lidar::eval::CheckpointReport>(
        folders.sources.join("lidar_checkpoints.json"),
    )?
    .map(|r| LidarCheck::new(&r, &crate::lidar::CheckpointOptions::default()));
    if let Some(l) = &lidar {
        if !l.outliers.is_empty() {
            warnings.push(Warning::new(
                WarningKind::Lidar,
                format!(
                    "the LiDAR differs from {} checkpoint(s) by more than 3σ: {}",
                    l.outliers.len(),
                    l.outliers.join(", ")
                ),
            ));
        }
        let skipped: Vec<String> = l
            .rows
            .iter()
            .filter(|r| r.skipped.is_some())
            .map(|r| r.id.clone())
            .collect();
        if !skipped.is_empty() {
            warnings.push(Warning::new(
                WarningKind::Lidar,
                format!(
                    "{} checkpoint(s) have no LiDAR height (too few ground points around them): {}",
                    skipped.len(),
                    listed(&skipped)
                ),
            ));
        }
    }
    let lidar_strips =
        read_if_file::<crate::lidar::CleanReport>(folders.sources.join("clean.json"))?
            .and_then(|c| c.strip_offsets);
    if let Some(why) = lidar_strips
        .as_ref()
        .and_then(|s| s.vertical_because.as_ref())
    {
        warnings.push(Warning::new(
            WarningKind::Lidar,
            format!("the LiDAR strips were corrected in height alone: {why}"),
        ));
    }
    Ok(Report {
        project: project.name.clone(),
        crs: project.crs.clone(),
        run: Some(RunInfo {
            cloudcontrol_version: crate::VERSION.to_string(),
            project_sha256: project.file_sha256.clone(),
            date_utc: now_utc(),
            options: run_options(project),
        }),
        warnings,
        lidar_checkpoints: lidar,
        lidar_strips,
        epochs,
        ortho,
    })
}
