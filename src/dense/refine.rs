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
//! (`tests/units/dense_sgm.rs`, `refinement_cost`, run by hand). Those figures are from
//! before the window's sums were taken once per start column ([`Moments`]); on a busy
//! machine after it, the whole match with its refinement took 0.60 s CPU there and `lsm`
//! 4.32 s.

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

/// Sums over a window whose right samples start at one integer column: with the window
/// fixed, the linear interpolation at fraction `f` is `R0 + f·G` (`G` = next column −
/// this one), so every sum of the iteration below is a polynomial in `f` of these
/// moments. A solve moves less than a pixel and meets one or two start columns, so the
/// 49 samples are read once per column instead of once per iteration (`perf` on the
/// demo's reference surface: the refinement was 37 % of the stage, every iteration
/// interpolating and summing its window again).
#[derive(Clone, Copy)]
struct Moments {
    /// Σa², Σa·b, Σb², Σl·a, Σl·b of the centred right samples a = R0 − mean, slopes
    /// b = G − mean and centred left samples l.
    saa: f64,
    sab: f64,
    sbb: f64,
    sla: f64,
    slb: f64,
}

impl Window<'_> {
    /// The moments of the window whose right samples start at column `c0` (bounds checked
    /// by the caller), or `None` when a sample lies outside the right photo.
    fn moments(&self, c0: usize, l: &[f32; N]) -> Option<Moments> {
        let rw = self.right.width;
        let mut r0 = [0.0f32; N];
        let mut g = [0.0f32; N];
        let mut k = 0;
        for yy in self.y - RADIUS..=self.y + RADIUS {
            let row = yy * rw + c0;
            let valid = &self.right_valid[row..row + 2 * RADIUS + 2];
            if valid.iter().any(|v| !v) {
                return None;
            }
            let data = &self.right.data[row..row + 2 * RADIUS + 2];
            for j in 0..=2 * RADIUS {
                r0[k] = data[j];
                // The derivative of the interpolation itself: a central difference
                // underestimates the slope of a texture near the sampling limit and the
                // iteration then overshoots back and forth.
                g[k] = data[j + 1] - data[j];
                k += 1;
            }
        }
        let mr = r0.iter().sum::<f32>() / N as f32;
        let mg = g.iter().sum::<f32>() / N as f32;
        let (mut saa, mut sab, mut sbb, mut sla, mut slb) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for k in 0..N {
            let a = r0[k] - mr;
            let b = g[k] - mg;
            saa += a * a;
            sab += a * b;
            sbb += b * b;
            sla += l[k] * a;
            slb += l[k] * b;
        }
        Some(Moments {
            saa: saa as f64,
            sab: sab as f64,
            sbb: sbb as f64,
            sla: sla as f64,
            slb: slb as f64,
        })
    }

    /// The refined disparity from `d0`, or `None` when the window leaves the photos, has
    /// too little texture or the iteration does not settle within [`MAX_MOVE`].
    fn solve(&self, d0: f32) -> Option<f32> {
        let (lw, rw) = (self.left.width, self.right.width);
        let mut l = [0.0f32; N];
        let mut i = 0;
        for yy in self.y - RADIUS..=self.y + RADIUS {
            let row = yy * lw + self.x - RADIUS;
            if self.left_valid[row..=row + 2 * RADIUS].iter().any(|v| !v) {
                return None;
            }
            l[i..i + 2 * RADIUS + 1].copy_from_slice(&self.left.data[row..=row + 2 * RADIUS]);
            i += 2 * RADIUS + 1;
        }
        let ml = l.iter().sum::<f32>() / N as f32;
        let mut sll = 0.0f32;
        for v in &mut l {
            *v -= ml;
            sll += *v * *v;
        }
        let sll = sll as f64;
        let mut d = d0;
        let mut window: Option<(isize, Moments)> = None;
        for _ in 0..ITERATIONS {
            // Left pixel column xx (centre xx + 0.5) lies at right position xx + 0.5 − d,
            // i.e. between right columns ⌊xx − d⌋ and ⌊xx − d⌋ + 1.
            let u0 = self.x as f32 - RADIUS as f32 - d;
            let i0 = u0.floor();
            let f = (u0 - i0) as f64;
            let c0 = i0 as isize;
            if c0 < 1 || c0 as usize + 2 * RADIUS + 2 >= rw {
                return None;
            }
            let m = match window {
                Some((c, m)) if c == c0 => m,
                _ => {
                    let m = self.moments(c0 as usize, &l)?;
                    window = Some((c0, m));
                    m
                }
            };
            // Gain and offset projected out: regress the left window on the right one,
            // r − mean(r) = a + f·b.
            let srr = m.saa + f * (2.0 * m.sab + f * m.sbb);
            let slr = m.sla + f * m.slb;
            if srr < (MIN_VARIANCE * N as f32) as f64 || slr <= 0.0 {
                return None;
            }
            let gain = slr / srr;
            // e(d + δ) = l − gain (a + f·b) ≈ e + gain·b·δ: the sums of g·e, g² and e²
            // with g = gain·b.
            let sge = gain * (m.slb - gain * (m.sab + f * m.sbb));
            let sgg = gain * gain * m.sbb;
            let see = sll - 2.0 * gain * slr + gain * gain * srr;
            if sgg <= f32::EPSILON as f64 {
                return None;
            }
            let step = (-sge / sgg) as f32;
            d += step.clamp(-MAX_MOVE, MAX_MOVE);
            if (d - d0).abs() > MAX_MOVE {
                return None;
            }
            if step.abs() < CONVERGED {
                // Its standard deviation from the residuals: where the window holds too
                // little texture for the noise, the sums of SGM's paths, which pool a
                // wide neighbourhood, are the better estimate.
                let sigma2 = (see - sge * sge / sgg).max(0.0) / (N - 3) as f64;
                return (sigma2 / sgg <= (MAX_SIGMA * MAX_SIGMA) as f64).then_some(d);
            }
        }
        None
    }
}
