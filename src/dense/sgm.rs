//! Hierarchical semi-global matching of a rectified pair (tSGM / SURE-like).
//!
//! The pair is matched coarse to fine on factor-2 pyramids. The coarsest level searches
//! the prior's band (a global range, or a per-pixel band from a prior surface); every
//! finer level searches, per pixel, the hull of the coarser level's valid disparities
//! around it, doubled and widened by a margin, and never beyond the prior's band. Where
//! the coarser level found nothing nearby, a wider neighbourhood and at last the prior
//! band are searched. Where the prior is a surface model, its own disparities around the
//! pixel are searched at every finer level too: a roof narrower than the coarser level's
//! census window is matched there at the ground's disparity. The prior narrows the search;
//! the matching decides.
//!
//! Per level: census cost over the bands within each pixel's adaptive support
//! ([`super::census`], [`super::volume`]), eight aggregation paths
//! ([`super::aggregate`]), winner-take-all with a uniqueness ratio, a left–right check
//! against the right image's winners of the same sums, a texture mask; at full
//! resolution sub-pixel refinement, the ordering check and the trimming of depth edges
//! back to the image's edges ([`super::filter`]); the 3 × 3 median and the speckle filter.

use super::aggregate::{aggregate, Penalties, SweepInput};
use super::census::{census_transform, grey_range, support_masks};
use super::filter::{median3, remove_occluded, remove_speckles, texture_mask, trim_depth_edges};
use super::rectify::BandGrid;
use super::refine::refine_disparities;
use super::volume::{census_costs, Bands};
use super::{invalid, DenseError, Result};
use crate::matching::pyramid::downsample;
use crate::matching::smooth::gaussian_blur;
use crate::matching::GreyImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Why a pixel has no disparity (or that it has one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum PixelStatus {
    Valid = 0,
    /// Outside the left photo, or no disparity of its band lands in the right photo.
    NoData = 1,
    /// Too little texture around the pixel ([`SgmOptions::min_texture`]).
    LowTexture = 2,
    /// The best disparity lies on the edge of the searched band.
    BandEdge = 3,
    /// A disparity away from the best costs almost as little ([`SgmOptions::uniqueness`]).
    NotUnique = 4,
    /// The right image's best match points elsewhere (occlusion or mismatch).
    LeftRight = 5,
    /// Part of a small isolated region ([`SgmOptions::speckle_size`]).
    Speckle = 6,
    /// The census costs of the matches around the pixel are those of unrelated pixels
    /// ([`SgmOptions::max_cost`]): the band holds no match (e.g. a prior that missed).
    HighCost = 7,
    /// Hidden in the right image by a nearer surface at its disparity
    /// ([`SgmOptions::occlusion_tolerance`]).
    Occluded = 8,
    /// Between a depth edge and the image edge it belongs on ([`SgmOptions::edge_jump`]).
    DepthEdge = 9,
}

/// Sub-pixel refinement of the winning disparity from its two neighbours' sums.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Subpixel {
    /// Parabola through the three sums.
    Parabola,
    /// Symmetric V (equal slopes) through the three sums.
    Equiangular,
}

/// Options of semi-global matching.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct SgmOptions {
    /// Census window (columns, rows): odd sides, at most 65 samples.
    pub census: [usize; 2],
    /// Pixels between the census window's samples.
    pub census_stride: usize,
    /// Standard deviation (px) of a Gaussian blur of the images before the census (0:
    /// none).
    pub smooth: f32,

    /// Adaptive support: a census sample counts in the cost only where its grey value is
    /// within this share of the left image's grey-value range (2nd to 98th percentile) of
    /// the window's centre (0: every sample counts). Against edge fattening: a window
    /// across a roof's eave otherwise carries the roof's disparity onto the ground beside
    /// it, by up to half its width (about 5 m on a 0.6 m film).
    pub support: f32,

    /// Penalty of a disparity step of one pixel between neighbours.
    pub p1: u16,
    /// Penalty of a larger step where the grey value does not change.
    pub p2: u16,
    /// Grey-value step between neighbours at which P2 halves (0: P2 constant).
    pub p2_gradient: f32,
    /// The best sum must be at most (1 − uniqueness) times any sum two or more disparities
    /// away from it.
    pub uniqueness: f32,
    /// Largest difference of the left and right winners (px).
    pub lr_max_diff: f32,
    /// Ordering check: how far (px) a pixel's right position may lie beyond that of a
    /// pixel to its right before it counts as occluded (negative: no check).
    pub occlusion_tolerance: f32,
    /// Disparity step (px) between neighbours that makes a depth edge, whose pixels up to
    /// the nearest strong grey-value step are removed (0: none).
    pub edge_jump: f32,
    pub subpixel: Subpixel,
    /// 3 × 3 median of the disparities.
    pub median: bool,
    /// Regions of at most this many pixels (at full resolution) are removed.
    pub speckle_size: usize,
    /// Neighbours differing by more than this (px) separate regions.
    pub speckle_diff: f32,
    /// Least standard deviation of the grey values in a 5 × 5 window (the images' units).
    pub min_texture: f32,
    /// Largest mean census cost of the winners in the 5 × 5 window around a pixel, as a
    /// share of the census bits (unrelated pixels cost about half of them).
    pub max_cost: f32,
    /// Pyramid levels below full resolution; `None` chooses from the prior's band.
    pub levels: Option<usize>,
    /// Margin (px) added on each side of the band found at the coarser level.
    pub band_margin: i32,
    /// Radius (coarser-level pixels) of the neighbourhood whose disparities make the band.
    pub band_radius: usize,
}

impl Default for SgmOptions {
    fn default() -> Self {
        Self {
            census: [9, 7],
            census_stride: 2,
            smooth: 1.2,
            support: 0.08,
            p1: 16,
            p2: 200,
            p2_gradient: 12.0,
            uniqueness: 0.05,
            lr_max_diff: 1.0,
            occlusion_tolerance: 1.0,
            edge_jump: 2.0,
            subpixel: Subpixel::Equiangular,
            median: true,
            speckle_size: 100,
            speckle_diff: 1.0,
            min_texture: 0.0,
            max_cost: 0.3,
            levels: None,
            band_margin: 3,
            band_radius: 4,
        }
    }
}

impl SgmOptions {
    fn validate(&self) -> Result<()> {
        let [cw, ch] = self.census;
        if cw % 2 == 0 || ch % 2 == 0 || cw * ch > 65 || cw * ch < 9 {
            return Err(invalid(
                "census window",
                format!("{cw}×{ch} needs odd sides and 9 to 65 pixels"),
            ));
        }
        if self.p1 == 0 || self.p2 < self.p1 || self.p2 > 2000 {
            return Err(invalid(
                "penalties",
                format!(
                    "need 0 < P1 ≤ P2 ≤ 2000, got P1 = {}, P2 = {}",
                    self.p1, self.p2
                ),
            ));
        }
        for (v, what) in [
            (self.p2_gradient, "p2_gradient"),
            (self.uniqueness, "uniqueness"),
            (self.lr_max_diff, "lr_max_diff"),
            (self.speckle_diff, "speckle_diff"),
            (self.min_texture, "min_texture"),
            (self.max_cost, "max_cost"),
            (self.smooth, "smooth"),
            (self.edge_jump, "edge_jump"),
            (self.support, "support"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(invalid(what, format!("must be finite and ≥ 0, got {v}")));
            }
        }
        if self.occlusion_tolerance.is_nan() {
            return Err(invalid("occlusion_tolerance", "must be a number"));
        }
        if self.census_stride == 0 || self.census_stride > 8 {
            return Err(invalid("census_stride", "must be 1 to 8"));
        }
        if self.uniqueness >= 1.0 {
            return Err(invalid("uniqueness", "must be below 1"));
        }
        if self.band_margin < 0 {
            return Err(invalid("band_margin", "must be ≥ 0"));
        }
        Ok(())
    }
}

/// The prior that bounds the search: a range of disparities every pixel may take, and
/// optionally a per-pixel band from a prior surface (intersected with the range; pixels
/// without a prior in the grid search the range).
#[derive(Debug, Clone, Copy)]
pub struct DisparityPrior<'a> {
    /// Inclusive [min, max] (px).
    pub range: [f32; 2],
    /// Band over the left rectified image of the whole pair.
    pub grid: Option<&'a BandGrid>,
    /// Rectified row of the matched window's first row (to look up the grid).
    pub first_row: usize,
    /// Pixels without a band in the grid are not searched (`NoData`) instead of searching
    /// the range: a prior surface (a DEM) that ends within the photos bounds where
    /// matching is wanted.
    pub grid_only: bool,
}

impl DisparityPrior<'_> {
    /// Every pixel searches `min..=max`.
    pub fn range(min: f32, max: f32) -> Self {
        Self {
            range: [min, max],
            grid: None,
            first_row: 0,
            grid_only: false,
        }
    }

    /// Band (px at full resolution) of window pixel (col, row); `None`: not searched.
    fn band(&self, col: usize, row: usize) -> Option<(f32, f32)> {
        let [lo, hi] = self.range;
        match self.grid.and_then(|g| g.band_at(col, row + self.first_row)) {
            Some((a, b)) if a.max(lo) <= b.min(hi) => Some((a.max(lo), b.min(hi))),
            Some(_) => Some((lo, hi)),
            None if self.grid_only && self.grid.is_some() => None,
            None => Some((lo, hi)),
        }
    }

    /// Hull of the prior surface's own disparities (px at full resolution) around window
    /// pixel (col, row) ([`BandGrid::surface_at`]); `None` where the grid knows none.
    fn surface(&self, col: usize, row: usize) -> Option<(f32, f32)> {
        self.grid
            .and_then(|g| g.surface_at(col, row + self.first_row))
    }
}

/// Work of one pyramid level.
#[derive(Debug, Clone, Serialize)]
pub struct LevelStats {
    pub level: usize,
    pub width: usize,
    pub height: usize,
    /// Mean number of disparities searched per pixel.
    pub mean_band: f64,
    /// Share of pixels with a disparity.
    pub valid: f64,
    pub seconds: f64,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct MatchStats {
    /// Coarsest level first.
    pub levels: Vec<LevelStats>,
}

/// Disparities of the left rectified image: `disparity` (px, NaN without one) and why.
#[derive(Debug, Clone)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub disparity: Vec<f32>,
    pub status: Vec<PixelStatus>,
    pub stats: MatchStats,
}

impl DisparityMap {
    pub fn at(&self, col: usize, row: usize) -> Option<f32> {
        let d = self.disparity[row * self.width + col];
        d.is_finite().then_some(d)
    }

    /// Share of pixels with a disparity.
    pub fn valid_fraction(&self) -> f64 {
        let n = self.disparity.iter().filter(|d| d.is_finite()).count();
        n as f64 / self.disparity.len().max(1) as f64
    }
}

/// Pyramid levels below full resolution for a band of `width` disparities: the coarsest
/// searches at most about 24 disparities, and keeps at least 32 × 32 pixels.
fn auto_levels(band_width: f32, w: usize, h: usize) -> usize {
    let mut l = 0usize;
    while l < 6 && band_width / (1u32 << l) as f32 > 24.0 && (w.min(h) >> (l + 1)) >= 32 {
        l += 1;
    }
    l
}

/// A level's validity: a coarse pixel has data where all four of its pixels do.
fn mask_down(mask: &[bool], w: usize, h: usize) -> Vec<bool> {
    let (nw, nh) = (w / 2, h / 2);
    let mut out = vec![false; nw * nh];
    for y in 0..nh {
        for x in 0..nw {
            let p = 2 * y * w + 2 * x;
            out[y * nw + x] = mask[p] && mask[p + 1] && mask[p + w] && mask[p + w + 1];
        }
    }
    out
}

/// Matches the left rectified image against the right one (same rows; the right may be
/// of another width) within the prior's band. `left_valid` / `right_valid` mark pixels
/// the photos cover (`None`: all).
pub fn match_images(
    left: &GreyImage,
    left_valid: Option<&[bool]>,
    right: &GreyImage,
    right_valid: Option<&[bool]>,
    prior: &DisparityPrior<'_>,
    options: &SgmOptions,
) -> Result<DisparityMap> {
    options.validate()?;
    if left.height != right.height {
        return Err(invalid(
            "rectified pair",
            format!(
                "the left image has {} rows, the right {}",
                left.height, right.height
            ),
        ));
    }
    for (mask, img, side) in [(left_valid, left, "left"), (right_valid, right, "right")] {
        if let Some(m) = mask {
            if m.len() != img.width * img.height {
                return Err(invalid(
                    side,
                    format!(
                        "validity mask of {} values for {}×{} pixels",
                        m.len(),
                        img.width,
                        img.height
                    ),
                ));
            }
        }
    }
    let [lo, hi] = prior.range;
    if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
        return Err(invalid(
            "disparity prior",
            format!("range [{lo}, {hi}] is not a finite interval"),
        ));
    }
    let levels = options
        .levels
        .unwrap_or_else(|| auto_levels(hi - lo, left.width.min(right.width), left.height));
    // Pyramids of both images and their masks.
    let mut pyr: Vec<[(GreyImage, Vec<bool>); 2]> = Vec::with_capacity(levels + 1);
    pyr.push([
        (
            left.clone(),
            left_valid.map_or_else(|| vec![true; left.data.len()], <[bool]>::to_vec),
        ),
        (
            right.clone(),
            right_valid.map_or_else(|| vec![true; right.data.len()], <[bool]>::to_vec),
        ),
    ]);
    for l in 1..=levels {
        let prev = &pyr[l - 1];
        if prev[0].0.width < 4 || prev[1].0.width < 4 || prev[0].0.height < 4 {
            break;
        }
        let next = [0, 1].map(|s| {
            let (img, mask) = &prev[s];
            (downsample(img), mask_down(mask, img.width, img.height))
        });
        pyr.push(next);
    }
    let levels = pyr.len() - 1;
    let mut stats = MatchStats::default();
    let mut coarse: Option<(Vec<f32>, usize, usize)> = None;
    let mut result = None;
    for l in (0..=levels).rev() {
        let t0 = Instant::now();
        let [(li, lm), (ri, rm)] = &pyr[l];
        let scale = (1u32 << l) as f32;
        let half = 1usize << l >> 1;
        let prior_band = |x: usize, y: usize| -> Option<(i32, i32)> {
            let (a, b) = prior.band((x << l) + half, ((y << l) + half).min(left.height - 1))?;
            Some((
                (a / scale).floor() as i32 - 1,
                (b / scale).ceil() as i32 + 1,
            ))
        };
        let c0 = cpu_seconds();
        let hood = coarse.as_ref().map(|(d, cw, ch)| {
            Neighbourhood::new(d, *cw, *ch, options.band_radius, options.band_margin)
        });
        let bands = Bands::new(li.width, li.height, ri.width, |x, y| {
            if !lm[y * li.width + x] {
                return None;
            }
            let (plo, phi) = prior_band(x, y)?;
            // The coarser level cannot resolve what is narrower than its census window (a
            // roof at the film's ground pixel): it matches it at the ground's disparity, and
            // a band around that alone never reaches the roof. The prior surface's own
            // disparities around the pixel stay searched; the matching decides between them.
            let surface = || {
                let (a, b) =
                    prior.surface((x << l) + half, ((y << l) + half).min(left.height - 1))?;
                Some((
                    (a / scale).floor() as i32 - options.band_margin,
                    (b / scale).ceil() as i32 + options.band_margin,
                ))
            };
            let hull = match (hood.as_ref().and_then(|h| h.band(x, y)), surface()) {
                (Some((a, b)), Some((c, d))) => Some((a.min(c), b.max(d))),
                (band, _) => band,
            };
            match hull {
                Some((a, b)) if a.max(plo) <= b.min(phi) => Some((a.max(plo), b.min(phi))),
                _ => Some((plo, phi)),
            }
        })
        .ok_or_else(|| {
            invalid(
                "rectified window",
                format!(
                    "{}×{} px with its bands needs more than 2³² cost entries; match it in \
                     smaller tiles",
                    li.width, li.height
                ),
            )
        })?;
        if std::env::var_os("DENSE_DEBUG").is_some() {
            eprintln!(
                "level {l} bands: {:.1} ms CPU, mean {:.1}",
                1e3 * (cpu_seconds() - c0),
                bands.total() as f64 / bands.len.len().max(1) as f64
            );
        }
        let map = match_level(li, lm, ri, rm, &bands, options, l)?;
        stats.levels.push(LevelStats {
            level: l,
            width: li.width,
            height: li.height,
            mean_band: bands.total() as f64 / bands.len.len().max(1) as f64,
            valid: map.0.iter().filter(|d| d.is_finite()).count() as f64
                / map.0.len().max(1) as f64,
            seconds: t0.elapsed().as_secs_f64(),
        });
        if let Some(dir) = std::env::var_os("DENSE_DEBUG_DIR") {
            let [lo, hi] = prior.range;
            let img = GreyImage {
                width: li.width,
                height: li.height,
                data: map
                    .0
                    .iter()
                    .map(|&d| {
                        if d.is_finite() {
                            (d * scale - lo) / (hi - lo) * 254.0 + 1.0
                        } else {
                            0.0
                        }
                    })
                    .collect(),
            };
            let _ = img.save(
                &std::path::Path::new(&dir).join(format!("level{l}.png")),
                false,
            );
            let st = GreyImage {
                width: li.width,
                height: li.height,
                data: map.1.iter().map(|&s| s as u8 as f32 * 36.0).collect(),
            };
            let _ = st.save(
                &std::path::Path::new(&dir).join(format!("status{l}.png")),
                false,
            );
        }
        if l == 0 {
            result = Some(map);
        } else {
            coarse = Some((map.0, li.width, li.height));
        }
    }
    let (disparity, status) = result.ok_or_else(|| DenseError::InvalidInput {
        what: "pyramid".into(),
        message: "no level matched".into(),
    })?;
    Ok(DisparityMap {
        width: left.width,
        height: left.height,
        disparity,
        status,
        stats,
    })
}

/// The coarser level's disparities around each finer pixel: min and max over a
/// neighbourhood, and over a four times wider one where the first holds none.
struct Neighbourhood {
    w: usize,
    h: usize,
    near: (Vec<f32>, Vec<f32>),
    wide: (Vec<f32>, Vec<f32>),
    own: Vec<f32>,
    margin: i32,
}

impl Neighbourhood {
    fn new(d: &[f32], w: usize, h: usize, radius: usize, margin: i32) -> Self {
        Self {
            w,
            h,
            near: min_max_filter(d, w, h, radius),
            wide: min_max_filter(d, w, h, 4 * radius.max(1)),
            own: d.to_vec(),
            margin,
        }
    }

    /// Band of finer pixel (x, y); `None` (search the prior's band) where the coarser
    /// level has no disparity at the pixel itself: a small raised object (a tree, a narrow
    /// building) the coarser level failed on would otherwise be searched for only within
    /// the ground's band around it, and never found.
    fn band(&self, x: usize, y: usize) -> Option<(i32, i32)> {
        let c = (y / 2).min(self.h - 1) * self.w + (x / 2).min(self.w - 1);
        if !self.own[c].is_finite() {
            return None;
        }
        for (lo, hi) in [&self.near, &self.wide] {
            if lo[c].is_finite() {
                return Some((
                    (2.0 * lo[c]).floor() as i32 - self.margin,
                    (2.0 * hi[c]).ceil() as i32 + self.margin,
                ));
            }
        }
        None
    }
}

/// Min and max of the finite values in the (2r + 1)² window around each pixel (∞ / −∞
/// where there are none), separably.
fn min_max_filter(d: &[f32], w: usize, h: usize, r: usize) -> (Vec<f32>, Vec<f32>) {
    let mut tmin = vec![f32::INFINITY; w * h];
    let mut tmax = vec![f32::NEG_INFINITY; w * h];
    tmin.par_chunks_mut(w)
        .zip(tmax.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (mn, mx))| {
            let row = &d[y * w..(y + 1) * w];
            for x in 0..w {
                let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
                for &v in &row[x.saturating_sub(r)..(x + r + 1).min(w)] {
                    if v.is_finite() {
                        a = a.min(v);
                        b = b.max(v);
                    }
                }
                mn[x] = a;
                mx[x] = b;
            }
        });
    let mut omin = vec![f32::INFINITY; w * h];
    let mut omax = vec![f32::NEG_INFINITY; w * h];
    omin.par_chunks_mut(w)
        .zip(omax.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (mn, mx))| {
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                let (a, b) = (&tmin[yy * w..(yy + 1) * w], &tmax[yy * w..(yy + 1) * w]);
                for x in 0..w {
                    mn[x] = mn[x].min(a[x]);
                    mx[x] = mx[x].max(b[x]);
                }
            }
        });
    (omin, omax)
}

/// Matches one level within `bands`: disparities (NaN invalid) and statuses.
fn match_level(
    left: &GreyImage,
    left_valid: &[bool],
    right: &GreyImage,
    right_valid: &[bool],
    bands: &Bands,
    options: &SgmOptions,
    level: usize,
) -> Result<(Vec<f32>, Vec<PixelStatus>)> {
    let debug = std::env::var_os("DENSE_DEBUG").is_some();
    let mut lap = cpu_seconds();
    let mut stage = |name: &str| {
        if debug {
            let now = cpu_seconds();
            eprintln!("level {level} {name}: {:.1} ms CPU", 1e3 * (now - lap));
            lap = now;
        }
    };
    let [cw, ch] = options.census;
    let stride = options.census_stride;
    fn blurred(img: &GreyImage, sigma: f32) -> std::borrow::Cow<'_, GreyImage> {
        if sigma > 0.0 {
            std::borrow::Cow::Owned(gaussian_blur(img, sigma))
        } else {
            std::borrow::Cow::Borrowed(img)
        }
    }
    let ((cl, support), cr) = rayon::join(
        || {
            let img = blurred(left, options.smooth);
            let support = (options.support > 0.0).then(|| {
                let tau = options.support * grey_range(&img, left_valid);
                support_masks(&img, cw, ch, stride, tau)
            });
            (census_transform(&img, cw, ch, stride), support)
        },
        || census_transform(&blurred(right, options.smooth), cw, ch, stride),
    );
    stage("census");
    let bits = (cw * ch - 1) as u8;
    let costs = census_costs(
        bands,
        &cl,
        support.as_deref(),
        &cr,
        right.width,
        right_valid,
        bits,
    );
    drop(support);
    drop((cl, cr));
    stage("costs");
    let sum = aggregate(&SweepInput {
        bands,
        costs: &costs,
        image: &left.data,
        penalties: Penalties::new(options.p1 as i16, options.p2 as i16, options.p2_gradient),
    });
    stage("aggregation");
    let (mut disparity, mut status, winner_cost) =
        winner_take_all(bands, &sum, &costs, right.width, options);
    drop((sum, costs));
    stage("winners");
    let (w, h) = (left.width, left.height);
    let mean_cost = box_mean_u8(&winner_cost, w, h, 2);
    if std::env::var_os("DENSE_DEBUG").is_some() {
        let mut hist = [0usize; 16];
        for (m, s) in mean_cost.iter().zip(&status) {
            if *s == PixelStatus::Valid && m.is_finite() {
                hist[((m / bits as f32) * 32.0).min(15.0) as usize] += 1;
            }
        }
        eprintln!("level {level}: mean winner cost histogram (1/32 of the bits): {hist:?}");
    }
    let cost_limit = options.max_cost * bits as f32;
    for ((d, s), m) in disparity.iter_mut().zip(status.iter_mut()).zip(&mean_cost) {
        if d.is_finite() && *m > cost_limit {
            *d = f32::NAN;
            *s = PixelStatus::HighCost;
        }
    }
    if options.min_texture > 0.0 {
        let textured = texture_mask(left, 2, options.min_texture);
        // Too little texture is the reason wherever it holds, whatever else failed there
        // (a flat patch is also ambiguous: NotUnique would hide why).
        for ((d, s), t) in disparity.iter_mut().zip(status.iter_mut()).zip(textured) {
            if !t && *s != PixelStatus::NoData {
                *d = f32::NAN;
                *s = PixelStatus::LowTexture;
            }
        }
    }
    for ((d, s), v) in disparity.iter_mut().zip(status.iter_mut()).zip(left_valid) {
        if !v {
            *d = f32::NAN;
            *s = PixelStatus::NoData;
        }
    }
    if level == 0 {
        refine_disparities(
            left,
            left_valid,
            right,
            right_valid,
            &mut disparity,
            &status,
        );
        stage("refinement");
        if options.occlusion_tolerance >= 0.0 {
            remove_occluded(&mut disparity, &mut status, w, options.occlusion_tolerance);
        }
        if options.edge_jump > 0.0 {
            let reach = [cw / 2 * stride, ch / 2 * stride];
            trim_depth_edges(&mut disparity, &mut status, left, reach, options.edge_jump);
        }
        stage("occlusions and depth edges");
    }
    if options.median {
        disparity = median3(&disparity, w, h);
    }
    let speckle = options.speckle_size >> (2 * level);
    remove_speckles(
        &mut disparity,
        &mut status,
        w,
        h,
        speckle,
        options.speckle_diff,
    );
    stage("filters");
    Ok((disparity, status))
}

/// Winner-take-all per pixel with uniqueness, left–right check and sub-pixel refinement.
fn winner_take_all(
    bands: &Bands,
    sum: &[i16],
    raw: &[u8],
    right_width: usize,
    options: &SgmOptions,
) -> (Vec<f32>, Vec<PixelStatus>, Vec<u8>) {
    let w = bands.width;
    let mut disparity = vec![f32::NAN; w * bands.height];
    let mut status = vec![PixelStatus::NoData; w * bands.height];
    let mut winner_cost = vec![u8::MAX; w * bands.height];
    disparity
        .par_chunks_mut(w)
        .zip(status.par_chunks_mut(w))
        .zip(winner_cost.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((disp, stat), wc))| {
            let row = WtaRow {
                bands,
                y,
                sum,
                raw,
                right_width,
                options,
            };
            super::simd::wta_row(&row, disp, stat, wc);
        });
    (disparity, status, winner_cost)
}

/// One row of [`winner_take_all`].
pub(crate) struct WtaRow<'a> {
    pub bands: &'a Bands,
    pub y: usize,
    pub sum: &'a [i16],
    pub raw: &'a [u8],
    pub right_width: usize,
    pub options: &'a SgmOptions,
}

/// Winner-take-all of one row (the kernel the SIMD dispatch instantiates): per left
/// pixel the smallest sum (first on ties), per right pixel the smallest sum over the
/// left pixels that reach it; then the uniqueness test, the left–right check and the
/// sub-pixel fit.
#[inline(always)]
pub(crate) fn wta_row_generic(
    r: &WtaRow<'_>,
    disp: &mut [f32],
    stat: &mut [PixelStatus],
    wc: &mut [u8],
) {
    let bands = r.bands;
    let w = bands.width;
    let y = r.y;
    let range = bands.row_range(y);
    let row = &r.sum[range.clone()];
    let row0 = range.start;
    let wr = r.right_width as i32;
    let mut right_cost = vec![i16::MAX; r.right_width];
    let mut right_d = vec![i32::MIN; r.right_width];
    let mut best_k = vec![u16::MAX; w];
    for x in 0..w {
        let p = y * w + x;
        let n = bands.len[p] as usize;
        if n == 0 {
            continue;
        }
        let s = bands.offset[p] as usize - row0;
        let costs = &row[s..s + n];
        let dmin = bands.dmin[p];
        // The band asked for, without the padding to whole vectors.
        let (ks, ke) = (
            bands.pad[p] as usize,
            bands.pad[p] as usize + bands.real[p] as usize,
        );
        let real = &costs[ks..ke];
        let best = real.iter().copied().fold(i16::MAX, i16::min);
        let k_best = ks + real.iter().position(|&c| c == best).unwrap_or(0);
        best_k[x] = k_best as u16;
        wc[x] = r.raw[row0 + s + k_best];
        // Right pixels x − dmin − k within the right image.
        let k0 = ((x as i32 - dmin - (wr - 1)).max(0) as usize).max(ks);
        let k1 = ((x as i32 - dmin + 1).max(0) as usize).min(ke);
        for (k, &c) in costs.iter().enumerate().take(k1).skip(k0) {
            let xr = (x as i32 - dmin - k as i32) as usize;
            if c < right_cost[xr] {
                right_cost[xr] = c;
                right_d[xr] = dmin + k as i32;
            }
        }
    }
    let keep = 1.0 - r.options.uniqueness;
    for x in 0..w {
        let k = best_k[x] as usize;
        if best_k[x] == u16::MAX {
            continue;
        }
        let p = y * w + x;
        let n = bands.len[p] as usize;
        let s = bands.offset[p] as usize - row0;
        let costs = &row[s..s + n];
        let (ks, ke) = (
            bands.pad[p] as usize,
            bands.pad[p] as usize + bands.real[p] as usize,
        );
        if k == ks || k + 1 == ke {
            stat[x] = PixelStatus::BandEdge;
            continue;
        }
        // Second best two or more disparities away, within the band asked for.
        let second = costs[ks..(k - 1)]
            .iter()
            .chain(&costs[(k + 2).min(ke)..ke])
            .copied()
            .fold(i16::MAX, i16::min);
        let best = costs[k] as f32;
        if best > keep * second as f32 {
            stat[x] = PixelStatus::NotUnique;
            continue;
        }
        let d = bands.dmin[p] + k as i32;
        let xr = x as i32 - d;
        if xr < 0 || xr >= wr {
            stat[x] = PixelStatus::BandEdge;
            continue;
        }
        if (right_d[xr as usize] - d).abs() as f32 > r.options.lr_max_diff {
            stat[x] = PixelStatus::LeftRight;
            continue;
        }
        let (c0, c1, c2) = (costs[k - 1] as f32, best, costs[k + 1] as f32);
        let den = match r.options.subpixel {
            Subpixel::Parabola => c0 - 2.0 * c1 + c2,
            Subpixel::Equiangular => 2.0 * (c0 - c1).max(c2 - c1),
        };
        let offset = if den > 0.0 { (c0 - c2) / den } else { 0.0 };
        let offset = match r.options.subpixel {
            Subpixel::Parabola => 0.5 * offset,
            Subpixel::Equiangular => offset,
        };
        disp[x] = d as f32 + offset;
        stat[x] = PixelStatus::Valid;
    }
}

/// Mean of the values below `u8::MAX` in the (2r + 1)² window around each pixel (NaN
/// where there are none), by separable sums of values and counts.
fn box_mean_u8(v: &[u8], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Horizontal sums: value in the low 16 bits, count in the high 16 (≤ 2r + 1 values).
    let mut rows = vec![0u32; w * h];
    rows.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let src = &v[y * w..(y + 1) * w];
        let item = |c: u8| if c == u8::MAX { 0 } else { c as u32 | 1 << 16 };
        let mut acc = 0u32;
        for &c in &src[..r.min(w)] {
            acc += item(c);
        }
        for x in 0..w {
            if x + r < w {
                acc += item(src[x + r]);
            }
            out[x] = acc;
            if x >= r {
                acc -= item(src[x - r]);
            }
        }
    });
    let mut out = vec![f32::NAN; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        let mut acc = vec![0u32; w];
        for yy in y0..y1 {
            for (a, &b) in acc.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                *a += b;
            }
        }
        for (o, a) in o.iter_mut().zip(acc) {
            let n = a >> 16;
            if n > 0 {
                *o = (a & 0xFFFF) as f32 / n as f32;
            }
        }
    });
    out
}

/// CPU time of the process (s): timings of matching (its debug output, the bench) count
/// work, not waiting for a core while other work runs on the machine.
pub fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
}
