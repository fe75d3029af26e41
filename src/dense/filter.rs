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

/// Marks as occluded the pixels the right image cannot see at their disparity: along a
/// row the right positions `x − d` of a visible surface keep the left order, so a pixel
/// whose right position lies more than `tolerance` beyond that of a pixel to its right is
/// hidden there by the nearer surface (Scharstein & Szeliski's ordering constraint). A
/// wall the left photo sees and the right one does not is otherwise matched at the
/// ground's disparity behind it and triangulated under the roof; the left–right check
/// passes it, since the right image's winner there is the ground's too.
pub fn remove_occluded(
    disparity: &mut [f32],
    status: &mut [PixelStatus],
    width: usize,
    tolerance: f32,
) {
    disparity
        .par_chunks_mut(width)
        .zip(status.par_chunks_mut(width))
        .for_each(|(d, s)| {
            let mut least = f32::INFINITY;
            for x in (0..d.len()).rev() {
                if !d[x].is_finite() {
                    continue;
                }
                let r = x as f32 - d[x];
                if r > least + tolerance {
                    d[x] = f32::NAN;
                    s[x] = PixelStatus::Occluded;
                } else {
                    least = least.min(r);
                }
            }
        });
}

/// Moves depth edges onto the image's edges: where neighbouring disparities jump by more
/// than `jump` px, the pixels between the jump and the strongest grey-value step within
/// `reach` px of it (`[columns, rows]`, half the census window: how far a window carries a
/// nearer surface's disparity onto its neighbours, "edge fattening") are removed, along
/// rows and along columns. A roof's outline is a grey-value edge; the band the census
/// window fattened past it is not.
pub fn trim_depth_edges(
    disparity: &mut [f32],
    status: &mut [PixelStatus],
    image: &GreyImage,
    reach: [usize; 2],
    jump: f32,
) {
    let (w, h) = (image.width, image.height);
    let mut remove = vec![false; w * h];
    // Along rows, then along columns: offsets of a line's k-th pixel.
    let lines: [(usize, usize, usize, usize); 2] = [(h, w, w, 1), (w, h, 1, w)];
    for (axis, &(count, len, line_step, step)) in lines.iter().enumerate() {
        let r = reach[axis];
        if r == 0 {
            continue;
        }
        for line in 0..count {
            let at = |k: usize| line * line_step + k * step;
            for k in 0..len.saturating_sub(1) {
                let (a, b) = (disparity[at(k)], disparity[at(k + 1)]);
                if !(a.is_finite() && b.is_finite() && (a - b).abs() > jump) {
                    continue;
                }
                // Steps between pixels e and e + 1 for e within reach of k.
                let lo = k.saturating_sub(r);
                let hi = (k + r).min(len - 2);
                let mut edge = k;
                let mut best = -1.0f32;
                for e in lo..=hi {
                    let g = (image.data[at(e + 1)] - image.data[at(e)]).abs();
                    if g > best {
                        best = g;
                        edge = e;
                    }
                }
                if edge == k {
                    continue;
                }
                let (from, to) = if edge < k {
                    (edge + 1, k)
                } else {
                    (k + 1, edge)
                };
                for m in from..=to {
                    remove[at(m)] = true;
                }
            }
        }
    }
    for ((d, s), r) in disparity.iter_mut().zip(status.iter_mut()).zip(remove) {
        if r && d.is_finite() {
            *d = f32::NAN;
            *s = PixelStatus::DepthEdge;
        }
    }
}
