//! A tile store over a catalogue: loads only the tiles a query needs and keeps the most
//! recently used ones in memory up to a bound on the number of points.

use super::catalogue::Catalogue;
use super::las::{read_points, PointBatch};
use super::{LidarError, Result};
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

/// Loads tiles of a catalogue on demand with an LRU bound on the points held.
pub struct TileStore {
    catalogue: Catalogue,
    max_points: u64,
    /// (tile index, points), most recently used last.
    cache: Vec<(usize, Arc<PointBatch>)>,
    loads: usize,
}

impl TileStore {
    /// `max_points`: cached points above which least recently used tiles are dropped
    /// (a tile in use by the current query is kept even when it alone exceeds the bound).
    pub fn new(catalogue: Catalogue, max_points: u64) -> Self {
        Self {
            catalogue,
            max_points,
            cache: Vec::new(),
            loads: 0,
        }
    }

    pub fn catalogue(&self) -> &Catalogue {
        &self.catalogue
    }

    /// Points currently held in the cache.
    pub fn cached_points(&self) -> u64 {
        self.cache.iter().map(|(_, b)| b.len() as u64).sum()
    }

    /// How many tile reads the store has done.
    pub fn loads(&self) -> usize {
        self.loads
    }

    /// A tile's points, from the cache or read from its file.
    pub fn tile(&mut self, index: usize) -> Result<Arc<PointBatch>> {
        if index >= self.catalogue.tiles.len() {
            return Err(LidarError::InvalidOption(format!(
                "tile index {index} out of range"
            )));
        }
        if let Some(pos) = self.cache.iter().position(|(i, _)| *i == index) {
            let e = self.cache.remove(pos);
            let b = e.1.clone();
            self.cache.push(e);
            return Ok(b);
        }
        let entry = &self.catalogue.tiles[index];
        let pts = Arc::new(read_points(&entry.file, None, None)?);
        if pts.len() as u64 != entry.point_count {
            return Err(LidarError::CountMismatch {
                path: entry.file.clone(),
                declared: entry.point_count,
                found: pts.len() as u64,
            });
        }
        self.loads += 1;
        let n = pts.len() as u64;
        let mut held = self.cached_points();
        while held + n > self.max_points && !self.cache.is_empty() {
            let (_, old) = self.cache.remove(0);
            held -= old.len() as u64;
        }
        self.cache.push((index, pts.clone()));
        Ok(pts)
    }

    /// The points inside `bbox`, optionally of the listed classes, from every tile that
    /// intersects it (tiles are taken through the LRU cache).
    pub fn query(&mut self, bbox: &Bbox, classes: Option<&[u8]>) -> Result<PointBatch> {
        let mut out = PointBatch::default();
        for t in self.catalogue.tiles_in(bbox) {
            let pts = self.tile(t)?;
            for i in 0..pts.len() {
                let p = pts.xyz[i];
                if bbox.contains(p[0], p[1]) && classes.is_none_or(|c| c.contains(&pts.class[i])) {
                    out.push(p, pts.class[i], pts.source[i], pts.gps_time[i]);
                }
            }
        }
        Ok(out)
    }
}
