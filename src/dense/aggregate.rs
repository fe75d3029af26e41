//! Semi-global aggregation of the census costs along eight paths (Hirschmüller 2008) over
//! per-pixel disparity bands.
//!
//! Along a path r, `L_r(p, d) = C(p, d) + min(L_r(q, d), L_r(q, d ± 1) + P1,
//! min_k L_r(q, k) + P2) − min_k L_r(q, k)` with q the path's previous pixel; a
//! disparity outside q's band counts as unreachable except through the P2 jump. P2 falls
//! with the grey-value step from q to p so that depth edges, which mostly coincide with
//! grey-value edges, cost less. The eight paths run as two sweeps of four: top to bottom
//! (from the left, upper left, above, upper right) and bottom to top (the mirror), each
//! holding one row of path costs per direction. The two sweeps run in parallel into two
//! sums when more than one thread is available; the integer sums are the same either way.

use super::volume::{Bands, LANES};
use rayon::prelude::*;

/// Larger than any path cost; adding P1 or P2 to it cannot overflow i16.
pub(crate) const INF: i16 = 0x3FFF;

/// Smoothness penalties of one level.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Penalties {
    pub p1: i16,
    /// P2 by the grey-value step between the two pixels (0..=255, larger steps as 255).
    pub p2: [i16; 256],
}

impl Penalties {
    /// P1, and P2 falling with the grey-value step: `p2 · g / (g + step)`, at least P1
    /// (`gradient` ≤ 0: P2 constant).
    pub fn new(p1: i16, p2: i16, gradient: f32) -> Self {
        Self {
            p1,
            p2: std::array::from_fn(|step| {
                if gradient > 0.0 {
                    ((p2 as f32 * gradient / (gradient + step as f32)) as i16).max(p1)
                } else {
                    p2
                }
            }),
        }
    }

    #[inline(always)]
    fn p2(&self, a: f32, b: f32) -> i16 {
        // `as` saturates: NaN gives 0, steps beyond 255 the last entry.
        self.p2[((a - b).abs() as usize).min(255)]
    }
}

/// Everything one sweep reads.
pub(crate) struct SweepInput<'a> {
    pub bands: &'a Bands,
    pub costs: &'a [u8],
    /// Left image at the level (for the adaptive P2).
    pub image: &'a [f32],
    pub penalties: Penalties,
}

/// Row buffers of one sweep. A pixel's path costs are stored with a guard of INF on
/// each side (`n + 2` entries from `offset − row start + 2·x`), so a step from a pixel
/// of the same band reads its neighbours' d − 1, d, d + 1 in place.
pub(crate) struct SweepState {
    prev: [Vec<i16>; 3],
    cur: [Vec<i16>; 3],
    prev_min: [Vec<i16>; 3],
    cur_min: [Vec<i16>; 3],
    h_prev: Vec<i16>,
    h_cur: Vec<i16>,
    tmp: Vec<i16>,
}

impl SweepState {
    fn new(bands: &Bands) -> Self {
        let w = bands.width;
        let row = bands.max_row() + 2 * w;
        let band = bands.len.iter().copied().max().unwrap_or(0) as usize + 2;
        Self {
            prev: std::array::from_fn(|_| vec![INF; row]),
            cur: std::array::from_fn(|_| vec![INF; row]),
            prev_min: std::array::from_fn(|_| vec![0; w]),
            cur_min: std::array::from_fn(|_| vec![0; w]),
            h_prev: vec![INF; band],
            h_cur: vec![INF; band],
            tmp: vec![INF; band],
        }
    }
}

/// Sum over the eight paths of the path costs, one i16 per volume entry.
pub(crate) fn aggregate(input: &SweepInput<'_>) -> Vec<i16> {
    let total = input.bands.total();
    if rayon::current_num_threads() >= 2 {
        let mut forward = vec![0i16; total];
        let mut backward = vec![0i16; total];
        rayon::join(
            || sweep::<true>(input, true, &mut forward),
            || sweep::<true>(input, false, &mut backward),
        );
        const CHUNK: usize = 1 << 16;
        forward
            .par_chunks_mut(CHUNK)
            .zip(backward.par_chunks(CHUNK))
            .for_each(|(f, b)| {
                for (f, b) in f.iter_mut().zip(b) {
                    *f += *b;
                }
            });
        forward
    } else {
        let mut sum = vec![0i16; total];
        sweep::<true>(input, true, &mut sum);
        sweep::<false>(input, false, &mut sum);
        sum
    }
}

/// One sweep of four paths over all rows, adding (or, with `INIT`, writing) their costs
/// into `sum`.
fn sweep<const INIT: bool>(input: &SweepInput<'_>, forward: bool, sum: &mut [i16]) {
    let bands = input.bands;
    let mut state = SweepState::new(bands);
    let h = bands.height;
    for i in 0..h {
        let y = if forward { i } else { h - 1 - i };
        let range = bands.row_range(y);
        if INIT {
            super::simd::sweep_row::<true>(input, &mut state, y, forward, i == 0, &mut sum[range]);
        } else {
            super::simd::sweep_row::<false>(input, &mut state, y, forward, i == 0, &mut sum[range]);
        }
        std::mem::swap(&mut state.prev, &mut state.cur);
        std::mem::swap(&mut state.prev_min, &mut state.cur_min);
    }
}

/// One row of a sweep: the horizontal path and the three paths from the previous row.
#[inline(always)]
pub(crate) fn sweep_row_generic<const INIT: bool>(
    input: &SweepInput<'_>,
    st: &mut SweepState,
    y: usize,
    forward: bool,
    first_row: bool,
    sum: &mut [i16],
) {
    let b = input.bands;
    let w = b.width;
    let sx: isize = if forward { 1 } else { -1 };
    let row0 = b.offset[y * w] as usize;
    let prev_y = if forward { y.wrapping_sub(1) } else { y + 1 };
    let prow0 = if first_row {
        0
    } else {
        b.offset[prev_y * w] as usize
    };
    let pen = &input.penalties;
    let p1 = pen.p1;
    let mut h_valid = false;
    let (mut h_dmin, mut h_len, mut h_min) = (0i32, 0usize, 0i16);
    for i in 0..w {
        let x = if forward { i } else { w - 1 - i };
        let p = y * w + x;
        let n = b.len[p] as usize;
        if n == 0 {
            h_valid = false;
            continue;
        }
        let s = b.offset[p] as usize - row0;
        let cost = &input.costs[row0 + s..row0 + s + n];
        let dmin = b.dmin[p];
        let ip = input.image[p];
        let acc = &mut sum[s..s + n];
        // Horizontal path from the previous pixel of the row.
        let out = &mut st.h_cur[..n + 2];
        let m = if h_valid {
            let p2 = pen.p2(ip, input.image[(p as isize - sx) as usize]);
            let prev = &st.h_prev[..h_len + 2];
            if h_dmin == dmin && h_len == n {
                step::<INIT>(cost, prev, h_min, p1, p2, out, acc)
            } else {
                let t = guarded(&mut st.tmp, dmin, n, prev, h_dmin);
                step::<INIT>(cost, t, h_min, p1, p2, out, acc)
            }
        } else {
            start::<INIT>(cost, out, acc)
        };
        std::mem::swap(&mut st.h_prev, &mut st.h_cur);
        (h_valid, h_dmin, h_len, h_min) = (true, dmin, n, m);
        // Paths from the previous row: from x − sx, x and x + sx.
        let g = s + 2 * x;
        for j in 0..3 {
            let xq = x as isize - sx * (1 - j as isize);
            let out = &mut st.cur[j][g..g + n + 2];
            let mut m = None;
            if !first_row && xq >= 0 && (xq as usize) < w {
                let q = prev_y * w + xq as usize;
                let qn = b.len[q] as usize;
                if qn > 0 {
                    let qg = b.offset[q] as usize - prow0 + 2 * xq as usize;
                    let prev = &st.prev[j][qg..qg + qn + 2];
                    let qmin = st.prev_min[j][xq as usize];
                    let p2 = pen.p2(ip, input.image[q]);
                    m = Some(if b.dmin[q] == dmin && qn == n {
                        step::<false>(cost, prev, qmin, p1, p2, out, acc)
                    } else {
                        let t = guarded(&mut st.tmp, dmin, n, prev, b.dmin[q]);
                        step::<false>(cost, t, qmin, p1, p2, out, acc)
                    });
                }
            }
            st.cur_min[j][x] = m.unwrap_or_else(|| start::<false>(cost, out, acc));
        }
    }
}

/// The previous pixel's guarded path costs `prev` (band from `prev_dmin`) laid over the
/// current band: `tmp[k] = L(q, dmin − 1 + k)` for k in 0..n + 2, INF outside q's band.
#[inline(always)]
fn guarded<'a>(tmp: &'a mut [i16], dmin: i32, n: usize, prev: &[i16], prev_dmin: i32) -> &'a [i16] {
    let tmp = &mut tmp[..n + 2];
    let prev = &prev[1..prev.len() - 1];
    let lo = dmin - 1;
    let a = lo.max(prev_dmin);
    let e = (lo + n as i32 + 2).min(prev_dmin + prev.len() as i32);
    if a < e {
        let (ta, te) = ((a - lo) as usize, (e - lo) as usize);
        tmp[..ta].fill(INF);
        tmp[ta..te].copy_from_slice(&prev[(a - prev_dmin) as usize..(e - prev_dmin) as usize]);
        tmp[te..].fill(INF);
    } else {
        tmp.fill(INF);
    }
    tmp
}

/// First pixel of a path: its costs as they are (written guarded into `out`).
#[inline(always)]
fn start<const INIT: bool>(cost: &[u8], out: &mut [i16], acc: &mut [i16]) -> i16 {
    let n = cost.len();
    out[0] = INF;
    out[n + 1] = INF;
    let mut m = [INF; LANES];
    for ((o, a), c) in out[1..n + 1]
        .chunks_exact_mut(LANES)
        .zip(acc.chunks_exact_mut(LANES))
        .zip(cost.chunks_exact(LANES))
    {
        for k in 0..LANES {
            let v = c[k] as i16;
            o[k] = v;
            a[k] = if INIT { v } else { a[k] + v };
            m[k] = m[k].min(v);
        }
    }
    hmin(&m)
}

#[inline(always)]
fn hmin(m: &[i16; LANES]) -> i16 {
    let mut r = m[0];
    for &v in &m[1..] {
        r = r.min(v);
    }
    r
}

/// One step of a path from q to p: `prev[k] = L(q, dmin − 1 + k)` for k in 0..n + 2
/// (guarded), `prev_min` = min L(q); writes L(p) guarded into `out`, adds it to (or, with
/// `INIT`, writes it into) `acc`, returns min L(p). Bands are whole multiples of
/// [`LANES`].
#[inline(always)]
fn step<const INIT: bool>(
    cost: &[u8],
    prev: &[i16],
    prev_min: i16,
    p1: i16,
    p2: i16,
    out: &mut [i16],
    acc: &mut [i16],
) -> i16 {
    let n = cost.len();
    let prev = &prev[..n + 2];
    out[0] = INF;
    out[n + 1] = INF;
    let jump = prev_min + p2;
    let mut m = [INF; LANES];
    for (c, ((o, a), cs)) in out[1..n + 1]
        .chunks_exact_mut(LANES)
        .zip(acc.chunks_exact_mut(LANES))
        .zip(cost.chunks_exact(LANES))
        .enumerate()
    {
        let base = c * LANES;
        let t0: &[i16; LANES] = prev[base..base + LANES].try_into().unwrap();
        let t1: &[i16; LANES] = prev[base + 1..base + 1 + LANES].try_into().unwrap();
        let t2: &[i16; LANES] = prev[base + 2..base + 2 + LANES].try_into().unwrap();
        for k in 0..LANES {
            let v = t1[k].min(t0[k].min(t2[k]) + p1).min(jump) - prev_min + cs[k] as i16;
            o[k] = v;
            a[k] = if INIT { v } else { a[k] + v };
            m[k] = m[k].min(v);
        }
    }
    hmin(&m)
}
