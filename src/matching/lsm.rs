//! Least-squares matching (Ackermann/Grün): the template g1 is related to the image g2 by
//! g1(u) = r0 + r1 · g2(p + A·u), u the offset from the template centre, with 6 affine
//! parameters (A, p) and 2 radiometric ones (r0, r1), solved by Gauss–Newton. Only ever
//! run at full resolution, starting from an NCC position.

use super::resample::{bicubic, bicubic_with_gradient};
use super::GreyImage;
use nalgebra::{SMatrix, SVector};

#[derive(Debug, Clone)]
pub struct LsmOptions {
    pub max_iterations: usize,
    /// Converged when the shift update is below this (px) and A changes by < 1e-3.
    pub shift_tolerance: f64,
    /// Diverged when the position wanders farther than this from the start (px).
    pub max_shift: f64,
    /// Diverged when a scale of A leaves [1/max_scale, max_scale].
    pub max_scale: f64,
    /// Estimate the 4 shape parameters of A (false: shifts and radiometry only).
    pub affine: bool,
}

impl Default for LsmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 40,
            shift_tolerance: 5e-3,
            max_shift: 3.0,
            max_scale: 1.5,
            affine: true,
        }
    }
}

/// The LSM solution. `x, y` is the template centre in the image; `affine` is A (row-major
/// 2×2) mapping template offsets to image offsets; σ's are a-posteriori.
#[derive(Debug, Clone, PartialEq)]
pub struct LsmResult {
    pub x: f64,
    pub y: f64,
    pub affine: [f64; 4],
    pub r0: f64,
    pub r1: f64,
    /// A-posteriori σ0 of the grey-value residuals.
    pub sigma0: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub iterations: usize,
    pub converged: bool,
    /// Why it did not converge, when it did not.
    pub reason: Option<String>,
}

/// Adds one pixel's observation (design `row`, residual `res`) to the normal equations
/// of the first `N` parameters (upper triangle, mirrored when solved). Constant bounds so
/// the loops unroll; the shift-only model's 4 parameters skip the 30 products of zeros
/// the 8-parameter loop would add (the same sums).
#[inline(always)]
fn accumulate<const N: usize>(
    row: &[f64; 8],
    res: f64,
    rhs: &mut SVector<f64, 8>,
    nsum: &mut [f64; 64],
) {
    for a in 0..N {
        rhs[a] += row[a] * res;
        for b in a..N {
            nsum[a * 8 + b] += row[a] * row[b];
        }
    }
}

/// Runs LSM of `tpl` in `img` from the centre position (x, y) and an initial shape.
pub fn lsm(
    img: &GreyImage,
    tpl: &GreyImage,
    x: f64,
    y: f64,
    initial_affine: Option<[f64; 4]>,
    opts: &LsmOptions,
) -> LsmResult {
    let a0 = initial_affine.unwrap_or([1.0, 0.0, 0.0, 1.0]);
    let mut p = [x, y, a0[0], a0[1], a0[2], a0[3], 0.0, 1.0];
    // Initial radiometry from the moments, so the first step is not dominated by contrast.
    let (tw, th) = (tpl.width, tpl.height);
    let (cx, cy) = (tw as f64 / 2.0, th as f64 / 2.0);
    let mut out = LsmResult {
        x,
        y,
        affine: a0,
        r0: 0.0,
        r1: 1.0,
        sigma0: f64::NAN,
        sigma_x: f64::NAN,
        sigma_y: f64::NAN,
        iterations: 0,
        converged: false,
        reason: None,
    };
    let np = if opts.affine { 8 } else { 4 };
    {
        let (mut s1, mut s2, mut t1, mut t2, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for r in 0..th {
            for c in 0..tw {
                let (u, v) = (c as f64 + 0.5 - cx, r as f64 + 0.5 - cy);
                if let Some(g) = bicubic(img, x + a0[0] * u + a0[1] * v, y + a0[2] * u + a0[3] * v)
                {
                    let t = tpl.at(c, r) as f64;
                    s1 += g;
                    s2 += g * g;
                    t1 += t;
                    t2 += t * t;
                    n += 1.0;
                }
            }
        }
        if n < 9.0 {
            out.reason = Some("patch lies outside the image".into());
            return out;
        }
        let vg = (s2 / n - (s1 / n).powi(2)).max(0.0).sqrt();
        let vt = (t2 / n - (t1 / n).powi(2)).max(0.0).sqrt();
        if vg < 1e-9 || vt < 1e-9 {
            out.reason = Some("no texture in the patch".into());
            return out;
        }
        p[7] = vt / vg;
        p[6] = t1 / n - p[7] * s1 / n;
    }
    let mut last_sigma = f64::INFINITY;
    for it in 1..=opts.max_iterations {
        out.iterations = it;
        let mut nsum = [0.0f64; 64];
        let mut rhs = SVector::<f64, 8>::zeros();
        let (mut vv, mut n) = (0.0, 0usize);
        for r in 0..th {
            for c in 0..tw {
                let (u, v) = (c as f64 + 0.5 - cx, r as f64 + 0.5 - cy);
                let qx = p[0] + p[2] * u + p[3] * v;
                let qy = p[1] + p[4] * u + p[5] * v;
                // Value and gradient from one 4×4 neighbourhood; near the border,
                // differences of the (bilinear) fallback samples.
                let Some((g, gx, gy)) = bicubic_with_gradient(img, qx, qy).or_else(|| {
                    Some((
                        bicubic(img, qx, qy)?,
                        bicubic(img, qx + 0.5, qy)? - bicubic(img, qx - 0.5, qy)?,
                        bicubic(img, qx, qy + 0.5)? - bicubic(img, qx, qy - 0.5)?,
                    ))
                }) else {
                    continue;
                };
                let (gx, gy) = (gx * p[7], gy * p[7]);
                let res = tpl.at(c, r) as f64 - (p[6] + p[7] * g);
                let row: [f64; 8] = if opts.affine {
                    [gx, gy, gx * u, gx * v, gy * u, gy * v, 1.0, g]
                } else {
                    [gx, gy, 1.0, g, 0.0, 0.0, 0.0, 0.0]
                };
                if opts.affine {
                    accumulate::<8>(&row, res, &mut rhs, &mut nsum);
                } else {
                    accumulate::<4>(&row, res, &mut rhs, &mut nsum);
                }
                vv += res * res;
                n += 1;
            }
        }
        if n <= np + 4 || n < tw * th / 2 {
            out.reason = Some("patch left the image".into());
            return out;
        }
        let mut nmat = SMatrix::<f64, 8, 8>::zeros();
        for a in 0..np {
            for b in a..np {
                nmat[(a, b)] = nsum[a * 8 + b];
                nmat[(b, a)] = nsum[a * 8 + b];
            }
        }
        for a in np..8 {
            nmat[(a, a)] = 1.0;
        }
        let Some(ninv) = nmat.try_inverse() else {
            out.reason = Some("singular normal equations (no gradient in one direction)".into());
            return out;
        };
        let dx = ninv * rhs;
        let d: [f64; 8] = if opts.affine {
            [dx[0], dx[1], dx[2], dx[3], dx[4], dx[5], dx[6], dx[7]]
        } else {
            [dx[0], dx[1], 0.0, 0.0, 0.0, 0.0, dx[2], dx[3]]
        };
        if d.iter().any(|v| !v.is_finite()) {
            out.reason = Some("non-finite update".into());
            return out;
        }
        for (pi, di) in p.iter_mut().zip(d) {
            *pi += di;
        }
        let sigma0 = (vv / (n - np) as f64).sqrt();
        out.sigma0 = sigma0;
        out.sigma_x = sigma0 * ninv[(0, 0)].sqrt();
        out.sigma_y = sigma0 * ninv[(1, 1)].sqrt();
        out.x = p[0];
        out.y = p[1];
        out.affine = [p[2], p[3], p[4], p[5]];
        out.r0 = p[6];
        out.r1 = p[7];
        let det = p[2] * p[5] - p[3] * p[4];
        let (sx, sy) = (
            (p[2].powi(2) + p[4].powi(2)).sqrt(),
            (p[3].powi(2) + p[5].powi(2)).sqrt(),
        );
        let m = opts.max_scale;
        if ((p[0] - x).powi(2) + (p[1] - y).powi(2)).sqrt() > opts.max_shift {
            out.reason = Some(format!(
                "diverged: moved {:.2} px from the start (limit {})",
                ((p[0] - x).powi(2) + (p[1] - y).powi(2)).sqrt(),
                opts.max_shift
            ));
            return out;
        }
        if det <= 0.0 || sx > m || sy > m || sx < 1.0 / m || sy < 1.0 / m {
            out.reason = Some(format!(
                "diverged: implausible shape (scales {sx:.2}, {sy:.2})"
            ));
            return out;
        }
        if it > 3 && sigma0 > 3.0 * last_sigma {
            out.reason = Some("diverged: residuals grow".into());
            return out;
        }
        last_sigma = sigma0;
        tracing::trace!(it, dx = d[0], dy = d[1], sigma0, "LSM step");
        let shape_step = d[2..6].iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if d[0].abs() < opts.shift_tolerance
            && d[1].abs() < opts.shift_tolerance
            && shape_step < 1e-3
        {
            out.converged = true;
            out.reason = None;
            return out;
        }
    }
    out.reason = Some(format!(
        "not converged after {} iterations",
        opts.max_iterations
    ));
    out
}
