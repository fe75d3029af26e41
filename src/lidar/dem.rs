//! Gridding of ground points into a DEM: per-cell mean or inverse-distance weighting of the
//! points around each cell centre, then hole filling from the valid neighbours up to a
//! given distance. Writing is formats::raster::write_dem (GeoTIFF with CRS and nodata).

use super::store::Bbox;
use super::{LidarError, Result};
use crate::geometry::{Dem, GeoTransform};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DemMethod {
    /// Mean height of the points in the cell.
    Mean,
    /// Inverse-distance weighting (power p) of the points in the cell and its 8 neighbours,
    /// distances to the cell centre.
    Idw { power: f64 },
}

#[derive(Debug, Clone, Copy)]
pub struct DemOptions {
    pub cell: f64,
    pub method: DemMethod,
    /// Holes up to this many cells from valid data are filled; farther cells stay nodata.
    pub max_fill_cells: usize,
    /// Grid extent; default: the points' bounding box.
    pub bbox: Option<Bbox>,
    /// Refuse grids larger than this many cells (memory guard).
    pub max_cells: usize,
}

impl Default for DemOptions {
    fn default() -> Self {
        Self {
            cell: 1.0,
            method: DemMethod::Mean,
            max_fill_cells: 5,
            bbox: None,
            max_cells: 400_000_000,
        }
    }
}

/// Grids points (world coordinates, already restricted to ground) into a north-up DEM whose
/// top-left corner is the bbox's (min_x, max_y) snapped outward to the cell size.
pub fn grid_dem(points: &[[f64; 3]], opts: &DemOptions) -> Result<Dem> {
    if !(opts.cell > 0.0 && opts.cell.is_finite()) {
        return Err(LidarError::InvalidOption(format!(
            "DEM cell size {} must be positive",
            opts.cell
        )));
    }
    if let DemMethod::Idw { power } = opts.method {
        if !(power > 0.0 && power.is_finite()) {
            return Err(LidarError::InvalidOption(format!(
                "IDW power {power} must be positive"
            )));
        }
    }
    if points.is_empty() {
        return Err(LidarError::TooFewPoints {
            what: "DEM ground points".into(),
            got: 0,
            need: 1,
        });
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(LidarError::NonFinite {
            what: "DEM ground points".into(),
            index: i,
        });
    }
    let b = opts
        .bbox
        .unwrap_or_else(|| Bbox::of_points(points, 0.0).expect("non-empty"));
    let c = opts.cell;
    let x0 = (b.min_x / c).floor() * c;
    let y1 = (b.max_y / c).ceil() * c;
    let w = (((b.max_x - x0) / c).floor() as usize + 1).max(1);
    let h = (((y1 - b.min_y) / c).floor() as usize + 1).max(1);
    if w.saturating_mul(h) > opts.max_cells {
        return Err(LidarError::InvalidOption(format!(
            "DEM of {w}×{h} cells exceeds the limit of {} cells; use a larger cell or a smaller extent",
            opts.max_cells
        )));
    }
    let t = GeoTransform::north_up(x0, y1, c);
    let cell_of = |p: &[f64; 3]| -> Option<usize> {
        let col = ((p[0] - x0) / c).floor();
        let row = ((y1 - p[1]) / c).floor();
        (col >= 0.0 && row >= 0.0 && (col as usize) < w && (row as usize) < h)
            .then(|| row as usize * w + col as usize)
    };
    let mut data = vec![f32::NAN; w * h];
    match opts.method {
        DemMethod::Mean => {
            let mut sum = vec![0.0f64; w * h];
            let mut cnt = vec![0u32; w * h];
            for p in points {
                if let Some(i) = cell_of(p) {
                    sum[i] += p[2];
                    cnt[i] += 1;
                }
            }
            for i in 0..w * h {
                if cnt[i] > 0 {
                    data[i] = (sum[i] / cnt[i] as f64) as f32;
                }
            }
        }
        DemMethod::Idw { power } => {
            // Bucket points by cell (counting sort), then weight the 3×3 neighbourhood.
            let mut start = vec![0u32; w * h + 1];
            let cells: Vec<Option<usize>> = points.iter().map(cell_of).collect();
            for i in cells.iter().flatten() {
                start[i + 1] += 1;
            }
            for i in 0..w * h {
                start[i + 1] += start[i];
            }
            let mut fill = start.clone();
            let mut order = vec![0u32; start[w * h] as usize];
            for (k, ci) in cells.iter().enumerate() {
                if let Some(i) = ci {
                    order[fill[*i] as usize] = k as u32;
                    fill[*i] += 1;
                }
            }
            for row in 0..h {
                for col in 0..w {
                    let (cx, cy) = t.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
                    let (mut sw, mut sz, mut exact) = (0.0, 0.0, None);
                    for r in row.saturating_sub(1)..(row + 2).min(h) {
                        for q in col.saturating_sub(1)..(col + 2).min(w) {
                            let i = r * w + q;
                            for &k in &order[start[i] as usize..start[i + 1] as usize] {
                                let p = points[k as usize];
                                let d = ((p[0] - cx).powi(2) + (p[1] - cy).powi(2)).sqrt();
                                if d < 1e-9 {
                                    exact = Some(p[2]);
                                }
                                let wgt = 1.0 / d.max(1e-9).powf(power);
                                sw += wgt;
                                sz += wgt * p[2];
                            }
                        }
                    }
                    if let Some(z) = exact {
                        data[row * w + col] = z as f32;
                    } else if sw > 0.0 {
                        data[row * w + col] = (sz / sw) as f32;
                    }
                }
            }
        }
    }
    fill_holes(&mut data, w, h, opts.max_fill_cells);
    Dem::new(w, h, t, data).map_err(|e| LidarError::data("DEM", e.to_string()))
}

/// Fills NaN cells ring by ring: each pass gives a hole cell bordering valid cells the mean
/// of its valid 8-neighbours (values of the previous pass only, so the result does not
/// depend on scan order).
fn fill_holes(data: &mut [f32], w: usize, h: usize, passes: usize) {
    for _ in 0..passes {
        let prev = data.to_vec();
        let mut changed = false;
        for row in 0..h {
            for col in 0..w {
                if prev[row * w + col].is_finite() {
                    continue;
                }
                let (mut s, mut n) = (0.0f64, 0u32);
                for r in row.saturating_sub(1)..(row + 2).min(h) {
                    for q in col.saturating_sub(1)..(col + 2).min(w) {
                        let v = prev[r * w + q];
                        if v.is_finite() {
                            s += v as f64;
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    data[row * w + col] = (s / n as f64) as f32;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
}
