//! Epipolar rectification of a pair of oriented photos onto two virtual pinhole cameras.
//!
//! The rectified cameras keep the photos' projection centres and share one rotation
//! (Fusiello, Trucco and Verri's construction): the new x axis is the baseline from the
//! left to the right centre, the new y axis is perpendicular to it and to the mean of the
//! two optical axes, and z completes the right-handed frame, forward. Both share the focal
//! length (the mean of the photos', in pixels) and the principal-point row, so an object
//! point lies on the same row in both; each view has its own principal-point column so it
//! covers its own photo without a band of empty columns. Distortion and a film scan's
//! interior orientation are removed by going through the photo's camera model for every
//! rectified pixel ([`Camera::project`] for rendering, [`Camera::unproject`] for the
//! forward map).

use super::{invalid, DenseError, Result};
use crate::geometry::{Brown, Camera, Dem, FrameCamera, Pose, Ray};
use crate::matching::oriented::Surface;
use crate::matching::resample::bilinear;
use crate::matching::GreyImage;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::ops::Range;

/// One of the two photos of a pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

/// One rectified view: a pinhole camera of the pair's rotation and focal length at the
/// photo's projection centre, and the photo it is rendered from.
#[derive(Debug, Clone)]
pub struct RectifiedView {
    /// Columns of the rectified image (rows are the pair's).
    pub width: usize,
    /// Principal-point column (px, corner origin).
    pub cx: f64,
    /// Projection centre (the photo's).
    pub center: Vector3<f64>,
    /// The photo's camera and exterior orientation.
    pub source: Camera,
    pub source_pose: Pose,
    /// Rectified camera frame → the photo's camera frame.
    to_source: Matrix3<f64>,
}

/// Geometry of a rectified pair. Rectified pixel (col, row) of a view is the direction
/// `rotationᵀ · ((col + 0.5 − cx) / f, (row + 0.5 − cy) / f, 1)` from its centre.
#[derive(Debug, Clone)]
pub struct RectifiedPair {
    /// World → rectified camera frame, shared by both views.
    pub rotation: Matrix3<f64>,
    /// Focal length of both views (px).
    pub focal_px: f64,
    /// Principal-point row of both views (px, corner origin).
    pub cy: f64,
    /// Rows of both rectified images.
    pub height: usize,
    pub left: RectifiedView,
    pub right: RectifiedView,
}

/// A window of rows of one rectified image, rendered from its photo.
#[derive(Debug, Clone)]
pub struct RectifiedImage {
    /// The rows' grey values; pixels the photo does not cover repeat the nearest covered
    /// pixel of their row (so the census of covered pixels near the edge sees no step).
    pub image: GreyImage,
    /// Per pixel: covered by the photo.
    pub valid: Vec<bool>,
    /// Rectified row of the window's first row.
    pub first_row: usize,
}

/// A prior band of disparities over the left rectified image on a grid of nodes every
/// `step` pixels: node (i, j) holds the band at pixel (i·step, j·step); a pixel's band is
/// the hull of the four nodes around it. NaN marks a node without a prior.
///
/// `surface_min` / `surface_max` hold, per node, the hull of the prior surface's own
/// disparities (no margin) over the node's cell of `step × step` pixels to its lower right
/// (NaN: none known, e.g. a plane prior).
#[derive(Debug, Clone, PartialEq)]
pub struct BandGrid {
    pub step: usize,
    pub cols: usize,
    pub rows: usize,
    pub min: Vec<f32>,
    pub max: Vec<f32>,
    pub surface_min: Vec<f32>,
    pub surface_max: Vec<f32>,
}

impl BandGrid {
    /// A grid of `cols × rows` nodes without a prior (NaN).
    pub fn empty(step: usize, cols: usize, rows: usize) -> Self {
        Self {
            step: step.max(1),
            cols,
            rows,
            min: vec![f32::NAN; cols * rows],
            max: vec![f32::NAN; cols * rows],
            surface_min: vec![f32::NAN; cols * rows],
            surface_max: vec![f32::NAN; cols * rows],
        }
    }

    /// The grid that covers an image of `width × height` pixels.
    pub fn covering(step: usize, width: usize, height: usize) -> Self {
        let step = step.max(1);
        Self::empty(step, width.div_ceil(step) + 1, height.div_ceil(step) + 1)
    }

    /// Band of left rectified pixel (col, row): the hull of those of its four nodes that
    /// have a prior (at the edge of a prior surface, the nodes on it); `None` where none
    /// has or the pixel is beyond the grid.
    pub fn band_at(&self, col: usize, row: usize) -> Option<(f32, f32)> {
        let (i, j) = (col / self.step, row / self.step);
        if i >= self.cols || j >= self.rows {
            return None;
        }
        let (i1, j1) = ((i + 1).min(self.cols - 1), (j + 1).min(self.rows - 1));
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for (a, b) in [(i, j), (i1, j), (i, j1), (i1, j1)] {
            let k = b * self.cols + a;
            let (l, h) = (self.min[k], self.max[k]);
            if l.is_finite() && h.is_finite() {
                lo = lo.min(l);
                hi = hi.max(h);
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// Hull of the prior surface's disparities in the node cell of left rectified pixel
    /// (col, row); `None` where none is known.
    pub fn surface_at(&self, col: usize, row: usize) -> Option<(f32, f32)> {
        let (i, j) = (col / self.step, row / self.step);
        if i >= self.cols || j >= self.rows {
            return None;
        }
        let k = j * self.cols + i;
        let (lo, hi) = (self.surface_min[k], self.surface_max[k]);
        (lo <= hi).then_some((lo, hi))
    }
}

/// Samples along the border of each photo to bound its rectified image.
const BORDER_SAMPLES: usize = 64;
/// A rectified view may cover at most this many times its photo's pixels (a pair whose
/// epipole lies near a photo stretches towards infinity instead).
const MAX_AREA_RATIO: f64 = 4.0;

impl RectifiedPair {
    /// Rectifies the pair `left`, `right` (camera and exterior orientation of each).
    /// Fails when the centres coincide, the baseline runs along the viewing direction or
    /// a photo's rays leave the rectified cameras' front (epipole inside a photo).
    pub fn new(left: (&Camera, &Pose), right: (&Camera, &Pose)) -> Result<Self> {
        for (cam, pose, side) in [(left.0, left.1, "left"), (right.0, right.1, "right")] {
            cam.validate()?;
            pose.validate(1e-6)
                .map_err(|e| invalid(side, e.to_string()))?;
        }
        let base = right.1.center - left.1.center;
        let b = base.norm();
        if b.is_nan() || b <= 0.0 {
            return Err(DenseError::Rectification(
                "the two projection centres coincide".into(),
            ));
        }
        let e1 = base / b;
        let k: Vector3<f64> =
            left.1.rotation.row(2).transpose() + right.1.rotation.row(2).transpose();
        let e2 = k.cross(&e1);
        if e2.norm() < 1e-3 * k.norm() {
            return Err(DenseError::Rectification(
                "the baseline runs along the viewing direction".into(),
            ));
        }
        let e2 = e2.normalize();
        let e3 = e1.cross(&e2);
        let rotation = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
        let f = 0.5 * (left.0.focal_px() + right.0.focal_px());
        let extent = |cam: &Camera, pose: &Pose, side: &str| -> Result<[f64; 4]> {
            let to_rect = rotation * pose.rotation.transpose();
            let (w, h) = cam.image_size();
            let (w, h) = (w as f64, h as f64);
            let mut e = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            for s in 0..BORDER_SAMPLES {
                let t = s as f64 / BORDER_SAMPLES as f64;
                for px in [[t * w, 0.0], [w, t * h], [w - t * w, h], [0.0, h - t * h]] {
                    let v = to_rect * cam.unproject(px)?;
                    if v.z < 0.05 {
                        return Err(DenseError::Rectification(format!(
                            "the {side} photo's pixel ({:.0}, {:.0}) looks away from the \
                             rectified cameras (the epipole lies in or near the photo)",
                            px[0], px[1]
                        )));
                    }
                    let (x, y) = (f * v.x / v.z, f * v.y / v.z);
                    e = [e[0].min(x), e[1].min(y), e[2].max(x), e[3].max(y)];
                }
            }
            Ok(e)
        };
        let el = extent(left.0, left.1, "left")?;
        let er = extent(right.0, right.1, "right")?;
        let (y0, y1) = (el[1].max(er[1]), el[3].min(er[3]));
        if y1 - y0 < 1.0 {
            return Err(DenseError::Rectification(
                "the photos share no rectified rows (they do not overlap)".into(),
            ));
        }
        let cy = -y0.floor();
        let height = (y1.ceil() + cy) as usize;
        let view = |cam: &Camera, pose: &Pose, e: [f64; 4], side: &str| -> Result<RectifiedView> {
            let cx = -e[0].floor();
            let width = (e[2].ceil() + cx) as usize;
            let (w, h) = cam.image_size();
            if (width * height) as f64 > MAX_AREA_RATIO * (w as f64 * h as f64) {
                return Err(DenseError::Rectification(format!(
                    "the {side} rectified image would be {width}×{height} px for a {w}×{h} px \
                     photo (the pair is too convergent or its epipole lies near the photo)"
                )));
            }
            Ok(RectifiedView {
                width,
                cx,
                center: pose.center,
                source: cam.clone(),
                source_pose: *pose,
                to_source: pose.rotation * rotation.transpose(),
            })
        };
        Ok(Self {
            rotation,
            focal_px: f,
            cy,
            height,
            left: view(left.0, left.1, el, "left")?,
            right: view(right.0, right.1, er, "right")?,
        })
    }

    pub fn view(&self, side: Side) -> &RectifiedView {
        match side {
            Side::Left => &self.left,
            Side::Right => &self.right,
        }
    }

    /// Length of the baseline (object units).
    pub fn baseline(&self) -> f64 {
        (self.right.center - self.left.center).norm()
    }

    /// The rectified view as a distortion-free frame camera and its exterior orientation.
    pub fn camera(&self, side: Side) -> (Camera, Pose) {
        let v = self.view(side);
        (
            Camera::Frame(FrameCamera {
                width: v.width as u32,
                height: self.height as u32,
                fx: self.focal_px,
                fy: self.focal_px,
                cx: v.cx,
                cy: self.cy,
                distortion: Brown::default(),
            }),
            Pose::new(self.rotation, v.center),
        )
    }

    /// Photo pixel position of a rectified position (both corner origin); `None` behind
    /// the photo's camera.
    pub fn to_source(&self, side: Side, p: [f64; 2]) -> Option<[f64; 2]> {
        let v = self.view(side);
        let d = Vector3::new(
            (p[0] - v.cx) / self.focal_px,
            (p[1] - self.cy) / self.focal_px,
            1.0,
        );
        let s = v.source.project(&(v.to_source * d)).ok()?;
        Some([s.x, s.y])
    }

    /// Rectified position of a photo pixel position (distortion removed).
    pub fn from_source(&self, side: Side, p: [f64; 2]) -> Result<[f64; 2]> {
        let v = self.view(side);
        let r = v.to_source.transpose() * v.source.unproject(p)?;
        if r.z.is_nan() || r.z <= 0.0 {
            return Err(DenseError::Rectification(format!(
                "photo pixel ({:.2}, {:.2}) looks away from the rectified camera",
                p[0], p[1]
            )));
        }
        Ok([
            self.focal_px * r.x / r.z + v.cx,
            self.focal_px * r.y / r.z + self.cy,
        ])
    }

    /// Rectified position of an object point in a view; `None` behind it.
    pub fn project(&self, side: Side, x: &Vector3<f64>) -> Option<[f64; 2]> {
        let v = self.view(side);
        let c = self.rotation * (x - v.center);
        (c.z > 0.0).then(|| {
            [
                self.focal_px * c.x / c.z + v.cx,
                self.focal_px * c.y / c.z + self.cy,
            ]
        })
    }

    /// Left rectified position and disparity of an object point.
    pub fn disparity_of(&self, x: &Vector3<f64>) -> Option<([f64; 2], f64)> {
        let l = self.project(Side::Left, x)?;
        let r = self.project(Side::Right, x)?;
        Some((l, l[0] - r[0]))
    }

    /// Object point of left rectified position `left` matched at disparity `d` (right
    /// position `left[0] − d` on the same row). The two rays lie in one epipolar plane, so
    /// they meet exactly; `None` when they meet behind the cameras or are parallel.
    pub fn triangulate(&self, left: [f64; 2], d: f64) -> Option<Vector3<f64>> {
        let f = self.focal_px;
        let denom = d + self.right.cx - self.left.cx;
        if denom.is_nan() || denom <= 0.0 {
            return None;
        }
        let z = f * self.baseline() / denom;
        let ray = Vector3::new((left[0] - self.left.cx) / f, (left[1] - self.cy) / f, 1.0);
        Some(self.left.center + self.rotation.transpose() * (ray * z))
    }

    /// Photo pixels `[col, row, width, height]` that the rectified rows `rows` of a view
    /// are rendered from (with a margin for the bilinear support), clipped to the photo;
    /// `None` when they do not meet it.
    pub fn source_window(&self, side: Side, rows: Range<usize>) -> Option<[usize; 4]> {
        let v = self.view(side);
        let (sw, sh) = v.source.image_size();
        let (w, r0, r1) = (v.width as f64, rows.start as f64, rows.end as f64);
        let mut e = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let n = BORDER_SAMPLES;
        for s in 0..=n {
            let t = s as f64 / n as f64;
            for p in [
                [t * w, r0],
                [t * w, r1],
                [0.0, r0 + t * (r1 - r0)],
                [w, r0 + t * (r1 - r0)],
            ] {
                if let Some(q) = self.to_source(side, p) {
                    e = [
                        e[0].min(q[0]),
                        e[1].min(q[1]),
                        e[2].max(q[0]),
                        e[3].max(q[1]),
                    ];
                }
            }
        }
        let c0 = (e[0] - 3.0).floor().max(0.0);
        let q0 = (e[1] - 3.0).floor().max(0.0);
        let c1 = (e[2] + 3.0).ceil().min(sw as f64);
        let q1 = (e[3] + 3.0).ceil().min(sh as f64);
        (c1 > c0 && q1 > q0).then_some([
            c0 as usize,
            q0 as usize,
            (c1 - c0) as usize,
            (q1 - q0) as usize,
        ])
    }

    /// Renders rectified rows `rows` of a view by inverse mapping with bilinear
    /// interpolation from `source`, a window of the view's photo whose top-left pixel is
    /// photo pixel `origin` (the whole photo with `[0, 0]`).
    pub fn render_rows(
        &self,
        side: Side,
        source: &GreyImage,
        origin: [usize; 2],
        rows: Range<usize>,
    ) -> Result<RectifiedImage> {
        if rows.start >= rows.end || rows.end > self.height {
            return Err(invalid(
                "rectified rows",
                format!(
                    "{}..{} is empty or beyond the {} rows of the pair",
                    rows.start, rows.end, self.height
                ),
            ));
        }
        let v = self.view(side);
        let (w, h) = (v.width, rows.len());
        let f = self.focal_px;
        let (ox, oy) = (origin[0] as f64, origin[1] as f64);
        let mut data = vec![0.0f32; w * h];
        let mut valid = vec![false; w * h];
        data.par_chunks_mut(w)
            .zip(valid.par_chunks_mut(w))
            .enumerate()
            .for_each(|(i, (out, ok))| {
                let row = (rows.start + i) as f64 + 0.5;
                // The ray of column u is linear in u: start + u·step.
                let start = v.to_source * Vector3::new((0.5 - v.cx) / f, (row - self.cy) / f, 1.0);
                let step = v.to_source * Vector3::new(1.0 / f, 0.0, 0.0);
                for (col, (o, k)) in out.iter_mut().zip(ok.iter_mut()).enumerate() {
                    let d = start + step * col as f64;
                    if let Ok(p) = v.source.project(&d) {
                        if let Some(g) = bilinear(source, p.x - ox, p.y - oy) {
                            *o = g as f32;
                            *k = true;
                        }
                    }
                }
                fill_row(out, ok);
            });
        Ok(RectifiedImage {
            image: GreyImage {
                width: w,
                height: h,
                data,
            },
            valid,
            first_row: rows.start,
        })
    }

    /// A prior band of disparities from a surface (in the pair's coordinates): every
    /// `step` pixels of the left view, the ray meets `surface` and the band holds the
    /// disparities of the ray's points `margin` (object units, vertical) above and below
    /// that intersection. Nodes whose ray misses the surface have no prior (NaN).
    pub fn band_from_surface(&self, surface: &Surface, margin: f64, step: usize) -> BandGrid {
        let mut grid = BandGrid::covering(step, self.left.width, self.height);
        let f = self.focal_px;
        let cols = grid.cols;
        let nodes: Vec<(f32, f32)> = (0..grid.cols * grid.rows)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % cols, k / cols);
                let u = (i * grid.step) as f64 + 0.5;
                let r = (j * grid.step) as f64 + 0.5;
                let d = self.rotation.transpose()
                    * Vector3::new((u - self.left.cx) / f, (r - self.cy) / f, 1.0);
                let ray = Ray {
                    origin: self.left.center,
                    direction: d.normalize(),
                };
                let Some(p) = surface.intersect(&ray) else {
                    return (f32::NAN, f32::NAN);
                };
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for z in [p.z - margin, p.z + margin] {
                    let t = (z - ray.origin.z) / ray.direction.z;
                    if t.is_nan() || t <= 0.0 {
                        continue;
                    }
                    if let Some((_, disp)) = self.disparity_of(&ray.at(t)) {
                        lo = lo.min(disp);
                        hi = hi.max(disp);
                    }
                }
                if lo <= hi {
                    (lo as f32, hi as f32)
                } else {
                    (f32::NAN, f32::NAN)
                }
            })
            .collect();
        for (k, (lo, hi)) in nodes.into_iter().enumerate() {
            grid.min[k] = lo;
            grid.max[k] = hi;
        }
        if let Surface::Dem { dem, origin, .. } = surface {
            self.splat_surface(dem, origin, &mut grid);
        }
        grid
    }

    /// Fills the grid's surface hulls from a DEM (heights in world less `origin`): every
    /// cell's centre projected into the left rectified view, its disparity kept in the
    /// node whose cell it falls in. A roof narrower than a coarse pyramid level's census
    /// window is matched there at the ground's disparity, and the finer levels, searching
    /// around the coarser one's disparities, would never reach it; the prior knows it.
    /// Cells the left view does not see (behind a roof) widen a hull a little, never narrow it.
    fn splat_surface(&self, dem: &Dem, origin: &Vector3<f64>, grid: &mut BandGrid) {
        let (cols, rows, step) = (grid.cols, grid.rows, grid.step as f64);
        let (w, h) = (self.left.width as f64, self.height as f64);
        let n = cols * rows;
        let empty = || (vec![f32::INFINITY; n], vec![f32::NEG_INFINITY; n]);
        let (lo, hi) = (0..dem.height)
            .into_par_iter()
            .fold(empty, |(mut lo, mut hi), r| {
                for c in 0..dem.width {
                    let z = dem.data[r * dem.width + c];
                    if !z.is_finite() {
                        continue;
                    }
                    let (x, y) = dem.transform.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                    let p = Vector3::new(x, y, z as f64) - origin;
                    let Some(([u, v], d)) = self.disparity_of(&p) else {
                        continue;
                    };
                    if !(u >= 0.0 && u < w && v >= 0.0 && v < h && d.is_finite()) {
                        continue;
                    }
                    let k = (v / step) as usize * cols + (u / step) as usize;
                    lo[k] = lo[k].min(d as f32);
                    hi[k] = hi[k].max(d as f32);
                }
                (lo, hi)
            })
            .reduce(empty, |(mut a, mut b), (c, d)| {
                for k in 0..n {
                    a[k] = a[k].min(c[k]);
                    b[k] = b[k].max(d[k]);
                }
                (a, b)
            });
        for k in 0..n {
            if lo[k] <= hi[k] {
                grid.surface_min[k] = lo[k];
                grid.surface_max[k] = hi[k];
            }
        }
    }
}

/// Pixels of a row without data take the value of the nearest pixel with data.
fn fill_row(values: &mut [f32], valid: &[bool]) {
    let Some(first) = valid.iter().position(|&v| v) else {
        return;
    };
    let first_value = values[first];
    values[..first].fill(first_value);
    let mut last = first_value;
    let mut gap_start: Option<usize> = None;
    for i in first..values.len() {
        if valid[i] {
            if let Some(s) = gap_start.take() {
                // Nearest of the two ends of the gap.
                let mid = (s + i).div_ceil(2);
                values[s..mid].fill(last);
                let v = values[i];
                values[mid..i].fill(v);
            }
            last = values[i];
        } else if gap_start.is_none() {
            gap_start = Some(i);
        }
    }
    if let Some(s) = gap_start {
        values[s..].fill(last);
    }
}
