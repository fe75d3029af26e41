//! Control points with their chips, and how one is found in a photo.
//!
//! A [`ChipStore`] holds control points (block-local), each seen in one or more *views*: a
//! chip of an oriented photo with that photo's camera and pose. The chips come from DCP
//! packages (read on demand, checksums verified) or are cut from oriented photos of the
//! same block (the epoch's own photos in the second pass, tie points among them). The
//! [`ChipMatcher`] aligns a view's chip to the target photo through the point's ground
//! plane, then runs NCC over the pyramid inside the search window, LSM at full resolution
//! and the NCC/LSM cross-check (seed 001).

use super::dcp::{ChipRef, DcpError, DcpPackage, PlanIndex};
use super::orient::{ControlPatch, PatchMatch, PatchMatcher};
use super::predict::{self, Plane, Prediction, View};
use crate::geometry::{Camera, Pose};
use crate::matching::{self, match_template, GreyImage, MatchOptions, Pyramid, Window};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::Arc;

/// A DCP control point: package index and point index in its manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct PointKey {
    pub package: usize,
    pub point: usize,
}

/// Where a view's pixels are.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum ChipPixels {
    /// A chip file of a package, read (and verified) when first needed.
    Package { package: usize, chip: ChipRef },
    /// A chip already cut from a photo in memory. Written as its grey pixels (a task
    /// file); the reader rebuilds the same pyramid from them.
    Memory(#[serde(with = "cut_chip")] Arc<Pyramid>),
}

/// The pyramid of a cut chip written as its level 0 (the levels above follow from it
/// deterministically), in the narrowest exact form: a photo's grey values are integers
/// of its file's range, so 8-bit photos take a byte a pixel, not the four of `f32`.
mod cut_chip {
    use super::{Arc, GreyImage, Pyramid};
    use serde::{de::Error, Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    enum Grey {
        U8(#[serde(with = "serde_bytes")] Vec<u8>),
        U16(Vec<u16>),
        F32(Vec<f32>),
    }

    #[derive(Serialize, Deserialize)]
    struct Chip {
        width: usize,
        height: usize,
        grey: Grey,
    }

    pub fn serialize<S: Serializer>(p: &Arc<Pyramid>, s: S) -> Result<S::Ok, S::Error> {
        let g = &p.levels[0];
        let integral = |max: f32| {
            g.data
                .iter()
                .all(|&v| v.fract() == 0.0 && (0.0..=max).contains(&v))
        };
        let grey = if integral(255.0) {
            Grey::U8(g.data.iter().map(|&v| v as u8).collect())
        } else if integral(65535.0) {
            Grey::U16(g.data.iter().map(|&v| v as u16).collect())
        } else {
            Grey::F32(g.data.clone())
        };
        Chip {
            width: g.width,
            height: g.height,
            grey,
        }
        .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Arc<Pyramid>, D::Error> {
        let c = Chip::deserialize(d)?;
        let data: Vec<f32> = match c.grey {
            Grey::U8(v) => v.into_iter().map(f32::from).collect(),
            Grey::U16(v) => v.into_iter().map(f32::from).collect(),
            Grey::F32(v) => v,
        };
        if data.len() != c.width.saturating_mul(c.height) {
            return Err(D::Error::custom(format!(
                "chip of {}×{} pixels holds {} values",
                c.width,
                c.height,
                data.len()
            )));
        }
        let g = GreyImage::new(c.width, c.height, data).map_err(D::Error::custom)?;
        Ok(Arc::new(Pyramid::new(
            &g,
            super::CUT_LEVELS,
            super::CUT_MIN_SIZE,
        )))
    }
}

/// The pyramid of a cut chip: levels, smallest side.
const CUT_LEVELS: usize = 5;
const CUT_MIN_SIZE: usize = 8;

/// One view of a control point: its chip in an oriented photo.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ChipView {
    pub camera: Camera,
    /// Block-local pose of the photo the chip was cut from.
    pub pose: Pose,
    /// The point's pixel in that photo.
    pub pixel: [f64; 2],
    /// Photo pixel of the chip's top-left corner and the chip size.
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    /// Index of the epoch photo the chip was cut from, for chips of the block itself.
    pub photo: Option<usize>,
    pixels: ChipPixels,
}

/// A pixel coordinate within this of an integer is that integer when a chip is placed.
const GRID_SNAP: f64 = 1e-6;

/// Top-left photo pixel of a chip of side 2·half + 1 whose centre pixel holds `pixel`.
/// Control points are chosen on the pixel grid and come back from their object
/// coordinates at 886.0 or 885.9999999999998 as the orientation's last bits fall: a plain
/// `floor` cut 14 of small seed 1's 203 DCP chips one pixel apart between two builds whose
/// reference solutions differed by 1e-10 (the digital epoch's height then 0.79 or 0.91
/// GSD). Snapped to the grid, both give one chip.
pub fn chip_origin(pixel: [f64; 2], half: usize) -> (i64, i64) {
    (
        (pixel[0] + GRID_SNAP).floor() as i64 - half as i64,
        (pixel[1] + GRID_SNAP).floor() as i64 - half as i64,
    )
}

impl ChipView {
    /// A view whose chip is cut from `image` (a photo of the block) around `pixel`, of
    /// side `2·half + 1`; `None` when the chip would leave the photo.
    pub fn cut(
        camera: &Camera,
        pose: &Pose,
        image: &GreyImage,
        pixel: [f64; 2],
        half: usize,
        photo: Option<usize>,
    ) -> Option<Self> {
        let size = 2 * half + 1;
        let (x0, y0) = chip_origin(pixel, half);
        if x0 < 0 || y0 < 0 {
            return None;
        }
        let crop = image.crop(x0 as usize, y0 as usize, size, size).ok()?;
        Some(Self {
            camera: camera.clone(),
            pose: *pose,
            pixel,
            x0: x0 as u32,
            y0: y0 as u32,
            width: size as u32,
            height: size as u32,
            photo,
            pixels: ChipPixels::Memory(Arc::new(Pyramid::from_image(
                crop,
                CUT_LEVELS,
                CUT_MIN_SIZE,
            ))),
        })
    }
}

/// A control point offered to the photos.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ControlPoint {
    /// The DCP point this is, when it comes from a package (also for chips re-cut from
    /// the epoch's own photos); `None` for a tie point of the epoch.
    pub key: Option<PointKey>,
    /// `epoch:name` of a DCP point, for reports.
    pub label: String,
    /// Block-local object coordinates and their 1σ (m).
    pub position: Vector3<f64>,
    pub sigma: [f64; 3],
    /// Unit normal of the supporting surface (the chip is aligned through this plane).
    pub normal: Vector3<f64>,
    pub views: Vec<ChipView>,
}

/// Control points with their views and a plan index over them.
pub struct ChipStore<'a> {
    packages: &'a [DcpPackage],
    pub origin: Vector3<f64>,
    pub points: Vec<ControlPoint>,
    index: PlanIndex,
}

impl<'a> ChipStore<'a> {
    /// Every point of the packages (their CRS checked by the caller), block-local.
    pub fn from_packages(packages: &'a [DcpPackage], origin: Vector3<f64>) -> Self {
        let mut points = Vec::new();
        for (k, pkg) in packages.iter().enumerate() {
            let m = &pkg.manifest;
            for (i, p) in m.points.iter().enumerate() {
                let views = p
                    .measurements
                    .iter()
                    .filter_map(|ms| {
                        let ph = m.photos.iter().find(|ph| ph.id == ms.photo)?;
                        Some(ChipView {
                            camera: ph.camera.clone(),
                            pose: ph.pose(&origin),
                            pixel: ms.pixel,
                            x0: ms.chip.x0,
                            y0: ms.chip.y0,
                            width: ms.chip.width,
                            height: ms.chip.height,
                            photo: None,
                            pixels: ChipPixels::Package {
                                package: k,
                                chip: ms.chip.clone(),
                            },
                        })
                    })
                    .collect();
                points.push(ControlPoint {
                    key: Some(PointKey {
                        package: k,
                        point: i,
                    }),
                    label: format!("{}:{}", m.epoch.name, p.name),
                    position: Vector3::from(p.xyz) - origin,
                    sigma: p.sigma,
                    normal: p.normal.map(Vector3::from).unwrap_or_else(Vector3::z),
                    views,
                });
            }
        }
        Self::new(packages, origin, points)
    }

    /// Points whose views are chips in memory (cut with [`ChipView::cut`]).
    pub fn from_points(origin: Vector3<f64>, points: Vec<ControlPoint>) -> ChipStore<'static> {
        ChipStore::new(&[], origin, points)
    }

    fn new(packages: &'a [DcpPackage], origin: Vector3<f64>, points: Vec<ControlPoint>) -> Self {
        let index = PlanIndex::new(
            points
                .iter()
                .map(|p| [p.position.x, p.position.y])
                .collect(),
        );
        Self {
            packages,
            origin,
            points,
            index,
        }
    }

    /// The points, the store given up.
    pub fn into_points(self) -> Vec<ControlPoint> {
        self.points
    }

    /// Matches of a photo (store point index, pixel, σ) as DCP points: the points without
    /// a key (tie points of the epoch) are left out.
    pub fn keyed(
        &self,
        matches: &[(usize, Vector2<f64>, f64)],
    ) -> Vec<(PointKey, Vector2<f64>, f64)> {
        matches
            .iter()
            .filter_map(|(i, px, s)| Some((self.points[*i].key?, *px, *s)))
            .collect()
    }

    /// Of the points `indices`, the first in each cell of a `cells` × `cells` grid over
    /// their plan extent: at most `cells`² points spread over the same ground, in the
    /// order given.
    pub fn spread(&self, indices: &[usize], cells: usize) -> Vec<usize> {
        let xy = |i: usize| self.points[i].position.xy();
        let (mut lo, mut hi) = (
            Vector2::repeat(f64::INFINITY),
            Vector2::repeat(f64::NEG_INFINITY),
        );
        for &i in indices {
            lo = lo.inf(&xy(i));
            hi = hi.sup(&xy(i));
        }
        let side = (hi - lo).max() / cells.max(1) as f64;
        if side.is_nan() || side <= 0.0 {
            return indices.iter().copied().take(1).collect();
        }
        let last = cells.max(1) as i64 - 1;
        let mut taken = std::collections::BTreeSet::new();
        indices
            .iter()
            .copied()
            .filter(|&i| {
                let c = ((xy(i) - lo) / side).map(|v| (v as i64).min(last));
                taken.insert((c.x, c.y))
            })
            .collect()
    }

    /// The points `indices` with their chips read into memory: a store that a round of
    /// the epoch's passes can carry to a process without the packages.
    pub fn owned(&self, indices: &[usize]) -> Result<ChipStore<'static>, DcpError> {
        let mut points = Vec::with_capacity(indices.len());
        for &i in indices {
            let p = &self.points[i];
            let views = (0..p.views.len())
                .map(|v| {
                    Ok(ChipView {
                        pixels: ChipPixels::Memory(self.pyramid(i, v)?),
                        ..p.views[v].clone()
                    })
                })
                .collect::<Result<Vec<_>, DcpError>>()?;
            points.push(ControlPoint { views, ..p.clone() });
        }
        Ok(ChipStore::from_points(self.origin, points))
    }

    /// Indices of the points inside a block-local plan polygon, in a fixed order.
    pub fn query_polygon(&self, polygon: &[[f64; 2]]) -> Vec<usize> {
        self.index.query_polygon(polygon)
    }

    /// The patches of the points inside a polygon, as the orientation loop takes them.
    pub fn patches_in(&self, polygon: &[[f64; 2]]) -> Vec<ControlPatch> {
        self.query_polygon(polygon)
            .into_iter()
            .map(|i| {
                let s = self.points[i].sigma;
                ControlPatch {
                    id: i,
                    position: self.points[i].position,
                    covariance: Matrix3::from_diagonal(&Vector3::new(
                        s[0] * s[0],
                        s[1] * s[1],
                        s[2] * s[2],
                    )),
                }
            })
            .collect()
    }

    /// The chip pyramid of a view (a package chip is read, verified and decoded).
    fn pyramid(&self, point: usize, view: usize) -> Result<Arc<Pyramid>, DcpError> {
        match &self.points[point].views[view].pixels {
            ChipPixels::Memory(p) => Ok(p.clone()),
            ChipPixels::Package { package, chip } => {
                let pkg = &self.packages[*package];
                let img = pkg.chip(chip)?;
                let g = img.to_luma32f();
                let data: Vec<f32> = g.as_raw().iter().map(|v| v * 255.0).collect();
                let grey =
                    GreyImage::new(g.width() as usize, g.height() as usize, data).map_err(|e| {
                        DcpError::Chip {
                            package: pkg.dir.clone(),
                            file: chip.file.clone(),
                            message: e.to_string(),
                        }
                    })?;
                Ok(Arc::new(Pyramid::from_image(
                    grey,
                    CUT_LEVELS,
                    CUT_MIN_SIZE,
                )))
            }
        }
    }
}

/// A store of cut chips as a task file holds it: origin and points.
#[derive(Serialize, Deserialize)]
struct StoreFile<P> {
    origin: Vector3<f64>,
    points: P,
}

/// Only a store of chips cut from photos is written: a package's chips are read from the
/// package, which the reader opens itself.
impl Serialize for ChipStore<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if !self.packages.is_empty() {
            return Err(serde::ser::Error::custom(
                "a store over DCP packages is not written, its packages are",
            ));
        }
        StoreFile {
            origin: self.origin,
            points: &self.points,
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for ChipStore<'static> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let f = StoreFile::<Vec<ControlPoint>>::deserialize(d)?;
        if f.points
            .iter()
            .flat_map(|p| &p.views)
            .any(|v| matches!(v.pixels, ChipPixels::Package { .. }))
        {
            return Err(serde::de::Error::custom(
                "a written store holds chips cut from photos only",
            ));
        }
        Ok(ChipStore::from_points(f.origin, f.points))
    }
}

/// Options of the chip matcher.
#[derive(Debug, Clone)]
pub struct ChipMatchOptions {
    pub matching: MatchOptions,
    /// Largest template half size in target pixels (template = 2·h + 1); smaller when the
    /// chip does not hold it at the target's scale, but never below `min_template_half`.
    pub template_half: usize,
    pub min_template_half: usize,
    /// Minimum grey-value standard deviation of an aligned chip (textureless chips are
    /// not offered to NCC).
    pub min_chip_std: f64,
}

impl Default for ChipMatchOptions {
    fn default() -> Self {
        Self {
            matching: MatchOptions {
                ncc_threshold: 0.6,
                // Large first-round windows over fields and roads hold near-repeats of
                // a patch; the best peak is still mostly right, and the resection's
                // RANSAC removes the rest.
                max_ambiguity: 0.97,
                // The NCC peak of a rescaled template is good to a pixel or two; LSM is
                // the precise one, the cross-check only has to catch its divergence.
                agreement_px: 2.0,
                ..MatchOptions::default()
            },
            template_half: 30,
            min_template_half: 7,
            min_chip_std: 2.0,
        }
    }
}

/// Why the matcher rejected patches, counted for the report.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct MatchStats {
    pub offered: usize,
    pub no_chip: usize,
    pub textureless: usize,
    pub rejected: usize,
    pub accepted: usize,
}

/// A chip's pyramid from level `.0` on (its first levels dropped).
type ChipLevels = (usize, Arc<Pyramid>);

/// The [`PatchMatcher`] of real photos: finds the points of a [`ChipStore`] in one photo.
pub struct ChipMatcher<'a> {
    camera: &'a Camera,
    pyramid: &'a Pyramid,
    store: &'a ChipStore<'a>,
    opts: &'a ChipMatchOptions,
    /// Chip pyramids read so far, by (point, view), from the first level kept on; None =
    /// unreadable. A target coarser than the chips needs only their coarse levels, and a
    /// photo holds every chip it matched: a film scan at 0.5 m over the large preset's
    /// 16,000 points of 5 cm chips held 3 GiB of full pyramids, two scans at a time.
    chips: HashMap<(usize, usize), Option<ChipLevels>>,
    pub stats: MatchStats,
    /// First chip error met (a damaged package is an input error, not a mismatch).
    pub chip_error: Option<DcpError>,
}

impl<'a> ChipMatcher<'a> {
    pub fn new(
        camera: &'a Camera,
        pyramid: &'a Pyramid,
        store: &'a ChipStore<'a>,
        opts: &'a ChipMatchOptions,
    ) -> Self {
        Self {
            camera,
            pyramid,
            store,
            opts,
            chips: HashMap::new(),
            stats: MatchStats::default(),
            chip_error: None,
        }
    }

    /// The pyramid of a view's chip from level `base` on (`base` ≤ `level`, the level
    /// wanted), read once per photo unless a finer level is wanted later.
    fn chip(&mut self, point: usize, view: usize, level: usize) -> Option<ChipLevels> {
        match self.chips.get(&(point, view)) {
            Some(None) => return None,
            Some(Some((base, p))) if *base <= level => return Some((*base, p.clone())),
            _ => {}
        }
        let c = match self.store.pyramid(point, view) {
            // A pyramid read for this matcher alone keeps the levels from the wanted one;
            // one shared with the store (a chip cut in memory) costs nothing to hold.
            Ok(p) => Some(match Arc::try_unwrap(p) {
                Ok(mut p) => {
                    let base = level.min(p.levels.len().saturating_sub(1));
                    p.levels.drain(..base);
                    (base, Arc::new(p))
                }
                Err(shared) => (0, shared),
            }),
            Err(e) => {
                self.chip_error.get_or_insert(e);
                None
            }
        };
        self.chips.insert((point, view), c.clone());
        c
    }

    /// Views of a point, best first: the photo whose viewing direction is closest to the
    /// target's, then the one with the closest ground pixel.
    fn ranked_views(&self, point: usize, target: &Pose) -> Vec<usize> {
        let p = &self.store.points[point];
        let x = &p.position;
        let to_target = (target.center - x).normalize();
        let target_gsd = (target.center - x).norm() / self.camera.focal_px();
        let mut scored: Vec<(usize, f64, f64)> = p
            .views
            .iter()
            .enumerate()
            .map(|(j, v)| {
                let d = (v.pose.center - x).normalize();
                let gsd = (v.pose.center - x).norm() / v.camera.focal_px();
                (j, d.dot(&to_target), (gsd / target_gsd).ln().abs())
            })
            .collect();
        scored.sort_by(|a, b| {
            // Directions within ~2.5° are equivalent; then prefer the closer scale.
            let (qa, qb) = ((a.1 * 400.0).round(), (b.1 * 400.0).round());
            qb.total_cmp(&qa).then(a.2.total_cmp(&b.2))
        });
        scored.into_iter().map(|s| s.0).collect()
    }

    /// The chip of view `view` aligned to the target at `pixel` as a template of half
    /// size at most `max_half`, or None when the chip does not hold the template.
    fn template(
        &mut self,
        point: usize,
        view: usize,
        pose: &Pose,
        pixel: Vector2<f64>,
        max_half: f64,
    ) -> Option<GreyImage> {
        let store = self.store;
        let p = &store.points[point];
        let v = &p.views[view];
        let plane = Plane::through(&p.position, &p.normal);
        let a = predict::transfer_affine(
            View {
                camera: self.camera,
                pose,
            },
            View {
                camera: &v.camera,
                pose: &v.pose,
            },
            &plane,
            [pixel.x, pixel.y],
        )
        .ok()?;
        let s = Vector2::new(v.pixel[0] - v.x0 as f64, v.pixel[1] - v.y0 as f64);
        let l = a.fixed_view::<2, 2>(0, 0).into_owned();
        // The largest template (up to the option) whose footprint stays inside the chip:
        // a coarser target needs more chip pixels per template pixel.
        let stretch = l.column(0).norm().max(l.column(1).norm()).max(1e-9);
        let room = (v.width.min(v.height) as f64 / 2.0 - 3.0) / (stretch * 1.05);
        let th = max_half.min(room.floor() - 1.0);
        if th < self.opts.min_template_half as f64 {
            return None;
        }
        let t = 2.0 * th + 1.0;
        let want = predict::pyramid_level(&a) as usize;
        let (base, chip) = self.chip(point, view, want)?;
        let level = want.min(base + chip.levels.len() - 1);
        let f = (1u64 << level) as f64;
        let img = &chip.levels[level - base];
        // Template pixel u (corner origin) ↦ offset u − t/2 from the point ↦ chip pixel
        // L·offset + s ↦ level pixel /2^level: the chip rotated and rescaled into the
        // target's geometry, centred on the control point's own chip position.
        let c = s - l * Vector2::new(t / 2.0, t / 2.0);
        let warp = matching::PatchWarp::Affine([
            l[(0, 0)] / f,
            l[(0, 1)] / f,
            c.x / f,
            l[(1, 0)] / f,
            l[(1, 1)] / f,
            c.y / f,
        ]);
        let (tpl, outside) = matching::warp_patch(
            img,
            &warp,
            t as usize,
            t as usize,
            matching::Interpolation::Bicubic,
        );
        (outside == 0).then_some(tpl)
    }
}

/// Half size of the retry template relative to the first one's.
const SMALLER_TEMPLATE: f64 = 0.55;

impl ChipMatcher<'_> {
    /// The template of the best-ranked view that holds one of half size ≤ `max_half`.
    fn best_template(
        &mut self,
        point: usize,
        pose: &Pose,
        pixel: Vector2<f64>,
        max_half: f64,
    ) -> Option<GreyImage> {
        self.ranked_views(point, pose)
            .into_iter()
            .find_map(|view| self.template(point, view, pose, pixel, max_half))
    }

    /// NCC + LSM of `tpl` in the window around the prediction; None when rejected.
    fn search(
        &self,
        patch: usize,
        tpl: &GreyImage,
        prediction: &Prediction,
        half_size: [f64; 2],
    ) -> Option<crate::matching::MatchResult> {
        let img = &self.pyramid.levels[0];
        let th = tpl.width as f64 / 2.0;
        let window = Window::around(
            img,
            prediction.pixel.x,
            prediction.pixel.y,
            half_size[0] + th,
            half_size[1] + th,
        )?;
        let rr = match_template(self.pyramid, tpl, window, None, &self.opts.matching);
        if let Ok(r) = &rr {
            tracing::debug!(
                patch,
                pred_x = prediction.pixel.x,
                pred_y = prediction.pixel.y,
                half = half_size[0],
                template_half = tpl.width / 2,
                x = r.x,
                y = r.y,
                ncc = r.ncc,
                ambiguity = r.ambiguity,
                reason = r.reason.as_deref().unwrap_or(""),
                "control patch match"
            );
        }
        let r = rr.ok().filter(|r| r.accepted)?;
        // The match must lie in the window that was searched (LSM may drift out of it).
        ((r.x - prediction.pixel.x).abs() <= half_size[0] + 1.0
            && (r.y - prediction.pixel.y).abs() <= half_size[1] + 1.0)
            .then_some(r)
    }
}

impl PatchMatcher for ChipMatcher<'_> {
    fn find(
        &mut self,
        patch: &ControlPatch,
        pose: &Pose,
        prediction: &Prediction,
        half_size: [f64; 2],
    ) -> Option<PatchMatch> {
        self.stats.offered += 1;
        // The largest template first: in a wide window its many pixels set the true peak
        // apart from near-repeats. Where it is rejected, once more with a template of
        // about half the size: the larger the template's ground footprint, the likelier
        // it spans a parcel or roof that changed since, or relief the plane transfer
        // does not follow (film from 0.2 m digital chips: 30 m templates matched 0 of 64
        // patches in a photo where 17 m ones matched 12).
        let mut max_half = self.opts.template_half as f64;
        let mut found = None;
        let mut offered = false;
        loop {
            let mut th = max_half;
            if let Some(tpl) = self.best_template(patch.id, pose, prediction.pixel, max_half) {
                if tpl.std_dev() < self.opts.min_chip_std {
                    if !offered {
                        self.stats.textureless += 1;
                        return None;
                    }
                    break;
                }
                offered = true;
                found = self.search(patch.id, &tpl, prediction, half_size);
                th = (tpl.width / 2) as f64;
            }
            // A template that did not fit in the chip may fit at the smaller size. It
            // keeps enough pixels for a coarse pyramid level: a full-resolution search
            // of a first-round window costs ~20× the search one level up.
            let smaller = (th * SMALLER_TEMPLATE)
                .round()
                .max(self.opts.matching.min_template_px as f64);
            if found.is_some() || smaller < self.opts.min_template_half as f64 || smaller > th - 2.0
            {
                break;
            }
            max_half = smaller;
        }
        let r = match (found, offered) {
            (Some(r), _) => r,
            (None, true) => {
                self.stats.rejected += 1;
                return None;
            }
            (None, false) => {
                self.stats.no_chip += 1;
                return None;
            }
        };
        self.stats.accepted += 1;
        let sigma = (0.5 * (r.sigma_x.powi(2) + r.sigma_y.powi(2))).sqrt();
        Some(PatchMatch {
            pixel: Vector2::new(r.x, r.y),
            sigma_px: if sigma.is_finite() { sigma } else { 1.0 },
            ncc: r.ncc,
        })
    }
}
