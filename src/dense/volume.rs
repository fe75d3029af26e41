//! The cost volume with a band of disparities of its own per pixel: pixel p holds
//! `len[p]` consecutive disparities from `dmin[p]`, stored at `offset[p]..offset[p + 1]`
//! of flat arrays (u8 census costs, i16 aggregated costs), rows one after another.

use rayon::prelude::*;
use std::ops::Range;

/// Per-pixel disparity bands of a `width × height` image and their place in the volume.
#[derive(Debug, Clone)]
pub(crate) struct Bands {
    pub width: usize,
    pub height: usize,
    pub dmin: Vec<i32>,
    pub len: Vec<u16>,
    /// Entries at the start of each band that only pad it to whole vectors: the band
    /// asked for is `pad[p]..pad[p] + real[p]` of the pixel's entries. Matching costs and
    /// sums the padding too, but a winner is taken from the band asked for only; else a
    /// prior band that excludes the truth would find it a few pixels beyond its edge.
    pub pad: Vec<u8>,
    pub real: Vec<u16>,
    /// `width·height + 1` prefix sums of `len`.
    pub offset: Vec<u32>,
}

/// Widest band of one pixel (entries of the aggregation's row buffers are i16, sums stay
/// far below i16::MAX for any band; this bounds the per-pixel work).
pub(crate) const MAX_BAND: i32 = 4096;

/// Bands are whole multiples of this many disparities, so the kernels run on full
/// vectors (16 i16 lanes of AVX2) with no scalar remainder; the extra disparities are
/// searched like the others.
pub(crate) const LANES: usize = 16;

impl Bands {
    /// Bands from `band(x, y)` = inclusive [lo, hi] or `None`, clipped so that the right
    /// position `x − d` lies in `0..right_width`, then widened on both sides to a
    /// multiple of [`LANES`] (the widening may reach up to `LANES − 1` positions beyond the
    /// right image). Fails (returns `None`) when the volume would exceed `u32` entries.
    pub fn new(
        width: usize,
        height: usize,
        right_width: usize,
        band: impl Fn(usize, usize) -> Option<(i32, i32)> + Sync,
    ) -> Option<Self> {
        let n = width * height;
        let mut dmin = vec![0i32; n];
        let mut len = vec![0u16; n];
        let mut pad = vec![0u8; n];
        let mut real = vec![0u16; n];
        dmin.par_chunks_mut(width)
            .zip(len.par_chunks_mut(width))
            .zip(pad.par_chunks_mut(width).zip(real.par_chunks_mut(width)))
            .enumerate()
            .for_each(|(y, ((dm, ln), (pd, rl)))| {
                for x in 0..width {
                    let Some((lo, hi)) = band(x, y) else {
                        continue;
                    };
                    // x − d ∈ [0, right_width − 1]  ⇔  d ∈ [x − right_width + 1, x].
                    let lo = lo.max(x as i32 - right_width as i32 + 1);
                    let hi = hi.min(x as i32).min(lo + MAX_BAND - 1);
                    if hi >= lo {
                        let n = (hi - lo + 1) as usize;
                        let padded = n.div_ceil(LANES) * LANES;
                        dm[x] = lo - ((padded - n) / 2) as i32;
                        ln[x] = padded as u16;
                        pd[x] = ((padded - n) / 2) as u8;
                        rl[x] = n as u16;
                    }
                }
            });
        let mut offset = Vec::with_capacity(n + 1);
        let mut total = 0u64;
        offset.push(0u32);
        for &l in &len {
            total += l as u64;
            if total > u32::MAX as u64 {
                return None;
            }
            offset.push(total as u32);
        }
        Some(Self {
            width,
            height,
            dmin,
            len,
            pad,
            real,
            offset,
        })
    }

    pub fn total(&self) -> usize {
        *self.offset.last().expect("offsets") as usize
    }

    /// Volume entries of row `y`.
    #[inline]
    pub fn row_range(&self, y: usize) -> Range<usize> {
        self.offset[y * self.width] as usize..self.offset[(y + 1) * self.width] as usize
    }

    /// Largest number of entries of one row.
    pub fn max_row(&self) -> usize {
        (0..self.height)
            .map(|y| self.row_range(y).len())
            .max()
            .unwrap_or(0)
    }

    /// Splits a volume-shaped slice into its rows.
    pub fn split_rows<'a, T>(&self, mut data: &'a mut [T]) -> Vec<&'a mut [T]> {
        let mut rows = Vec::with_capacity(self.height);
        for y in 0..self.height {
            let (row, rest) = data.split_at_mut(self.row_range(y).len());
            rows.push(row);
            data = rest;
        }
        rows
    }
}

/// Census matching costs of the whole volume: the Hamming distance between the left
/// pixel's census and the right one's at `x − d`; `cost_max` where the right pixel has
/// no data or lies beyond the right image. With `support` (each left pixel's mask of
/// census bits, [`super::census::support_masks`]) only the bits within the mask count,
/// scaled to all of them; a pixel with fewer than a quarter of the bits in its support (a
/// lone speck of grey) is matched on all of them rather than on a handful.
#[allow(clippy::too_many_arguments)]
pub(crate) fn census_costs(
    bands: &Bands,
    left: &[u64],
    support: Option<&[u64]>,
    right: &[u64],
    right_width: usize,
    right_valid: &[bool],
    cost_max: u8,
) -> Vec<u8> {
    let mut costs = vec![0u8; bands.total()];
    let w = bands.width;
    let rows = bands.split_rows(&mut costs);
    rows.into_par_iter().enumerate().for_each(|(y, out)| {
        // The right row with LANES columns of no data on both sides.
        let mut penalty = vec![cost_max; right_width + 2 * LANES];
        for (p, &v) in penalty[LANES..]
            .iter_mut()
            .zip(&right_valid[y * right_width..(y + 1) * right_width])
        {
            if v {
                *p = 0;
            }
        }
        let mut cr = vec![0u64; right_width + 2 * LANES];
        cr[LANES..LANES + right_width]
            .copy_from_slice(&right[y * right_width..(y + 1) * right_width]);
        let cl = &left[y * w..(y + 1) * w];
        let base = y * w;
        // Each pixel's support and the factor (Q8) that scales its share of the bits to
        // all of them, so the costs of pixels with more or fewer support bits stay on
        // one scale for the aggregation's penalties.
        let all = if cost_max >= 64 {
            u64::MAX
        } else {
            (1u64 << cost_max) - 1
        };
        let mask: Vec<u64> = match support {
            Some(m) => m[base..base + w]
                .iter()
                .map(|&m| {
                    if m.count_ones() * 4 >= cost_max as u32 {
                        m
                    } else {
                        all
                    }
                })
                .collect(),
            None => vec![all; w],
        };
        let scale: Vec<u16> = mask
            .iter()
            .map(|m| ((cost_max as u32 * 256) / m.count_ones().max(1)) as u16)
            .collect();
        let row0 = bands.offset[base] as usize;
        super::simd::costs_row(
            (cl, &mask, &scale),
            &cr,
            &penalty,
            &bands.dmin[base..base + w],
            &bands.offset[base..base + w + 1],
            row0,
            out,
        );
    });
    costs
}

/// One row of [`census_costs`] (the kernel the SIMD dispatch instantiates). `left`: each
/// left pixel's census, its support (a mask of the census bits) and the factor (Q8) that
/// scales the bits differing within it to all of them.
#[inline(always)]
pub(crate) fn costs_row_generic(
    (cl, mask, scale): (&[u64], &[u64], &[u16]),
    cr: &[u64],
    penalty: &[u8],
    dmin: &[i32],
    offset: &[u32],
    row0: usize,
    out: &mut [u8],
) {
    for (x, &c) in cl.iter().enumerate() {
        let (s, e) = (offset[x] as usize - row0, offset[x + 1] as usize - row0);
        if e == s {
            continue;
        }
        let n = e - s;
        // Right positions x − dmin − k for k = 0..n, i.e. the slice [x − dmin − n + 1, x − dmin]
        // read backwards (the right row starts LANES columns early).
        let hi = (x as i32 - dmin[x] + LANES as i32) as usize;
        let lo = hi + 1 - n;
        let o = &mut out[s..e];
        let r = &cr[lo..=hi];
        let p = &penalty[lo..=hi];
        let (m, f) = (mask[x], scale[x] as u32);
        for ((o, &rv), &pv) in o.iter_mut().zip(r.iter().rev()).zip(p.iter().rev()) {
            *o = ((((c ^ rv) & m).count_ones() * f + 128) >> 8).min(255) as u8;
            *o = (*o).max(pv);
        }
    }
}
