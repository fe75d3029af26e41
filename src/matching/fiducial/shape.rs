//! Fiducial mark shapes and their templates: primitives (cross, circle, ring, dot), the
//! composites cameras actually have (a crosshair in a ring with a central dot, a cross
//! whose bars stop short of the centre), and image templates cut from real marks.

use super::camera::MAX_TEMPLATE_PIXELS;
use crate::matching::resample::bilinear;
use crate::matching::GreyImage;
use nalgebra::{Matrix2, Vector2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// Two bars of length `size_mm` and width `line_mm`.
    Cross,
    /// Filled disc of diameter `size_mm`.
    Circle,
    /// Annulus of outer diameter `size_mm` and width `line_mm`.
    Ring,
    /// Small filled disc of diameter `size_mm`.
    Dot,
    /// An image of the real mark (`file`, `pixel_mm`, `centre_px`).
    Template,
}

/// A fiducial mark: a primitive with optional composite parts (central dot, surrounding
/// ring, central gap of a cross), or an image template.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FiducialShape {
    #[serde(rename = "type")]
    pub kind: ShapeKind,
    /// Cross span, disc or ring outer diameter (mm); unused by a template.
    #[serde(default)]
    pub size_mm: f64,
    #[serde(default)]
    pub line_mm: f64,
    /// Optional central dot (diameter, mm) inside a cross, ring or circle outline.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dot_mm: Option<f64>,
    /// Optional ring added around the mark: its outer diameter (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ring_mm: Option<f64>,
    /// Width of that ring (mm); `line_mm` when left out.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ring_line_mm: Option<f64>,
    /// Cross only: the bars stop this diameter short of the centre (mm), an open
    /// crosshair.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gap_mm: Option<f64>,
    /// Template only: image file of the mark, relative to the camera JSON's folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Template only: the template's pixel size (mm) on the film.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_mm: Option<f64>,
    /// Template only: the mark's calibrated point in the template (pixels, origin at the
    /// top-left corner of the image); the image centre when left out.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centre_px: Option<[f64; 2]>,
    /// Template only: the image read from `file` by `CameraDefinition::load`.
    #[serde(skip)]
    pub image: Option<Arc<GreyImage>>,
}

impl FiducialShape {
    /// A primitive of `size_mm` with line width `line_mm` and no composite parts.
    pub fn primitive(kind: ShapeKind, size_mm: f64, line_mm: f64) -> Self {
        Self {
            kind,
            size_mm,
            line_mm,
            dot_mm: None,
            ring_mm: None,
            ring_line_mm: None,
            gap_mm: None,
            file: None,
            pixel_mm: None,
            centre_px: None,
            image: None,
        }
    }

    /// Whether a point (mm, relative to the mark centre) is on the mark (primitives and
    /// composites; a template covers nothing: it is drawn from its image).
    pub fn covers(&self, x: f64, y: f64) -> bool {
        let r = (x * x + y * y).sqrt();
        if let Some(d) = self.dot_mm {
            if r <= d / 2.0 {
                return true;
            }
        }
        if let Some(d) = self.ring_mm {
            let w = self.ring_line_mm.unwrap_or(self.line_mm);
            if r <= d / 2.0 && r >= d / 2.0 - w {
                return true;
            }
        }
        let (s, l) = (self.size_mm / 2.0, self.line_mm.max(0.0) / 2.0);
        match self.kind {
            ShapeKind::Cross => {
                let g = self.gap_mm.unwrap_or(0.0) / 2.0;
                (x.abs() <= s && x.abs() >= g && y.abs() <= l)
                    || (y.abs() <= s && y.abs() >= g && x.abs() <= l)
            }
            ShapeKind::Circle | ShapeKind::Dot => r <= s,
            ShapeKind::Ring => r <= s && r >= s - self.line_mm,
            ShapeKind::Template => false,
        }
    }

    /// Radius (mm) of the circle that contains the mark.
    pub fn extent_mm(&self) -> f64 {
        let base = match self.kind {
            ShapeKind::Cross => (self.size_mm / 2.0).hypot(self.line_mm / 2.0),
            ShapeKind::Template => match (&self.image, self.pixel_mm) {
                (Some(img), Some(p)) => {
                    let [cx, cy] = self.template_centre(img);
                    let dx = cx.max(img.width as f64 - cx);
                    let dy = cy.max(img.height as f64 - cy);
                    dx.hypot(dy) * p
                }
                _ => 0.0,
            },
            _ => self.size_mm / 2.0,
        };
        base.max(self.ring_mm.unwrap_or(0.0) / 2.0)
            .max(self.dot_mm.unwrap_or(0.0) / 2.0)
    }

    /// Upper bound of the pixels of this mark's template drawn at a scan pixel of at least
    /// `pixel_mm` (a primitive within a `margin_mm` border, an image template over its
    /// crop), before it is drawn ([`render_template`]).
    pub(super) fn template_pixels_bound(&self, pixel_mm: f64, margin_mm: f64) -> f64 {
        match (self.kind, &self.image, self.pixel_mm) {
            (ShapeKind::Template, Some(img), Some(tp)) => {
                (img.width as f64 * tp / pixel_mm + 3.0) * (img.height as f64 * tp / pixel_mm + 3.0)
            }
            (ShapeKind::Template, ..) => 0.0,
            _ => (2.0 * ((self.extent_mm() + margin_mm) / pixel_mm).ceil() + 1.0).powi(2),
        }
    }

    fn template_centre(&self, img: &GreyImage) -> [f64; 2] {
        self.centre_px
            .unwrap_or([img.width as f64 / 2.0, img.height as f64 / 2.0])
    }

    /// Identity of the rendered template (cache key).
    pub(super) fn key(&self) -> String {
        format!(
            "{:?}/{}/{}/{:?}/{:?}/{:?}/{:?}/{:?}/{:?}/{:?}",
            self.kind,
            self.size_mm,
            self.line_mm,
            self.dot_mm,
            self.ring_mm,
            self.ring_line_mm,
            self.gap_mm,
            self.file,
            self.pixel_mm,
            self.centre_px
        )
    }

    pub(super) fn validate(&self) -> std::result::Result<(), String> {
        let positive = |what: &str, v: Option<f64>| match v {
            Some(v) if !(v.is_finite() && v > 0.0) => {
                Err(format!("{what} {v} must be a positive length"))
            }
            _ => Ok(()),
        };
        positive("dot_mm", self.dot_mm)?;
        positive("ring_mm", self.ring_mm)?;
        positive("ring_line_mm", self.ring_line_mm)?;
        positive("gap_mm", self.gap_mm)?;
        if self.kind == ShapeKind::Template {
            if self.file.as_deref().is_none_or(str::is_empty) {
                return Err("template needs its image `file`".into());
            }
            return match self.pixel_mm {
                Some(p) if p.is_finite() && p > 0.0 && p < 1.0 => Ok(()),
                p => Err(format!(
                    "template needs `pixel_mm`, the template's pixel on the film (0–1 mm), \
                     got {p:?}"
                )),
            };
        }
        if self.size_mm.is_nan() || self.size_mm <= 0.0 {
            return Err("size_mm must be positive".into());
        }
        if matches!(self.kind, ShapeKind::Cross | ShapeKind::Ring)
            && (self.line_mm.is_nan() || self.line_mm <= 0.0)
        {
            return Err(format!("{:?} needs line_mm > 0", self.kind));
        }
        if let Some(d) = self.ring_mm {
            let w = self.ring_line_mm.unwrap_or(self.line_mm);
            if !(w > 0.0 && w <= d / 2.0) {
                return Err(format!(
                    "ring of {d} mm needs a line width (ring_line_mm or line_mm) in (0, {}] mm, \
                     got {w}",
                    d / 2.0
                ));
            }
        }
        if let Some(g) = self.gap_mm {
            if self.kind != ShapeKind::Cross || g >= self.size_mm {
                return Err(format!(
                    "gap_mm {g}: a central gap belongs to a cross and must be shorter than \
                     its size_mm {}",
                    self.size_mm
                ));
            }
        }
        Ok(())
    }
}

/// Renders a mark as a template, `lin` mapping a pixel offset to an mm offset: a
/// primitive as mark 1 on background 0, anti-aliased by 4×4 supersampling, within a
/// `margin_mm` border; a template image resampled into the scan's geometry (its own
/// extent, no border). Width and height are odd, the mark centre at the middle.
/// `None` for a template whose image is not loaded, and for one of more than
/// [`MAX_TEMPLATE_PIXELS`] (a mark large for the scan's pixel: nothing is drawn).
pub fn render_template(
    shape: &FiducialShape,
    lin: &Matrix2<f64>,
    margin_mm: f64,
) -> Option<GreyImage> {
    let s = (lin.determinant().abs()).sqrt();
    if shape.kind == ShapeKind::Template {
        return render_image_template(shape, lin);
    }
    let half = ((shape.extent_mm() + margin_mm) / s).ceil();
    let pixels = (2.0 * half + 1.0).powi(2);
    if pixels.is_nan() || pixels > MAX_TEMPLATE_PIXELS as f64 {
        return None;
    }
    let n = 2 * half as usize + 1;
    let c = n as f64 / 2.0;
    // Nothing of the mark lies beyond its extent along either axis: the samples there
    // (half the template, its border) skip the shape's test.
    let reach = shape.extent_mm() * (1.0 + 1e-9);
    Some(from_fn_rows(n, n, |x, y| {
        let mut hit = 0;
        for sy in 0..4 {
            for sx in 0..4 {
                let dx = x - 0.5 + (sx as f64 + 0.5) / 4.0 - c;
                let dy = y - 0.5 + (sy as f64 + 0.5) / 4.0 - c;
                let mm = lin * Vector2::new(dx, dy);
                if mm.x.abs() <= reach && mm.y.abs() <= reach && shape.covers(mm.x, mm.y) {
                    hit += 1;
                }
            }
        }
        hit as f64 / 16.0
    }))
}

/// [`GreyImage::from_fn`] with its rows in parallel (each alone: the same values): a
/// template at a fine scan pixel is 10⁵ pixels of 16 samples, drawn 18 times a scan.
fn from_fn_rows(width: usize, height: usize, f: impl Fn(f64, f64) -> f64 + Sync) -> GreyImage {
    let mut data = vec![0f32; width * height];
    data.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
        for (c, v) in row.iter_mut().enumerate() {
            *v = f(c as f64 + 0.5, r as f64 + 0.5) as f32;
        }
    });
    GreyImage {
        width,
        height,
        data,
    }
}

/// The template image seen through `lin`: the crop's rectangle mapped into scan pixels,
/// trimmed to what the crop covers (a rotated or sheared crop leaves no blank corners
/// larger than the scan's shear).
fn render_image_template(shape: &FiducialShape, lin: &Matrix2<f64>) -> Option<GreyImage> {
    let img = shape.image.as_deref()?;
    let tp = shape.pixel_mm?;
    let inv = lin.try_inverse()?;
    let [cx, cy] = shape.template_centre(img);
    // Template pixel (u, v) ↔ mm offset ((u − cx)·tp, −(v − cy)·tp): columns along +x,
    // rows down the film's y.
    let (mut hx, mut hy) = (f64::INFINITY, f64::INFINITY);
    for (u, v) in [
        (0.0, 0.0),
        (img.width as f64, 0.0),
        (0.0, img.height as f64),
        (img.width as f64, img.height as f64),
    ] {
        let p = inv * Vector2::new((u - cx) * tp, -(v - cy) * tp);
        // The largest centred box inside the mapped crop, per axis.
        hx = hx.min(p.x.abs());
        hy = hy.min(p.y.abs());
    }
    let (hw, hh) = ((hx - 1.0).floor(), (hy - 1.0).floor());
    if !(hw >= 2.0
        && hh >= 2.0
        && (2.0 * hw + 1.0) * (2.0 * hh + 1.0) <= MAX_TEMPLATE_PIXELS as f64)
    {
        return None;
    }
    let (w, h) = (2 * hw as usize + 1, 2 * hh as usize + 1);
    let (c_x, c_y) = (w as f64 / 2.0, h as f64 / 2.0);
    let clamp = |v: f64, n: usize| v.clamp(0.5, n as f64 - 0.5);
    // A scan pixel coarser than the template's averages k×k samples (no aliasing).
    let k = ((lin.determinant().abs().sqrt() / tp).ceil() as usize).clamp(1, 6);
    Some(from_fn_rows(w, h, |x, y| {
        let mut sum = 0.0;
        for sy in 0..k {
            for sx in 0..k {
                let d = Vector2::new(
                    x - 0.5 + (sx as f64 + 0.5) / k as f64 - c_x,
                    y - 0.5 + (sy as f64 + 0.5) / k as f64 - c_y,
                );
                let mm = lin * d;
                let u = clamp(cx + mm.x / tp, img.width);
                let v = clamp(cy - mm.y / tp, img.height);
                sum += bilinear(img, u, v).unwrap_or(0.0);
            }
        }
        sum / (k * k) as f64
    }))
}
