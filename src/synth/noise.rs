//! Stateless hash noise. Every random quantity that depends on a position (texture,
//! film grain, per-pixel noise) is a hash of the seed and integer coordinates, so any
//! pixel can be evaluated in any order — parallel rendering gives identical bytes.

#[inline]
pub fn mix(mut z: u64) -> u64 {
    // splitmix64 finaliser: full avalanche, cheap.
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[inline]
pub fn hash3(seed: u64, a: i64, b: i64) -> u64 {
    row(column(seed, a), b)
}

/// The two rounds of [`hash3`], apart so a lattice can reuse a column's first round.
#[inline]
fn column(seed: u64, a: i64) -> u64 {
    mix(seed ^ (a as u64).wrapping_mul(0x9E37_79B9))
}

#[inline]
fn row(column: u64, b: i64) -> u64 {
    mix(column ^ (b as u64).wrapping_mul(0x85EB_CA6B))
}

/// Uniform in [0, 1) from a hash.
#[inline]
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Approximately standard normal from a hash (sum of four uniforms, rescaled): cheap and
/// bounded, which suits grain and sensor noise.
#[inline]
pub fn gauss(h: u64) -> f64 {
    let a = (h & 0xFFFF) as f64
        + ((h >> 16) & 0xFFFF) as f64
        + ((h >> 32) & 0xFFFF) as f64
        + (h >> 48) as f64;
    (a / 65535.0 - 2.0) * (3.0f64).sqrt()
}

/// floor() by native truncation (libm's floor is a call on the baseline x86-64 target).
#[inline]
pub fn ffloor(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

#[inline]
fn smooth(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in [0, 1) on a lattice of spacing `cell` (m), bilinear with smoothstep.
pub fn value(seed: u64, x: f64, y: f64, cell: f64) -> f64 {
    let u = x / cell;
    let v = y / cell;
    let i = ffloor(u);
    let j = ffloor(v);
    let fu = smooth(u - i as f64);
    let fv = smooth(v - j as f64);
    // hash3 of the four corners, sharing each column's first round (6 mixes, not 8).
    let (ci, ci1) = (column(seed, i), column(seed, i + 1));
    let a = unit(row(ci, j));
    let b = unit(row(ci1, j));
    let c = unit(row(ci, j + 1));
    let d = unit(row(ci1, j + 1));
    let ab = a + (b - a) * fu;
    let cd = c + (d - c) * fu;
    ab + (cd - ab) * fv
}

/// Band-limited fractal noise in [-0.5, 0.5]: octaves finer than the pixel footprint
/// `fp` fade out instead of aliasing (the texture's own anti-aliasing).
pub fn fractal(seed: u64, x: f64, y: f64, coarsest: f64, octaves: u32, fp: f64) -> f64 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut cell = coarsest;
    let mut amp = 1.0;
    for o in 0..octaves {
        let w = attenuation(cell, fp);
        // Octaves beyond Nyquist weigh exactly 0: skipping their lattice hashes leaves the
        // sum bit-identical and saves a third of the noise on a 0.5 m film footprint.
        if w > 0.0 {
            sum += amp * w * (value(seed.wrapping_add(o as u64 * 7919), x, y, cell) - 0.5);
        }
        norm += amp;
        cell *= 0.5;
        amp *= 0.6;
    }
    sum / norm
}

/// Weight of a pattern of period `period` seen by a pixel of ground footprint `fp`:
/// 1 when well resolved, 0 beyond Nyquist.
#[inline]
pub fn attenuation(period: f64, fp: f64) -> f64 {
    let r = period / fp.max(1e-9);
    ((r - 1.0) / 2.0).clamp(0.0, 1.0)
}

/// Fraction of a pixel of width `fp` covered by the region `d < 0` of a signed distance
/// `d` (m): the analytic anti-aliasing of sharp edges (targets, road markings).
#[inline]
pub fn coverage(d: f64, fp: f64) -> f64 {
    (0.5 - d / fp.max(1e-9)).clamp(0.0, 1.0)
}

/// sin(x) by range reduction and an odd Taylor polynomial to x⁹ (|error| < 4e-6): several
/// times faster than libm in the ray-marching loop, and pure arithmetic, so terrain heights
/// are bit-identical on every platform.
#[inline]
pub fn fast_sin(x: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    // Branch-free: round to the nearest period by the 1.5·2⁵² trick (no SSE4.1 round in
    // the baseline target) and fold |r| into [0, π/2] with sin(a) = sin(π − a). The
    // terrain's phases are random, so the former sign branches were mispredicted half
    // the time, in a function evaluated a dozen times per rendered pixel.
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let q = x * (1.0 / TAU);
    let k = (q + ROUND) - ROUND;
    let r = x - TAU * k;
    let a = r.abs();
    let f = a.min(PI - a);
    let f2 = f * f;
    let s = f
        * (1.0
            + f2 * (-1.0 / 6.0
                + f2 * (1.0 / 120.0 + f2 * (-1.0 / 5040.0 + f2 * (1.0 / 362_880.0)))));
    s.copysign(r)
}
