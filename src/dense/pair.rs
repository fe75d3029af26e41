//! A whole rectified pair matched tile by tile: each tile is a band of rectified rows,
//! rendered from the two photos with a margin of rows above and below, matched, and
//! handed to the caller without its margins. Only one tile's rectified rows and cost
//! volumes are held at a time.

use super::rectify::{RectifiedPair, Side};
use super::sgm::{match_images, DisparityMap, DisparityPrior, SgmOptions};
use super::{invalid, Result};
use crate::matching::GreyImage;
use std::ops::Range;

/// The disparities of one tile's rows of the left rectified image.
#[derive(Debug, Clone)]
pub struct PairTile {
    /// Rectified rows the tile's map covers.
    pub rows: Range<usize>,
    /// Disparities of those rows (the map's row 0 is rectified row `rows.start`).
    pub map: DisparityMap,
}

/// How a pair is cut into tiles of rectified rows.
#[derive(Debug, Clone)]
pub struct Tiling {
    /// Rectified rows a tile hands over.
    pub rows: usize,
    /// Rows matched on both sides of a tile beyond the ones it hands over, so that its
    /// aggregation paths start outside it.
    pub overlap: usize,
    /// Rectified rows matched (clipped to the pair's); the rest are not.
    pub within: Range<usize>,
}

/// Matches `pair` from its two photos (whole, as `left` and `right`) tile by tile;
/// calls `sink` with each tile in order of rows. The prior's `first_row` is ignored (each
/// tile sets its own).
pub fn match_pair(
    pair: &RectifiedPair,
    left: &GreyImage,
    right: &GreyImage,
    prior: &DisparityPrior<'_>,
    options: &SgmOptions,
    tiling: Tiling,
    mut sink: impl FnMut(PairTile) -> Result<()>,
) -> Result<()> {
    for (img, side, name) in [(left, Side::Left, "left"), (right, Side::Right, "right")] {
        let (w, h) = pair.view(side).source.image_size();
        if (img.width, img.height) != (w as usize, h as usize) {
            return Err(invalid(
                name,
                format!(
                    "photo of {}×{} px for a camera of {w}×{h} px",
                    img.width, img.height
                ),
            ));
        }
    }
    let Tiling {
        rows: tile_rows,
        overlap,
        within,
    } = tiling;
    if tile_rows == 0 {
        return Err(invalid("tile rows", "must be at least 1"));
    }
    let h = within.end.min(pair.height);
    let mut r0 = within.start;
    while r0 < h {
        let r1 = (r0 + tile_rows).min(h);
        let (w0, w1) = (r0.saturating_sub(overlap), (r1 + overlap).min(pair.height));
        let (l, r) = rayon::join(
            || pair.render_rows(Side::Left, left, [0, 0], w0..w1),
            || pair.render_rows(Side::Right, right, [0, 0], w0..w1),
        );
        let (l, r) = (l?, r?);
        let tile_prior = DisparityPrior {
            first_row: w0,
            ..*prior
        };
        let map = match_images(
            &l.image,
            Some(&l.valid),
            &r.image,
            Some(&r.valid),
            &tile_prior,
            options,
        )?;
        drop((l, r));
        let w = map.width;
        let (a, b) = ((r0 - w0) * w, (r1 - w0) * w);
        sink(PairTile {
            rows: r0..r1,
            map: DisparityMap {
                width: w,
                height: r1 - r0,
                disparity: map.disparity[a..b].to_vec(),
                status: map.status[a..b].to_vec(),
                stats: map.stats,
            },
        })?;
        r0 = r1;
    }
    Ok(())
}
