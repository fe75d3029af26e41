//! Normalised cross-correlation. Window means and variances come from integral images,
//! so each position costs one multiply–add per template pixel against the zero-mean
//! template; the correlation sum is accumulated as row-wise axpy updates over all
//! positions of a result row, which the compiler vectorises. Result rows run in
//! parallel (rayon) and each is computed independently, so results do not depend on
//! the thread count.

use super::{invalid, GreyImage, MatchingError, Pyramid, Result};
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::cell::RefCell;
use std::sync::Arc;

/// A pixel rectangle of an image: top-left corner (col, row) and size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub col: usize,
    pub row: usize,
    pub width: usize,
    pub height: usize,
}

impl Window {
    pub fn whole(img: &GreyImage) -> Self {
        Self {
            col: 0,
            row: 0,
            width: img.width,
            height: img.height,
        }
    }

    /// The window centred on (x, y) with the given half-size, clipped to the image.
    pub fn around(img: &GreyImage, x: f64, y: f64, half_w: f64, half_h: f64) -> Option<Self> {
        let c0 = (x - half_w).floor().max(0.0);
        let r0 = (y - half_h).floor().max(0.0);
        let c1 = (x + half_w).ceil().min(img.width as f64);
        let r1 = (y + half_h).ceil().min(img.height as f64);
        if c1 <= c0 || r1 <= r0 {
            return None;
        }
        Some(Self {
            col: c0 as usize,
            row: r0 as usize,
            width: (c1 - c0) as usize,
            height: (r1 - r0) as usize,
        })
    }
}

/// Correlation surface: value at (i, j) belongs to the template's top-left corner at
/// window (col + i, row + j).
#[derive(Debug, Clone)]
pub struct NccSurface {
    pub window: Window,
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

/// The correlation peak: template centre in image pixels (sub-pixel), its coefficient and
/// the ambiguity measure (second-best local maximum outside the peak's neighbourhood
/// divided by the best; near 1 means a repetitive or ambiguous match).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NccPeak {
    pub x: f64,
    pub y: f64,
    pub ncc: f64,
    pub second: f64,
    pub ratio: f64,
}

/// Zero-mean template and its norm; `Textureless` for a constant template.
fn prepared_template(tpl: &GreyImage, what: &str) -> Result<(Vec<f32>, f64)> {
    let n = tpl.data.len() as f64;
    let mean = tpl.data.iter().map(|&v| v as f64).sum::<f64>() / n;
    let t: Vec<f32> = tpl.data.iter().map(|&v| (v as f64 - mean) as f32).collect();
    let norm = t.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
    let range = tpl
        .data
        .iter()
        .fold(0.0f32, |m, &v| m.max((v - mean as f32).abs()));
    if norm < 1e-9 * n.sqrt() || range < 1e-6 * (mean.abs() as f32).max(1.0) {
        return Err(MatchingError::Textureless {
            what: what.to_string(),
        });
    }
    Ok((t, norm))
}

/// One output row of the correlation numerator: out[i] = Σ_r Σ_c t[r][c] · img[j + r][i + c].
/// Outputs are produced in register-resident blocks of B (32, then 8, then single)
/// while the whole template streams past, so each multiply–add costs one unaligned
/// load and no accumulator traffic. With AVX2 + FMA available at run time the same loop
/// is compiled for 8-lane fused multiply–adds (results then differ from the SSE2 path
/// in the last bits, but never between runs or thread counts on one machine).
#[inline(always)]
fn correlate_block<const B: usize, const FMA: bool>(
    rows: &[&[f32]],
    t: &[f32],
    tw: usize,
    i0: usize,
) -> [f32; B] {
    let mut acc = [0.0f32; B];
    for (r, row) in rows.iter().enumerate() {
        let trow = &t[r * tw..(r + 1) * tw];
        for (c, &tv) in trow.iter().enumerate() {
            let src: &[f32; B] = row[i0 + c..i0 + c + B].try_into().expect("block");
            for k in 0..B {
                acc[k] = if FMA {
                    src[k].mul_add(tv, acc[k])
                } else {
                    acc[k] + tv * src[k]
                };
            }
        }
    }
    acc
}

#[inline(always)]
fn correlate_row_generic<const FMA: bool>(out: &mut [f32], rows: &[&[f32]], t: &[f32], tw: usize) {
    let sw = out.len();
    let mut i = 0;
    while i + 32 <= sw {
        out[i..i + 32].copy_from_slice(&correlate_block::<32, FMA>(rows, t, tw, i));
        i += 32;
    }
    while i + 8 <= sw {
        out[i..i + 8].copy_from_slice(&correlate_block::<8, FMA>(rows, t, tw, i));
        i += 8;
    }
    // The tail as one more 8-block overlapping the previous one (recomputing a few
    // outputs is cheaper than a scalar pass over the whole template per output).
    if i < sw && sw >= 8 {
        out[sw - 8..sw].copy_from_slice(&correlate_block::<8, FMA>(rows, t, tw, sw - 8));
        i = sw;
    }
    while i < sw {
        out[i] = correlate_block::<1, FMA>(rows, t, tw, i)[0];
        i += 1;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn correlate_row_avx2(out: &mut [f32], rows: &[&[f32]], t: &[f32], tw: usize) {
    correlate_row_generic::<true>(out, rows, t, tw)
}

#[inline]
fn correlate_row(out: &mut [f32], rows: &[&[f32]], t: &[f32], tw: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports the features the function was compiled for.
            return unsafe { correlate_row_avx2(out, rows, t, tw) };
        }
    }
    correlate_row_generic::<false>(out, rows, t, tw)
}

thread_local! {
    static PLANNER: RefCell<FftPlanner<f32>> = RefCell::new(FftPlanner::new());
}

/// Forward and inverse plans for rows of length w and h.
type Plans = [Arc<dyn Fft<f32>>; 4];

fn plans(w: usize, h: usize) -> Plans {
    PLANNER.with(|p| {
        let mut p = p.borrow_mut();
        [
            p.plan_fft_forward(w),
            p.plan_fft_forward(h),
            p.plan_fft_inverse(w),
            p.plan_fft_inverse(h),
        ]
    })
}

/// Row-major w×h → h×w, in 32×32 tiles to stay in cache.
fn transpose(src: &[Complex32], dst: &mut [Complex32], w: usize, h: usize) {
    const T: usize = 32;
    for r0 in (0..h).step_by(T) {
        for c0 in (0..w).step_by(T) {
            for r in r0..(r0 + T).min(h) {
                for c in c0..(c0 + T).min(w) {
                    dst[c * h + r] = src[r * w + c];
                }
            }
        }
    }
}

/// In-place 2-D FFT of a row-major w×h complex array: rows, transpose, rows (the
/// columns), transpose back. Rows are independent, so the parallel split cannot change
/// the result.
fn fft2(
    data: &mut [Complex32],
    w: usize,
    h: usize,
    fw: &Arc<dyn Fft<f32>>,
    fh: &Arc<dyn Fft<f32>>,
) {
    let run = |d: &mut [Complex32], len: usize, f: &Arc<dyn Fft<f32>>| {
        d.par_chunks_mut(len * 8).for_each_init(
            || vec![Complex32::default(); f.get_inplace_scratch_len()],
            |scratch, chunk| f.process_with_scratch(chunk, scratch),
        );
    };
    run(data, w, fw);
    let mut t = vec![Complex32::default(); w * h];
    transpose(data, &mut t, w, h);
    run(&mut t, h, fh);
    transpose(&t, data, h, w);
}

/// Correlation numerator Σ t'(r, c) · I(j + r, i + c) for every valid position through
/// the FFT: image and zero-padded template are packed as real and imaginary parts of one
/// complex array (one forward transform for both), separated by conjugate symmetry,
/// multiplied, and transformed back. The circular correlation equals the linear one on
/// the valid positions because the template never wraps there.
fn correlate_fft(win: &[f32], ww: usize, wh: usize, t: &[f32], tw: usize, th: usize) -> Vec<f32> {
    let [fw, fh, iw, ih] = plans(ww, wh);
    let (sw, sh) = (ww + 1 - tw, wh + 1 - th);
    let mut z = vec![Complex32::default(); ww * wh];
    for (k, v) in win.iter().enumerate() {
        z[k].re = *v;
    }
    for r in 0..th {
        for c in 0..tw {
            z[r * ww + c].im = t[r * tw + c];
        }
    }
    fft2(&mut z, ww, wh, &fw, &fh);
    let mut p = vec![Complex32::default(); ww * wh];
    for v in 0..wh {
        let vn = (wh - v) % wh;
        for u in 0..ww {
            let un = (ww - u) % ww;
            let a = z[v * ww + u];
            let b = z[vn * ww + un].conj();
            let x = (a + b) * 0.5;
            // T = (a − b) / (2i); the correlation needs X · conj(T).
            let tt = (a - b) * Complex32::new(0.0, -0.5);
            p[v * ww + u] = x * tt.conj();
        }
    }
    fft2(&mut p, ww, wh, &iw, &ih);
    let scale = 1.0 / (ww * wh) as f32;
    let mut out = vec![0.0f32; sw * sh];
    for j in 0..sh {
        for i in 0..sw {
            out[j * sw + i] = p[j * ww + i].re * scale;
        }
    }
    out
}

/// How the correlation numerator is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CorrelationMethod {
    /// The cheaper of the two by operation count.
    Auto,
    /// Direct sums (register-blocked, SIMD).
    Direct,
    /// FFT of the window and the template.
    Fft,
}

/// Full correlation surface of `tpl` over `window` of `img`.
pub fn ncc_surface(img: &GreyImage, tpl: &GreyImage, window: Window) -> Result<NccSurface> {
    ncc_surface_with(img, tpl, window, CorrelationMethod::Auto)
}

/// [`ncc_surface`] with a chosen correlation method (benchmarks, tests).
pub fn ncc_surface_with(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    method: CorrelationMethod,
) -> Result<NccSurface> {
    if window.col + window.width > img.width || window.row + window.height > img.height {
        return Err(invalid(
            "search window",
            format!(
                "{}×{} at ({}, {}) is outside the {}×{} image",
                window.width, window.height, window.col, window.row, img.width, img.height
            ),
        ));
    }
    let (tw, th) = (tpl.width, tpl.height);
    if window.width < tw || window.height < th {
        return Err(MatchingError::TooSmall {
            what: "search window".into(),
            width: window.width,
            height: window.height,
            tw,
            th,
        });
    }
    let (t, tnorm) = prepared_template(tpl, "template")?;
    let (sw, sh) = (window.width - tw + 1, window.height - th + 1);
    // Integral images (f64: sums of squares of 16-bit data over large windows).
    let (ww, wh) = (window.width, window.height);
    let mut s1 = vec![0.0f64; (ww + 1) * (wh + 1)];
    let mut s2 = vec![0.0f64; (ww + 1) * (wh + 1)];
    for r in 0..wh {
        let row = &img.row(window.row + r)[window.col..window.col + ww];
        let (mut a, mut b) = (0.0, 0.0);
        for c in 0..ww {
            let v = row[c] as f64;
            a += v;
            b += v * v;
            s1[(r + 1) * (ww + 1) + c + 1] = s1[r * (ww + 1) + c + 1] + a;
            s2[(r + 1) * (ww + 1) + c + 1] = s2[r * (ww + 1) + c + 1] + b;
        }
    }
    let n = (tw * th) as f64;
    let box_sum = |s: &[f64], i: usize, j: usize| {
        s[(j + th) * (ww + 1) + i + tw] - s[j * (ww + 1) + i + tw] - s[(j + th) * (ww + 1) + i]
            + s[j * (ww + 1) + i]
    };
    // Direct sums cost sw·sh·tw·th multiply–adds, the FFT about 2·ww·wh·log2(ww·wh)
    // butterflies of ~10 flops; the factor was tuned with benches/matching_ncc.py.
    let direct_cost = (sw * sh * tw * th) as f64;
    let fft_cost = 20.0 * (ww * wh) as f64 * ((ww * wh) as f64).log2();
    let use_fft = match method {
        CorrelationMethod::Auto => direct_cost > fft_cost,
        CorrelationMethod::Direct => false,
        CorrelationMethod::Fft => true,
    };
    let mut values = if use_fft {
        let mut win = Vec::with_capacity(ww * wh);
        for r in 0..wh {
            win.extend_from_slice(&img.row(window.row + r)[window.col..window.col + ww]);
        }
        correlate_fft(&win, ww, wh, &t, tw, th)
    } else {
        let mut v = vec![0.0f32; sw * sh];
        let fill = |(j, out): (usize, &mut [f32])| {
            let rows: Vec<&[f32]> = (0..th)
                .map(|r| &img.row(window.row + j + r)[window.col..window.col + ww])
                .collect();
            correlate_row(out, &rows, &t, tw);
        };
        // Small surfaces are cheaper on one thread than the cost of waking the pool.
        if direct_cost < (1 << 21) as f64 {
            v.chunks_mut(sw).enumerate().for_each(fill);
        } else {
            v.par_chunks_mut(sw).enumerate().for_each(fill);
        }
        v
    };
    for (j, out) in values.chunks_mut(sw).enumerate() {
        for (i, o) in out.iter_mut().enumerate() {
            let sum = box_sum(&s1, i, j);
            let var = box_sum(&s2, i, j) - sum * sum / n;
            *o = if var > 1e-12 * n {
                (*o as f64 / (var.sqrt() * tnorm)).clamp(-1.0, 1.0) as f32
            } else {
                0.0
            };
        }
    }
    Ok(NccSurface {
        window,
        width: sw,
        height: sh,
        values,
    })
}

impl NccSurface {
    #[inline]
    fn v(&self, i: usize, j: usize, absolute: bool) -> f64 {
        let v = self.values[j * self.width + i] as f64;
        if absolute {
            v.abs()
        } else {
            v
        }
    }

    /// Best peak (sub-pixel by a parabola through the neighbours in x and in y) and the
    /// second-best local maximum at least `exclusion` positions away.
    pub fn peak(&self, tw: usize, th: usize, exclusion: usize, absolute: bool) -> NccPeak {
        let (w, h) = (self.width, self.height);
        let mut best = (0usize, 0usize, f64::NEG_INFINITY);
        for j in 0..h {
            for i in 0..w {
                let v = self.v(i, j, absolute);
                if v > best.2 {
                    best = (i, j, v);
                }
            }
        }
        let (bi, bj, bv) = best;
        let mut second = f64::NEG_INFINITY;
        for j in 0..h {
            for i in 0..w {
                if i.abs_diff(bi) <= exclusion && j.abs_diff(bj) <= exclusion {
                    continue;
                }
                let v = self.v(i, j, absolute);
                if v <= second {
                    continue;
                }
                let is_max = (j.saturating_sub(1)..(j + 2).min(h)).all(|jj| {
                    (i.saturating_sub(1)..(i + 2).min(w)).all(|ii| self.v(ii, jj, absolute) <= v)
                });
                if is_max {
                    second = v;
                }
            }
        }
        let para = |m: f64, c: f64, p: f64| {
            let d = m - 2.0 * c + p;
            if d < 0.0 {
                (0.5 * (m - p) / d).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        };
        let dx = if bi > 0 && bi + 1 < w {
            para(
                self.v(bi - 1, bj, absolute),
                bv,
                self.v(bi + 1, bj, absolute),
            )
        } else {
            0.0
        };
        let dy = if bj > 0 && bj + 1 < h {
            para(
                self.v(bi, bj - 1, absolute),
                bv,
                self.v(bi, bj + 1, absolute),
            )
        } else {
            0.0
        };
        let second = second.max(0.0);
        NccPeak {
            x: self.window.col as f64 + bi as f64 + dx + tw as f64 / 2.0,
            y: self.window.row as f64 + bj as f64 + dy + th as f64 / 2.0,
            ncc: bv,
            second,
            ratio: if bv > 0.0 { second / bv } else { 1.0 },
        }
    }
}

/// NCC search of `tpl` over `window` of `img` at one resolution.
pub fn ncc_search(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    absolute: bool,
) -> Result<NccPeak> {
    let s = ncc_surface(img, tpl, window)?;
    let excl = (tpl.width.min(tpl.height) / 4).max(2);
    Ok(s.peak(tpl.width, tpl.height, excl, absolute))
}

/// Coarse-to-fine NCC: a full search of `window` at the coarsest level where the
/// template still has `min_template_px` pixels across, then ±2 px searches around the
/// doubled position on each finer level, ending at full resolution. The ambiguity ratio
/// is the one of the full search (the only level where all candidates compete).
pub fn ncc_search_pyramid(
    pyr: &Pyramid,
    tpl: &GreyImage,
    window: Window,
    min_template_px: usize,
    absolute: bool,
) -> Result<NccPeak> {
    let img = &pyr.levels[0];
    if window.width < tpl.width || window.height < tpl.height {
        return Err(MatchingError::TooSmall {
            what: "search window".into(),
            width: window.width,
            height: window.height,
            tw: tpl.width,
            th: tpl.height,
        });
    }
    prepared_template(tpl, "template")?;
    let mut tpls = vec![tpl.clone()];
    let mut level = 0;
    while level + 1 < pyr.levels.len() {
        let t = tpls.last().expect("level 0");
        let l = level + 1;
        let s = 1usize << l;
        if t.width / 2 < min_template_px.max(3)
            || t.height / 2 < min_template_px.max(3)
            || window.width / s < t.width / 2 + 2
            || window.height / s < t.height / 2 + 2
        {
            break;
        }
        let next = super::pyramid::downsample(t);
        if next.std_dev() < 1e-6 {
            break;
        }
        tpls.push(next);
        level = l;
    }
    let scale_win = |l: usize| {
        let s = 1usize << l;
        let lv = &pyr.levels[l];
        let c0 = window.col.div_ceil(s);
        let r0 = window.row.div_ceil(s);
        let c1 = ((window.col + window.width) / s).min(lv.width);
        let r1 = ((window.row + window.height) / s).min(lv.height);
        Window {
            col: c0,
            row: r0,
            width: c1.saturating_sub(c0),
            height: r1.saturating_sub(r0),
        }
    };
    let coarse = ncc_search(&pyr.levels[level], &tpls[level], scale_win(level), absolute)?;
    let mut peak = coarse;
    for l in (0..level).rev() {
        let t = &tpls[l];
        let lim = scale_win(l);
        // Predicted template centre at this level, then a ±2 px window around it.
        let (px, py) = (peak.x * 2.0, peak.y * 2.0);
        let half_w = t.width as f64 / 2.0 + 2.5;
        let half_h = t.height as f64 / 2.0 + 2.5;
        let c0 = ((px - half_w).floor().max(lim.col as f64)) as usize;
        let r0 = ((py - half_h).floor().max(lim.row as f64)) as usize;
        let c1 = ((px + half_w).ceil() as usize).min(lim.col + lim.width);
        let r1 = ((py + half_h).ceil() as usize).min(lim.row + lim.height);
        let w = Window {
            col: c0,
            row: r0,
            width: c1.saturating_sub(c0),
            height: r1.saturating_sub(r0),
        };
        peak = ncc_search(&pyr.levels[l], t, w, absolute)?;
    }
    peak.second = coarse.second;
    peak.ratio = coarse.ratio;
    let _ = img;
    Ok(peak)
}
