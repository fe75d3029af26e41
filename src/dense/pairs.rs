//! Stereo pairs of an oriented block for dense matching: photos whose footprints on the
//! terrain overlap enough, with a base-to-height ratio that gives a useful intersection
//! angle, in strip and across strips; each photo keeps its best partners so that every
//! surface point is matched by two or more pairs where the block's overlap allows.

use crate::block::{Block, PhotoId};
use crate::matching::oriented::{grid_transfer, Surface};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How pairs are chosen.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct PairOptions {
    /// Least overlap of the two footprints, as a share of each photo (the smaller of the
    /// two directions): 60 % forward and 30 % side overlap both qualify.
    pub min_overlap: f64,
    /// Base-to-height ratios accepted: below the low end the intersection is too flat
    /// for useful heights, above the high end the views differ too much to match.
    pub base_to_height: [f64; 2],
    /// Partners each photo keeps at most (the best by overlap); a pair is kept when either
    /// of its photos keeps it.
    pub max_partners: usize,
}

impl Default for PairOptions {
    fn default() -> Self {
        Self {
            min_overlap: 0.25,
            base_to_height: [0.05, 1.0],
            max_partners: 3,
        }
    }
}

/// A pair to match: `left` and `right` photos of the block, with the overlap and
/// base-to-height ratio it was chosen by.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StereoPair {
    pub left: PhotoId,
    pub right: PhotoId,
    pub overlap: f64,
    pub base_to_height: f64,
}

/// The stereo pairs of the block's oriented photos over `surface` (block-local), in
/// photo order, each pair once (left < right).
pub fn select_pairs(block: &Block, surface: &Surface, options: &PairOptions) -> Vec<StereoPair> {
    let photos: Vec<_> = block
        .photos
        .values()
        .filter(|p| p.is_oriented())
        .filter_map(|p| block.camera_of(p).map(|c| (p.id, &c.model, &p.pose)))
        .collect();
    // Candidates: both directions' overlap and the base against the height above ground
    // of the pair's mean centre.
    let candidates: Vec<StereoPair> = (0..photos.len())
        .into_par_iter()
        .flat_map_iter(|i| {
            let photos = &photos;
            (i + 1..photos.len()).filter_map(move |j| {
                let (a, b) = (photos[i], photos[j]);
                // Over the part of each photo that sees the surface: a DEM prior may
                // cover less than a film photo.
                let ab = grid_transfer((a.1, a.2), (b.1, b.2), surface, 9).overlap_on_surface;
                if ab < options.min_overlap {
                    return None;
                }
                let ba = grid_transfer((b.1, b.2), (a.1, a.2), surface, 9).overlap_on_surface;
                let overlap = ab.min(ba);
                if overlap < options.min_overlap {
                    return None;
                }
                let base = (a.2.center - b.2.center).norm();
                let mid = 0.5 * (a.2.center + b.2.center);
                let below = crate::geometry::Ray {
                    origin: mid,
                    direction: nalgebra::Vector3::new(0.0, 0.0, -1.0),
                };
                let height = (mid - surface.intersect(&below)?).norm();
                let bh = base / height.max(f64::EPSILON);
                let [lo, hi] = options.base_to_height;
                (bh >= lo && bh <= hi).then_some(StereoPair {
                    left: a.0,
                    right: b.0,
                    overlap,
                    base_to_height: bh,
                })
            })
        })
        .collect();
    // Each photo's best partners by overlap.
    let mut keep = vec![false; candidates.len()];
    for (id, ..) in &photos {
        let mut mine: Vec<usize> = (0..candidates.len())
            .filter(|&k| candidates[k].left == *id || candidates[k].right == *id)
            .collect();
        mine.sort_by(|&x, &y| candidates[y].overlap.total_cmp(&candidates[x].overlap));
        for &k in mine.iter().take(options.max_partners) {
            keep[k] = true;
        }
    }
    candidates
        .into_iter()
        .zip(keep)
        .filter_map(|(c, k)| k.then_some(c))
        .collect()
}
