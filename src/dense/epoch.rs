//! An oriented block's own surface: its stereo pairs ([`super::pairs`]) rectified and
//! matched tile by tile within a band around a prior surface, every matched pixel
//! triangulated, and all pairs' points fused into a DSM ([`super::fusion`]).
//!
//! The prior (the LiDAR or control DEM, or a plane at the tie points' height) only bounds
//! the search, widened by a margin that covers what changed since it was measured; the
//! heights come from the photos alone.

use super::fusion::{DsmGrid, FusedSurface, Fusion};
use super::pair::{match_pair, Tiling};
use super::pairs::{select_pairs, PairOptions, StereoPair};
use super::rectify::{BandGrid, RectifiedPair};
use super::sgm::{DisparityPrior, SgmOptions};
use super::{invalid, DenseError, Result};
use crate::block::{Block, Photo, PhotoId, PointKind};
use crate::geometry::back_project;
use crate::geometry::lattice::{lattice_cell_at_least, Lattice};
use crate::matching::oriented::Surface;
use crate::matching::GreyImage;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Options of an epoch's surface.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct DsmOptions {
    /// Cell of the DSM (m); `None`: the finest lattice cell not finer than the block's
    /// ground pixel (median over its photos).
    pub cell: Option<f64>,
    /// Base cell (m) of the raster lattice the DSM is on ([`Lattice`]).
    pub grid_base_m: f64,
    /// The lattice's corner (world x_min, y_max), a project's; `None`: around the DSM's
    /// own area.
    pub corner: Option<[f64; 2]>,
    /// Vertical margin (m) of the search around the prior surface: the relief the prior
    /// misses and what was built or removed since it was measured.
    pub prior_margin_m: f64,
    /// Least number of points in a cell for it to get a height.
    pub min_count: usize,
    pub pairs: PairOptions,
    pub sgm: SgmOptions,
    /// Rectified pixels of the left view matched at a time (whole rows): bounds the cost
    /// volumes of a tile whatever the photo's width; and rows more on both sides.
    pub tile_pixels: usize,
    pub tile_overlap: usize,
}

impl Default for DsmOptions {
    fn default() -> Self {
        Self {
            cell: None,
            grid_base_m: 1.0,
            corner: None,
            prior_margin_m: 25.0,
            min_count: 1,
            pairs: PairOptions::default(),
            sgm: SgmOptions::default(),
            tile_pixels: 1 << 20,
            tile_overlap: 48,
        }
    }
}

/// What one pair gave.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairReport {
    pub pair: StereoPair,
    /// Rectified size of the left view.
    pub rectified: [usize; 2],
    /// Share of the left view's rectified pixels with a disparity.
    pub matched: f64,
    pub points: usize,
    pub seconds: f64,
}

/// An epoch's surface and how it was made.
#[derive(Debug, Clone)]
pub struct EpochDsm {
    pub surface: FusedSurface,
    /// The block's ground pixel (m, median over its photos).
    pub ground_pixel: f64,
    pub grid: DsmGrid,
    pub pairs: Vec<PairReport>,
}

/// Where an `n × n` grid of a photo's pixels meets `surface` (block-local), with the
/// distance from the projection centre; rays that miss it (a DEM smaller than a film
/// photo's footprint) are left out.
fn ground_hits(
    block: &Block,
    photo: &Photo,
    surface: &Surface,
    n: usize,
) -> Vec<(Vector3<f64>, f64)> {
    let Some(cam) = block.camera_of(photo).map(|c| &c.model) else {
        return Vec::new();
    };
    let (w, h) = cam.image_size();
    let mut out = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let q = [
                w as f64 * i as f64 / (n - 1) as f64,
                h as f64 * j as f64 / (n - 1) as f64,
            ];
            let x = back_project(cam, &photo.pose, q)
                .ok()
                .and_then(|r| surface.intersect(&r));
            if let Some(x) = x {
                out.push((x, (x - photo.pose.center).norm()));
            }
        }
    }
    out
}

/// The ground pixel of the block's oriented photos over `surface` (median, m).
pub fn ground_pixel(block: &Block, surface: &Surface) -> Option<f64> {
    let mut gsd: Vec<f64> = block
        .photos
        .values()
        .filter(|p| p.is_oriented())
        .flat_map(|p| {
            let f = block.camera_of(p).map_or(f64::NAN, |c| c.model.focal_px());
            ground_hits(block, p, surface, 5)
                .into_iter()
                .map(move |(_, d)| d / f)
        })
        .filter(|g| g.is_finite() && *g > 0.0)
        .collect();
    gsd.sort_by(f64::total_cmp);
    gsd.get(gsd.len() / 2).copied()
}

/// The world area the oriented photos see on `surface`: the bounding box of where a grid
/// of their pixels meets it.
pub fn footprint_area(block: &Block, surface: &Surface) -> Option<[f64; 4]> {
    let mut area = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in block.photos.values().filter(|p| p.is_oriented()) {
        for (x, _) in ground_hits(block, p, surface, 9) {
            let x = block.to_world(&x);
            area = [
                area[0].min(x.x),
                area[1].min(x.y),
                area[2].max(x.x),
                area[3].max(x.y),
            ];
        }
    }
    area.iter().all(|v| v.is_finite()).then_some(area)
}

/// The prior as a horizontal plane (block-local): a DEM's median height with the half
/// range of its 2nd to 98th percentile as relief. Pairs, the ground pixel and the
/// footprint are judged over it: a DEM may cover only part of a photo (a film photo sees
/// kilometres around a LiDAR survey), and rays that miss it would say nothing.
pub fn plane_of(prior: &Surface<'_>) -> Option<Surface<'static>> {
    match prior {
        Surface::Plane { height, sigma_m } => Some(Surface::Plane {
            height: *height,
            sigma_m: *sigma_m,
        }),
        Surface::Dem { dem, origin, .. } => {
            let mut z: Vec<f32> = dem.data.iter().copied().filter(|v| v.is_finite()).collect();
            if z.is_empty() {
                return None;
            }
            z.sort_unstable_by(f32::total_cmp);
            let q = |f: f64| z[((z.len() - 1) as f64 * f) as usize] as f64 - origin.z;
            Some(Surface::Plane {
                height: q(0.5),
                sigma_m: 0.5 * (q(0.98) - q(0.02)),
            })
        }
    }
}

/// A horizontal plane at the median height of the block's tie points (block-local), the
/// prior of a block without a DEM; `None` without tie points.
pub fn tie_point_plane(block: &Block) -> Option<Surface<'static>> {
    let mut z: Vec<f64> = block
        .points
        .values()
        .filter(|p| p.kind == PointKind::Tie && p.position.z.is_finite())
        .map(|p| p.position.z)
        .collect();
    if z.is_empty() {
        return None;
    }
    z.sort_by(f64::total_cmp);
    let median = z[z.len() / 2];
    // The relief about the median: the 2nd to 98th percentile of the tie points.
    let q = |f: f64| z[((z.len() - 1) as f64 * f) as usize];
    Some(Surface::Plane {
        height: median,
        sigma_m: (q(0.98) - median).max(median - q(0.02)),
    })
}

/// What an epoch's surface is made from, decided before any pixel is matched: the grid,
/// the ground pixel, the stereo pairs and the search margin. The same block, prior and
/// options give the same plan wherever it is made (a worker matching one pair rebuilds it).
#[derive(Debug, Clone)]
pub struct SurfacePlan {
    /// The block's ground pixel (m, median over its photos).
    pub ground_pixel: f64,
    pub grid: DsmGrid,
    pub pairs: Vec<StereoPair>,
    /// Vertical margin of the search around the prior (object units): the options' margin
    /// plus a plane prior's relief.
    pub margin: f64,
}

/// The plan of the surface of `block`'s oriented photos on `grid` (world; `None`: the
/// photos' footprint at the ground pixel or `options.cell`, within a DEM prior's extent),
/// searched around `prior` (block-local). [`DenseError::NoSurface`] when the block has no
/// stereo pair over the prior.
pub fn plan_surface(
    block: &Block,
    prior: &Surface,
    grid: Option<DsmGrid>,
    options: &DsmOptions,
) -> Result<SurfacePlan> {
    let plane = plane_of(prior).ok_or_else(|| invalid("prior", "holds no height"))?;
    let gsd = ground_pixel(block, &plane)
        .ok_or_else(|| DenseError::NoSurface("no oriented photo sees the prior surface".into()))?;
    let grid = match grid {
        Some(g) => g,
        None => {
            let mut area = footprint_area(block, &plane).ok_or_else(|| {
                DenseError::NoSurface("no oriented photo sees the prior surface".into())
            })?;
            // Where a DEM bounds the search, the surface is made within it.
            if let Surface::Dem { dem, origin, .. } = prior {
                // The DEM's world extent: it holds world coordinates less `origin` (a
                // block-local DEM has the block's origin there, a world one zero).
                let shift = Vector3::from(block.origin) - origin;
                let (x0, y0, x1, y1) = dem.extent();
                let (x0, y0, x1, y1) = (x0 + shift.x, y0 + shift.y, x1 + shift.x, y1 + shift.y);
                area = [
                    area[0].max(x0),
                    area[1].max(y0),
                    area[2].min(x1),
                    area[3].min(y1),
                ];
            }
            let cell = options
                .cell
                .unwrap_or_else(|| lattice_cell_at_least(options.grid_base_m, gsd));
            let lattice = match options.corner {
                Some(corner) => Lattice {
                    base_m: options.grid_base_m,
                    corner,
                },
                None => Lattice::around(options.grid_base_m, area)?,
            };
            lattice.grid(cell, area)?
        }
    };
    let pairs = select_pairs(block, &plane, &options.pairs);
    if pairs.is_empty() {
        let n = block.photos.values().filter(|p| p.is_oriented()).count();
        return Err(DenseError::NoSurface(format!(
            "no stereo pair among {n} oriented photo(s) (overlap ≥ {:.0} %, base-to-height {}–{})",
            100.0 * options.pairs.min_overlap,
            options.pairs.base_to_height[0],
            options.pairs.base_to_height[1]
        )));
    }
    let margin = options.prior_margin_m
        + match prior {
            Surface::Plane { sigma_m, .. } => *sigma_m,
            Surface::Dem { .. } => 0.0,
        };
    Ok(SurfacePlan {
        ground_pixel: gsd,
        grid,
        pairs,
        margin,
    })
}

/// Matches stereo pair `pair` of `plan` and hands its points, as samples of the plan's
/// grid (cell, height: [`DsmGrid::sample`]), to `sink` tile by tile. `load` gives a
/// photo's pixels (the size of its camera), asked only once the pair has rectified; a
/// pair that fails to rectify or does not see the prior is reported with nothing matched.
pub fn match_plan_pair(
    block: &Block,
    plan: &SurfacePlan,
    pair: &StereoPair,
    prior: &Surface,
    options: &DsmOptions,
    mut load: impl FnMut(&Photo) -> Result<std::sync::Arc<GreyImage>>,
    mut sink: impl FnMut(&[(u32, f32)]),
) -> Result<PairReport> {
    let t0 = Instant::now();
    let photo = |id: PhotoId| {
        block
            .photos
            .get(&id)
            .ok_or_else(|| invalid("pair", format!("photo {id} is not in the block")))
    };
    let (pl, pr) = (photo(pair.left)?, photo(pair.right)?);
    let camera = |p: &Photo| {
        block
            .camera_of(p)
            .map(|c| &c.model)
            .ok_or_else(|| invalid(&p.name, format!("camera {} is not in the block", p.camera)))
    };
    let mut report = PairReport {
        pair: *pair,
        rectified: [0, 0],
        matched: 0.0,
        points: 0,
        seconds: 0.0,
    };
    let origin = Vector3::from(block.origin);
    let rectified = RectifiedPair::new((camera(pl)?, &pl.pose), (camera(pr)?, &pr.pose));
    if let Ok(rect) = rectified {
        let (left, right) = (load(pl)?, load(pr)?);
        let mut points = 0;
        let mut samples = Vec::new();
        let matched = match_stereo(&rect, &left, &right, prior, plan.margin, options, |pts| {
            samples.clear();
            samples.extend(pts.into_iter().filter_map(|x| {
                let x = x + origin;
                plan.grid.sample(x.x, x.y, x.z)
            }));
            points += samples.len();
            sink(&samples);
        })?;
        if let Some(m) = matched {
            report.rectified = m.rectified;
            report.matched = m.matched;
            report.points = points;
        }
    }
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// The surface of `block`'s oriented photos ([`plan_surface`]; `grid` as there), every
/// pair matched in turn ([`match_plan_pair`]) and fused; `image` gives a photo's pixels
/// (the size of its camera). An error of `image` stops the run.
pub fn epoch_dsm(
    block: &Block,
    image: &(dyn Fn(&Photo) -> std::result::Result<GreyImage, String> + Sync),
    prior: &Surface,
    grid: Option<DsmGrid>,
    options: &DsmOptions,
    mut progress: impl FnMut(usize, usize, &PairReport),
) -> Result<EpochDsm> {
    let plan = plan_surface(block, prior, grid, options)?;
    let mut fusion = Fusion::new(plan.grid);
    let mut reports = Vec::with_capacity(plan.pairs.len());
    // The photos of the last pairs: pairs come in photo order, so a photo is mostly
    // needed again by the next few pairs.
    let mut cache: Vec<(PhotoId, std::sync::Arc<GreyImage>)> = Vec::new();
    for (k, sp) in plan.pairs.iter().enumerate() {
        let load = |p: &Photo| -> Result<std::sync::Arc<GreyImage>> {
            if let Some((_, img)) = cache.iter().find(|(id, _)| *id == p.id) {
                return Ok(img.clone());
            }
            let img = std::sync::Arc::new(image(p).map_err(|e| invalid(&p.name, e))?);
            if cache.len() == 3 {
                cache.remove(0);
            }
            cache.push((p.id, img.clone()));
            Ok(img)
        };
        let report = match_plan_pair(block, &plan, sp, prior, options, load, |s| fusion.push(s))?;
        progress(k + 1, plan.pairs.len(), &report);
        reports.push(report);
    }
    fuse(&plan, fusion, reports, options)
}

/// The epoch's surface from the samples of every pair of `plan` (`reports` in pair order).
pub fn fuse(
    plan: &SurfacePlan,
    fusion: Fusion,
    reports: Vec<PairReport>,
    options: &DsmOptions,
) -> Result<EpochDsm> {
    if fusion.is_empty() {
        return Err(DenseError::NoSurface(format!(
            "none of the {} pair(s) matched a pixel within the prior's band",
            plan.pairs.len()
        )));
    }
    Ok(EpochDsm {
        surface: fusion.finish(options.min_count)?,
        ground_pixel: plan.ground_pixel,
        grid: plan.grid,
        pairs: reports,
    })
}

/// What matching one pair gave.
#[derive(Debug, Clone, Copy)]
pub struct PairMatch {
    /// Columns and rows of the left rectified view.
    pub rectified: [usize; 2],
    /// Share of the matched rows' left rectified pixels with a disparity.
    pub matched: f64,
}

/// Matches the rectified `pair` (photos `left`, `right`, the size of their cameras) within
/// `margin` (vertical, object units) of `prior` (in the pair's coordinates) and hands the
/// object point of every matched pixel to `sink`, tile by tile. Only the rows that see the
/// prior are matched, and beyond a DEM prior no pixel is; `None` when the pair does not
/// see the prior at all.
pub fn match_stereo(
    pair: &RectifiedPair,
    left: &GreyImage,
    right: &GreyImage,
    prior: &Surface,
    margin: f64,
    options: &DsmOptions,
    mut sink: impl FnMut(Vec<Vector3<f64>>),
) -> Result<Option<PairMatch>> {
    let band = pair.band_from_surface(prior, margin, 16);
    let Some([lo, hi]) = band_range(&band.min, &band.max) else {
        return Ok(None);
    };
    let disparity = DisparityPrior {
        range: [lo, hi],
        grid: Some(&band),
        first_row: 0,
        grid_only: matches!(prior, Surface::Dem { .. }),
    };
    let (mut valid, mut total) = (0usize, 0usize);
    match_pair(
        pair,
        left,
        right,
        &disparity,
        &options.sgm,
        Tiling {
            rows: (options.tile_pixels / pair.left.width.max(1)).max(32),
            overlap: options.tile_overlap,
            within: band_rows(&band),
        },
        |tile| {
            let w = tile.map.width;
            total += tile.map.disparity.len();
            let mut pts = Vec::new();
            for (i, &d) in tile.map.disparity.iter().enumerate() {
                if !d.is_finite() {
                    continue;
                }
                valid += 1;
                let px = [(i % w) as f64 + 0.5, (tile.rows.start + i / w) as f64 + 0.5];
                pts.extend(pair.triangulate(px, d as f64));
            }
            sink(pts);
            Ok(())
        },
    )?;
    Ok(Some(PairMatch {
        rectified: [pair.left.width, pair.height],
        matched: valid as f64 / total.max(1) as f64,
    }))
}

/// Rectified rows within a node of the band grid's rows that hold a finite node.
fn band_rows(band: &BandGrid) -> std::ops::Range<usize> {
    let finite = |j: usize| (0..band.cols).any(|i| band.min[j * band.cols + i].is_finite());
    let first = (0..band.rows).find(|&j| finite(j));
    let last = (0..band.rows).rev().find(|&j| finite(j));
    match (first, last) {
        (Some(a), Some(b)) => a.saturating_sub(1) * band.step..(b + 2) * band.step,
        _ => 0..0,
    }
}

/// The range of a band grid's finite nodes; `None` when none is (the pair does not see
/// the prior).
fn band_range(min: &[f32], max: &[f32]) -> Option<[f32; 2]> {
    let lo = min
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f32::INFINITY, f32::min);
    let hi = max
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f32::NEG_INFINITY, f32::max);
    (lo <= hi).then(|| [lo.floor(), hi.ceil()])
}
