//! B's horizontal shift, vertical shift and tilt against A fitted together on stable
//! terrain, with standard errors from a delete-one-block jackknife.
//!
//! Nuth & Kääb fits the shift alone, and over terrain of few slope directions a tilted B
//! (dh = g·x) changes dh much as a moved one does: on one 10 m hill with slopes up to 5°, B
//! tilted by 2 and −1 m/km (east, north) and not moved gives a Nuth & Kääb shift of 4.9 m,
//! with a standard error from its aspect bins of 0.21 m, because the bins take the cells as
//! independent and a tilt is the same in every cell (tests/units/change.rs). Here each
//! stable cell contributes dh = tan S (u_e sin ψ + u_n cos ψ) + c + g_e (x − x̄) + g_n (y − ȳ),
//! at the position Nuth & Kääb ended at (so u is what it left and the linearisation holds),
//! solved by iteratively reweighted least squares (Tukey's biweight): on that hill 0.01 m
//! and the tilt to 0.005 m/km. The cells' errors are spatially correlated (a matched surface
//! warps), so the standard errors come from refitting with each of 4 × 4 blocks of the
//! extent left out.

use super::compare::Tilt;
use super::terrain::Terrain;
use crate::geometry::Dem;
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

type Mat5 = SMatrix<f64, 5, 5>;
type Vec5 = SVector<f64, 5>;

/// Blocks per side of the jackknife.
const BLOCKS: usize = 4;
/// Tukey's biweight constant, in robust residual scales (95 % efficiency on Gaussian dh).
const TUKEY_C: f64 = 4.685;
const IRLS_ITERATIONS: usize = 10;

/// The shift and tilt that, applied together, move B onto A.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ShiftTilt {
    /// East, north, up (m): B moved by this and tilted back by `tilt` matches A; the up
    /// part at the compared extent's centre. Comparable with `nuth_kaab.shift_m`.
    pub shift_m: [f64; 3],
    /// Standard errors of `shift_m` (m), delete-one-block jackknife.
    pub sigma_m: [f64; 3],
    /// The gradient of dh fitted with the shift.
    pub tilt: Tilt,
    /// Standard errors of the tilt's east and north gradients (m per km), as `sigma_m`.
    pub tilt_sigma_m_per_km: [f64; 2],
    /// Stable cells fitted, and the jackknife's blocks that held any.
    pub cells: usize,
    pub blocks: usize,
}

/// One stable cell's row of the fit.
struct Row {
    a: Vec5,
    dh: f64,
    block: usize,
}

/// The joint fit on `dh` (B moved horizontally by `moved_by`, the Nuth & Kääb shift, with
/// no vertical part) over the `stable` cells of A's grid; None when they do not determine
/// the five terms (flat ground determines no shift) or lie in fewer than 3 of the
/// jackknife's blocks.
pub fn shift_and_tilt(
    a: &Dem,
    terrain: &Terrain,
    stable: &[bool],
    dh: &[f64],
    moved_by: [f64; 2],
) -> Option<ShiftTilt> {
    let (x0, y0, x1, y1) = a.extent();
    let (xm, ym) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let rows: Vec<Row> = (0..dh.len())
        .filter(|&i| stable[i] && dh[i].is_finite() && terrain.slope_tan[i].is_finite())
        .map(|i| {
            let (c, r) = (i % a.width, i / a.width);
            let (x, y) = a.transform.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let t = terrain.slope_tan[i];
            // A flat cell has no aspect: it tells the level and the tilt, not the shift.
            let (s, co) = if t > 0.0 {
                terrain.aspect[i].sin_cos()
            } else {
                (0.0, 0.0)
            };
            Row {
                a: Vec5::new(t * s, t * co, 1.0, (x - xm) / 1000.0, (y - ym) / 1000.0),
                dh: dh[i],
                block: (r * BLOCKS / a.height) * BLOCKS + c * BLOCKS / a.width,
            }
        })
        .collect();
    if rows.len() < 5 {
        return None;
    }
    let weights = irls_weights(&rows)?;
    let p = solve(&rows, &weights, None)?;
    let held: Vec<usize> = (0..BLOCKS * BLOCKS)
        .filter(|&k| rows.iter().any(|r| r.block == k))
        .collect();
    // Delete-one-block jackknife with the full fit's weights: var = (g − 1)/g Σ (θ_k − θ̄)².
    // A fit whose uncertainty cannot be told (under 3 blocks, or one left out leaves the
    // rest undetermined) is not reported.
    if held.len() < 3 {
        return None;
    }
    let fits = held
        .iter()
        .map(|&k| solve(&rows, &weights, Some(k)))
        .collect::<Option<Vec<Vec5>>>()?;
    let g = fits.len() as f64;
    let mean = fits.iter().sum::<Vec5>() / g;
    let ss = fits
        .iter()
        .map(|f| (f - mean).component_mul(&(f - mean)))
        .sum::<Vec5>();
    let sigma = (ss * ((g - 1.0) / g)).map(f64::sqrt);
    let (hx, hy) = ((x1 - x0) / 2000.0, (y1 - y0) / 2000.0);
    Some(ShiftTilt {
        shift_m: [moved_by[0] + p[0], moved_by[1] + p[1], -p[2]],
        sigma_m: [sigma[0], sigma[1], sigma[2]],
        tilt: Tilt {
            east_m_per_km: p[3],
            north_m_per_km: p[4],
            max_over_extent_m: p[3].abs() * hx + p[4].abs() * hy,
        },
        tilt_sigma_m_per_km: [sigma[3], sigma[4]],
        cells: rows.len(),
        blocks: held.len(),
    })
}

/// Tukey biweights of the rows after reweighted least squares from unit weights; the
/// scale is the residuals' NMAD.
fn irls_weights(rows: &[Row]) -> Option<Vec<f64>> {
    let mut w = vec![1.0; rows.len()];
    for _ in 0..IRLS_ITERATIONS {
        let p = solve(rows, &w, None)?;
        let res: Vec<f64> = rows.iter().map(|r| r.dh - r.a.dot(&p)).collect();
        let scale = super::nmad(&res).max(1e-6);
        let next: Vec<f64> = res
            .iter()
            .map(|v| {
                let u = v / (TUKEY_C * scale);
                if u.abs() < 1.0 {
                    (1.0 - u * u).powi(2)
                } else {
                    0.0
                }
            })
            .collect();
        let moved = w
            .iter()
            .zip(&next)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        w = next;
        if moved < 1e-6 {
            break;
        }
    }
    Some(w)
}

/// Weighted least squares of the rows, leaving out block `without`; None when singular.
fn solve(rows: &[Row], w: &[f64], without: Option<usize>) -> Option<Vec5> {
    let mut n = Mat5::zeros();
    let mut b = Vec5::zeros();
    for (r, &wi) in rows.iter().zip(w) {
        if wi == 0.0 || Some(r.block) == without {
            continue;
        }
        n += wi * r.a * r.a.transpose();
        b += wi * r.dh * r.a;
    }
    // A shift needs sloped cells in more than one aspect: a near-singular system is an
    // undetermined fit, not a number.
    let eig = n.symmetric_eigen();
    let (lo, hi) = (eig.eigenvalues.min(), eig.eigenvalues.max());
    if !(hi > 0.0 && lo > 1e-12 * hi) {
        return None;
    }
    n.cholesky().map(|c| c.solve(&b))
}
