//! Sub-pixel refinement of the winning disparities by least-squares matching along the
//! rectified row.
//!
//! A V or parabola through SGM's aggregated sums locks disparities to the pixel grid: the
//! path sums of neighbouring disparities are smoothed by P1 and the census cost of a
//! blurred texture is not symmetric about the fraction, so a constant 17.3 px shift came
//! back with a median error of 0.19 px (a slanted plane, whose fractions vary across the
//! image, averages this out to 0.04 px and hides it). Least-squares matching of the grey
//! values in a small window around the pixel, with a gain and offset between the photos
//! (Gruen 1985, reduced to one shift along the epipolar line), has no such bias: the
//! shift is estimated from the images, not from the cost curve. Started from the
//! sub-pixel fit, it is kept only when it converges within half a pixel of it.
//!
//! Written here rather than calling the project's least-squares matcher
//! (`matching::lsm`, 2-D, bicubic, a template image per call): on the 274 688 matched
//! pixels of a 640 × 480 pair, `lsm` with shifts and radiometry only took 1.51 s CPU, this
//! one-dimensional version 0.16 s, the whole semi-global match around it 0.25 s
//! (`tests/units/dense_sgm.rs`, `refinement_cost`, run by hand).

use super::sgm::PixelStatus;
use crate::matching::GreyImage;
use rayon::prelude::*;

/// Window radius (px): 7 × 7 samples.
const RADIUS: usize = 3;
/// Gauss–Newton iterations at most, and the step (px) below which it has converged.
const ITERATIONS: usize = 6;
const CONVERGED: f32 = 0.002;
/// Largest move from the start (px).
const MAX_MOVE: f32 = 0.5;
/// Largest standard deviation (px) of a refined disparity for it to replace the fit to
/// SGM's sums.
const MAX_SIGMA: f32 = 0.1;
/// Least variance of the right window's grey values (grey levels²) for the gain to be
/// estimable.
const MIN_VARIANCE: f32 = 1.0;

/// Refines `disparity` (of the `left` image against `right`, same rows) in place at its
/// `Valid` pixels; `left_valid` / `right_valid` mark the pixels the photos cover.
pub(crate) fn refine_disparities(
    left: &GreyImage,
    left_valid: &[bool],
    right: &GreyImage,
    right_valid: &[bool],
    disparity: &mut [f32],
    status: &[PixelStatus],
) {
    let w = left.width;
    let h = left.height;
    if h < 2 * RADIUS + 1 || w < 2 * RADIUS + 1 || right.width < 2 * RADIUS + 3 {
        return;
    }
    disparity
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, disp)| {
            if y < RADIUS || y + RADIUS >= h {
                return;
            }
            for (x, d) in disp.iter_mut().enumerate().take(w - RADIUS).skip(RADIUS) {
                let p = y * w + x;
                if status[p] != PixelStatus::Valid || !d.is_finite() {
                    continue;
                }
                let window = Window {
                    left,
                    left_valid,
                    right,
                    right_valid,
                    x,
                    y,
                };
                if let Some(refined) = window.solve(*d) {
                    *d = refined;
                }
            }
        });
}

struct Window<'a> {
    left: &'a GreyImage,
    left_valid: &'a [bool],
    right: &'a GreyImage,
    right_valid: &'a [bool],
    x: usize,
    y: usize,
}

const N: usize = (2 * RADIUS + 1) * (2 * RADIUS + 1);

impl Window<'_> {
    /// The refined disparity from `d0`, or `None` when the window leaves the photos, has
    /// too little texture or the iteration does not settle within [`MAX_MOVE`].
    fn solve(&self, d0: f32) -> Option<f32> {
        let (lw, rw) = (self.left.width, self.right.width);
        let mut l = [0.0f32; N];
        let mut i = 0;
        for yy in self.y - RADIUS..=self.y + RADIUS {
            for xx in self.x - RADIUS..=self.x + RADIUS {
                let p = yy * lw + xx;
                if !self.left_valid[p] {
                    return None;
                }
                l[i] = self.left.data[p];
                i += 1;
            }
        }
        let ml = l.iter().sum::<f32>() / N as f32;
        let mut d = d0;
        let mut r = [0.0f32; N];
        let mut g = [0.0f32; N];
        for _ in 0..ITERATIONS {
            // Left pixel column xx (centre xx + 0.5) lies at right position xx + 0.5 − d,
            // i.e. between right columns ⌊xx − d⌋ and ⌊xx − d⌋ + 1.
            let u0 = self.x as f32 - RADIUS as f32 - d;
            let i0 = u0.floor();
            let f = u0 - i0;
            let c0 = i0 as isize;
            if c0 < 1 || c0 as usize + 2 * RADIUS + 2 >= rw {
                return None;
            }
            let mut k = 0;
            for yy in self.y - RADIUS..=self.y + RADIUS {
                let row = yy * rw;
                for j in 0..=2 * RADIUS {
                    let c = row + c0 as usize + j;
                    if !self.right_valid[c] || !self.right_valid[c + 1] {
                        return None;
                    }
                    r[k] = (1.0 - f) * self.right.data[c] + f * self.right.data[c + 1];
                    // The derivative of the interpolation itself: a central difference
                    // underestimates the slope of a texture near the sampling limit and
                    // the iteration then overshoots back and forth.
                    g[k] = self.right.data[c + 1] - self.right.data[c];
                    k += 1;
                }
            }
            // Gain and offset projected out: regress the left window on the right one.
            let mr = r.iter().sum::<f32>() / N as f32;
            let mg = g.iter().sum::<f32>() / N as f32;
            let (mut srr, mut slr) = (0.0f32, 0.0f32);
            for k in 0..N {
                let a = r[k] - mr;
                srr += a * a;
                slr += (l[k] - ml) * a;
            }
            if srr < MIN_VARIANCE * N as f32 || slr <= 0.0 {
                return None;
            }
            let gain = slr / srr;
            // e(d + δ) = L − ml − gain (R(u − δ) − mr) ≈ e + gain·g·δ.
            let (mut sge, mut sgg, mut see) = (0.0f32, 0.0f32, 0.0f32);
            for k in 0..N {
                let e = (l[k] - ml) - gain * (r[k] - mr);
                let gk = gain * (g[k] - mg);
                sge += gk * e;
                sgg += gk * gk;
                see += e * e;
            }
            if sgg <= f32::EPSILON {
                return None;
            }
            let step = -sge / sgg;
            d += step.clamp(-MAX_MOVE, MAX_MOVE);
            if (d - d0).abs() > MAX_MOVE {
                return None;
            }
            if step.abs() < CONVERGED {
                // Its standard deviation from the residuals: where the window holds too
                // little texture for the noise, the sums of SGM's paths, which pool a
                // wide neighbourhood, are the better estimate.
                let sigma2 = (see - sge * sge / sgg).max(0.0) / (N - 3) as f32;
                return (sigma2 / sgg <= MAX_SIGMA * MAX_SIGMA).then_some(d);
            }
        }
        None
    }
}
