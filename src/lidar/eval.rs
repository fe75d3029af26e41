//! Evaluation of a LiDAR source against surveyed checkpoints: the LiDAR height at each
//! checkpoint from a local least-squares plane of ground points, the difference and the
//! statistics (mean, σ, RMSE, max, 3σ outliers), as JSON and text.

use super::store::{Bbox, TileStore};
use super::{LidarError, Result};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::num::NonZero;

#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct CheckpointOptions {
    /// Ground points within this plan distance (m) enter the local plane.
    pub radius: f64,
    /// Nearest ground points considered (within `radius`).
    pub k: usize,
    /// Fewer accepted neighbours and the checkpoint is skipped.
    pub min_points: usize,
}

impl Default for CheckpointOptions {
    fn default() -> Self {
        Self {
            radius: 3.0,
            k: 16,
            min_points: 6,
        }
    }
}

/// One checkpoint's comparison; `dz_m = lidar_z − checkpoint z`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointRow {
    pub id: String,
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub lidar_z: Option<f64>,
    pub dz_m: Option<f64>,
    pub neighbours: usize,
    /// RMS of the ground points about the local plane (m).
    pub plane_rms_m: Option<f64>,
    pub outlier: bool,
    /// Why no height was derived.
    pub skipped: Option<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckpointReport {
    /// Checkpoints with a LiDAR height.
    pub count: usize,
    pub skipped: usize,
    pub mean_m: f64,
    pub std_m: f64,
    pub rmse_m: f64,
    pub max_abs_m: f64,
    /// Ids with |dz − mean| > 3σ.
    pub outliers: Vec<String>,
    /// RMSE without the outliers.
    pub rmse_without_outliers_m: f64,
    pub rows: Vec<CheckpointRow>,
}

impl CheckpointReport {
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!(
            "checkpoints {} (skipped {}): mean {:+.3} m, σ {:.3} m, RMSE {:.3} m, max |dz| {:.3} m, 3σ outliers {}\n",
            self.count, self.skipped, self.mean_m, self.std_m, self.rmse_m, self.max_abs_m, self.outliers.len()
        ));
        if !self.outliers.is_empty() {
            s.push_str(&format!(
                "  without outliers: RMSE {:.3} m; outliers: {}\n",
                self.rmse_without_outliers_m,
                self.outliers.join(", ")
            ));
        }
        s.push_str("  id                 X              Y           Z      LiDAR Z      dz  n\n");
        for r in &self.rows {
            match (r.lidar_z, r.dz_m) {
                (Some(l), Some(d)) => s.push_str(&format!(
                    "  {:<12} {:>13.3} {:>14.3} {:>9.3} {:>10.3} {:>+7.3} {:>2}{}\n",
                    r.id,
                    r.x,
                    r.y,
                    r.z,
                    l,
                    d,
                    r.neighbours,
                    if r.outlier { "  outlier" } else { "" }
                )),
                _ => s.push_str(&format!(
                    "  {:<12} {:>13.3} {:>14.3} {:>9.3}  skipped: {}\n",
                    r.id,
                    r.x,
                    r.y,
                    r.z,
                    r.skipped.as_deref().unwrap_or("")
                )),
            }
        }
        s
    }
}

fn validate(checkpoints: &[(String, [f64; 3])], opts: &CheckpointOptions) -> Result<()> {
    if opts.radius.is_nan() || opts.radius <= 0.0 || opts.k < 3 || opts.min_points < 3 {
        return Err(LidarError::InvalidOption(
            "checkpoint evaluation needs radius > 0, k >= 3 and min_points >= 3".into(),
        ));
    }
    if checkpoints.is_empty() {
        return Err(LidarError::data("checkpoints", "no checkpoint given"));
    }
    for (id, p) in checkpoints {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(LidarError::data(
                format!("checkpoint {id}"),
                "coordinate is not finite",
            ));
        }
    }
    Ok(())
}

/// Height of the local plane of `nbrs` (local coordinates about the checkpoint) at (0, 0).
/// Points off the ground surface (a low wall, a car, noise) are rejected iteratively at
/// 3 robust σ (1.4826·MAD, floored at 1 cm) of the plane residuals.
fn local_plane_height(
    nbrs: &[[f64; 3]],
    min_points: usize,
) -> std::result::Result<(f64, f64, usize), String> {
    let fit = |pts: &[&[f64; 3]]| -> Option<Vector3<f64>> {
        let mut n = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for p in pts {
            let a = Vector3::new(1.0, p[0], p[1]);
            n += a * a.transpose();
            b += a * p[2];
        }
        n.cholesky().map(|c| c.solve(&b))
    };
    let res = |c: &Vector3<f64>, p: &[f64; 3]| p[2] - (c[0] + c[1] * p[0] + c[2] * p[1]);
    let all: Vec<&[f64; 3]> = nbrs.iter().collect();
    let mut used = all.clone();
    let mut coef = fit(&used).ok_or("ground points are collinear")?;
    for _ in 0..5 {
        let mut abs: Vec<f64> = all.iter().map(|p| res(&coef, p).abs()).collect();
        abs.sort_by(|a, b| a.total_cmp(b));
        let cut = 3.0 * (1.4826 * abs[abs.len() / 2]).max(0.01);
        let kept: Vec<&[f64; 3]> = all
            .iter()
            .copied()
            .filter(|p| res(&coef, p).abs() <= cut)
            .collect();
        if kept.len() < min_points || kept.len() == used.len() {
            break;
        }
        match fit(&kept) {
            Some(c) => {
                coef = c;
                used = kept;
            }
            None => break,
        }
    }
    let rms = (used.iter().map(|p| res(&coef, p).powi(2)).sum::<f64>() / used.len() as f64).sqrt();
    Ok((coef[0], rms, used.len()))
}

fn row_from(id: &str, c: [f64; 3], nbrs: &[[f64; 3]], opts: &CheckpointOptions) -> CheckpointRow {
    let mut row = CheckpointRow {
        id: id.to_string(),
        x: c[0],
        y: c[1],
        z: c[2],
        lidar_z: None,
        dz_m: None,
        neighbours: nbrs.len(),
        plane_rms_m: None,
        outlier: false,
        skipped: None,
    };
    if nbrs.len() < opts.min_points {
        row.skipped = Some(format!(
            "{} ground points within {} m (need {})",
            nbrs.len(),
            opts.radius,
            opts.min_points
        ));
        return row;
    }
    match local_plane_height(nbrs, opts.min_points) {
        Ok((h, rms, used)) => {
            let lz = c[2] + h;
            row.lidar_z = Some(lz);
            row.dz_m = Some(h);
            row.neighbours = used;
            row.plane_rms_m = Some(rms);
        }
        Err(e) => row.skipped = Some(e.to_string()),
    }
    row
}

fn report(rows: Vec<CheckpointRow>) -> Result<CheckpointReport> {
    let mut rows = rows;
    let d: Vec<f64> = rows.iter().filter_map(|r| r.dz_m).collect();
    let count = d.len();
    if count == 0 {
        return Err(LidarError::data(
            "checkpoints",
            "no checkpoint has enough ground points around it (check the CRS, the ground class and the radius)",
        ));
    }
    let n = count as f64;
    let mean = d.iter().sum::<f64>() / n;
    let std = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
    let rmse = (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let max_abs = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut outliers = Vec::new();
    let (mut s2, mut m) = (0.0, 0usize);
    for r in rows.iter_mut() {
        if let Some(v) = r.dz_m {
            if count >= 4 && (v - mean).abs() > 3.0 * std {
                r.outlier = true;
                outliers.push(r.id.clone());
            } else {
                s2 += v * v;
                m += 1;
            }
        }
    }
    Ok(CheckpointReport {
        count,
        skipped: rows.len() - count,
        mean_m: mean,
        std_m: std,
        rmse_m: rmse,
        max_abs_m: max_abs,
        outliers,
        rmse_without_outliers_m: (s2 / m.max(1) as f64).sqrt(),
        rows,
    })
}

/// Evaluates ground points (world coordinates) against checkpoints `(id, [X, Y, Z])`.
pub fn evaluate_checkpoints(
    ground: &[[f64; 3]],
    checkpoints: &[(String, [f64; 3])],
    opts: &CheckpointOptions,
) -> Result<CheckpointReport> {
    validate(checkpoints, opts)?;
    if ground.len() < opts.min_points {
        return Err(LidarError::TooFewPoints {
            what: "ground points".into(),
            got: ground.len(),
            need: opts.min_points,
        });
    }
    let o = ground[0];
    let xy: Vec<[f64; 2]> = ground.iter().map(|p| [p[0] - o[0], p[1] - o[1]]).collect();
    let tree = ImmutableKdTree::new_from_slice(&xy);
    let k = NonZero::new(opts.k).expect("k >= 3");
    let r2 = opts.radius * opts.radius;
    let rows = checkpoints
        .iter()
        .map(|(id, c)| {
            let nn = tree.nearest_n::<SquaredEuclidean>(&[c[0] - o[0], c[1] - o[1]], k);
            let nbrs: Vec<[f64; 3]> = nn
                .iter()
                .filter(|n| n.distance <= r2)
                .map(|n| {
                    let p = ground[n.item as usize];
                    [p[0] - c[0], p[1] - c[1], p[2] - c[2]]
                })
                .collect();
            row_from(id, *c, &nbrs, opts)
        })
        .collect();
    report(rows)
}

/// Evaluates a tiled source: per checkpoint, only the tiles around it are loaded (LRU).
/// `ground_classes`: classes taken as ground (e.g. [2]); None takes every point.
pub fn evaluate_checkpoints_store(
    store: &mut TileStore,
    checkpoints: &[(String, [f64; 3])],
    ground_classes: Option<&[u8]>,
    opts: &CheckpointOptions,
) -> Result<CheckpointReport> {
    validate(checkpoints, opts)?;
    // Visit checkpoints tile by tile so the LRU cache is used well; report in input order.
    let mut order: Vec<usize> = (0..checkpoints.len()).collect();
    let tile_of = |c: &[f64; 3]| {
        store
            .catalogue()
            .tiles_in(&Bbox::new(c[0], c[1], c[0], c[1]))
            .first()
            .copied()
            .unwrap_or(usize::MAX)
    };
    let keys: Vec<usize> = checkpoints.iter().map(|(_, c)| tile_of(c)).collect();
    order.sort_by_key(|&i| (keys[i], i));
    let mut rows: Vec<Option<CheckpointRow>> = vec![None; checkpoints.len()];
    for i in order {
        let (id, c) = &checkpoints[i];
        let b = Bbox::new(c[0], c[1], c[0], c[1]).grown(opts.radius);
        let pts = store.query(&b, ground_classes)?;
        let r2 = opts.radius * opts.radius;
        let mut local: Vec<(f64, [f64; 3])> = pts
            .xyz
            .iter()
            .map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]])
            .map(|p| (p[0] * p[0] + p[1] * p[1], p))
            .filter(|(d, _)| *d <= r2)
            .collect();
        local.sort_by(|a, b| a.0.total_cmp(&b.0));
        local.truncate(opts.k);
        let nbrs: Vec<[f64; 3]> = local.into_iter().map(|(_, p)| p).collect();
        rows[i] = Some(row_from(id, *c, &nbrs, opts));
    }
    report(
        rows.into_iter()
            .map(|r| r.expect("every checkpoint visited"))
            .collect(),
    )
}
