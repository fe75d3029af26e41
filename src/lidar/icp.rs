//! Point-to-plane ICP with a 7-parameter similarity (rigid as an option): minimises
//! Σ w·dist² of transformed source points to LiDAR planes (seed 000 Eq. 1).
//!
//! Each iteration re-finds correspondences (nearest LiDAR neighbourhood, cached plane),
//! gates them with a distance that shrinks from the start gate towards a multiple of the
//! robust residual scale, weights them by coplanarity × Tukey biweight, and solves the
//! linearised normal equations for an increment about the centroid of the current
//! correspondences (centring decorrelates scale/rotation from translation).

use super::planes::PlaneIndex;
use super::{LidarError, Result};
use crate::geometry::{rotation_from_vector, Similarity};
use nalgebra::{Matrix4, SMatrix, SVector, Vector3};
use rayon::prelude::*;
use serde::Serialize;

/// Which transform ICP estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum IcpModel {
    Similarity,
    Rigid,
}

#[derive(Debug, Clone, Copy)]
pub struct IcpOptions {
    pub model: IcpModel,
    pub max_iterations: usize,
    /// Gate (|point-to-plane distance|, metres) at the first iteration; must cover the
    /// start error along the normals.
    pub initial_gate: f64,
    /// Floor of the gate (metres), around 3–5× the LiDAR noise.
    pub min_gate: f64,
    /// Gate factor per iteration (0 < f < 1).
    pub gate_shrink: f64,
    /// Tukey biweight constant in units of the robust residual scale.
    pub tukey_c: f64,
    /// Converged when the increment moves no point of the source extent by more than
    /// this (metres) or by more than 2 % of the robust residual scale: below that,
    /// steps are correspondence switching between neighbouring LiDAR planes, not progress.
    pub tolerance: f64,
    pub min_correspondences: usize,
    /// Directions of the (unit-scaled) normal matrix with an eigenvalue below this
    /// fraction of the largest are not estimated: the surfaces do not determine them.
    pub min_eigenvalue_ratio: f64,
}

impl Default for IcpOptions {
    fn default() -> Self {
        Self {
            model: IcpModel::Similarity,
            max_iterations: 100,
            initial_gate: 30.0,
            min_gate: 0.3,
            gate_shrink: 0.7,
            tukey_c: 4.685,
            tolerance: 1e-3,
            min_correspondences: 20,
            min_eigenvalue_ratio: 1e-3,
        }
    }
}

/// Statistics of one iteration.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct IcpIteration {
    pub iteration: usize,
    pub gate_m: f64,
    pub correspondences: usize,
    pub rmse_m: f64,
    pub robust_sigma_m: f64,
    pub step_m: f64,
}

#[derive(Debug, Clone)]
pub struct IcpResult {
    /// Maps source world coordinates onto the target (world, not local).
    pub transform: Similarity,
    /// Covariance of the final increment [ω (rad), t (m), ds] from σ0²·N⁻¹; ds row/column
    /// zero in rigid mode. Translation about the centroid of the correspondences.
    pub covariance: SMatrix<f64, 7, 7>,
    pub sigma0_m: f64,
    pub rmse_m: f64,
    pub inliers: usize,
    pub converged: bool,
    pub iterations: Vec<IcpIteration>,
    /// Directions of the similarity the surfaces left undetermined in the last
    /// iteration (not moved; 0 on well-shaped relief).
    pub degenerate_directions: usize,
}

impl IcpResult {
    pub fn matrix(&self) -> Matrix4<f64> {
        self.transform.to_matrix4()
    }
}

struct Corr {
    q: Vector3<f64>,
    n: Vector3<f64>,
    r: f64,
    w: f64,
}

/// Registers `source` (world coordinates) onto the LiDAR of `index`, starting from `initial`.
pub fn icp_point_to_plane(
    index: &PlaneIndex,
    source: &[[f64; 3]],
    initial: &Similarity,
    opts: &IcpOptions,
) -> Result<IcpResult> {
    // Written as one negated conjunction so NaN options are rejected too.
    let valid = opts.gate_shrink > 0.0
        && opts.gate_shrink < 1.0
        && opts.min_gate > 0.0
        && opts.initial_gate >= opts.min_gate;
    if !valid {
        return Err(LidarError::InvalidOption(
            "need 0 < gate_shrink < 1 and 0 < min_gate <= initial_gate".into(),
        ));
    }
    let need = opts.min_correspondences.max(7);
    if source.len() < need {
        return Err(LidarError::TooFewPoints {
            what: "ICP source points".into(),
            got: source.len(),
            need,
        });
    }
    let o = index.origin();
    let mut local = Vec::with_capacity(source.len());
    for (i, p) in source.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(LidarError::NonFinite {
                what: "ICP source points".into(),
                index: i,
            });
        }
        local.push(Vector3::new(p[0], p[1], p[2]) - o);
    }
    // Work in local coordinates: T_local(x) = T(x + o) − o.
    let shift = Similarity::new(1.0, nalgebra::Matrix3::identity(), o);
    let unshift = shift.inverse();
    let mut t = unshift.compose(initial).compose(&shift);
    let extent = {
        let c = local.iter().sum::<Vector3<f64>>() / local.len() as f64;
        local
            .iter()
            .map(|p| (p - c).norm())
            .fold(0.0, f64::max)
            .max(1.0)
    };
    let npar = if opts.model == IcpModel::Similarity {
        7
    } else {
        6
    };

    // Points spanning the source: how far one transform is from another over them.
    let span: Vec<Vector3<f64>> = {
        let c = local.iter().sum::<Vector3<f64>>() / local.len() as f64;
        std::iter::once(c)
            .chain((0..3).flat_map(|k| {
                let mut e = Vector3::zeros();
                e[k] = extent;
                [c + e, c - e]
            }))
            .collect()
    };
    let apart = |a: &Similarity, b: &Similarity| {
        span.iter()
            .map(|p| (a.apply(p) - b.apply(p)).norm())
            .fold(0.0, f64::max)
    };
    // The transforms after the last two iterations: at the gate's floor the correspondences
    // can flip between neighbouring planes every other iteration, and the solution then
    // alternates between two states millimetres apart for ever.
    let mut previous: [Option<Similarity>; 2] = [None, None];
    let mut gate = opts.initial_gate;
    let mut iterations = Vec::new();
    let mut converged = false;
    let mut degenerate = 0;
    let mut last_cov = SMatrix::<f64, 7, 7>::zeros();
    let mut sigma0 = 0.0;
    let mut rmse = 0.0;
    let mut inliers = 0;

    for it in 0..opts.max_iterations {
        // Correspondences in parallel; collect preserves order, so sums are deterministic.
        let corr: Vec<Corr> = local
            .par_iter()
            .filter_map(|p| {
                let q = t.apply(p);
                let pl = index.plane_at(&q)?;
                let r = pl.distance(&q);
                (r.abs() <= gate).then_some(Corr {
                    q,
                    n: pl.normal,
                    r,
                    w: pl.weight,
                })
            })
            .collect();
        if corr.len() < need {
            return Err(LidarError::TooFewCorrespondences {
                got: corr.len(),
                need,
                iteration: it,
            });
        }
        // Robust scale from the median absolute residual.
        let mut abs: Vec<f64> = corr.iter().map(|c| c.r.abs()).collect();
        abs.sort_by(|a, b| a.total_cmp(b));
        let sigma = (1.4826 * abs[abs.len() / 2]).max(1e-6);
        let cut = opts.tukey_c * sigma;
        let centre = corr.iter().map(|c| c.q).sum::<Vector3<f64>>() / corr.len() as f64;

        let mut n_mat = SMatrix::<f64, 7, 7>::zeros();
        let mut b = SVector::<f64, 7>::zeros();
        let (mut sw, mut swr2, mut sr2, mut used) = (0.0, 0.0, 0.0, 0usize);
        for c in &corr {
            let u = c.r / cut;
            if u.abs() >= 1.0 {
                continue;
            }
            let w = c.w * (1.0 - u * u).powi(2);
            let d = c.q - centre;
            // r(δ) = n·(centre + (1+ds)(I+[ω]×)d + τ − plane) ≈ r + (d×n)·ω + n·τ + (n·d)·ds
            let dxn = d.cross(&c.n);
            let a = SVector::<f64, 7>::from_column_slice(&[
                dxn.x,
                dxn.y,
                dxn.z,
                c.n.x,
                c.n.y,
                c.n.z,
                c.n.dot(&d),
            ]);
            n_mat += w * a * a.transpose();
            b -= w * c.r * a;
            sw += w;
            swr2 += w * c.r * c.r;
            sr2 += c.r * c.r;
            used += 1;
        }
        if used < need {
            return Err(LidarError::TooFewCorrespondences {
                got: used,
                need,
                iteration: it,
            });
        }
        if opts.model == IcpModel::Rigid {
            for k in 0..7 {
                n_mat[(6, k)] = 0.0;
                n_mat[(k, 6)] = 0.0;
            }
            n_mat[(6, 6)] = 1.0;
            b[6] = 0.0;
        }
        // Solve in units where every parameter moves the source extent by metres, and
        // leave out the directions the surfaces do not determine (degeneracy-aware ICP):
        // over flat ground, horizontal shifts and rotation about the vertical are free, and
        // a plain solve would wander along them on noise.
        let ext = extent.max(1.0);
        let dscale = SVector::<f64, 7>::from_column_slice(&[ext, ext, ext, 1.0, 1.0, 1.0, ext]);
        let scaled = SMatrix::<f64, 7, 7>::from_fn(|i, j| n_mat[(i, j)] / (dscale[i] * dscale[j]));
        let eig = scaled.symmetric_eigen();
        let lmax = eig.eigenvalues.max();
        if !(lmax.is_finite() && lmax > 0.0) {
            return Err(LidarError::Singular { iteration: it });
        }
        let mut x = SVector::<f64, 7>::zeros();
        let mut cov = SMatrix::<f64, 7, 7>::zeros();
        degenerate = 0;
        for k in 0..7 {
            let l = eig.eigenvalues[k];
            let v = eig.eigenvectors.column(k);
            if l <= opts.min_eigenvalue_ratio * lmax {
                if !(opts.model == IcpModel::Rigid && v[6].abs() > 0.9) {
                    degenerate += 1;
                }
                continue;
            }
            let bs = SVector::<f64, 7>::from_fn(|i, _| b[i] / dscale[i]);
            x += v * (v.dot(&bs) / l);
            cov += v * v.transpose() / l;
        }
        for i in 0..7 {
            x[i] /= dscale[i];
            for j in 0..7 {
                cov[(i, j)] /= dscale[i] * dscale[j];
            }
        }
        if opts.model == IcpModel::Rigid {
            x[6] = 0.0;
            for k in 0..7 {
                cov[(6, k)] = 0.0;
                cov[(k, 6)] = 0.0;
            }
        }
        let omega = Vector3::new(x[0], x[1], x[2]);
        let tau = Vector3::new(x[3], x[4], x[5]);
        let ds = x[6];
        let rot = rotation_from_vector(&omega);
        // D(x) = centre + (1+ds)·R(x − centre) + τ
        let s = 1.0 + ds;
        let delta = Similarity::new(s, rot, centre + tau - s * (rot * centre));
        t = delta.compose(&t);
        let two_back = previous[0];
        previous = [previous[1], Some(t)];

        let step = tau.norm() + extent * (omega.norm() + ds.abs());
        // Redundancy uses the effective (weighted) count so σ0 is in metres per unit weight.
        let redundancy = (used as f64 - npar as f64).max(1.0);
        sigma0 = (swr2 / sw * used as f64 / redundancy).sqrt();
        last_cov = cov * (swr2 / redundancy);
        rmse = (sr2 / used as f64).sqrt();
        inliers = used;
        iterations.push(IcpIteration {
            iteration: it,
            gate_m: gate,
            correspondences: corr.len(),
            rmse_m: rmse,
            robust_sigma_m: sigma,
            step_m: step,
        });
        tracing::debug!(
            iteration = it,
            gate,
            correspondences = corr.len(),
            rmse,
            sigma,
            step,
            "icp"
        );
        let gate_floor = opts.min_gate.max(3.0 * opts.tukey_c * sigma).min(gate);
        let next_gate = (gate * opts.gate_shrink).max(gate_floor);
        let settled = (next_gate - gate).abs() < 1e-12;
        let small = opts.tolerance.max(0.02 * sigma);
        // A two-iteration cycle counts as converged: the states differ by less than a step
        // that would not be progress either.
        let cycling = two_back.is_some_and(|b| apart(&t, &b) < small);
        if settled && (step < small || cycling) {
            converged = true;
            break;
        }
        gate = next_gate;
    }
    Ok(IcpResult {
        transform: shift.compose(&t).compose(&unshift),
        covariance: last_cov,
        sigma0_m: sigma0,
        rmse_m: rmse,
        inliers,
        converged,
        iterations,
        degenerate_directions: degenerate,
    })
}
