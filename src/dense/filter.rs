//! Filters of a disparity map: 3 × 3 median of the valid disparities, removal of small
//! isolated regions (speckles), and the mask of pixels with too little texture to match.

use super::sgm::PixelStatus;
use crate::matching::GreyImage;
use rayon::prelude::*;

/// 3 × 3 median of the finite disparities around each finite pixel (NaN stays NaN; of an
/// even count the upper middle one).
pub fn median3(disparity: &[f32], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![f32::NAN; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let mut v = [0.0f32; 9];
        let full = y > 0 && y + 1 < height;
        for (x, o) in row.iter_mut().enumerate() {
            let c = disparity[y * width + x];
            if !c.is_finite() {
                continue;
            }
            if full && x > 0 && x + 1 < width {
                let at = |dx: usize, dy: usize| disparity[(y + dy - 1) * width + x + dx - 1];
                let cols = [0, 1, 2].map(|i| [at(i, 0), at(i, 1), at(i, 2)]);
                if cols.iter().flatten().all(|v| v.is_finite()) {
                    *o = median9(cols);
                    continue;
                }
            }
            let mut n = 0;
            for yy in y.saturating_sub(1)..(y + 2).min(height) {
                for xx in x.saturating_sub(1)..(x + 2).min(width) {
                    let d = disparity[yy * width + xx];
                    if d.is_finite() {
                        v[n] = d;
                        n += 1;
                    }
                }
            }
            let s = &mut v[..n];
            // Insertion sort of at most nine values.
            for i in 1..n {
                let mut j = i;
                while j > 0 && s[j - 1] > s[j] {
                    s.swap(j - 1, j);
                    j -= 1;
                }
            }
            *o = s[n / 2];
        }
    });
    out
}

/// Median of three.
#[inline(always)]
fn med3(a: f32, b: f32, c: f32) -> f32 {
    a.min(b).max(a.max(b).min(c))
}

/// Median of a 3 × 3 window given as three columns: with each column sorted, the median
/// is the median of the largest low, the median of the middles and the smallest high.
#[inline(always)]
fn median9(cols: [[f32; 3]; 3]) -> f32 {
    let sorted = cols.map(|[a, b, c]| {
        let (lo, hi) = (a.min(b), a.max(b));
        [lo.min(c), med3(a, b, c), hi.max(c)]
    });
    let lo = sorted[0][0].max(sorted[1][0]).max(sorted[2][0]);
    let mid = med3(sorted[0][1], sorted[1][1], sorted[2][1]);
    let hi = sorted[0][2].min(sorted[1][2]).min(sorted[2][2]);
    med3(lo, mid, hi)
}

/// Invalidates connected regions of at most `max_size` pixels, where neighbours (4-connected)
/// belong to one region when their disparities differ by at most `max_diff` (OpenCV's
/// speckle filter). Returns the number of pixels removed.
pub fn remove_speckles(
    disparity: &mut [f32],
    status: &mut [PixelStatus],
    width: usize,
    height: usize,
    max_size: usize,
    max_diff: f32,
) -> usize {
    if max_size == 0 {
        return 0;
    }
    let n = width * height;
    let mut seen = vec![false; n];
    let mut region = Vec::new();
    let mut stack = Vec::new();
    let mut removed = 0;
    for start in 0..n {
        if seen[start] || !disparity[start].is_finite() {
            continue;
        }
        seen[start] = true;
        crate::geometry::region::grow_region(
            (width, height),
            start,
            &mut region,
            &mut stack,
            |p, q| {
                let joins = !seen[q]
                    && disparity[q].is_finite()
                    && (disparity[q] - disparity[p]).abs() <= max_diff;
                seen[q] |= joins;
                joins
            },
        );
        if region.len() <= max_size {
            for &p in &region {
                disparity[p] = f32::NAN;
                status[p] = PixelStatus::Speckle;
            }
            removed += region.len();
        }
    }
    removed
}

/// Per pixel: the standard deviation of the grey values in the `(2·radius + 1)²` window
/// around it reaches `min_std` (windows clamped at the edges).
pub fn texture_mask(image: &GreyImage, radius: usize, min_std: f32) -> Vec<bool> {
    let (w, h) = (image.width, image.height);
    if min_std <= 0.0 {
        return vec![true; w * h];
    }
    // Integral images of the values and their squares (f64: exact enough for 10⁸ pixels).
    let stride = w + 1;
    let mut s1 = vec![0.0f64; stride * (h + 1)];
    let mut s2 = vec![0.0f64; stride * (h + 1)];
    for y in 0..h {
        let (mut r1, mut r2) = (0.0, 0.0);
        for x in 0..w {
            let v = image.data[y * w + x] as f64;
            r1 += v;
            r2 += v * v;
            s1[(y + 1) * stride + x + 1] = s1[y * stride + x + 1] + r1;
            s2[(y + 1) * stride + x + 1] = s2[y * stride + x + 1] + r2;
        }
    }
    let min_var = (min_std as f64).powi(2);
    let mut out = vec![false; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (y0, y1) = (y.saturating_sub(radius), (y + radius + 1).min(h));
        for (x, o) in row.iter_mut().enumerate() {
            let (x0, x1) = (x.saturating_sub(radius), (x + radius + 1).min(w));
            let box_sum = |s: &[f64]| {
                s[y1 * stride + x1] - s[y0 * stride + x1] - s[y1 * stride + x0]
                    + s[y0 * stride + x0]
            };
            let n = ((y1 - y0) * (x1 - x0)) as f64;
            let m = box_sum(&s1) / n;
            *o = box_sum(&s2) / n - m * m >= min_var;
        }
    });
    out
}
