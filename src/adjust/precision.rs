//! Precision of the adjustment: σ0, redundancy numbers and standardised residuals,
//! EO covariance from the reduced camera system, determinability of self-calibrated
//! parameters, and intersection of check points.
//!
//! Redundancy numbers are local: for an observation of an object point,
//! r = 1 − diag(J_x V⁻¹ J_xᵀ W) with the point's own normal block V, i.e. the
//! exterior orientations are treated as known. With tens of rays per photo the EO
//! contribution to an image point's cofactor is small, so this slightly overestimates
//! r and underestimates the standardised residual (conservative for rejection). POS
//! priors use r = 1 for the same reason.

use super::residual::{Kind, ResidualBlock};
use super::solver::{Evaluated, Factor, PointSys, Structure};
use crate::geometry::{Camera, Pose};
use nalgebra::{DMatrix, Matrix3, Vector3};
use rayon::prelude::*;

/// Smallest redundancy number used when standardising (guards against r → 0 for
/// observations that alone determine a parameter).
const MIN_REDUNDANCY: f64 = 0.05;

/// Redundancy number and standardised residual (largest component) of every residual
/// block; `None` for inactive blocks.
pub(crate) fn standardized(
    res: &[ResidualBlock],
    ev: &Evaluated,
    pts: &[PointSys],
    sigma0: f64,
) -> Vec<Option<(f64, f64)>> {
    res.par_iter()
        .enumerate()
        .map(|(i, r)| {
            let e = ev.evals[i].as_ref()?;
            let mut rmin = 1.0f64;
            let mut w = 0.0f64;
            for k in 0..e.dim {
                let red = match r.point {
                    Some(p) => {
                        let jx = e.j_point.row(k);
                        let h = (jx * pts[p].vinv * jx.transpose())[(0, 0)] * ev.weights[i];
                        (1.0 - h).max(MIN_REDUNDANCY)
                    }
                    None => 1.0,
                };
                rmin = rmin.min(red);
                w = w.max(e.r[k].abs() / (sigma0 * red.sqrt()));
            }
            Some((rmin, w))
        })
        .collect()
}

/// Per-block covariance (diagonal blocks, free parameters only, unscaled cofactors) and
/// the full cofactor columns of the camera blocks (self-calibration).
pub(crate) struct Cofactors {
    pub diag_blocks: Vec<DMatrix<f64>>,
    /// Global parameter index → its column of S⁻¹ (only camera parameters).
    pub columns: Vec<(usize, Vec<f64>)>,
    /// Diagonal of S⁻¹.
    pub diag: Vec<f64>,
}

pub(crate) fn cofactors(st: &Structure, factor: &Factor, want_photos: bool) -> Cofactors {
    let n = st.n;
    let nb = st.free.len();
    let mut diag_blocks = vec![DMatrix::zeros(0, 0); nb];
    let mut columns = Vec::new();
    let mut diag = vec![f64::NAN; n];
    let blocks: Vec<usize> = (0..nb)
        .filter(|&b| want_photos || b >= st.n_photos)
        .collect();
    let mut k = 0;
    // Multi-right-hand-side solves in batches bound the memory to n × 192 values.
    while k < blocks.len() {
        let mut batch = Vec::new();
        let mut cols = 0;
        while k < blocks.len() && cols + st.free[blocks[k]].len() <= 192 {
            cols += st.free[blocks[k]].len();
            batch.push(blocks[k]);
            k += 1;
        }
        if batch.is_empty() {
            batch.push(blocks[k]);
            cols = st.free[blocks[k]].len();
            k += 1;
        }
        let mut x = DMatrix::zeros(n, cols);
        let mut c = 0;
        for &b in &batch {
            for i in 0..st.free[b].len() {
                x[(st.offset[b] + i, c)] = 1.0;
                c += 1;
            }
        }
        factor.solve_in_place(&mut x);
        let mut c = 0;
        for &b in &batch {
            let m = st.free[b].len();
            let o = st.offset[b];
            let mut q = DMatrix::zeros(m, m);
            for j in 0..m {
                for i in 0..m {
                    q[(i, j)] = x[(o + i, c + j)];
                }
                diag[o + j] = x[(o + j, c + j)];
                if b >= st.n_photos {
                    columns.push((o + j, x.column(c + j).iter().copied().collect()));
                }
            }
            diag_blocks[b] = q;
            c += m;
        }
    }
    Cofactors {
        diag_blocks,
        columns,
        diag,
    }
}

/// Intersects an object point from its rays by least squares on the reprojection error
/// (midpoint start, then Gauss–Newton); `None` with fewer than two usable rays or a
/// glancing intersection.
pub fn intersect(rays: &[(&Camera, &Pose, [f64; 2], f64)]) -> Option<Vector3<f64>> {
    if rays.len() < 2 {
        return None;
    }
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (cam, pose, px, _) in rays {
        let d = pose.direction_to_world(&cam.unproject(*px).ok()?);
        let p = Matrix3::identity() - d * d.transpose();
        a += p;
        b += p * pose.center;
    }
    let mut x = a.try_inverse()? * b;
    for _ in 0..10 {
        let mut n = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for (cam, pose, px, s) in rays {
            let (p, j) = crate::geometry::project_with_jacobians(cam, pose, &x).ok()?;
            let r = (p.pixel - nalgebra::Vector2::new(px[0], px[1])) / *s;
            let jx = j.point / *s;
            n += jx.transpose() * jx;
            g += jx.transpose() * r;
        }
        let dx = n.try_inverse()? * (-g);
        x += dx;
        if dx.norm() < 1e-9 {
            break;
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// σ0 from the residuals of the active observations and the redundancy of the system
/// (unweighted: after gross-error elimination the remaining observations are taken as
/// clean, and IRLS weights would bias σ0 low).
pub(crate) fn sigma0(
    res: &[ResidualBlock],
    ev: &Evaluated,
    n_unknowns: usize,
) -> (f64, usize, usize) {
    let mut sum = 0.0;
    let mut n_obs = 0;
    for (i, r) in res.iter().enumerate() {
        if let (true, Some(e)) = (r.active, &ev.evals[i]) {
            sum += e.norm_sq();
            n_obs += e.dim;
        }
    }
    let redundancy = n_obs.saturating_sub(n_unknowns);
    let s0 = if redundancy > 0 {
        (sum / redundancy as f64).sqrt()
    } else {
        f64::NAN
    };
    (s0, n_obs, redundancy)
}

/// RMS image residual in pixels over active image observations.
pub(crate) fn image_rmse(res: &[ResidualBlock], ev: &Evaluated) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (i, r) in res.iter().enumerate() {
        if let (Kind::Image { sigma, .. }, Some(e)) = (&r.kind, &ev.evals[i]) {
            s += e.norm_sq() * sigma * sigma;
            n += 2;
        }
    }
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

/// Robust σ0 for the rejection test: 1.4826 × the median of |v|/√r over all active
/// residual components. Unbiased for Gaussian errors and unaffected by the gross errors
/// still in the solution, so the k·σ0 threshold neither cascades nor starts too wide.
pub(crate) fn robust_sigma0(ev: &Evaluated, std_unit: &[Option<(f64, f64)>]) -> f64 {
    let mut v: Vec<f64> = std_unit
        .iter()
        .zip(&ev.evals)
        .filter_map(|(s, e)| {
            let (red, _) = (*s)?;
            let e = e.as_ref()?;
            Some((0..e.dim).map(move |k| e.r[k].abs() / red.sqrt()))
        })
        .flatten()
        .collect();
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    let m = *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    1.4826 * m
}
