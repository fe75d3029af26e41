//! Raster digital elevation models and the intersection of image rays with them.

use super::{GeometryError, Ray, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// GDAL geotransform `[x0, dx, rx, y0, ry, dy]`: `X = x0 + col·dx + row·rx`,
/// `Y = y0 + col·ry + row·dy`, (col, row) at pixel corners. Our grids are north-up
/// (rx = ry = 0, dy < 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeoTransform(pub [f64; 6]);

impl GeoTransform {
    /// North-up transform from the top-left corner and the cell size.
    pub fn north_up(x_min: f64, y_max: f64, cell: f64) -> Self {
        Self([x_min, cell, 0.0, y_max, 0.0, -cell])
    }

    pub fn is_north_up(&self) -> bool {
        self.0[2] == 0.0 && self.0[4] == 0.0 && self.0[1] > 0.0 && self.0[5] < 0.0
    }

    /// World coordinates of a (fractional) pixel position measured from the top-left corner.
    pub fn pixel_to_world(&self, col: f64, row: f64) -> (f64, f64) {
        let g = &self.0;
        (
            g[0] + col * g[1] + row * g[2],
            g[3] + col * g[4] + row * g[5],
        )
    }

    /// Fractional pixel position (from the top-left corner) of world coordinates; north-up only.
    pub fn world_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        let g = &self.0;
        ((x - g[0]) / g[1], (y - g[3]) / g[5])
    }
}

/// Heights on a north-up grid; a value is the height at its cell's centre (GDAL's
/// PixelIsArea), NaN where there is no data. Heights are interpolated bilinearly.
#[derive(Debug, Clone, PartialEq)]
pub struct Dem {
    pub width: usize,
    pub height: usize,
    pub transform: GeoTransform,
    /// Row-major heights, NaN for no data.
    pub data: Vec<f32>,
    z_min: f64,
    z_max: f64,
}

impl Dem {
    /// The same DEM in a frame whose origin is at `origin` of this one (world → block
    /// local with the block origin; block local → world with its negation).
    pub fn shifted(&self, origin: [f64; 3]) -> Result<Self> {
        let t = self.transform.0;
        let tr = GeoTransform([t[0] - origin[0], t[1], t[2], t[3] - origin[1], t[4], t[5]]);
        let data = self
            .data
            .iter()
            .map(|v| (*v as f64 - origin[2]) as f32)
            .collect();
        Self::new(self.width, self.height, tr, data)
    }

    pub fn new(
        width: usize,
        height: usize,
        transform: GeoTransform,
        data: Vec<f32>,
    ) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(GeometryError::InvalidArgument(format!(
                "DEM size {width}×{height} is empty"
            )));
        }
        if data.len() != width * height {
            return Err(GeometryError::InvalidArgument(format!(
                "DEM of {width}×{height} cells needs {} values, got {}",
                width * height,
                data.len()
            )));
        }
        if !transform.is_north_up() {
            return Err(GeometryError::InvalidArgument(
                "DEM geotransform must be north-up (no rotation terms, negative dy)".into(),
            ));
        }
        let (mut z_min, mut z_max) = (f64::INFINITY, f64::NEG_INFINITY);
        for &v in data.iter().filter(|v| v.is_finite()) {
            z_min = z_min.min(v as f64);
            z_max = z_max.max(v as f64);
        }
        if !z_min.is_finite() {
            return Err(GeometryError::InvalidArgument(
                "DEM holds no valid height".into(),
            ));
        }
        Ok(Self {
            width,
            height,
            transform,
            data,
            z_min,
            z_max,
        })
    }

    /// Samples `f(x, y)` at the cell centres of a north-up grid.
    pub fn from_fn(
        x_min: f64,
        y_max: f64,
        cell: f64,
        width: usize,
        height: usize,
        f: impl Fn(f64, f64) -> f64,
    ) -> Result<Self> {
        let t = GeoTransform::north_up(x_min, y_max, cell);
        let mut data = Vec::with_capacity(width * height);
        for r in 0..height {
            for c in 0..width {
                let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                data.push(f(x, y) as f32);
            }
        }
        Self::new(width, height, t, data)
    }

    pub fn cell_size(&self) -> f64 {
        self.transform.0[1].min(-self.transform.0[5])
    }

    pub fn z_range(&self) -> (f64, f64) {
        (self.z_min, self.z_max)
    }

    /// Plan extent `(x_min, y_min, x_max, y_max)`.
    pub fn extent(&self) -> (f64, f64, f64, f64) {
        let (x0, y1) = self.transform.pixel_to_world(0.0, 0.0);
        let (x1, y0) = self
            .transform
            .pixel_to_world(self.width as f64, self.height as f64);
        (x0, y0, x1, y1)
    }

    #[inline]
    fn at(&self, col: usize, row: usize) -> f64 {
        self.data[row * self.width + col] as f64
    }

    /// Bilinearly interpolated height, `None` outside the grid or next to a hole.
    pub fn height_at(&self, x: f64, y: f64) -> Option<f64> {
        let (c, r) = self.transform.world_to_pixel(x, y);
        if !(c >= 0.0 && r >= 0.0 && c <= self.width as f64 && r <= self.height as f64) {
            return None;
        }
        let fc = (c - 0.5).clamp(0.0, (self.width - 1) as f64);
        let fr = (r - 0.5).clamp(0.0, (self.height - 1) as f64);
        let c0 = (fc.floor() as usize).min(self.width.saturating_sub(2));
        let r0 = (fr.floor() as usize).min(self.height.saturating_sub(2));
        let c1 = (c0 + 1).min(self.width - 1);
        let r1 = (r0 + 1).min(self.height - 1);
        let (u, v) = (fc - c0 as f64, fr - r0 as f64);
        let h = (1.0 - v) * ((1.0 - u) * self.at(c0, r0) + u * self.at(c1, r0))
            + v * ((1.0 - u) * self.at(c0, r1) + u * self.at(c1, r1));
        h.is_finite().then_some(h)
    }

    /// First intersection of a ray with the surface, marching along the ray in half-cell
    /// steps (so ridges between the camera and the ground occlude, as they should) and then
    /// bracketing the crossing by regula falsi. Bounded: fails rather than loops.
    pub fn intersect(&self, ray: &Ray) -> Result<Vector3<f64>> {
        let d = ray.direction;
        if !ray.origin.iter().chain(d.iter()).all(|v| v.is_finite()) || d.norm() == 0.0 {
            return Err(GeometryError::NotFinite { what: "ray".into() });
        }
        let d = d.normalize();
        let o = ray.origin;
        // Segment of the ray inside the DEM's height range and plan extent.
        let (mut t0, mut t1) = (0.0_f64, f64::INFINITY);
        let slab = |t0: &mut f64, t1: &mut f64, o: f64, d: f64, lo: f64, hi: f64| -> bool {
            if d.abs() < 1e-15 {
                return o >= lo && o <= hi;
            }
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            *t0 = t0.max(a.min(b));
            *t1 = t1.min(a.max(b));
            *t0 <= *t1
        };
        let (x_min, y_min, x_max, y_max) = self.extent();
        let margin = 1e-3;
        let inside = slab(
            &mut t0,
            &mut t1,
            o.z,
            d.z,
            self.z_min - margin,
            self.z_max + margin,
        ) && slab(&mut t0, &mut t1, o.x, d.x, x_min, x_max)
            && slab(&mut t0, &mut t1, o.y, d.y, y_min, y_max);
        if !inside || !t1.is_finite() {
            return Err(GeometryError::NoIntersection(
                "the ray passes outside the DEM's extent or height range".into(),
            ));
        }
        let f = |t: f64| -> Option<f64> {
            let p = o + d * t;
            self.height_at(p.x, p.y).map(|h| p.z - h)
        };
        let horizontal = (d.x * d.x + d.y * d.y).sqrt();
        let step = if horizontal > 1e-12 {
            (0.5 * self.cell_size() / horizontal).min(t1 - t0)
        } else {
            t1 - t0
        };
        let steps = ((t1 - t0) / step).ceil() as usize;
        const MAX_STEPS: usize = 20_000_000;
        if steps > MAX_STEPS {
            return Err(GeometryError::InvalidArgument(format!(
                "ray crosses {steps} DEM cells; more than the {MAX_STEPS} allowed"
            )));
        }
        let mut prev: Option<(f64, f64)> = None;
        for i in 0..=steps {
            let t = (t0 + i as f64 * step).min(t1);
            let Some(ft) = f(t) else {
                prev = None;
                continue;
            };
            if ft <= 0.0 {
                let Some((ta, fa)) = prev else {
                    if i == 0 && ft.abs() < 1e-9 {
                        return Ok(o + d * t);
                    }
                    if i == 0 {
                        return Err(GeometryError::NoIntersection(
                            "the ray starts below the surface".into(),
                        ));
                    }
                    prev = None;
                    continue;
                };
                return self.refine(&f, ta, fa, t, ft).map(|t| o + d * t);
            }
            prev = Some((t, ft));
        }
        Err(GeometryError::NoIntersection(
            "the ray does not reach the surface".into(),
        ))
    }

    /// Illinois regula falsi on a bracket with f(a) > 0 ≥ f(b).
    fn refine(
        &self,
        f: &impl Fn(f64) -> Option<f64>,
        mut a: f64,
        mut fa: f64,
        mut b: f64,
        mut fb: f64,
    ) -> Result<f64> {
        let mut side = 0;
        for _ in 0..200 {
            let t = if fa != fb {
                (a * fb - b * fa) / (fb - fa)
            } else {
                0.5 * (a + b)
            };
            let ft = match f(t) {
                Some(v) => v,
                None => return Ok(b),
            };
            if ft.abs() < 1e-9 || (b - a).abs() < 1e-12 {
                return Ok(t);
            }
            if ft > 0.0 {
                a = t;
                fa = ft;
                if side == 1 {
                    fb *= 0.5;
                }
                side = 1;
            } else {
                b = t;
                fb = ft;
                if side == -1 {
                    fa *= 0.5;
                }
                side = -1;
            }
        }
        Err(GeometryError::NotConverged {
            what: "ray–DEM intersection".into(),
            iterations: 200,
        })
    }
}
