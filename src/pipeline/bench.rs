//! The accuracy bench (`cloudcontrol bench accuracy`): a finished run of a synthetic block
//! scored epoch by epoch against the targets of the workflow, beside what the *true*
//! orientation scores at the same checkpoints. The checkpoints carry survey noise (5 cm,
//! half a reference ground pixel) and their image measurements carry the operator's, so a
//! figure near 1 GSD may be the checkpoints' own; the truth figure tells which.
//!
//! Every figure counts per seed and per epoch: the summary is the worst row, never a mean.

use super::project::Project;
use super::report::{EpochReport, Report};
use super::run::{evaluate, read_checkpoints};
use super::stages::WorkError;
use crate::control::EpochError;
use crate::synth::reading::synth_truth_block;
use serde::Serialize;
use std::path::Path;

/// The targets of issue "any seed, any size" (ground pixels of the epoch).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Targets {
    /// Fraction of an epoch's photos that must be oriented.
    pub oriented_fraction: f64,
    /// Reference epoch: checkpoint RMSE in plan and in height.
    pub reference_gsd: f64,
    /// Archive epochs: checkpoint RMSE in plan, and in height.
    pub archive_plan_gsd: f64,
    pub archive_height_gsd: f64,
    /// A reference figure above its target still passes when it is within this factor of
    /// what the true orientation scores (the checkpoints' own noise).
    pub truth_factor: f64,
}

impl Default for Targets {
    fn default() -> Self {
        Self {
            oriented_fraction: 0.95,
            reference_gsd: 1.0,
            archive_plan_gsd: 1.0,
            archive_height_gsd: 1.5,
            truth_factor: 1.10,
        }
    }
}

/// One epoch of one seed.
#[derive(Debug, Clone, Serialize)]
pub struct EpochScore {
    pub seed: u64,
    pub epoch: String,
    pub reference: bool,
    pub photos_total: usize,
    pub photos_oriented: usize,
    /// Checkpoints intersected in the epoch.
    pub checkpoints: usize,
    pub gsd_m: f64,
    /// Checkpoint RMSE of the workflow's orientation, ground pixels (NaN: not evaluated).
    pub plan_gsd: f64,
    pub height_gsd: f64,
    /// The same checkpoints and measurements with the true orientation.
    pub truth_plan_gsd: f64,
    pub truth_height_gsd: f64,
    pub time_s: f64,
    /// Each target this epoch misses, in words (empty: every target met).
    pub misses: Vec<String>,
}

/// Why a run could not be scored.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Work(#[from] WorkError),
    #[error(transparent)]
    Epoch(#[from] EpochError),
}

/// Scores every epoch of `report`, the run of `project` over the synthetic block in
/// `block_dir` (its `truth/` gives the true orientation).
pub fn score_run(
    seed: u64,
    block_dir: &Path,
    project: &Project,
    report: &Report,
    targets: &Targets,
) -> Result<Vec<EpochScore>, BenchError> {
    let cps = read_checkpoints(project)?;
    let mut rows = Vec::new();
    for (k, e) in report.epochs.iter().enumerate() {
        let truth = synth_truth_block(block_dir, &e.name)?;
        let truth_eval = if e.gsd_m.is_finite() && e.gsd_m > 0.0 {
            evaluate(&cps, &truth, &e.name, e.gsd_m, &[])?
        } else {
            None
        };
        let (truth_plan, truth_height) = truth_eval
            .map(|t| (t.rmse_plan_px, t.rmse_height_px))
            .unwrap_or((f64::NAN, f64::NAN));
        let mut row = EpochScore {
            seed,
            epoch: e.name.clone(),
            // The first epoch is the reference when the project has one (an orthophoto
            // with a DEM controls archive epochs only).
            reference: k == 0 && project.reference.is_some(),
            photos_total: e.photos_total,
            photos_oriented: e.photos_oriented,
            checkpoints: e.checkpoints.len(),
            gsd_m: e.gsd_m,
            plan_gsd: e.check_rmse_plan_m / e.gsd_m,
            height_gsd: e.check_rmse_height_m / e.gsd_m,
            truth_plan_gsd: truth_plan,
            truth_height_gsd: truth_height,
            time_s: e.time_s,
            misses: Vec::new(),
        };
        row.misses = misses(&row, e, targets);
        rows.push(row);
    }
    Ok(rows)
}

/// The targets `row` misses.
#[doc(hidden)]
pub fn misses(row: &EpochScore, e: &EpochReport, t: &Targets) -> Vec<String> {
    let mut out = Vec::new();
    let need = (t.oriented_fraction * row.photos_total as f64).ceil() as usize;
    if row.photos_oriented < need {
        out.push(format!(
            "{} of {} photos oriented (target {need})",
            row.photos_oriented, row.photos_total
        ));
    }
    if e.checkpoints.is_empty() || !row.plan_gsd.is_finite() {
        out.push("no checkpoint evaluated".into());
        return out;
    }
    let (plan_t, height_t) = if row.reference {
        (t.reference_gsd, t.reference_gsd)
    } else {
        (t.archive_plan_gsd, t.archive_height_gsd)
    };
    let over = |what: &str, v: f64, target: f64, truth: f64| -> Option<String> {
        if v <= target {
            return None;
        }
        // The reference is held to the truth where the checkpoints themselves are the limit.
        if row.reference && truth.is_finite() && v <= t.truth_factor * truth {
            return None;
        }
        Some(format!(
            "{what} {v:.2} GSD > {target} (truth {truth:.2} GSD)"
        ))
    };
    out.extend(over("plan", row.plan_gsd, plan_t, row.truth_plan_gsd));
    out.extend(over(
        "height",
        row.height_gsd,
        height_t,
        row.truth_height_gsd,
    ));
    out
}

/// The LiDAR's own height error at the checkpoints, as the run's sources stage measured it
/// (`sources/lidar_checkpoints.json`): mean and RMSE (m). The reference epoch takes its
/// datum from the LiDAR, so a LiDAR bias shows in its height however well it is oriented.
pub fn lidar_height_error(output: &Path) -> Option<(f64, f64)> {
    let text = std::fs::read_to_string(output.join("sources/lidar_checkpoints.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    Some((v["mean_m"].as_f64()?, v["rmse_m"].as_f64()?))
}

/// The table header of [`row_line`].
pub const TABLE_HEADER: &str =
    "seed  epoch              photos   cps  plan GSD (truth)  height GSD (truth)   time s  result";

/// One line of the bench table.
pub fn row_line(r: &EpochScore) -> String {
    format!(
        "{:>4}  {:<18} {:>3}/{:<3} {:>5}  {:>5.2} ({:>5.2})     {:>5.2} ({:>5.2})      {:>7.1}  {}",
        r.seed,
        r.epoch,
        r.photos_oriented,
        r.photos_total,
        r.checkpoints,
        r.plan_gsd,
        r.truth_plan_gsd,
        r.height_gsd,
        r.truth_height_gsd,
        r.time_s,
        if r.misses.is_empty() {
            "ok".to_string()
        } else {
            format!("MISS: {}", r.misses.join("; "))
        }
    )
}

/// The summary: rows that meet every target, and the worst figure of each kind with its
/// seed and epoch.
pub fn summary_line(rows: &[EpochScore]) -> String {
    let ok = rows.iter().filter(|r| r.misses.is_empty()).count();
    let worst = |f: &dyn Fn(&EpochScore) -> f64, what: &str| {
        rows.iter()
            .filter(|r| f(r).is_finite())
            .max_by(|a, b| f(a).total_cmp(&f(b)))
            .map(|r| format!("{what} {:.2} (seed {}, {})", f(r), r.seed, r.epoch))
            .unwrap_or_else(|| format!("{what} -"))
    };
    let least_oriented = rows
        .iter()
        .min_by(|a, b| {
            let fa = a.photos_oriented as f64 / a.photos_total.max(1) as f64;
            let fb = b.photos_oriented as f64 / b.photos_total.max(1) as f64;
            fa.total_cmp(&fb)
        })
        .map(|r| {
            format!(
                "fewest oriented {}/{} (seed {}, {})",
                r.photos_oriented, r.photos_total, r.seed, r.epoch
            )
        })
        .unwrap_or_default();
    format!(
        "{ok} of {} epoch rows meet every target; worst: {}, {}, {}",
        rows.len(),
        worst(&|r| r.plan_gsd, "plan"),
        worst(&|r| r.height_gsd, "height"),
        least_oriented
    )
}
