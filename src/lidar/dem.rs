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
    /// Upper-left corner (x_min, y_max) of the grid, e.g. a project lattice's; it must lie
    /// left of and above the extent. Default: the extent's, snapped outward to the cell.
    pub corner: Option<[f64; 2]>,
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
            corner: None,
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
    let g = GridGeometry::new(&b, opts)?;
    let (w, h, t) = (g.w, g.h, g.transform());
    let cell_of = |p: &[f64; 3]| g.cell_of(p);
    let mut data = vec![f32::NAN; w * h];
    match opts.method {
        DemMethod::Mean => {
            let mut acc = MeanGrid::new(g);
            acc.add(points);
            data = acc.means();
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
    g.fill(&mut data, opts.max_fill_cells);
    Dem::new(w, h, t, data).map_err(|e| LidarError::data("DEM", e.to_string()))
}

/// Fills NaN cells ring by ring: each pass gives a hole cell bordering valid cells the mean
/// of its valid 8-neighbours (values of the previous pass only, so the result does not
/// depend on scan order).
fn fill_holes(data: &mut [f32], w: usize, [c0, r0, c1, r1]: [usize; 4], passes: usize) {
    for _ in 0..passes {
        let prev = data.to_vec();
        let mut changed = false;
        for row in r0..r1 {
            for col in c0..c1 {
                if prev[row * w + col].is_finite() {
                    continue;
                }
                let (mut s, mut n) = (0.0f64, 0u32);
                for r in row.saturating_sub(1).max(r0)..(row + 2).min(r1) {
                    for q in col.saturating_sub(1).max(c0)..(col + 2).min(c1) {
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

/// A north-up grid whose top-left corner is the bbox's (min_x, max_y) snapped outward to
/// the cell size.
#[derive(Debug, Clone, Copy)]
pub struct GridGeometry {
    pub x0: f64,
    pub y1: f64,
    pub cell: f64,
    pub w: usize,
    pub h: usize,
    /// Cells (col0, row0, col1, row1; ends exclusive) of the extent's own grid, the one
    /// snapped to the cell: a grid started at a farther corner has the same values there
    /// and none outside (holes are filled within it, never out into the margin).
    pub window: [usize; 4],
}

impl GridGeometry {
    pub fn new(b: &Bbox, opts: &DemOptions) -> Result<Self> {
        let c = opts.cell;
        if !(c.is_finite() && c > 0.0) {
            return Err(LidarError::InvalidOption(format!(
                "DEM cell size {c} must be positive"
            )));
        }
        let (x0, y1) = match opts.corner {
            Some([x0, y1]) if x0.is_finite() && y1.is_finite() => {
                if x0 > b.min_x || y1 < b.max_y {
                    return Err(LidarError::InvalidOption(format!(
                        "grid corner ({x0}, {y1}) is not left of and above the extent \
                         ({}, {})",
                        b.min_x, b.max_y
                    )));
                }
                (x0, y1)
            }
            Some(c) => {
                return Err(LidarError::InvalidOption(format!(
                    "grid corner {c:?} is not finite"
                )))
            }
            None => ((b.min_x / c).floor() * c, (b.max_y / c).ceil() * c),
        };
        let w = (((b.max_x - x0) / c).floor() as usize + 1).max(1);
        let h = (((y1 - b.min_y) / c).floor() as usize + 1).max(1);
        let (sx0, sy1) = ((b.min_x / c).floor() * c, (b.max_y / c).ceil() * c);
        let col0 = (((sx0 - x0) / c).round().max(0.0) as usize).min(w - 1);
        let row0 = (((y1 - sy1) / c).round().max(0.0) as usize).min(h - 1);
        let window = [col0, row0, w, h];
        if w.saturating_mul(h) > opts.max_cells {
            return Err(LidarError::InvalidOption(format!(
                "DEM of {w}×{h} cells exceeds the limit of {} cells; use a larger cell or a smaller extent",
                opts.max_cells
            )));
        }
        Ok(Self {
            x0,
            y1,
            cell: c,
            w,
            h,
            window,
        })
    }

    /// Holes filled up to `passes` cells within [`Self::window`]; nothing outside it.
    fn fill(&self, data: &mut [f32], passes: usize) {
        let [c0, r0, c1, r1] = self.window;
        for (i, v) in data.iter_mut().enumerate() {
            let (col, row) = (i % self.w, i / self.w);
            if !(c0..c1).contains(&col) || !(r0..r1).contains(&row) {
                *v = f32::NAN;
            }
        }
        fill_holes(data, self.w, self.window, passes);
    }

    pub fn transform(&self) -> GeoTransform {
        GeoTransform::north_up(self.x0, self.y1, self.cell)
    }

    #[inline]
    pub fn cell_of(&self, p: &[f64; 3]) -> Option<usize> {
        let col = ((p[0] - self.x0) / self.cell).floor();
        let row = ((self.y1 - p[1]) / self.cell).floor();
        (col >= 0.0 && row >= 0.0 && (col as usize) < self.w && (row as usize) < self.h)
            .then(|| row as usize * self.w + col as usize)
    }
}

/// Per-cell mean heights accumulated batch by batch, so a DEM over many tiles needs memory
/// for the grid only.
pub struct MeanGrid {
    pub geometry: GridGeometry,
    sum: Vec<f64>,
    count: Vec<u32>,
}

impl MeanGrid {
    pub fn new(geometry: GridGeometry) -> Self {
        let n = geometry.w * geometry.h;
        Self {
            geometry,
            sum: vec![0.0; n],
            count: vec![0; n],
        }
    }

    /// Adds points (outside the grid they are ignored).
    pub fn add(&mut self, points: &[[f64; 3]]) {
        for p in points {
            if let Some(i) = self.geometry.cell_of(p) {
                self.sum[i] += p[2];
                self.count[i] += 1;
            }
        }
    }

    fn means(&self) -> Vec<f32> {
        self.sum
            .iter()
            .zip(&self.count)
            .map(|(s, &n)| {
                if n > 0 {
                    (s / n as f64) as f32
                } else {
                    f32::NAN
                }
            })
            .collect()
    }

    /// The DEM, holes filled up to `max_fill_cells`.
    pub fn finish(self, max_fill_cells: usize) -> Result<Dem> {
        let g = self.geometry;
        let mut data = self.means();
        g.fill(&mut data, max_fill_cells);
        Dem::new(g.w, g.h, g.transform(), data).map_err(|e| LidarError::data("DEM", e.to_string()))
    }
}

/// Mean DEM over the tiles of a catalogue that intersect `bbox`, streaming each tile in
/// batches (memory: the grid plus one batch). `classes`: e.g. [2] for ground. Returns the
/// DEM and the number of points gridded.
pub fn grid_dem_tiles(
    catalogue: &super::catalogue::Catalogue,
    bbox: &Bbox,
    classes: Option<&[u8]>,
    opts: &DemOptions,
) -> Result<(Dem, u64)> {
    use super::las::{LasStream, PointBatch};
    let mut acc = MeanGrid::new(GridGeometry::new(bbox, opts)?);
    let mut used = 0u64;
    let mut batch = PointBatch::with_capacity(1 << 18);
    let mut kept = Vec::with_capacity(1 << 18);
    for t in catalogue.tiles_in(bbox) {
        let mut s = LasStream::open(&catalogue.tiles[t].file)?;
        loop {
            if s.read_batch(1 << 18, &mut batch)? == 0 {
                break;
            }
            kept.clear();
            for (p, c) in batch.xyz.iter().zip(&batch.class) {
                if bbox.contains(p[0], p[1]) && classes.is_none_or(|k| k.contains(c)) {
                    kept.push(*p);
                }
            }
            used += kept.len() as u64;
            acc.add(&kept);
        }
    }
    if used == 0 {
        return Err(LidarError::TooFewPoints {
            what: "DEM points in the extent (check the ground class)".into(),
            got: 0,
            need: 1,
        });
    }
    Ok((acc.finish(opts.max_fill_cells)?, used))
}
