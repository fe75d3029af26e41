//! Normalised cross-correlation. Window means and variances come from integral images,
//! so each position costs one multiply–add per template pixel against the zero-mean
//! template; the correlation sum is accumulated as row-wise axpy updates over all
//! positions of a result row, which the compiler vectorises. Result rows run in
//! parallel (rayon) and each is computed independently, so results do not depend on
//! the thread count.

use super::pyramid::Levels;
use super::{holds_template, invalid, GreyImage, MatchingError, Result};
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

/// Source of the correlation: the search window as a row-major view into the image
/// (`stride` = image width), so no copy is made for the direct sums.
#[derive(Clone, Copy)]
struct WinView<'a> {
    data: &'a [f32],
    stride: usize,
    width: usize,
    height: usize,
}

impl WinView<'_> {
    #[inline]
    fn row(&self, r: usize) -> &[f32] {
        &self.data[r * self.stride..r * self.stride + self.width]
    }
}

/// B outputs of one row held in registers while the whole template streams past.
#[inline(always)]
fn portable_block<const B: usize>(
    win: &WinView,
    j: usize,
    t: &[f32],
    tw: usize,
    i0: usize,
) -> [f32; B] {
    let th = t.len() / tw;
    let mut acc = [0.0f32; B];
    for r in 0..th {
        let row = &win.row(j + r)[i0..];
        let trow = &t[r * tw..(r + 1) * tw];
        for (c, &tv) in trow.iter().enumerate() {
            let src: &[f32; B] = row[c..c + B].try_into().expect("block inside the row");
            for k in 0..B {
                acc[k] += tv * src[k];
            }
        }
    }
    acc
}

/// Portable direct sums for one output row: out[i] = Σ_r Σ_c t[r][c] · win[j + r][i + c],
/// in constant-size register blocks (32, then 8, the tail as an overlapping block) so the
/// compiler vectorises them for whatever baseline the target has (SSE2 on generic
/// x86-64); 32 outputs are 8 independent accumulator chains, enough to hide the add
/// latency.
fn correlate_row_portable(out: &mut [f32], win: &WinView, j: usize, t: &[f32], tw: usize) {
    let sw = out.len();
    let mut i = 0;
    while i + 32 <= sw {
        out[i..i + 32].copy_from_slice(&portable_block::<32>(win, j, t, tw, i));
        i += 32;
    }
    while i + 8 <= sw {
        out[i..i + 8].copy_from_slice(&portable_block::<8>(win, j, t, tw, i));
        i += 8;
    }
    if i < sw && sw >= 8 {
        out[sw - 8..].copy_from_slice(&portable_block::<8>(win, j, t, tw, sw - 8));
        i = sw;
    }
    while i < sw {
        out[i] = portable_block::<1>(win, j, t, tw, i)[0];
        i += 1;
    }
}

/// AVX2/FMA register-blocked direct correlation (x86-64 with run-time detection; the
/// crate is built for generic x86-64, so this is the only place the wide units are used).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::WinView;
    use std::arch::x86_64::*;

    /// A KR×(8·KV) block of outputs at (i0, j0) held in KR·KV ymm accumulators while the
    /// whole template streams past: per template pixel one broadcast and KR·KV unaligned
    /// loads feed KR·KV independent FMA chains, enough to hide the FMA latency when
    /// KR·KV = 8. Rows below `skip` are not stored (the overlapping tail block of a band).
    ///
    /// # Safety
    /// AVX2 and FMA must be available; the block must lie inside the valid positions of
    /// `win` (i0 + 8·KV ≤ sw, j0 + KR ≤ sh), and `out` holds rows j_lo.. of width sw.
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn block<const KR: usize, const KV: usize>(
        win: &WinView,
        t: &[f32],
        tw: usize,
        i0: usize,
        j0: usize,
        skip: usize,
        out: &mut [f32],
        out_row0: usize,
        sw: usize,
    ) {
        let th = t.len() / tw;
        debug_assert!((j0 + KR - 1 + th - 1) * win.stride + i0 + 8 * KV + tw - 1 <= win.data.len());
        let base = win.data.as_ptr();
        let mut acc = [[_mm256_setzero_ps(); KV]; KR];
        for r in 0..th {
            let trow = t.as_ptr().add(r * tw);
            let rowp: [*const f32; KR] =
                std::array::from_fn(|k| base.add((j0 + k + r) * win.stride + i0));
            for c in 0..tw {
                let tv = _mm256_broadcast_ss(&*trow.add(c));
                for (accr, p) in acc.iter_mut().zip(&rowp) {
                    for (v, a) in accr.iter_mut().enumerate() {
                        *a = _mm256_fmadd_ps(_mm256_loadu_ps(p.add(c + 8 * v)), tv, *a);
                    }
                }
            }
        }
        for (k, a) in acc.iter().enumerate().skip(skip) {
            let o = (j0 + k - out_row0) * sw + i0;
            let dst = &mut out[o..o + 8 * KV];
            for (v, av) in a.iter().enumerate() {
                _mm256_storeu_ps(dst.as_mut_ptr().add(8 * v), *av);
            }
        }
    }
}

/// Block shape (rows, 8-lane vectors) for the AVX2 kernel: the fewest kernel calls
/// weighted by their cost; 8 accumulators hide the FMA latency, fewer are latency-bound
/// and cost about the same per template pixel however few there are.
fn block_shape(sw: usize, sh: usize) -> Option<(usize, usize)> {
    const SHAPES: [(usize, usize); 10] = [
        (1, 8),
        (2, 4),
        (4, 2),
        (8, 1),
        (1, 4),
        (2, 2),
        (4, 1),
        (1, 2),
        (2, 1),
        (1, 1),
    ];
    SHAPES
        .iter()
        .filter(|&&(kr, kv)| sh >= kr && sw >= 8 * kv)
        .map(|&(kr, kv)| {
            let blocks = sw.div_ceil(8 * kv) * sh.div_ceil(kr);
            let cost = blocks as f64 * if kr * kv == 8 { 4.5 } else { 4.0 };
            (cost, kr, kv)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, kr, kv)| (kr, kv))
}

/// Correlation numerator for output rows j_lo..j_hi into `out` (those rows, width sw).
#[allow(clippy::too_many_arguments)] // the kernel's geometry, passed flat on purpose
fn correlate_band(
    win: &WinView,
    t: &[f32],
    tw: usize,
    sw: usize,
    j_lo: usize,
    j_hi: usize,
    out: &mut [f32],
    shape: Option<(usize, usize)>,
) {
    #[cfg(target_arch = "x86_64")]
    if let Some((kr, kv)) = shape {
        macro_rules! run {
            ($kr:literal, $kv:literal) => {{
                let mut j = j_lo;
                while j < j_hi {
                    // The last block of a band overlaps upwards instead of running short;
                    // rows above the band are computed but not stored.
                    let j0 = j.min(j_hi - $kr);
                    let skip = j - j0;
                    let mut i = 0;
                    while i < sw {
                        let i0 = i.min(sw - 8 * $kv);
                        // SAFETY: shape was chosen with sh ≥ KR and sw ≥ 8·KV, and
                        // `shape` is Some only when AVX2 and FMA were detected.
                        unsafe { avx2::block::<$kr, $kv>(win, t, tw, i0, j0, skip, out, j_lo, sw) };
                        i += 8 * $kv;
                    }
                    j = j0 + $kr;
                }
            }};
        }
        match (kr, kv) {
            (1, 8) => run!(1, 8),
            (2, 4) => run!(2, 4),
            (4, 2) => run!(4, 2),
            (8, 1) => run!(8, 1),
            (1, 4) => run!(1, 4),
            (2, 2) => run!(2, 2),
            (4, 1) => run!(4, 1),
            (1, 2) => run!(1, 2),
            (2, 1) => run!(2, 1),
            _ => run!(1, 1),
        }
        return;
    }
    let _ = shape;
    for (j, o) in (j_lo..j_hi).zip(out.chunks_mut(sw)) {
        correlate_row_portable(o, win, j, t, tw);
    }
}

/// Direct correlation numerator of every valid position (row-major, sw × sh).
fn correlate_direct(win: &WinView, t: &[f32], tw: usize, th: usize, out: &mut [f32]) {
    let (sw, sh) = (win.width + 1 - tw, win.height + 1 - th);
    #[cfg(target_arch = "x86_64")]
    let shape = if std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
    {
        block_shape(sw, sh)
    } else {
        None
    };
    #[cfg(not(target_arch = "x86_64"))]
    let shape = None;
    let macs = sw * sh * tw * th;
    let threads = rayon::current_num_threads();
    // Below ~1 ms of work on one core, waking the pool costs more than it saves.
    if macs < (1 << 22) || threads < 2 || sh < 16 {
        correlate_band(win, t, tw, sw, 0, sh, out, shape);
        return;
    }
    // Bands of whole output rows, a few per thread for balance; each band is computed
    // independently, so the split does not change any value.
    let band = sh.div_ceil(threads * 2).max(8);
    out.par_chunks_mut(band * sw)
        .enumerate()
        .for_each(|(b, o)| {
            let j_lo = b * band;
            let j_hi = (j_lo + band).min(sh);
            correlate_band(win, t, tw, sw, j_lo, j_hi, o, shape);
        });
}

/// Scratch buffers and FFT plans reused across calls on one thread (tie matching calls
/// this thousands of times; fresh half-megabyte buffers cost page faults every time).
#[derive(Default)]
struct FftWork {
    planner: Option<FftPlanner<f32>>,
    a: Vec<Complex32>,
    b: Vec<Complex32>,
    scratch: Vec<Complex32>,
}

thread_local! {
    static FFT_WORK: RefCell<FftWork> = RefCell::new(FftWork::default());
}

/// Smallest n' ≥ n whose prime factors are 2, 3 and 5 (fast FFT sizes); padding the
/// window with zeros there leaves the valid positions unchanged.
fn fast_len(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k % p == 0 {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

/// Row-major w×h → h×w (only the first `rows_out` output rows), in 16×16 tiles to stay
/// in cache.
fn transpose(src: &[Complex32], dst: &mut [Complex32], w: usize, h: usize, rows_out: usize) {
    const T: usize = 16;
    for c0 in (0..rows_out).step_by(T) {
        for r0 in (0..h).step_by(T) {
            for c in c0..(c0 + T).min(rows_out) {
                let d = &mut dst[c * h..c * h + h];
                for r in r0..(r0 + T).min(h) {
                    d[r] = src[r * w + c];
                }
            }
        }
    }
}

/// Runs `f` over consecutive rows of length `len` (the first `rows` of them), on the
/// pool when the transform is large enough to pay for it.
fn fft_rows(
    data: &mut [Complex32],
    len: usize,
    rows: usize,
    f: &Arc<dyn Fft<f32>>,
    scratch: &mut Vec<Complex32>,
    parallel: bool,
) {
    let data = &mut data[..len * rows];
    let need = f.get_inplace_scratch_len();
    if parallel {
        let per = rows.div_ceil(rayon::current_num_threads() * 2).max(1);
        data.par_chunks_mut(len * per).for_each_init(
            || vec![Complex32::default(); need],
            |s, chunk| f.process_with_scratch(chunk, s),
        );
    } else {
        if scratch.len() < need {
            scratch.resize(need, Complex32::default());
        }
        f.process_with_scratch(data, &mut scratch[..need]);
    }
}

/// Correlation numerator Σ t'(r, c) · I(j + r, i + c) for every valid position through
/// the FFT. Window and zero-padded template are packed as real and imaginary parts of
/// one complex array (one forward transform for both) and separated by conjugate
/// symmetry. The spectrum stays transposed after the column pass, the product is formed
/// there, and the inverse runs the column pass on all columns but the row pass only on
/// the sh output rows. The circular correlation equals the linear one on the valid
/// positions because the template never wraps there.
fn correlate_fft(win: &WinView, t: &[f32], tw: usize, th: usize, out: &mut [f32]) {
    // While this thread waits inside a parallel FFT pass, rayon may hand it another
    // correlation (work stealing from an outer parallel loop); the buffers are then in
    // use, and that nested call works with fresh ones instead.
    FFT_WORK.with(|w| match w.try_borrow_mut() {
        Ok(mut guard) => correlate_fft_with(&mut guard, win, t, tw, th, out),
        Err(_) => correlate_fft_with(&mut FftWork::default(), win, t, tw, th, out),
    });
}

fn correlate_fft_with(
    work: &mut FftWork,
    win: &WinView,
    t: &[f32],
    tw: usize,
    th: usize,
    out: &mut [f32],
) {
    let (ww, wh) = (win.width, win.height);
    let (sw, sh) = (ww + 1 - tw, wh + 1 - th);
    let (nw, nh) = (fast_len(ww), fast_len(wh));
    let parallel = nw * nh >= 160 * 160 && rayon::current_num_threads() > 1;
    let planner = work.planner.get_or_insert_with(FftPlanner::new);
    let (fw, fh) = (planner.plan_fft_forward(nw), planner.plan_fft_forward(nh));
    let (iw, ih) = (planner.plan_fft_inverse(nw), planner.plan_fft_inverse(nh));
    let n = nw * nh;
    work.a.clear();
    work.a.resize(n, Complex32::default());
    if work.b.len() < n {
        work.b.resize(n, Complex32::default());
    }
    let (a, b) = (&mut work.a[..], &mut work.b[..n]);
    for r in 0..wh {
        for (d, &v) in a[r * nw..r * nw + ww].iter_mut().zip(win.row(r)) {
            d.re = v;
        }
    }
    for r in 0..th {
        for (d, &v) in a[r * nw..r * nw + tw]
            .iter_mut()
            .zip(&t[r * tw..(r + 1) * tw])
        {
            d.im = v;
        }
    }
    fft_rows(a, nw, nh, &fw, &mut work.scratch, parallel);
    transpose(a, b, nw, nh, nw);
    fft_rows(b, nh, nw, &fh, &mut work.scratch, parallel);
    // b[u][v]: column frequency u, row frequency v. With Z₋ = conj Z(−u, −v):
    // X = (Z + Z₋)/2, T = (Z − Z₋)/(2i), and the correlation spectrum is
    // X · conj(T) = i (Z + Z₋) conj(Z − Z₋) / 4. It is Hermitian (the correlation
    // is real), so only u ≤ nw/2 is formed and transformed back.
    let hw = nw / 2 + 1;
    for u in 0..hw {
        let un = if u == 0 { 0 } else { nw - u };
        let (row, rown) = (&b[u * nh..(u + 1) * nh], &b[un * nh..(un + 1) * nh]);
        let dst = &mut a[u * nh..(u + 1) * nh];
        let prod = |z: Complex32, zn: Complex32| {
            let zn = zn.conj();
            let s = z + zn;
            let d = (z - zn).conj();
            let p = s * d * 0.25;
            Complex32::new(-p.im, p.re)
        };
        dst[0] = prod(row[0], rown[0]);
        for ((d, &z), &zn) in dst[1..]
            .iter_mut()
            .zip(&row[1..])
            .zip(rown[1..].iter().rev())
        {
            *d = prod(z, zn);
        }
    }
    fft_rows(a, nh, hw, &ih, &mut work.scratch, parallel);
    // a[u][y] for u ≤ nw/2; the rest of each output row is its conjugate mirror.
    // Two real output rows share one complex inverse: row y1 + i·row y2.
    let pairs = sh.div_ceil(2);
    for m in 0..pairs {
        let (y1, y2) = (2 * m, (2 * m + 1).min(nh - 1));
        let dst = &mut b[m * nw..(m + 1) * nw];
        for u in 0..hw {
            let (q1, q2) = (a[u * nh + y1], a[u * nh + y2]);
            dst[u] = Complex32::new(q1.re - q2.im, q1.im + q2.re);
            if u != 0 && nw - u >= hw {
                let (c1, c2) = (q1.conj(), q2.conj());
                dst[nw - u] = Complex32::new(c1.re - c2.im, c1.im + c2.re);
            }
        }
    }
    fft_rows(b, nw, pairs, &iw, &mut work.scratch, parallel);
    let scale = 1.0 / n as f32;
    for (j, o) in out.chunks_mut(sw).enumerate().take(sh) {
        let src = &b[(j / 2) * nw..(j / 2) * nw + sw];
        if j % 2 == 0 {
            for (d, s) in o.iter_mut().zip(src) {
                *d = s.re * scale;
            }
        } else {
            for (d, s) in o.iter_mut().zip(src) {
                *d = s.im * scale;
            }
        }
    }
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

/// [`ncc_surface`] with a chosen correlation method (benchmarks, tests). With
/// [`CorrelationMethod::Auto`], a window whose correlation buffers would exceed
/// [`NCC_SCRATCH_BYTES`] is correlated in bands of rows ([`band_rows`]), so only the
/// surface itself is whole.
pub fn ncc_surface_with(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    method: CorrelationMethod,
) -> Result<NccSurface> {
    check_window(img, tpl, window)?;
    let (tw, th) = (tpl.width, tpl.height);
    let (sw, sh) = (window.width - tw + 1, window.height - th + 1);
    let band = match method {
        CorrelationMethod::Auto => band_rows(window, tw, th)?,
        _ => None,
    };
    let Some(band) = band else {
        return surface_at_once(img, tpl, window, method);
    };
    let mut values = Vec::new();
    values.try_reserve_exact(sw * sh).map_err(|e| {
        invalid(
            "search window",
            format!("cannot allocate a correlation surface of {sw}×{sh}: {e}"),
        )
    })?;
    for j0 in (0..sh).step_by(band) {
        let j1 = (j0 + band).min(sh);
        let part = surface_at_once(img, tpl, rows_of(window, th, j0, j1), method)?;
        values.extend_from_slice(&part.values);
    }
    Ok(NccSurface {
        window,
        width: sw,
        height: sh,
        values,
    })
}

/// Refuses a window outside the image or smaller than the template, and a constant
/// template.
fn check_window(img: &GreyImage, tpl: &GreyImage, window: Window) -> Result<()> {
    if window.col + window.width > img.width || window.row + window.height > img.height {
        return Err(invalid(
            "search window",
            format!(
                "{}×{} at ({}, {}) is outside the {}×{} image",
                window.width, window.height, window.col, window.row, img.width, img.height
            ),
        ));
    }
    holds_template("search window", window.width, window.height, tpl)?;
    prepared_template(tpl, "template").map(|_| ())
}

/// Largest correlation buffers (bytes) one search or surface takes at once: the surface,
/// two f64 integral images and two complex FFT arrays of the window, about 36 bytes a
/// window pixel. A larger window is correlated in bands of rows (the same values but for
/// the last bits of the window sums and the FFT), twice for a search (its best peak, then
/// the second), so that matching a template in a whole photo holds no float copies of the
/// photo beyond its pyramid.
pub const NCC_SCRATCH_BYTES: u64 = 64 << 20;

/// Correlation buffers of a `ww`×`wh` window and a `tw`×`th` template (bytes).
fn scratch_bytes(ww: usize, wh: usize, tw: usize, th: usize) -> u64 {
    let (sw, sh) = ((ww + 1 - tw) as u64, (wh + 1 - th) as u64);
    let (ww, wh) = (ww as u64, wh as u64);
    4 * sw * sh
        + 16 * (ww + 1) * (wh + 1)
        + 16 * fast_len(ww as usize) as u64 * fast_len(wh as usize) as u64
}

/// Surface rows per band for a window whose buffers exceed [`NCC_SCRATCH_BYTES`] (`None`:
/// at once). Each band also computes one row above and below it (for the local maxima of
/// a search). A band of 8 rows of a template too tall for the limit is refused beyond four
/// times it.
fn band_rows(window: Window, tw: usize, th: usize) -> Result<Option<usize>> {
    let (ww, wh) = (window.width, window.height);
    if scratch_bytes(ww, wh, tw, th) <= NCC_SCRATCH_BYTES {
        return Ok(None);
    }
    let per_row = scratch_bytes(ww, th + 1, tw, th) / (th as u64 + 1);
    let mut band = ((NCC_SCRATCH_BYTES / per_row.max(1)) as usize)
        .saturating_sub(th + 1)
        .max(8);
    while band > 8 && scratch_bytes(ww, band + th + 1, tw, th) > NCC_SCRATCH_BYTES {
        band = (band * 7 / 8).max(8);
    }
    let need = scratch_bytes(ww, (band + th + 1).min(wh), tw, th);
    if need > 4 * NCC_SCRATCH_BYTES {
        return Err(invalid(
            "search window",
            format!(
                "a {}×{} template over a {ww}×{wh} window needs {need} bytes of correlation \
                 buffers even in bands of 8 rows, over 4 × {NCC_SCRATCH_BYTES}: search a \
                 narrower window or on a coarser pyramid level",
                tw, th
            ),
        ));
    }
    Ok(Some(band))
}

/// The part of `window` whose surface rows are `j0..j1` (template height `th`).
fn rows_of(window: Window, th: usize, j0: usize, j1: usize) -> Window {
    Window {
        col: window.col,
        row: window.row + j0,
        width: window.width,
        height: j1 - j0 + th - 1,
    }
}

/// The surface of a checked window in one piece.
fn surface_at_once(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    method: CorrelationMethod,
) -> Result<NccSurface> {
    let (tw, th) = (tpl.width, tpl.height);
    let (t, tnorm) = prepared_template(tpl, "template")?;
    let (sw, sh) = (window.width - tw + 1, window.height - th + 1);
    let (ww, wh) = (window.width, window.height);
    let view = WinView {
        data: &img.data[window.row * img.width + window.col..],
        stride: img.width,
        width: ww,
        height: wh,
    };
    // Direct sums cost sw·sh·tw·th multiply–adds at ~7 per cycle with the AVX2 kernel
    // (on a core with 128-bit FMA units; wider ones only favour direct) and ~2.5 with the
    // portable SSE2 loop; the FFT about k·N·log2 N for the padded size N. Rates and k
    // were measured with examples/ncc_timing.rs.
    let (nw, nh) = (fast_len(ww), fast_len(wh));
    let direct_cost = (sw * sh * tw * th) as f64 / direct_macs_per_cycle();
    let fft_cost = FFT_COST * (nw * nh) as f64 * ((nw * nh) as f64).log2();
    let use_fft = match method {
        CorrelationMethod::Auto => direct_cost > fft_cost,
        CorrelationMethod::Direct => false,
        CorrelationMethod::Fft => true,
    };
    let mut values = vec![0.0f32; sw * sh];
    if use_fft {
        correlate_fft(&view, &t, tw, th, &mut values);
    } else {
        correlate_direct(&view, &t, tw, th, &mut values);
    }
    normalise(&view, tw, th, tnorm, &mut values);
    Ok(NccSurface {
        window,
        width: sw,
        height: sh,
        values,
    })
}

fn direct_macs_per_cycle() -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        return 7.0;
    }
    2.5
}

/// Cycles per N·log2 N of the FFT path (three passes of complex transforms, two
/// transposes and the spectrum product).
const FFT_COST: f64 = 1.4;

/// Divides the numerators by the window standard deviations and the template norm. The
/// window sums come from integral images in f64: sums of squares of 16-bit data over a
/// large template reach 10^13, beyond f32, and the variance is their difference.
fn normalise(win: &WinView, tw: usize, th: usize, tnorm: f64, values: &mut [f32]) {
    thread_local! {
        static SUMS: RefCell<(Vec<f64>, Vec<f64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
    }
    let (ww, wh) = (win.width, win.height);
    let sw = ww + 1 - tw;
    SUMS.with(|s| {
        let mut guard = s.borrow_mut();
        let (s1, s2) = &mut *guard;
        let len = (ww + 1) * (wh + 1);
        s1.clear();
        s1.resize(len, 0.0);
        s2.clear();
        s2.resize(len, 0.0);
        for r in 0..wh {
            let row = win.row(r);
            let (head, tail) = s1.split_at_mut((r + 1) * (ww + 1));
            let (prev1, cur1) = (&head[r * (ww + 1)..], &mut tail[..ww + 1]);
            let (head, tail) = s2.split_at_mut((r + 1) * (ww + 1));
            let (prev2, cur2) = (&head[r * (ww + 1)..], &mut tail[..ww + 1]);
            let (mut a, mut b) = (0.0, 0.0);
            for c in 0..ww {
                let v = row[c] as f64;
                a += v;
                b += v * v;
                cur1[c + 1] = prev1[c + 1] + a;
                cur2[c + 1] = prev2[c + 1] + b;
            }
        }
        let n = (tw * th) as f64;
        let stride = ww + 1;
        let inv_tnorm = (1.0 / tnorm) as f32;
        let mut var = vec![0.0f32; sw];
        for (j, out) in values.chunks_mut(sw).enumerate() {
            let (top, bot) = (j * stride, (j + th) * stride);
            // The variance is a difference of large sums: f64 here, f32 after.
            let (t0, t1) = (&s1[top..top + sw], &s1[top + tw..top + tw + sw]);
            let (b0, b1) = (&s1[bot..bot + sw], &s1[bot + tw..bot + tw + sw]);
            let (q0, q1) = (&s2[top..top + sw], &s2[top + tw..top + tw + sw]);
            let (p0, p1) = (&s2[bot..bot + sw], &s2[bot + tw..bot + tw + sw]);
            let inv_n = 1.0 / n;
            for i in 0..sw {
                let sum = b1[i] - t1[i] - b0[i] + t0[i];
                let sq = p1[i] - q1[i] - p0[i] + q0[i];
                var[i] = ((sq - sum * sum * inv_n) * inv_n) as f32;
            }
            // Per-pixel variance (not the sum) keeps f32 far from overflow; a window
            // variance below 1e-12 of the grey scale² is treated as constant.
            let inv_n_sqrt = (1.0 / n.sqrt()) as f32;
            for (o, &v) in out.iter_mut().zip(&var) {
                *o = if v > 1e-12 {
                    (*o * inv_tnorm * inv_n_sqrt / v.sqrt()).clamp(-1.0, 1.0)
                } else {
                    0.0
                };
            }
        }
    });
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
        let dx = if bi > 0 && bi + 1 < w {
            parabola(
                self.v(bi - 1, bj, absolute),
                bv,
                self.v(bi + 1, bj, absolute),
            )
        } else {
            0.0
        };
        let dy = if bj > 0 && bj + 1 < h {
            parabola(
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

/// NCC search of `tpl` over `window` of `img` at one resolution. A window whose
/// correlation buffers exceed [`NCC_SCRATCH_BYTES`] is searched in bands of rows, twice:
/// the best peak first, then the second-best local maximum and the peak's neighbours.
pub fn ncc_search(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    absolute: bool,
) -> Result<NccPeak> {
    check_window(img, tpl, window)?;
    let excl = (tpl.width.min(tpl.height) / 4).max(2);
    match band_rows(window, tpl.width, tpl.height)? {
        None => {
            let s = surface_at_once(img, tpl, window, CorrelationMethod::Auto)?;
            Ok(s.peak(tpl.width, tpl.height, excl, absolute))
        }
        Some(band) => search_in_bands(img, tpl, window, band, excl, absolute),
    }
}

/// [`NccSurface::peak`] of the surface of `window`, computed in bands of `band` rows
/// (each with one row more above and below, the same in both passes).
fn search_in_bands(
    img: &GreyImage,
    tpl: &GreyImage,
    window: Window,
    band: usize,
    exclusion: usize,
    absolute: bool,
) -> Result<NccPeak> {
    let (tw, th) = (tpl.width, tpl.height);
    let (sw, sh) = (window.width - tw + 1, window.height - th + 1);
    // Rows j0..j1 and their computed rows lo..hi (with the neighbouring rows).
    let bands = || {
        (0..sh).step_by(band).map(move |j0| {
            let j1 = (j0 + band).min(sh);
            (j0, j1, j0.saturating_sub(1), (j1 + 1).min(sh))
        })
    };
    let part = |lo: usize, hi: usize| {
        surface_at_once(
            img,
            tpl,
            rows_of(window, th, lo, hi),
            CorrelationMethod::Auto,
        )
    };
    let mut best = (0usize, 0usize, f64::NEG_INFINITY);
    for (j0, j1, lo, hi) in bands() {
        let s = part(lo, hi)?;
        for j in j0..j1 {
            for i in 0..sw {
                let v = s.v(i, j - lo, absolute);
                if v > best.2 {
                    best = (i, j, v);
                }
            }
        }
    }
    let (bi, bj, bv) = best;
    let mut second = f64::NEG_INFINITY;
    let (mut dx, mut dy) = (0.0, 0.0);
    for (j0, j1, lo, hi) in bands() {
        let s = part(lo, hi)?;
        let h = hi - lo;
        if (j0..j1).contains(&bj) {
            let (r, v) = (bj - lo, |i: usize, r: usize| s.v(i, r, absolute));
            if bi > 0 && bi + 1 < sw {
                dx = parabola(v(bi - 1, r), bv, v(bi + 1, r));
            }
            if bj > 0 && bj + 1 < sh {
                dy = parabola(v(bi, r - 1), bv, v(bi, r + 1));
            }
        }
        for j in j0..j1 {
            let r = j - lo;
            for i in 0..sw {
                if i.abs_diff(bi) <= exclusion && j.abs_diff(bj) <= exclusion {
                    continue;
                }
                let v = s.v(i, r, absolute);
                if v <= second {
                    continue;
                }
                let is_max = (r.saturating_sub(1)..(r + 2).min(h)).all(|rr| {
                    (i.saturating_sub(1)..(i + 2).min(sw)).all(|ii| s.v(ii, rr, absolute) <= v)
                });
                if is_max {
                    second = v;
                }
            }
        }
    }
    let second = second.max(0.0);
    Ok(NccPeak {
        x: window.col as f64 + bi as f64 + dx + tw as f64 / 2.0,
        y: window.row as f64 + bj as f64 + dy + th as f64 / 2.0,
        ncc: bv,
        second,
        ratio: if bv > 0.0 { second / bv } else { 1.0 },
    })
}

/// Sub-pixel offset of a peak `c` between its neighbours `m` and `p` (a parabola through
/// the three), within ±0.5.
fn parabola(m: f64, c: f64, p: f64) -> f64 {
    let d = m - 2.0 * c + p;
    if d < 0.0 {
        (0.5 * (m - p) / d).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Coarse-to-fine NCC: a full search of `window` at the coarsest level where the
/// template still has `min_template_px` pixels across, then ±2 px searches around the
/// doubled position on each finer level, ending at full resolution. The ambiguity ratio
/// is the one of the full search (the only level where all candidates compete).
pub fn ncc_search_pyramid<P: Levels + ?Sized>(
    pyr: &P,
    tpl: &GreyImage,
    window: Window,
    min_template_px: usize,
    absolute: bool,
) -> Result<NccPeak> {
    holds_template("search window", window.width, window.height, tpl)?;
    prepared_template(tpl, "template")?;
    let mut tpls = vec![tpl.clone()];
    let mut level = 0;
    while level + 1 < pyr.count() {
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
        let lv = pyr.level(l);
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
    let coarse = ncc_search(pyr.level(level), &tpls[level], scale_win(level), absolute)?;
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
        peak = ncc_search(pyr.level(l), t, w, absolute)?;
    }
    peak.second = coarse.second;
    peak.ratio = coarse.ratio;
    Ok(peak)
}
