//! An epoch's surface model scored against the epoch's true surface
//! (`truth/epochs/<epoch>/dsm.tif`), the way the dense-matching acceptance counts it:
//! heights minus the truth in ground pixels of the epoch on cells at least 2 ground
//! pixels from a height edge, completeness over the cells two photos of one matched pair
//! see, and the cells that changed since the present (`reference_2024`) apart.
//! Evaluation code only: a pipeline never reads `truth/`.

use crate::block::{Block, PhotoId};
use crate::formats::raster::read_dem;
use crate::geometry::{project, Dem};
use nalgebra::Vector3;
use serde::Serialize;
use std::path::Path;

/// Scores of one epoch's DSM, in ground pixels (GSD) of the epoch.
#[derive(Debug, Clone, Serialize)]
pub struct SurfaceScore {
    pub median_gsd: f64,
    pub nmad_gsd: f64,
    /// Share of the stereo-covered cells away from height edges with a height.
    pub completeness: f64,
    /// Cells scored.
    pub cells: usize,
    /// NMAD (GSD) and number of the scored cells whose truth differs from the present's by
    /// more than 2 m (built or demolished since).
    pub changed_nmad_gsd: f64,
    pub changed_cells: usize,
    /// The same cells scored against the present truth: a DSM copied from today's surface
    /// would score well there and badly above.
    pub changed_nmad_vs_present_gsd: f64,
}

fn median_nmad(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let med = v.get(v.len() / 2).copied().unwrap_or(f64::NAN);
    let mut d: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
    d.sort_by(f64::total_cmp);
    (
        med,
        1.4826 * d.get(d.len() / 2).copied().unwrap_or(f64::NAN),
    )
}

/// Scores `dsm` (world, the epoch's CRS) of `epoch` of the synthetic block `dir`, made
/// from the photo pairs `pairs` of `block` (the oriented block it was matched from),
/// with ground pixel `gsd` (m).
pub fn score_surface(
    dir: &Path,
    epoch: &str,
    dsm: &Dem,
    block: &Block,
    pairs: &[(PhotoId, PhotoId)],
    gsd: f64,
) -> Result<SurfaceScore, crate::formats::FormatError> {
    let (truth, _) = read_dem(&dir.join("truth/epochs").join(epoch).join("dsm.tif"))?;
    let (present, _) = read_dem(&dir.join("truth/epochs/reference_2024/dsm.tif"))?;
    let origin = Vector3::from(block.origin);
    // Seen well inside both photos of a pair: the stereo-covered area.
    let sees = |id: PhotoId, x: &Vector3<f64>| {
        let Some(p) = block.photos.get(&id) else {
            return false;
        };
        let Some(cam) = block.camera_of(p) else {
            return false;
        };
        let (w, h) = cam.model.image_size();
        project(&cam.model, &p.pose, &(x - origin)).is_ok_and(|q| {
            q.pixel.x > 8.0
                && q.pixel.y > 8.0
                && q.pixel.x < w as f64 - 8.0
                && q.pixel.y < h as f64 - 8.0
        })
    };
    let (mut dz, mut changed, mut changed_present) = (Vec::new(), Vec::new(), Vec::new());
    let (mut covered, mut found) = (0usize, 0usize);
    for r in 0..dsm.height {
        for c in 0..dsm.width {
            let (x, y) = dsm.transform.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let Some(t) = truth.height_at(x, y) else {
                continue;
            };
            // Away from height edges: the truth within 2 GSD stays within 0.5 m.
            let edge = (0..8).any(|a| {
                let (s, co) = (a as f64 * std::f64::consts::FRAC_PI_4).sin_cos();
                truth
                    .height_at(x + 2.0 * gsd * co, y + 2.0 * gsd * s)
                    .is_none_or(|u| (u - t).abs() > 0.5)
            });
            if edge {
                continue;
            }
            let xt = Vector3::new(x, y, t);
            if !pairs.iter().any(|&(a, b)| sees(a, &xt) && sees(b, &xt)) {
                continue;
            }
            covered += 1;
            let z = dsm.data[r * dsm.width + c];
            if !z.is_finite() {
                continue;
            }
            found += 1;
            let z = z as f64;
            dz.push((z - t) / gsd);
            if let Some(p) = present.height_at(x, y).filter(|p| (p - t).abs() > 2.0) {
                changed.push((z - t) / gsd);
                changed_present.push((z - p) / gsd);
            }
        }
    }
    let cells = dz.len();
    let (median_gsd, nmad_gsd) = median_nmad(&mut dz);
    let changed_cells = changed.len();
    let (_, changed_nmad_gsd) = median_nmad(&mut changed);
    let (_, changed_nmad_vs_present_gsd) = median_nmad(&mut changed_present);
    Ok(SurfaceScore {
        median_gsd,
        nmad_gsd,
        completeness: found as f64 / covered.max(1) as f64,
        cells,
        changed_nmad_gsd,
        changed_cells,
        changed_nmad_vs_present_gsd,
    })
}
