//! A tile store over a catalogue: loads only the tiles a query needs and keeps the most
//! recently used ones in memory up to a bound on the number of points.

use super::catalogue::Catalogue;
use super::las::{read_points, PointBatch};
use super::{LidarError, Result};
use crate::cache::Lru;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// An axis-aligned plan rectangle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bbox {
    pub min_x: f64,
    pub min_y: f64,
    pub max_x: f64,
    pub max_y: f64,
}

impl Bbox {
    pub fn new(min_x: f64, min_y: f64, max_x: f64, max_y: f64) -> Self {
        Self {
            min_x,
            min_y,
            max_x,
            max_y,
        }
    }
    /// Bounding box of points, grown by `margin`.
    pub fn of_points(points: &[[f64; 3]], margin: f64) -> Option<Self> {
        let first = points.first()?;
        let mut b = Self::new(first[0], first[1], first[0], first[1]);
        for p in points {
            b.min_x = b.min_x.min(p[0]);
            b.min_y = b.min_y.min(p[1]);
            b.max_x = b.max_x.max(p[0]);
            b.max_y = b.max_y.max(p[1]);
        }
        Some(b.grown(margin))
    }
    pub fn grown(&self, m: f64) -> Self {
        Self::new(
            self.min_x - m,
            self.min_y - m,
            self.max_x + m,
            self.max_y + m,
        )
    }
    pub fn intersects(&self, o: &Bbox) -> bool {
        self.min_x <= o.max_x
            && o.min_x <= self.max_x
            && self.min_y <= o.max_y
            && o.min_y <= self.max_y
    }
    #[inline]
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.min_x && x <= self.max_x && y >= self.min_y && y <= self.max_y
    }
    pub fn as_array(&self) -> [f64; 4] {
        [self.min_x, self.min_y, self.max_x, self.max_y]
    }
}

/// A loaded tile: its points bucketed on a plan grid (about 64 points per cell) so a small
/// query touches only the cells it overlaps. The bucket index costs 4 bytes per point.
pub struct LoadedTile {
    pub points: PointBatch,
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    /// Point indices ordered by cell; cell c holds order[starts[c]..starts[c + 1]].
    order: Vec<u32>,
    starts: Vec<u32>,
}

impl LoadedTile {
    pub fn new(points: PointBatch) -> Self {
        let b = Bbox::of_points(&points.xyz, 0.0).unwrap_or(Bbox::new(0.0, 0.0, 0.0, 0.0));
        let area = ((b.max_x - b.min_x) * (b.max_y - b.min_y)).max(1.0);
        let n = points.len().max(1) as f64;
        let mut cell = (64.0 * area / n).sqrt().max(0.5);
        // Keep the grid to at most ~4 M cells whatever the point layout.
        while ((b.max_x - b.min_x) / cell + 1.0) * ((b.max_y - b.min_y) / cell + 1.0) > 4.0e6 {
            cell *= 2.0;
        }
        let nx = ((b.max_x - b.min_x) / cell) as usize + 1;
        let ny = ((b.max_y - b.min_y) / cell) as usize + 1;
        let cell_of = |p: &[f64; 3]| {
            let cx = (((p[0] - b.min_x) / cell) as usize).min(nx - 1);
            let cy = (((p[1] - b.min_y) / cell) as usize).min(ny - 1);
            cy * nx + cx
        };
        let mut starts = vec![0u32; nx * ny + 1];
        for p in &points.xyz {
            starts[cell_of(p) + 1] += 1;
        }
        for i in 0..nx * ny {
            starts[i + 1] += starts[i];
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; points.len()];
        for (i, p) in points.xyz.iter().enumerate() {
            let c = cell_of(p);
            order[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        Self {
            points,
            x0: b.min_x,
            y0: b.min_y,
            cell,
            nx,
            ny,
            order,
            starts,
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Indices of the points inside `bbox` (cell order, ascending within a cell).
    pub fn indices_in(&self, bbox: &Bbox, mut f: impl FnMut(usize)) {
        let cx0 = ((bbox.min_x - self.x0) / self.cell).floor().max(0.0) as usize;
        let cy0 = ((bbox.min_y - self.y0) / self.cell).floor().max(0.0) as usize;
        let cx1 = ((bbox.max_x - self.x0) / self.cell).floor();
        let cy1 = ((bbox.max_y - self.y0) / self.cell).floor();
        if cx1 < 0.0 || cy1 < 0.0 || cx0 >= self.nx || cy0 >= self.ny {
            return;
        }
        let cx1 = (cx1 as usize).min(self.nx - 1);
        let cy1 = (cy1 as usize).min(self.ny - 1);
        for cy in cy0..=cy1 {
            for cx in cx0..=cx1 {
                let c = cy * self.nx + cx;
                for &i in &self.order[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let p = self.points.xyz[i as usize];
                    if bbox.contains(p[0], p[1]) {
                        f(i as usize);
                    }
                }
            }
        }
    }
}

/// Loads tiles of a catalogue on demand with an LRU bound on the points held.
pub struct TileStore {
    catalogue: Catalogue,
    /// Tiles by index, weighed by their points.
    cache: Lru<usize, LoadedTile>,
}

impl TileStore {
    /// `max_points`: cached points above which least recently used tiles are dropped
    /// (a tile in use by the current query is kept even when it alone exceeds the bound).
    pub fn new(catalogue: Catalogue, max_points: u64) -> Self {
        Self {
            catalogue,
            cache: Lru::new(max_points),
        }
    }

    pub fn catalogue(&self) -> &Catalogue {
        &self.catalogue
    }

    /// Points currently held in the cache.
    pub fn cached_points(&self) -> u64 {
        self.cache.held()
    }

    /// How many tile reads the store has done.
    pub fn loads(&self) -> usize {
        self.cache.loads()
    }

    /// A tile's points, from the cache or read from its file.
    pub fn tile(&mut self, index: usize) -> Result<Arc<LoadedTile>> {
        if index >= self.catalogue.tiles.len() {
            return Err(LidarError::InvalidOption(format!(
                "tile index {index} out of range"
            )));
        }
        let entry = &self.catalogue.tiles[index];
        self.cache.get_or_load(&index, || {
            let pts = read_points(&entry.file, None, None)?;
            if pts.len() as u64 != entry.point_count {
                return Err(LidarError::CountMismatch {
                    path: entry.file.clone(),
                    declared: entry.point_count,
                    found: pts.len() as u64,
                });
            }
            let n = pts.len() as u64;
            Ok((LoadedTile::new(pts), n))
        })
    }

    /// The points inside `bbox`, optionally of the listed classes, from every tile that
    /// intersects it (tiles are taken through the LRU cache).
    pub fn query(&mut self, bbox: &Bbox, classes: Option<&[u8]>) -> Result<PointBatch> {
        let mut out = PointBatch::default();
        for t in self.catalogue.tiles_in(bbox) {
            let tile = self.tile(t)?;
            let pts = &tile.points;
            let mut idx = Vec::new();
            tile.indices_in(bbox, |i| {
                if classes.is_none_or(|c| c.contains(&pts.class[i])) {
                    idx.push(i);
                }
            });
            // File order, whatever the bucket layout.
            idx.sort_unstable();
            for i in idx {
                out.push(pts.xyz[i], pts.class[i], pts.source[i], pts.gps_time[i]);
            }
        }
        Ok(out)
    }
}
