//! Resampling of a patch under a plane transform (affine or homography), bilinear or
//! bicubic (Keys, a = −0.5). Used to bring templates into a photo's geometry and by LSM.

use super::GreyImage;
use nalgebra::Matrix3;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    Bilinear,
    Bicubic,
}

/// Maps patch coordinates (corner origin) into source-image coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PatchWarp {
    /// x_src = A · (x, y, 1): a 2×3 row-major affine.
    Affine([f64; 6]),
    /// Homogeneous 3×3 transform.
    Homography(Matrix3<f64>),
}

impl PatchWarp {
    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        match self {
            PatchWarp::Affine(a) => (a[0] * x + a[1] * y + a[2], a[3] * x + a[4] * y + a[5]),
            PatchWarp::Homography(h) => {
                let w = h[(2, 0)] * x + h[(2, 1)] * y + h[(2, 2)];
                (
                    (h[(0, 0)] * x + h[(0, 1)] * y + h[(0, 2)]) / w,
                    (h[(1, 0)] * x + h[(1, 1)] * y + h[(1, 2)]) / w,
                )
            }
        }
    }
}

/// Bilinear sample at a continuous position (corner origin); `None` outside the
/// pixel-centre hull.
#[inline]
pub fn bilinear(img: &GreyImage, x: f64, y: f64) -> Option<f64> {
    let (u, v) = (x - 0.5, y - 0.5);
    if !(u >= 0.0 && v >= 0.0) {
        return None;
    }
    let (i, j) = (u.floor() as usize, v.floor() as usize);
    if i + 1 >= img.width || j + 1 >= img.height {
        // Exactly on the last centre line is still inside.
        if i + 1 == img.width && u == i as f64 && j < img.height {
            return Some(img.at(i, j.min(img.height - 1)) as f64);
        }
        return None;
    }
    let (fx, fy) = (u - i as f64, v - j as f64);
    let w = img.width;
    let d = &img.data;
    let p = j * w + i;
    let a = d[p] as f64 + fx * (d[p + 1] as f64 - d[p] as f64);
    let b = d[p + w] as f64 + fx * (d[p + w + 1] as f64 - d[p + w] as f64);
    Some(a + fy * (b - a))
}

/// floor() without the libm call that generic x86-64 (no SSE4.1 `roundsd`) makes of it.
/// Exact for |x| < 2⁶³; NaN gives 0 and ±∞ saturate, all of which the callers' range
/// checks send to their out-of-support paths.
#[inline]
fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

#[inline]
fn keys(t: f64) -> [f64; 4] {
    // Keys cubic convolution weights for the samples at −1, 0, 1, 2 relative to floor.
    let a = -0.5;
    let w = |x: f64| {
        let x = x.abs();
        if x <= 1.0 {
            ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
        } else if x < 2.0 {
            ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
        } else {
            0.0
        }
    };
    [w(1.0 + t), w(t), w(1.0 - t), w(2.0 - t)]
}

/// Bicubic sample; `None` when the 4×4 support leaves the image.
#[inline]
pub fn bicubic(img: &GreyImage, x: f64, y: f64) -> Option<f64> {
    let (u, v) = (x - 0.5, y - 0.5);
    let (fi, fj) = (fast_floor(u), fast_floor(v));
    if fi < 1.0 || fj < 1.0 || fi + 2.0 >= img.width as f64 || fj + 2.0 >= img.height as f64 {
        return bilinear(img, x, y);
    }
    let (i, j) = (fi as usize, fj as usize);
    let (wx, wy) = (keys(u - fi), keys(v - fj));
    let mut s = 0.0;
    for (dj, wyv) in wy.iter().enumerate() {
        let row = &img.data[(j + dj - 1) * img.width + i - 1..];
        let r = wx[0] * row[0] as f64
            + wx[1] * row[1] as f64
            + wx[2] * row[2] as f64
            + wx[3] * row[3] as f64;
        s += wyv * r;
    }
    Some(s)
}

/// Derivatives of the Keys weights of [`keys`] with respect to the fractional position.
#[inline]
fn keys_derivative(t: f64) -> [f64; 4] {
    let a = -0.5;
    // w'(x) for x ≥ 0; w is even, so w' is odd.
    let dw = |x: f64| {
        if x <= 1.0 {
            (3.0 * (a + 2.0) * x - 2.0 * (a + 3.0)) * x
        } else if x < 2.0 {
            (3.0 * a * x - 10.0 * a) * x + 8.0 * a
        } else {
            0.0
        }
    };
    [dw(1.0 + t), dw(t), -dw(1.0 - t), -dw(2.0 - t)]
}

/// Bicubic sample and its analytic gradient (∂/∂x, ∂/∂y per pixel) from one 4×4
/// neighbourhood; `None` when the support leaves the image (callers fall back to
/// differences of [`bicubic`], which degrades to bilinear there).
#[inline]
pub fn bicubic_with_gradient(img: &GreyImage, x: f64, y: f64) -> Option<(f64, f64, f64)> {
    let (u, v) = (x - 0.5, y - 0.5);
    let (fi, fj) = (fast_floor(u), fast_floor(v));
    if !(fi >= 1.0 && fj >= 1.0) || fi + 2.0 >= img.width as f64 || fj + 2.0 >= img.height as f64 {
        return None;
    }
    let (i, j) = (fi as usize, fj as usize);
    let (wx, wy) = (keys(u - fi), keys(v - fj));
    let (dx, dy) = (keys_derivative(u - fi), keys_derivative(v - fj));
    let (mut g, mut gx, mut gy) = (0.0, 0.0, 0.0);
    for dj in 0..4 {
        let row = &img.data[(j + dj - 1) * img.width + i - 1..][..4];
        let (r0, r1, r2, r3) = (row[0] as f64, row[1] as f64, row[2] as f64, row[3] as f64);
        let r = wx[0] * r0 + wx[1] * r1 + wx[2] * r2 + wx[3] * r3;
        let rd = dx[0] * r0 + dx[1] * r1 + dx[2] * r2 + dx[3] * r3;
        g += wy[dj] * r;
        gx += wy[dj] * rd;
        gy += dy[dj] * r;
    }
    Some((g, gx, gy))
}

#[inline]
pub fn sample(img: &GreyImage, x: f64, y: f64, interp: Interpolation) -> Option<f64> {
    match interp {
        Interpolation::Bilinear => bilinear(img, x, y),
        Interpolation::Bicubic => bicubic(img, x, y),
    }
}

/// Resamples a `width`×`height` patch whose pixel centres map into `src` through `warp`.
/// Returns the patch and the number of samples that fell outside `src` (filled with the
/// mean of the valid ones, so a partly outside patch is usable but flagged).
pub fn warp_patch(
    src: &GreyImage,
    warp: &PatchWarp,
    width: usize,
    height: usize,
    interp: Interpolation,
) -> (GreyImage, usize) {
    let mut data = vec![f32::NAN; width * height];
    let (mut sum, mut n) = (0.0, 0usize);
    for r in 0..height {
        for c in 0..width {
            let (x, y) = warp.apply(c as f64 + 0.5, r as f64 + 0.5);
            if let Some(v) = sample(src, x, y, interp) {
                data[r * width + c] = v as f32;
                sum += v;
                n += 1;
            }
        }
    }
    let fill = if n > 0 { (sum / n as f64) as f32 } else { 0.0 };
    let outside = width * height - n;
    for v in data.iter_mut().filter(|v| v.is_nan()) {
        *v = fill;
    }
    (
        GreyImage {
            width,
            height,
            data,
        },
        outside,
    )
}
