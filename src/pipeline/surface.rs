//! The surface stage of an epoch (`surface-<epoch>/`): the epoch's own DSM by dense
//! matching of its oriented photos ([`crate::dense`]), searched within a margin around
//! the control's surface model (the LiDAR's first-return surface, or the project's DEM),
//! never filled from it. Each stereo pair is a task ([`super::tasks::surface`]), so a
//! Dask run fans the pairs out; the stage fuses them. Film epochs are matched from their
//! scans through each scan's interior orientation (rectification goes through the camera
//! model, so the resampled fiducial-frame images would only add a resampling).

use super::epoch_files::write_json;
use super::stages::WorkError;
use super::tasks::surface::{SurfaceContext, SurfaceTaskPlan, SurfaceTasks};
use super::tasks::TaskMode;
use crate::dense::epoch::fuse;
use crate::dense::fusion::Fusion;
use crate::dense::products::write_dsm;
use crate::dense::DenseError;
use crate::formats::crs::Crs;
use std::path::Path;

/// Written instead of the DSM when the epoch has none (its reason inside).
pub(crate) const SKIPPED_FILE: &str = "skipped.json";

/// Writes the DSM of the epoch of `plan` into `dir`; `prior` names the control's surface
/// in dsm.json. The pairs are matched by `tasks` (here, or returned as pending).
pub(crate) fn write_epoch_surface(
    plan: &SurfaceTaskPlan,
    prior: &str,
    crs: &Crs,
    dir: &Path,
    (tasks, mode): (&SurfaceTasks, TaskMode),
) -> Result<(), WorkError> {
    let t0 = std::time::Instant::now();
    let ctx = SurfaceContext::load(plan)?;
    // An epoch with too few oriented photos or pairs has no surface of its own: said in
    // the stage folder, and the run goes on (as an epoch without DCPs does).
    let skipped = |reason: &str| -> Result<(), WorkError> {
        tracing::warn!(%reason, "no surface");
        write_json(
            &dir.join(SKIPPED_FILE),
            &serde_json::json!({ "reason": reason }),
        )?;
        tasks.clear();
        Ok(())
    };
    let surface_plan = match &ctx.plan {
        Ok(p) => p,
        Err(reason) => return skipped(reason),
    };
    let mut fusion = Fusion::new(surface_plan.grid);
    let mut reports = Vec::with_capacity(surface_plan.pairs.len());
    tasks.stereo(&ctx, surface_plan, mode, |report, samples| {
        fusion.push(&samples);
        reports.push(report);
    })?;
    // The work of the pairs (wherever they ran) and the fusion here.
    let seconds = reports.iter().map(|r| r.seconds).sum::<f64>() + t0.elapsed().as_secs_f64();
    match fuse(surface_plan, fusion, reports, &plan.options) {
        Ok(result) => {
            let points = plan.project.outputs.dsm_points;
            write_dsm(dir, &result, crs, prior, &plan.options, seconds, points)?;
            tasks.clear();
            Ok(())
        }
        Err(DenseError::NoSurface(reason)) => skipped(&reason),
        Err(e) => Err(e.into()),
    }
}
