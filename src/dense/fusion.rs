//! Fusion of the object points of many stereo pairs into one surface model: per cell of a
//! north-up grid the median height of every point that falls in it, the number of points
//! and their spread (NMAD). Cells without a point stay without data: a hole is never
//! filled from another source.

use super::Result;
use crate::geometry::Dem;
use rayon::prelude::*;

/// The DSM's grid: a north-up grid on a raster lattice (world coordinates).
pub use crate::geometry::LatticeGrid as DsmGrid;

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
