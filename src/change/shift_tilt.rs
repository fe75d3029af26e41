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

use super::terrain::Terrain;
use crate::geometry::Dem;
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

type Mat5 = SMatrix<f64, 5, 5>;
type Vec5 = SVector<f64, 5>;

/// Blocks per side of the jackknife.
const BLOCKS: usize = 4;
/// Tukey's biweight constant, in robust residual scales (95 % efficiency on Gaussian dh).
const TUKEY_C: f64 = 4.685;
const IRLS_ITERATIONS: usize = 10;

/// The gradient of dh: B tilted against A.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Tilt {
    /// dh gradient (m per km) east and north.
    pub east_m_per_km: f64,
    pub north_m_per_km: f64,
    /// Largest height the tilt makes over the compared extent, from its centre (m).
    pub max_over_extent_m: f64,
}

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
    /// Stable cells the last pass weighted (within the biweight's cut), and the jackknife's
    /// blocks that held any.
    pub cells: usize,
    pub blocks: usize,
}

/// Normal equations of the fit, one per jackknife block.
struct Normals {
    n: [Mat5; BLOCKS * BLOCKS],
    b: [Vec5; BLOCKS * BLOCKS],
    cells: [usize; BLOCKS * BLOCKS],
}

impl Normals {
    fn zero() -> Self {
        Self {
            n: [Mat5::zeros(); BLOCKS * BLOCKS],
            b: [Vec5::zeros(); BLOCKS * BLOCKS],
            cells: [0; BLOCKS * BLOCKS],
        }
    }

    fn add(mut self, o: &Self) -> Self {
        for k in 0..BLOCKS * BLOCKS {
            self.n[k] += o.n[k];
            self.b[k] += o.b[k];
            self.cells[k] += o.cells[k];
        }
        self
    }

    /// The solution without block `without` (None: with every block); None when singular.
    fn solve(&self, without: Option<usize>) -> Option<Vec5> {
        let mut n = Mat5::zeros();
        let mut b = Vec5::zeros();
        for k in (0..BLOCKS * BLOCKS).filter(|&k| Some(k) != without) {
            n += self.n[k];
            b += self.b[k];
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
}

/// The stable cells of A's grid, read row by row: the grid can hold tens of millions of
/// cells (an epoch against a younger epoch's 0.1 m DSM: 21 M stable cells on the medium
/// preset), so no per-cell row is stored and each pass of the fit streams over them.
struct Cells<'a> {
    a: &'a Dem,
    terrain: &'a Terrain,
    stable: &'a [bool],
    dh: &'a [f64],
    centre: (f64, f64),
}

impl Cells<'_> {
    /// Cell `i`'s row of the fit, its dh and block; None when it takes no part.
    #[inline]
    fn row(&self, i: usize) -> Option<(Vec5, f64, usize)> {
        let t = self.terrain.slope_tan[i];
        if !(self.stable[i] && self.dh[i].is_finite() && t.is_finite()) {
            return None;
        }
        let (c, r) = (i % self.a.width, i / self.a.width);
        let (x, y) = self
            .a
            .transform
            .pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
        // A flat cell has no aspect: it tells the level and the tilt, not the shift.
        let (s, co) = if t > 0.0 {
            self.terrain.aspect[i].sin_cos()
        } else {
            (0.0, 0.0)
        };
        let row = Vec5::new(
            t * s,
            t * co,
            1.0,
            (x - self.centre.0) / 1000.0,
            (y - self.centre.1) / 1000.0,
        );
        let block = (r * BLOCKS / self.a.height) * BLOCKS + c * BLOCKS / self.a.width;
        Some((row, self.dh[i], block))
    }

    /// The normal equations with Tukey weights of the residuals from `fit` in units of
    /// `scale` (unit weights without a fit). Grid rows in parallel, summed in row order, so
    /// the sums do not depend on the thread count.
    fn normals(&self, fit: Option<(&Vec5, f64)>) -> Normals {
        let w = self.a.width;
        let parts: Vec<Normals> = (0..self.a.height)
            .into_par_iter()
            .chunks(64)
            .map(|rows| {
                let mut acc = Normals::zero();
                for i in rows.iter().flat_map(|&r| r * w..(r + 1) * w) {
                    let Some((a, dh, k)) = self.row(i) else {
                        continue;
                    };
                    let wt = match fit {
                        None => 1.0,
                        Some((p, scale)) => {
                            let u = (dh - a.dot(p)) / (TUKEY_C * scale);
                            if u.abs() >= 1.0 {
                                continue;
                            }
                            (1.0 - u * u).powi(2)
                        }
                    };
                    acc.n[k] += wt * a * a.transpose();
                    acc.b[k] += wt * dh * a;
                    acc.cells[k] += 1;
                }
                acc
            })
            .collect();
        parts.iter().fold(Normals::zero(), |s, p| s.add(p))
    }

    /// NMAD of the residuals from `p` over at most [`SCALE_SAMPLE`] cells taken at an even
    /// stride: the robust scale needs no more.
    fn residual_scale(&self, p: &Vec5) -> f64 {
        let n = self.dh.len();
        let stride = n.div_ceil(SCALE_SAMPLE).max(1);
        let res: Vec<f64> = (0..n)
            .step_by(stride)
            .filter_map(|i| self.row(i).map(|(a, dh, _)| dh - a.dot(p)))
            .collect();
        super::nmad(&res).max(1e-6)
    }
}

/// Cells the robust scale is taken from, at most.
const SCALE_SAMPLE: usize = 1 << 20;

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
    let cells = Cells {
        a,
        terrain,
        stable,
        dh,
        centre: ((x0 + x1) / 2.0, (y0 + y1) / 2.0),
    };
    // Iteratively reweighted least squares from the unweighted fit; the weights of a pass
    // come from the previous pass's solution.
    let mut normals = cells.normals(None);
    let mut p = normals.solve(None)?;
    for _ in 0..IRLS_ITERATIONS {
        let scale = cells.residual_scale(&p);
        normals = cells.normals(Some((&p, scale)));
        let next = normals.solve(None)?;
        let step = (next - p).abs().max();
        p = next;
        if step < 1e-6 {
            break;
        }
    }
    let held: Vec<usize> = (0..BLOCKS * BLOCKS)
        .filter(|&k| normals.cells[k] > 0)
        .collect();
    // Delete-one-block jackknife on the last pass's weights: var = (g − 1)/g Σ (θ_k − θ̄)².
    // A fit whose uncertainty cannot be told (under 3 blocks, or one left out leaves the
    // rest undetermined) is not reported.
    if held.len() < 3 {
        return None;
    }
    let fits = held
        .iter()
        .map(|&k| normals.solve(Some(k)))
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
        cells: normals.cells.iter().sum(),
        blocks: held.len(),
    })
}
