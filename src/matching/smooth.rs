//! Gaussian smoothing of grey images: before the census transform of dense matching, and
//! of a fiducial mark's template and the scan around it before they are matched.

use super::GreyImage;
use rayon::prelude::*;

/// Gaussian blur of standard deviation `sigma` px (separable, kernel to 3σ, edges
/// clamped); the image itself when `sigma` ≤ 0. Rows in parallel, each computed alone, so
/// the values do not depend on the thread count.
pub fn gaussian_blur(img: &GreyImage, sigma: f32) -> GreyImage {
    if sigma <= 0.0 {
        return img.clone();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let (w, h) = (img.width, img.height);
    let ru = r as usize;
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let row = img.row(y);
        let clamped = |x: usize| {
            let mut acc = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x as isize + j as isize - r).clamp(0, w as isize - 1) as usize;
                acc += kv * row[xx];
            }
            acc
        };
        if w <= 2 * ru {
            for (x, o) in out.iter_mut().enumerate() {
                *o = clamped(x);
            }
            return;
        }
        // The columns whose taps all lie inside the row, as one multiply–add per tap over
        // them all (vectorised); each sum in the same order as the clamped one.
        let inner = &mut out[ru..w - ru];
        for (j, kv) in k.iter().enumerate() {
            for (o, v) in inner.iter_mut().zip(&row[j..]) {
                *o += kv * v;
            }
        }
        for x in (0..ru).chain(w - ru..w) {
            out[x] = clamped(x);
        }
    });
    let mut data = vec![0.0f32; w * h];
    data.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        for (j, kv) in k.iter().enumerate() {
            let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
            for (o, &t) in out.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *o += kv * t;
            }
        }
    });
    GreyImage {
        width: w,
        height: h,
        data,
    }
}
