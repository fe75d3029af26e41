//! Camera models: digital frame cameras (pixels, COLMAP/OpenCV-compatible) and film
//! cameras (calibrated in mm, with an interior orientation from scan pixels to fiducial mm).

use super::{check_finite, GeometryError, InteriorOrientation, Result};
use nalgebra::{Matrix2, SMatrix, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Largest number of interior parameters of any model (frame: fx, fy, cx, cy, k1, k2, k3, p1, p2).
pub const MAX_INTRINSICS: usize = 9;

/// Largest image (or scan) side a camera may have, px: a 500 mm film side scanned at
/// 2.5 µm. A camera JSON claiming more is refused when read (formats/cameras/README.md).
pub const MAX_IMAGE_SIDE_PX: u32 = 200_000;

/// A frame camera's focal length in pixels, as multiples of its longer image side: from a
/// field of view of 168° (0.05) to the near-orthographic view of an orthophoto's control
/// points (`control::ortho_source`: a camera thousands of kilometres up, fx/side up to
/// about 1e8).
pub const FOCAL_PX_PER_SIDE: [f64; 2] = [0.05, 1e9];

/// A frame camera's pixel aspect `fy / fx`.
pub const PIXEL_ASPECT: [f64; 2] = [0.1, 10.0];

/// Largest magnitude of a distortion coefficient (k1, k2, k3, p1, p2; normalised
/// coordinates: real lenses stay below 10).
pub const MAX_DISTORTION: f64 = 1000.0;

/// A film camera's calibrated focal length, mm (aerial cameras: 88–610 mm; the range
/// leaves room for any metric camera).
pub const FOCAL_MM: [f64; 2] = [1.0, 5000.0];

/// Largest distance of a film camera's principal point from the fiducial centre, mm (the
/// largest film format's side).
pub const MAX_PRINCIPAL_POINT_MM: f64 = 500.0;

use crate::formats::number_in_message as num;

/// Jacobian of a pixel with respect to the interior parameters; unused columns are zero.
pub type IntrinsicsJacobian = SMatrix<f64, 2, MAX_INTRINSICS>;

/// Brown–Conrady distortion in normalised image coordinates, OpenCV/COLMAP convention:
/// `p1` multiplies `2xy` in x and `r² + 2y²` in y.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Brown {
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub p1: f64,
    pub p2: f64,
}

impl Brown {
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.k3 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0
    }

    pub fn as_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.k3, self.p1, self.p2]
    }

    pub fn from_array(a: [f64; 5]) -> Self {
        Self {
            k1: a[0],
            k2: a[1],
            k3: a[2],
            p1: a[3],
            p2: a[4],
        }
    }

    /// Distorted normalised coordinates of undistorted ones.
    #[inline]
    pub fn distort(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// ∂(distorted)/∂(undistorted).
    #[inline]
    pub fn jacobian_point(&self, p: Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let dr = self.k1 + 2.0 * self.k2 * r2 + 3.0 * self.k3 * r2 * r2;
        let cross = 2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            cross,
            cross,
            radial + 2.0 * y * y * dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        )
    }

    /// ∂(distorted)/∂(k1, k2, k3, p1, p2).
    #[inline]
    pub fn jacobian_coefficients(&self, p: Vector2<f64>) -> SMatrix<f64, 2, 5> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        SMatrix::<f64, 2, 5>::new(
            x * r2,
            x * r4,
            x * r6,
            2.0 * x * y,
            r2 + 2.0 * x * x,
            y * r2,
            y * r4,
            y * r6,
            r2 + 2.0 * y * y,
            2.0 * x * y,
        )
    }

    /// Undistorts by Newton iteration until the re-distorted point matches `pd` to `tol`
    /// (normalised units). Distortion models are only invertible inside their valid radius;
    /// outside it this fails instead of returning a wrong point.
    pub fn undistort(&self, pd: Vector2<f64>, tol: f64) -> Result<Vector2<f64>> {
        if self.is_zero() {
            return Ok(pd);
        }
        let mut p = pd;
        for _ in 0..50 {
            let r = self.distort(p) - pd;
            if r.norm() <= tol {
                return Ok(p);
            }
            let j = self.jacobian_point(p);
            let step = j.try_inverse().map(|ji| ji * r).unwrap_or(r);
            p -= step;
            if !p.x.is_finite() || !p.y.is_finite() {
                break;
            }
        }
        let r = self.distort(p) - pd;
        if r.norm() <= tol * 10.0 {
            Ok(p)
        } else {
            Err(GeometryError::NotConverged {
                what: "undistortion".into(),
                iterations: 50,
            })
        }
    }
}

/// Digital frame camera, all in pixels: `u = fx·x_d + cx`, `v = fy·y_d + cy` where
/// `(x_d, y_d)` are the distorted normalised coordinates. Maps onto COLMAP's PINHOLE,
/// OPENCV and FULL_OPENCV (k4..k6 = 0) models.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameCamera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    #[serde(default)]
    pub distortion: Brown,
}

impl FrameCamera {
    /// Pinhole camera with square pixels and the principal point at the image centre.
    pub fn pinhole(width: u32, height: u32, focal_px: f64) -> Self {
        Self {
            width,
            height,
            fx: focal_px,
            fy: focal_px,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            distortion: Brown::default(),
        }
    }
}

/// Metric film camera: calibrated focal length, principal point (of best symmetry) and
/// distortion in the fiducial coordinate system (mm, x right, y up), plus the scan's
/// interior orientation that maps scan pixels to fiducial mm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilmCamera {
    /// Scan size in pixels.
    pub width: u32,
    pub height: u32,
    pub focal_mm: f64,
    /// Principal point in fiducial coordinates (mm).
    pub principal_point_mm: [f64; 2],
    /// Distortion in normalised coordinates (radial distortion in µm at radius r mm of a
    /// certificate converts as Δr/r = k1·(r/f)² + …).
    #[serde(default)]
    pub distortion: Brown,
    pub interior: InteriorOrientation,
}

/// A camera of any supported kind.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Camera {
    Frame(FrameCamera),
    Film(FilmCamera),
}

const FRAME_PARAM_NAMES: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2"];
const FILM_PARAM_NAMES: [&str; 8] = ["f_mm", "x0_mm", "y0_mm", "k1", "k2", "k3", "p1", "p2"];

impl Camera {
    pub fn image_size(&self) -> (u32, u32) {
        match self {
            Camera::Frame(c) => (c.width, c.height),
            Camera::Film(c) => (c.width, c.height),
        }
    }

    pub fn distortion(&self) -> &Brown {
        match self {
            Camera::Frame(c) => &c.distortion,
            Camera::Film(c) => &c.distortion,
        }
    }

    /// Mean focal length in pixels (for pixel-to-angle conversions and initial guesses).
    pub fn focal_px(&self) -> f64 {
        match self {
            Camera::Frame(c) => 0.5 * (c.fx + c.fy),
            Camera::Film(c) => c.focal_mm / c.interior.mean_pixel_size_mm(),
        }
    }

    /// Names of the interior parameters, in the order of [`Camera::params`].
    pub fn param_names(&self) -> &'static [&'static str] {
        match self {
            Camera::Frame(_) => &FRAME_PARAM_NAMES,
            Camera::Film(_) => &FILM_PARAM_NAMES,
        }
    }

    pub fn num_params(&self) -> usize {
        self.param_names().len()
    }

    /// Interior parameters as a vector (self-calibration unknowns).
    pub fn params(&self) -> Vec<f64> {
        match self {
            Camera::Frame(c) => {
                let d = c.distortion.as_array();
                vec![c.fx, c.fy, c.cx, c.cy, d[0], d[1], d[2], d[3], d[4]]
            }
            Camera::Film(c) => {
                let d = c.distortion.as_array();
                vec![
                    c.focal_mm,
                    c.principal_point_mm[0],
                    c.principal_point_mm[1],
                    d[0],
                    d[1],
                    d[2],
                    d[3],
                    d[4],
                ]
            }
        }
    }

    pub fn set_params(&mut self, p: &[f64]) -> Result<()> {
        if p.len() != self.num_params() {
            return Err(GeometryError::InvalidArgument(format!(
                "camera expects {} interior parameters, got {}",
                self.num_params(),
                p.len()
            )));
        }
        check_finite(p, "interior parameters")?;
        match self {
            Camera::Frame(c) => {
                c.fx = p[0];
                c.fy = p[1];
                c.cx = p[2];
                c.cy = p[3];
                c.distortion = Brown::from_array([p[4], p[5], p[6], p[7], p[8]]);
            }
            Camera::Film(c) => {
                c.focal_mm = p[0];
                c.principal_point_mm = [p[1], p[2]];
                c.distortion = Brown::from_array([p[3], p[4], p[5], p[6], p[7]]);
            }
        }
        Ok(())
    }

    /// Checks the camera is physically meaningful: sizes, finite numbers and the plausible
    /// ranges of formats/cameras/README.md ([`MAX_IMAGE_SIDE_PX`], [`FOCAL_PX_PER_SIDE`],
    /// [`PIXEL_ASPECT`], [`MAX_DISTORTION`], [`FOCAL_MM`], [`MAX_PRINCIPAL_POINT_MM`]). The
    /// message names the field and the range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(GeometryError::InvalidCamera(m));
        let (w, h) = self.image_size();
        if w == 0 || h == 0 {
            return bad(format!("image size {w}×{h} is empty"));
        }
        if w.max(h) > MAX_IMAGE_SIDE_PX {
            return bad(format!(
                "image size {w}×{h}: a side is at most {MAX_IMAGE_SIDE_PX} px (a 500 mm film \
                 side at 2.5 µm)"
            ));
        }
        for (name, v) in self.param_names().iter().zip(self.params()) {
            if !v.is_finite() {
                return bad(format!("{name} = {} is not finite", num(v)));
            }
        }
        for (name, v) in ["k1", "k2", "k3", "p1", "p2"]
            .iter()
            .zip(self.distortion().as_array())
        {
            if v.abs() > MAX_DISTORTION {
                return bad(format!(
                    "distortion {name} = {}: at most {MAX_DISTORTION} in magnitude",
                    num(v)
                ));
            }
        }
        match self {
            Camera::Frame(c) => {
                let side = f64::from(w.max(h));
                let [lo, hi] = FOCAL_PX_PER_SIDE.map(|f| f * side);
                for (name, f) in [("fx", c.fx), ("fy", c.fy)] {
                    if !(lo..=hi).contains(&f) {
                        return bad(format!(
                            "{name} = {} px is not a focal length for a {w}×{h} image: \
                             {} to {} px ({} to {} times the longer side)",
                            num(f),
                            num(lo),
                            num(hi),
                            FOCAL_PX_PER_SIDE[0],
                            num(FOCAL_PX_PER_SIDE[1])
                        ));
                    }
                }
                if !(PIXEL_ASPECT[0]..=PIXEL_ASPECT[1]).contains(&(c.fy / c.fx)) {
                    return bad(format!(
                        "fy / fx = {} / {}: the pixel aspect is {} to {}",
                        num(c.fy),
                        num(c.fx),
                        PIXEL_ASPECT[0],
                        PIXEL_ASPECT[1]
                    ));
                }
                for (name, v, size) in [("cx", c.cx, w), ("cy", c.cy, h)] {
                    let size = f64::from(size);
                    if !(-size..=2.0 * size).contains(&v) {
                        return bad(format!(
                            "{name} = {} px lies beyond the image ({} to {} px: one image \
                             size either side of it)",
                            num(v),
                            -size,
                            2.0 * size
                        ));
                    }
                }
            }
            Camera::Film(c) => {
                if !(FOCAL_MM[0]..=FOCAL_MM[1]).contains(&c.focal_mm) {
                    return bad(format!(
                        "focal_mm = {} is not a film camera's focal length ({} to {} mm)",
                        num(c.focal_mm),
                        FOCAL_MM[0],
                        FOCAL_MM[1]
                    ));
                }
                for (name, v) in ["x0_mm", "y0_mm"].iter().zip(c.principal_point_mm) {
                    if v.abs() > MAX_PRINCIPAL_POINT_MM {
                        return bad(format!(
                            "principal point {name} = {}: at most {MAX_PRINCIPAL_POINT_MM} mm \
                             from the fiducial centre",
                            num(v)
                        ));
                    }
                }
                c.interior.validate()?;
            }
        }
        Ok(())
    }

    /// Pixel of a distorted normalised image point, with ∂pixel/∂(x_d, y_d).
    #[inline]
    fn pixel_from_distorted(&self, pd: Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        match self {
            Camera::Frame(c) => (
                Vector2::new(c.fx * pd.x + c.cx, c.fy * pd.y + c.cy),
                Matrix2::new(c.fx, 0.0, 0.0, c.fy),
            ),
            Camera::Film(c) => {
                let mm = Vector2::new(
                    c.principal_point_mm[0] + c.focal_mm * pd.x,
                    c.principal_point_mm[1] - c.focal_mm * pd.y,
                );
                let (px, j_mm) = c.interior.mm_to_pixel_with_jacobian(mm);
                (px, j_mm * Matrix2::new(c.focal_mm, 0.0, 0.0, -c.focal_mm))
            }
        }
    }

    /// Projects a camera-frame point to pixels.
    #[inline]
    pub fn project(&self, xc: &Vector3<f64>) -> Result<Vector2<f64>> {
        if xc.z.is_nan() || xc.z <= 0.0 {
            return Err(GeometryError::BehindCamera { z: xc.z });
        }
        let pn = Vector2::new(xc.x / xc.z, xc.y / xc.z);
        let pd = self.distortion().distort(pn);
        Ok(self.pixel_from_distorted(pd).0)
    }

    /// [`Self::project`] with [`Self::project_with_jacobian`]'s arithmetic (one reciprocal
    /// of the depth), so a residual evaluated without Jacobians equals, to the bit, the one
    /// evaluated with them.
    #[inline]
    pub fn project_as_with_jacobian(&self, xc: &Vector3<f64>) -> Result<Vector2<f64>> {
        if xc.z.is_nan() || xc.z <= 0.0 {
            return Err(GeometryError::BehindCamera { z: xc.z });
        }
        let iz = 1.0 / xc.z;
        let pn = Vector2::new(xc.x * iz, xc.y * iz);
        let pd = self.distortion().distort(pn);
        Ok(self.pixel_from_distorted(pd).0)
    }

    /// Projects a camera-frame point and returns ∂pixel/∂X_cam and ∂pixel/∂(interior parameters).
    pub fn project_with_jacobian(
        &self,
        xc: &Vector3<f64>,
    ) -> Result<(Vector2<f64>, SMatrix<f64, 2, 3>, IntrinsicsJacobian)> {
        if xc.z.is_nan() || xc.z <= 0.0 {
            return Err(GeometryError::BehindCamera { z: xc.z });
        }
        let iz = 1.0 / xc.z;
        let pn = Vector2::new(xc.x * iz, xc.y * iz);
        let dist = self.distortion();
        let pd = dist.distort(pn);
        let j_dist = dist.jacobian_point(pn);
        let (px, j_pix) = self.pixel_from_distorted(pd);
        let j_norm = SMatrix::<f64, 2, 3>::new(iz, 0.0, -pn.x * iz, 0.0, iz, -pn.y * iz);
        let j_xc = j_pix * j_dist * j_norm;

        let j_coef = j_pix * dist.jacobian_coefficients(pn);
        let mut j_int = IntrinsicsJacobian::zeros();
        match self {
            Camera::Frame(_) => {
                j_int[(0, 0)] = pd.x;
                j_int[(1, 1)] = pd.y;
                j_int[(0, 2)] = 1.0;
                j_int[(1, 3)] = 1.0;
                j_int.fixed_view_mut::<2, 5>(0, 4).copy_from(&j_coef);
            }
            Camera::Film(c) => {
                let mm = Vector2::new(
                    c.principal_point_mm[0] + c.focal_mm * pd.x,
                    c.principal_point_mm[1] - c.focal_mm * pd.y,
                );
                let (_, j_mm) = c.interior.mm_to_pixel_with_jacobian(mm);
                j_int
                    .fixed_view_mut::<2, 1>(0, 0)
                    .copy_from(&(j_mm * Vector2::new(pd.x, -pd.y)));
                j_int.fixed_view_mut::<2, 2>(0, 1).copy_from(&j_mm);
                j_int.fixed_view_mut::<2, 5>(0, 3).copy_from(&j_coef);
            }
        }
        Ok((px, j_xc, j_int))
    }

    /// Undistorted normalised coordinates of a pixel.
    pub fn pixel_to_normalized(&self, pixel: [f64; 2]) -> Result<Vector2<f64>> {
        check_finite(&pixel, "pixel")?;
        let (pd, scale) = match self {
            Camera::Frame(c) => (
                Vector2::new((pixel[0] - c.cx) / c.fx, (pixel[1] - c.cy) / c.fy),
                c.fx.max(c.fy),
            ),
            Camera::Film(c) => {
                let mm = c.interior.pixel_to_mm(Vector2::new(pixel[0], pixel[1]));
                (
                    Vector2::new(
                        (mm.x - c.principal_point_mm[0]) / c.focal_mm,
                        -(mm.y - c.principal_point_mm[1]) / c.focal_mm,
                    ),
                    self.focal_px(),
                )
            }
        };
        // 1e-9 px in normalised units leaves ample margin for the 1e-6 px requirement.
        self.distortion().undistort(pd, 1e-9 / scale)
    }

    /// Unit direction of the ray through a pixel, in the camera frame.
    pub fn unproject(&self, pixel: [f64; 2]) -> Result<Vector3<f64>> {
        let p = self.pixel_to_normalized(pixel)?;
        Ok(Vector3::new(p.x, p.y, 1.0).normalize())
    }
}
