//! The surface stage of an epoch (`surface-<epoch>/`): the epoch's own DSM by dense
//! matching of its oriented photos ([`crate::dense`]), searched within a margin around
//! the control's surface model (the LiDAR's first-return surface, or the project's DEM),
//! never filled from it. Film epochs are matched from their scans through each scan's
//! interior orientation (rectification goes through the camera model, so the resampled
//! fiducial-frame images would only add a resampling).

use super::epoch_files::{load_block, write_json};
use super::stages::WorkError;
use crate::dense::epoch::{epoch_dsm, DsmOptions};
use crate::dense::products::write_dsm;
use crate::dense::DenseError;
use crate::formats::crs::Crs;
use crate::lidar::GroundSurface;
use crate::matching::oriented::Surface;
use crate::matching::GreyImage;
use nalgebra::Vector3;
use std::path::Path;

/// Written instead of the DSM when the epoch has none (its reason inside).
pub(crate) const SKIPPED_FILE: &str = "skipped.json";

/// Writes the DSM of the epoch oriented in `epoch_dir` into `dir`; `ground` is the
/// control's surface (block-local), `prior` names it in dsm.json.
pub(crate) fn write_epoch_surface(
    epoch_dir: &Path,
    ground: &GroundSurface,
    prior: &str,
    crs: &Crs,
    options: &DsmOptions,
    dir: &Path,
) -> Result<(), WorkError> {
    let t0 = std::time::Instant::now();
    let block = load_block(epoch_dir)?;
    let surface = Surface::Dem {
        dem: &ground.surface,
        origin: Vector3::zeros(),
        sigma_m: 0.0,
    };
    let image = |p: &crate::block::Photo| {
        let path = p
            .image
            .as_ref()
            .ok_or_else(|| format!("photo {} has no image file", p.name))?;
        GreyImage::load(path).map_err(|e| e.to_string())
    };
    let result = epoch_dsm(&block, &image, &surface, None, options, |k, n, r| {
        tracing::info!(
            pair = k,
            of = n,
            left = r.pair.left,
            right = r.pair.right,
            matched = r.matched,
            seconds = r.seconds,
            "pair matched"
        );
    });
    match result {
        Ok(result) => {
            write_dsm(
                dir,
                &result,
                crs,
                prior,
                options,
                t0.elapsed().as_secs_f64(),
            )?;
        }
        // An epoch with too few oriented photos or pairs has no surface of its own: said
        // in the stage folder, and the run goes on (as an epoch without DCPs does).
        Err(DenseError::NoSurface(reason)) => {
            tracing::warn!(%reason, "no surface");
            write_json(
                &dir.join(SKIPPED_FILE),
                &serde_json::json!({ "reason": reason }),
            )?;
        }
        Err(e) => return Err(e.into()),
    }
    Ok(())
}
