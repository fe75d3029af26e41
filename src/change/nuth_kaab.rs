//! Nuth & Kääb (2011) co-registration of a surface model B to a reference A on stable
//! terrain. A horizontal shift `s` of B shows in dh = B − A as
//! dh / tan(slope) = −(s_e sin ψ + s_n cos ψ) + c, ψ the aspect (upslope azimuth): the
//! cosine of the paper, `a cos(b − ψ) + c`, written linearly. Each iteration bins
//! dh / tan(slope) by aspect (72 bins of 5°, the median of each: robust to what changed
//! and to flat cells whose quotient explodes), fits the three terms to the bins by least
//! squares, moves B by what it found and samples it again (bilinear); until the step is
//! below `tolerance_px` or `max_iterations`. The vertical shift is the median dh at the
//! end. The same algorithm and defaults as xdem's `NuthKaab`, so the two agree on the
//! same rasters (bindings/python/tests/test_change.py).

use super::terrain::Terrain;
use super::{median, ChangeError, Result};
use crate::geometry::Dem;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NuthKaabOptions {
    pub max_iterations: usize,
    /// Stop when an iteration moves B by less than this (reference cells).
    pub tolerance_px: f64,
    /// Aspect bins.
    pub bins: usize,
}

impl Default for NuthKaabOptions {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            tolerance_px: 0.001,
            bins: 72,
        }
    }
}

/// A last step at least this long (reference cells) after the iterations leaves the shift
/// undetermined ([`NuthKaab::note`]); a shorter one is a shift known better than the
/// 0.05 cell users ask of it, though short of xdem's stopping rule.
pub const UNDETERMINED_STEP_PX: f64 = 0.05;

/// The shift that aligns B to A: B moved by `shift_m` (east, north, up) matches A.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NuthKaab {
    pub shift_m: [f64; 3],
    /// The horizontal shift in reference cells.
    pub shift_px: [f64; 2],
    pub iterations: usize,
    pub converged: bool,
    /// Stable cells the fit used (finite dh and slope).
    pub cells: usize,
    /// Standard errors (m) of the horizontal shift east and north, from the last fit's
    /// residuals over the aspect bins: a shift within about twice them is not determined
    /// by the data (noisy dh over gentle slopes), whatever its size.
    pub sigma_m: [f64; 2],
    /// Why the shift is not to be trusted, when it is not: the iterations ended with a step
    /// of [`UNDETERMINED_STEP_PX`] or more (the terrain does not determine the shift: too
    /// flat, too few sloped cells).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// dh = B(x − t) − A(x) at the centre of every cell of `a` (NaN where either has no
/// height): B moved by `t` (east, north) on A's grid.
pub fn dh_moved(a: &Dem, b: &Dem, t: [f64; 2]) -> Vec<f64> {
    (0..a.data.len())
        .map(|i| {
            let (c, r) = ((i % a.width) as f64 + 0.5, (i / a.width) as f64 + 0.5);
            let (x, y) = a.transform.pixel_to_world(c, r);
            let za = f64::from(a.data[i]);
            match b.height_at(x - t[0], y - t[1]) {
                Some(zb) if za.is_finite() => zb - za,
                _ => f64::NAN,
            }
        })
        .collect()
}

/// The Nuth & Kääb shift of `b` to `a` on the cells of `stable`, `terrain` being A's.
pub fn nuth_kaab(
    a: &Dem,
    b: &Dem,
    terrain: &Terrain,
    stable: &[bool],
    options: &NuthKaabOptions,
) -> Result<NuthKaab> {
    nuth_kaab_from(a, b, terrain, stable, options, dh_moved(a, b, [0.0, 0.0])).map(|r| r.0)
}

/// [`nuth_kaab`] from `dh`, B − A as given ([`dh_moved`] unmoved, which the caller has
/// already); also returns dh of B moved horizontally by the shift found (its vertical part
/// not added): each iteration samples B over the whole grid, so neither end is sampled
/// twice.
pub fn nuth_kaab_from(
    a: &Dem,
    b: &Dem,
    terrain: &Terrain,
    stable: &[bool],
    options: &NuthKaabOptions,
    mut dh: Vec<f64>,
) -> Result<(NuthKaab, Vec<f64>)> {
    let cell = a.transform.0[1];
    let bins = options.bins.max(3);
    let mut t = [0.0f64; 2];
    let mut iterations = 0;
    let mut converged = false;
    let mut cells = 0;
    let mut last_step = f64::NAN;
    let mut sigma_m = [f64::NAN; 2];
    for _ in 0..options.max_iterations {
        iterations += 1;
        let mut used: Vec<(f64, f64, f64)> = stable
            .iter()
            .enumerate()
            .filter(|&(i, &m)| m && dh[i].is_finite() && terrain.slope_tan[i] > 1e-8 / cell)
            .map(|(i, _)| (dh[i], terrain.slope_tan[i], terrain.aspect[i]))
            .collect();
        cells = used.len();
        let mut all: Vec<f64> = used.iter().map(|u| u.0).collect();
        let vshift = median(&mut all);
        for u in &mut used {
            u.0 -= vshift;
        }
        let mut binned: Vec<Vec<f64>> = vec![Vec::new(); bins];
        let width = std::f64::consts::TAU / bins as f64;
        for &(d, s, asp) in &used {
            let k = ((asp / width) as usize).min(bins - 1);
            binned[k].push(d / s);
        }
        // Least squares of y = p1 sin ψ + p2 cos ψ + p3 over the bins' medians.
        let mut n = Matrix3::zeros();
        let mut rhs = Vector3::zeros();
        let mut points = Vec::with_capacity(bins);
        for (k, ys) in binned.iter_mut().enumerate() {
            if ys.is_empty() {
                continue;
            }
            let y = median(ys);
            let psi = (k as f64 + 0.5) * width;
            let row = Vector3::new(psi.sin(), psi.cos(), 1.0);
            n += row * row.transpose();
            rhs += row * y;
            points.push((row, y));
        }
        let filled = points.len();
        if filled < 3 {
            return Err(ChangeError::TooLittle(format!(
                "{cells} stable cells with a slope fill {filled} of {bins} aspect bins (3 needed)"
            )));
        }
        let p = n.lu().solve(&rhs).ok_or_else(|| {
            ChangeError::TooLittle("the aspect bins do not determine a shift".into())
        })?;
        if filled > 3 {
            let rss: f64 = points
                .iter()
                .map(|(row, y)| (y - row.dot(&p)).powi(2))
                .sum();
            let s2 = rss / (filled - 3) as f64;
            if let Some(inv) = n.try_inverse() {
                sigma_m = [(s2 * inv[(0, 0)]).sqrt(), (s2 * inv[(1, 1)]).sqrt()];
            }
        }
        t[0] += p.x;
        t[1] += p.y;
        dh = dh_moved(a, b, t);
        last_step = p.x.hypot(p.y) / cell;
        if last_step < options.tolerance_px {
            converged = true;
            break;
        }
    }
    let mut stable_dh: Vec<f64> = dh
        .iter()
        .zip(stable)
        .filter_map(|(v, &m)| (m && v.is_finite()).then_some(*v))
        .collect();
    if stable_dh.is_empty() {
        return Err(ChangeError::TooLittle(
            "the shift moved B off every stable cell".into(),
        ));
    }
    let dz = median(&mut stable_dh);
    // NaN (no step, or a fit that failed) is not determined either.
    let determined = last_step < UNDETERMINED_STEP_PX;
    let found = NuthKaab {
        shift_m: [t[0], t[1], -dz],
        shift_px: [t[0] / cell, t[1] / cell],
        iterations,
        converged,
        cells,
        sigma_m,
        note: (!converged && !determined).then(|| {
            format!(
                "not converged in {iterations} iterations (last step {last_step:.3} cells, \
                 {cells} sloped stable cells): the terrain does not determine the shift"
            )
        }),
    };
    Ok((found, dh))
}
