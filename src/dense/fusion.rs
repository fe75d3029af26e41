//! Fusion of the object points of many stereo pairs into one surface model: per cell of a
//! north-up grid the median height of every point that falls in it, the number of points
//! and their spread (NMAD). Cells without a point stay without data: a hole is never
//! filled from another source.

use super::{invalid, Result};
use crate::geometry::{Dem, GeoTransform};
use rayon::prelude::*;

/// A north-up grid (world coordinates): `width × height` cells of `cell` m from the
/// upper-left corner (`x_min`, `y_max`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DsmGrid {
    pub x_min: f64,
    pub y_max: f64,
    pub cell: f64,
    pub width: usize,
    pub height: usize,
}

impl DsmGrid {
    /// The grid of `cell` m covering `[x_min, y_min, x_max, y_max]`, its corner on a
    /// multiple of the cell (so grids of one cell size line up).
    pub fn covering(area: [f64; 4], cell: f64) -> Result<Self> {
        let [x0, y0, x1, y1] = area;
        if !(cell.is_finite() && cell > 0.0) {
            return Err(invalid("DSM cell", format!("{cell} m is not a cell size")));
        }
        if !(area.iter().all(|v| v.is_finite()) && x1 > x0 && y1 > y0) {
            return Err(invalid("DSM area", format!("{area:?} is not an area")));
        }
        let x_min = (x0 / cell).floor() * cell;
        let y_max = (y1 / cell).ceil() * cell;
        let width = ((x1 - x_min) / cell).ceil() as usize;
        let height = ((y_max - y0) / cell).ceil() as usize;
        // Cell indices are u32 in the fusion; a grid beyond that is a mistake of the cell.
        if width.saturating_mul(height) >= u32::MAX as usize {
            return Err(invalid(
                "DSM grid",
                format!("{width}×{height} cells of {cell} m: more than 2³² cells"),
            ));
        }
        Ok(Self {
            x_min,
            y_max,
            cell,
            width,
            height,
        })
    }

    pub fn transform(&self) -> GeoTransform {
        GeoTransform::north_up(self.x_min, self.y_max, self.cell)
    }

    /// Index of the cell holding world (x, y), if inside.
    #[inline]
    pub fn cell_of(&self, x: f64, y: f64) -> Option<u32> {
        let c = ((x - self.x_min) / self.cell).floor();
        let r = ((self.y_max - y) / self.cell).floor();
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.width && (r as usize) < self.height)
            .then(|| (r as usize * self.width + c as usize) as u32)
    }

    /// A world point as a sample of the grid (its cell's index, its height); `None`
    /// outside the grid or when a coordinate is not finite.
    pub fn sample(&self, x: f64, y: f64, z: f64) -> Option<(u32, f32)> {
        if !z.is_finite() {
            return None;
        }
        self.cell_of(x, y).map(|c| (c, z as f32))
    }

    /// Cells of the grid.
    pub fn cells(&self) -> usize {
        self.width * self.height
    }
}

/// The fused surface: median height, point count and spread (1.4826 × the median
/// absolute deviation, NaN with fewer than two points) per cell; NaN without data.
#[derive(Debug, Clone)]
pub struct FusedSurface {
    pub dsm: Dem,
    pub count: Dem,
    pub spread: Dem,
}

/// Points gathered for fusion (cell index and height: 8 bytes a point).
#[derive(Debug)]
pub struct Fusion {
    grid: DsmGrid,
    samples: Vec<(u32, f32)>,
}

impl Fusion {
    pub fn new(grid: DsmGrid) -> Self {
        Self {
            grid,
            samples: Vec::new(),
        }
    }

    pub fn grid(&self) -> &DsmGrid {
        &self.grid
    }

    /// Number of points gathered.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Adds world points; those outside the grid or not finite are dropped.
    pub fn extend(&mut self, points: impl IntoIterator<Item = [f64; 3]>) {
        let g = self.grid;
        self.samples
            .extend(points.into_iter().filter_map(|[x, y, z]| g.sample(x, y, z)));
    }

    /// Adds samples of the grid ([`DsmGrid::sample`]).
    pub fn push(&mut self, samples: &[(u32, f32)]) {
        self.samples.extend_from_slice(samples);
    }

    /// Cells with at least `min_count` points get the median of their heights.
    pub fn finish(mut self, min_count: usize) -> Result<FusedSurface> {
        let g = self.grid;
        self.samples
            .par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let n = g.width * g.height;
        let mut dsm = vec![f32::NAN; n];
        let mut count = vec![f32::NAN; n];
        let mut spread = vec![f32::NAN; n];
        let mut dev = Vec::new();
        let mut start = 0;
        while start < self.samples.len() {
            let cell = self.samples[start].0;
            let mut end = start + 1;
            while end < self.samples.len() && self.samples[end].0 == cell {
                end += 1;
            }
            let run = &self.samples[start..end];
            start = end;
            if run.len() < min_count.max(1) {
                continue;
            }
            let c = cell as usize;
            let median = median_sorted(run.iter().map(|s| s.1), run.len());
            dsm[c] = median;
            count[c] = run.len() as f32;
            if run.len() >= 2 {
                dev.clear();
                dev.extend(run.iter().map(|s| (s.1 - median).abs()));
                dev.sort_unstable_by(f32::total_cmp);
                spread[c] = 1.4826 * median_sorted(dev.iter().copied(), dev.len());
            }
        }
        let t = g.transform();
        Ok(FusedSurface {
            dsm: Dem::new(g.width, g.height, t, dsm)?,
            count: Dem::new(g.width, g.height, t, count)?,
            spread: Dem::new(g.width, g.height, t, spread)?,
        })
    }
}

/// Median of `n` sorted values (the mean of the middle two of an even count).
fn median_sorted(values: impl Iterator<Item = f32> + Clone, n: usize) -> f32 {
    let mid = n / 2;
    if n % 2 == 1 {
        values.clone().nth(mid).unwrap_or(f32::NAN)
    } else {
        let mut it = values.skip(mid - 1);
        let a = it.next().unwrap_or(f32::NAN);
        let b = it.next().unwrap_or(f32::NAN);
        0.5 * (a + b)
    }
}
