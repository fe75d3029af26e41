//! The files of an epoch stage (`epoch-<name>/`, formats/workflow/): `block.json` (the
//! epoch's [`Block`], every photo with its status and image), `images.json` (photo id →
//! image), `result.json` (per-photo results and the adjustment report), `epoch.json` (the
//! report rows) and `checkpoints.json`; and the report rows made from an epoch's result,
//! with its film scans and warnings.

use super::report::{gather, CheckpointError, EpochReport, IcpIteration, PhotoSummary};
use super::tie_statistics::tie_statistics;
use crate::adjust::ObservationRef;
use crate::block::{Block, PhotoId};
use crate::control::archive::EpochResult;
use crate::control::checkpoints::CheckpointEvaluation;
use crate::control::export::read_oriented_block;
use crate::control::photo::PhotoReport;
use crate::formats::paths::relative_to;
use crate::formats::{write_bytes_atomically, FormatError};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<(), FormatError> {
    let bytes =
        serde_json::to_vec_pretty(v).map_err(|e| FormatError::invalid(path, e.to_string()))?;
    write_bytes_atomically(path, &bytes)
}

pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, FormatError> {
    let bytes = crate::formats::input::read_bytes(path, crate::formats::input::Cap::document())?;
    serde_json::from_slice(&bytes).map_err(|e| FormatError::invalid(path, e.to_string()))
}

/// Writes `block` as `path` (block.json) with its photos' images named relative to the
/// file's folder (formats/workflow), so that a project moved whole finds its photos, and
/// returns those names (photo id → image) for images.json. The block keeps its paths:
/// they are put back after the write, not copied with the block's points.
pub fn write_block_json(
    path: &Path,
    block: &mut Block,
) -> Result<BTreeMap<PhotoId, PathBuf>, FormatError> {
    let folder = crate::formats::paths::folder_of(path);
    let mut given = BTreeMap::new();
    let mut named = BTreeMap::new();
    for p in block.photos.values_mut() {
        if let Some(image) = &mut p.image {
            let rel = relative_to(image, folder);
            named.insert(p.id, rel.clone());
            given.insert(p.id, std::mem::replace(image, rel));
        }
    }
    let written = write_json(path, block);
    for (id, image) in given {
        if let Some(p) = block.photos.get_mut(&id) {
            p.image = Some(image);
        }
    }
    written.map(|()| named)
}

/// Writes the files of an epoch stage into `dir` (block.json and images.json name the
/// photos relative to `dir`, [`write_block_json`]).
pub fn save_epoch(
    dir: &Path,
    result: &mut EpochResult,
    report: &EpochReport,
    eval: &Option<CheckpointEvaluation>,
) -> Result<(), FormatError> {
    let named = write_block_json(&dir.join("block.json"), &mut result.block)?;
    write_json(&dir.join("images.json"), &named)?;
    write_json(&dir.join("result.json"), result)?;
    write_json(&dir.join("epoch.json"), report)?;
    if let Some(e) = eval {
        write_json(&dir.join("checkpoints.json"), e)?;
    }
    Ok(())
}

/// The oriented block of an epoch stage, its photos' images set.
pub fn load_block(dir: &Path) -> Result<Block, crate::control::EpochError> {
    read_oriented_block(&dir.join("block.json"), &dir.join("images.json"))
}

/// The report rows of an oriented epoch.
pub fn epoch_report(
    result: &EpochResult,
    date: &str,
    eval: &Option<CheckpointEvaluation>,
    surveyed: &[(String, [f64; 3])],
    icp: Vec<IcpIteration>,
) -> EpochReport {
    let block = &result.block;
    let origin = block.origin;
    // Mean residual vector and matching counts per photo.
    let mut res: BTreeMap<PhotoId, ([f64; 2], usize)> = BTreeMap::new();
    if let Some(a) = &result.adjustment {
        for r in &a.residuals {
            if let (ObservationRef::Image { photo, .. }, [dx, dy, ..]) =
                (&r.observation, r.residual.as_slice())
            {
                let e = res.entry(*photo).or_insert(([0.0; 2], 0));
                e.0[0] += dx;
                e.0[1] += dy;
                e.1 += 1;
            }
        }
    }
    let (ties, mut photo_ties) = tie_statistics(block);
    let by_name: BTreeMap<&str, &PhotoReport> =
        result.photos.iter().map(|p| (p.name.as_str(), p)).collect();
    let photos = block
        .photos
        .values()
        .map(|p| {
            let rep = by_name.get(p.name.as_str());
            let (sum, n) = res.get(&p.id).copied().unwrap_or(([0.0; 2], 0));
            let n = n.max(1) as f64;
            PhotoSummary {
                name: p.name.clone(),
                x: p.pose.center.x + origin[0],
                y: p.pose.center.y + origin[1],
                oriented: p.is_oriented(),
                reason: rep.and_then(|r| r.reason.as_ref()).map(|f| f.to_string()),
                mean_residual_px: [sum[0] / n, sum[1] / n],
                rmse_px: rep.map_or(f64::NAN, |r| r.sigma_px),
                patches_predicted: rep.map_or(0, |r| r.predicted),
                patches_matched: rep.map_or(0, |r| r.control_matches),
                ties: photo_ties.remove(&p.name).unwrap_or_default(),
            }
        })
        .collect();
    let checkpoints = eval
        .as_ref()
        .map(|e| {
            e.points
                .iter()
                .filter_map(|p| {
                    let (_, xyz) = surveyed.iter().find(|s| s.0 == p.id)?;
                    Some(CheckpointError {
                        id: p.id.clone(),
                        x: xyz[0],
                        y: xyz[1],
                        dx: p.error[0],
                        dy: p.error[1],
                        dz: p.error[2],
                        rays: p.rays,
                    })
                })
                .collect()
        })
        .unwrap_or_default();
    let mut rep = EpochReport {
        name: result.epoch.clone(),
        date: date.to_string(),
        gsd_m: result.gsd_m,
        photos_total: result.photos.len(),
        photos_oriented: result.photos.iter().filter(|p| p.oriented).count(),
        photos_through_ties: result
            .photos
            .iter()
            .filter(|p| p.oriented && p.tie_pass)
            .count(),
        check_rmse_plan_m: f64::NAN,
        check_rmse_height_m: f64::NAN,
        check_max_m: f64::NAN,
        sigma0: result.adjustment.as_ref().map_or(f64::NAN, |a| a.sigma0),
        rmse_px: result.adjustment.as_ref().map_or(f64::NAN, |a| a.rmse_px),
        time_s: result.time_s,
        checkpoints,
        checkpoints_not_evaluated: eval.as_ref().map_or(0, |e| e.not_evaluated),
        checkpoint_rejections: eval
            .as_ref()
            .map(|e| e.rejected.clone())
            .unwrap_or_default(),
        photos,
        scans: gather::scan_rows(result),
        icp,
        control: Vec::new(),
        ties,
        variance_components: result
            .adjustment
            .as_ref()
            .map(|a| a.variance_components.clone())
            .unwrap_or_default(),
        warnings: Vec::new(),
        surface_change: Vec::new(),
    };
    rep.set_check_statistics();
    rep.warnings = gather::epoch_warnings(result, &rep);
    rep
}
