//! Census transform: each pixel becomes a bit string saying which pixels of a window
//! around it are darker than it, so the matching cost (the Hamming distance of two bit
//! strings) ignores radiometric differences that keep the order of grey values.

use crate::matching::GreyImage;
use rayon::prelude::*;

/// Census of `img` over a window of `cw × ch` samples `stride` pixels apart (odd sides, at
/// most 64 bits without the centre): bit k is set where the window's k-th sample
/// (row-major, centre skipped) is darker than the centre. Windows are clamped at the
/// image edges.
pub fn census_transform(img: &GreyImage, cw: usize, ch: usize, stride: usize) -> Vec<u64> {
    assert!(
        cw % 2 == 1 && ch % 2 == 1 && cw * ch - 1 <= 64,
        "census window {cw}×{ch} must have odd sides and at most 65 pixels"
    );
    let w = img.width;
    let mut out = vec![0u64; w * img.height];
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, bits)| super::simd::census_row(img, y, cw, ch, stride, bits));
    out
}

/// One row of [`census_transform`] (the kernel the SIMD dispatch instantiates).
#[inline(always)]
pub(crate) fn census_row_generic(
    img: &GreyImage,
    y: usize,
    cw: usize,
    ch: usize,
    stride: usize,
    bits: &mut [u64],
) {
    window_bits(img, y, [cw, ch, stride], bits, |n, c| n < c);
}

/// One row of [`support_masks`] (the kernel the SIMD dispatch instantiates).
#[inline(always)]
pub(crate) fn support_row_generic(
    img: &GreyImage,
    y: usize,
    window: [usize; 3],
    tau: f32,
    bits: &mut [u64],
) {
    window_bits(img, y, window, bits, |n, c| (n - c).abs() <= tau);
}

/// Sets bit k of each pixel of row `y` where `test(sample, centre)` holds for the k-th
/// sample of its window (`[columns, rows, stride]`; row-major, centre skipped, clamped
/// at the image edges).
#[inline(always)]
fn window_bits(
    img: &GreyImage,
    y: usize,
    [cw, ch, stride]: [usize; 3],
    bits: &mut [u64],
    test: impl Fn(f32, f32) -> bool,
) {
    let (w, h) = (img.width, img.height);
    let (rx, ry) = ((cw / 2) as isize, (ch / 2) as isize);
    let st = stride.max(1) as isize;
    let centre = img.row(y);
    let mut k = 0u32;
    for dy in -ry..=ry {
        let ny = (y as isize + st * dy).clamp(0, h as isize - 1) as usize;
        let nb = img.row(ny);
        for sx in -rx..=rx {
            if sx == 0 && dy == 0 {
                continue;
            }
            let dx = st * sx;
            // Columns whose neighbour lies inside the row: no clamping.
            let lo = ((-dx).max(0) as usize).min(w);
            let hi = (w as isize - dx.max(0)).max(lo as isize) as usize;
            let shifted = &nb[(lo as isize + dx) as usize..(hi as isize + dx) as usize];
            for ((b, &c), &n) in bits[lo..hi].iter_mut().zip(&centre[lo..hi]).zip(shifted) {
                *b |= (test(n, c) as u64) << k;
            }
            for x in (0..lo).chain(hi..w) {
                let nx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                bits[x] |= (test(nb[nx], centre[x]) as u64) << k;
            }
            k += 1;
        }
    }
}

/// Support of each pixel's census window: bit k (the census's order) is set where the
/// window's k-th sample differs from the centre by at most `tau` grey values, i.e. likely
/// lies on the centre's own surface (adaptive support, after Yoon & Kweon 2005, as a mask
/// over the census bits; the cost counts the differing bits within it). A window across a
/// roof's eave then compares the pixel with the samples of its own side only, so the
/// nearer surface's disparity is not carried across the edge (edge fattening).
pub fn support_masks(img: &GreyImage, cw: usize, ch: usize, stride: usize, tau: f32) -> Vec<u64> {
    let w = img.width;
    let mut out = vec![0u64; w * img.height];
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, bits)| super::simd::support_row(img, y, [cw, ch, stride], tau, bits));
    out
}

/// The 2nd to 98th percentile range of the grey values of the pixels with data (of every
/// 7th such pixel: the range, not its last grey value, matters), 0 without data.
pub(crate) fn grey_range(img: &GreyImage, valid: &[bool]) -> f32 {
    let mut v: Vec<f32> = img
        .data
        .iter()
        .zip(valid)
        .step_by(7)
        .filter(|(g, ok)| **ok && g.is_finite())
        .map(|(g, _)| *g)
        .collect();
    if v.is_empty() {
        return 0.0;
    }
    let n = v.len() - 1;
    let lo = *v.select_nth_unstable_by(n / 50, f32::total_cmp).1;
    let hi = *v.select_nth_unstable_by(n - n / 50, f32::total_cmp).1;
    hi - lo
}
