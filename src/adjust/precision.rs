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
//!
//! Data snooping tests each observation with its own dimension: w² = vᵀQ_vv⁻¹v over the
//! components with redundancy (eigenvalues of the local Q_vv = I − J V⁻¹ Jᵀ at least
//! `MIN_REDUNDANCY`; the others are absorbed by the point and carry no test), against
//! χ²(d). A two-ray tie point's image observation is thus tested in one dimension (its
//! along-base component is absorbed by the point's height).

use super::evaluated::Evaluated;
use super::residual::{Eval, Kind, ResidualBlock, State};
use super::selinv::SelectedInverse;
use super::solver::{self, Factor, PointInverse, PointSys, Row, Structure};
use crate::geometry::{Camera, Pose};
use nalgebra::{DMatrix, Matrix3, Vector3};
use rayon::prelude::*;

/// Smallest redundancy number used when standardising (guards against r → 0 for
/// observations that alone determine a parameter).
const MIN_REDUNDANCY: f64 = 0.05;

/// Data-snooping statistic of one observation (whitened with its a-priori σ).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Snoop {
    /// w² = vᵀQ_vv⁻¹v over the testable components.
    pub t: f64,
    /// Testable components (the test's degrees of freedom), 0 when none.
    pub dof: usize,
    /// Decorrelated standardised components uᵀv/√λ (first `dof`), N(0, 1) under H0.
    pub z: [f64; 3],
}

/// Data-snooping statistics of every active block; `ev` and `pts` must come from unit
/// weights. The test is the least-squares one whatever loss the solver used: each object
/// point is re-intersected by least squares with the solved orientations (one
/// Gauss–Newton step) and its residuals tested with the matching Q_vv. Testing the robust
/// solution's residuals against the least-squares Q_vv would not be consistent: Huber
/// lets a down-weighted observation keep a larger residual, and re-admission (which
/// tests an observation against the solution without it) would then take back what the
/// next round rejects again.
pub(crate) fn snooping(ev: &Evaluated, pts: &[PointInverse]) -> Vec<Option<Snoop>> {
    let dx: Vec<Vector3<f64>> = pts.par_iter().map(|ps| -(ps.vinv * ps.g)).collect();
    ev.res
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let (e, _) = ev.at(i)?;
            let vinv = r.point().map(|p| (pts[p].vinv, dx[p]));
            Some(snoop_block(r, &e, vinv))
        })
        .collect()
}

/// Data snooping within one object point with the orientations held: its active blocks
/// `idx` are re-intersected by least squares and tested (the final sweep's local loop).
pub(crate) fn point_snooping(
    res: &[ResidualBlock],
    state: &State,
    idx: &[usize],
) -> Vec<Option<Snoop>> {
    let evals: Vec<Option<Eval>> = idx.iter().map(|&i| res[i].evaluate(state)).collect();
    let mut v = Matrix3::zeros();
    let mut g = Vector3::zeros();
    for e in evals.iter().flatten() {
        v += e.j_point.transpose() * e.j_point;
        g += e.j_point.transpose() * e.r;
    }
    let vinv = v.try_inverse().unwrap_or_else(Matrix3::zeros);
    let dx = -(vinv * g);
    idx.iter()
        .zip(&evals)
        .map(|(&i, e)| Some(snoop_block(&res[i], e.as_ref()?, Some((vinv, dx)))))
        .collect()
}

/// The local Q_vv = I − J V⁻¹ Jᵀ of a block whose point (if any) has normal-block inverse
/// `vinv` (the orientations held), its unknown components' rows and columns zeroed.
fn local_qvv(r: &ResidualBlock, e: &Eval, vinv: Option<&Matrix3<f64>>) -> Matrix3<f64> {
    let mut q = Matrix3::identity();
    if let Some(vinv) = vinv {
        q -= e.j_point * vinv * e.j_point.transpose();
    }
    let known = r.kind.known();
    for k in 0..3 {
        if k >= e.dim || !known[k] {
            for j in 0..3 {
                q[(k, j)] = 0.0;
                q[(j, k)] = 0.0;
            }
        }
    }
    q
}

/// The local redundancy of every active block, the trace of its [`local_qvv`] (the sum
/// of its eigenvalues: Q_vv is positive semi-definite); `ev` and `pts` from unit weights.
pub(crate) fn redundancies(ev: &Evaluated, pts: &[PointInverse]) -> Vec<Option<f64>> {
    ev.res
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let (e, _) = ev.at(i)?;
            Some(local_qvv(r, &e, r.point().map(|p| &pts[p].vinv)).trace())
        })
        .collect()
}

/// The statistic of one block whose point (if any) has normal-block inverse `vinv` and
/// least-squares update `dx`.
fn snoop_block(r: &ResidualBlock, e: &Eval, point: Option<(Matrix3<f64>, Vector3<f64>)>) -> Snoop {
    let mut e = *e;
    if let Some((_, dx)) = point {
        e.r += e.j_point * dx;
    }
    let q = local_qvv(r, &e, point.as_ref().map(|(vinv, _)| vinv));
    let eig = nalgebra::SymmetricEigen::new(q);
    let mut s = Snoop {
        t: 0.0,
        dof: 0,
        z: [0.0; 3],
    };
    for k in 0..3 {
        let l = eig.eigenvalues[k];
        if l >= MIN_REDUNDANCY {
            let u = eig.eigenvectors.column(k).dot(&e.r);
            s.t += u * u / l;
            s.z[s.dof] = u / l.sqrt();
            s.dof += 1;
        }
    }
    s
}

/// Test statistic of an observation that is not in the solution (rejected) against it:
/// its residual's cofactor is I + J V⁻¹ Jᵀ (its own σ plus its point's uncertainty from
/// the active observations). `image_var` scales the image part (variance factor of the
/// test): for an image observation both terms, for a prior or plane only the point's.
pub(crate) fn predicted(
    r: &ResidualBlock,
    e: &Eval,
    pts: &[PointInverse],
    image_var: f64,
) -> (f64, usize) {
    let image = matches!(r.kind, Kind::Image { .. });
    let mut q = Matrix3::zeros();
    if let Some(p) = r.point() {
        q = e.j_point * pts[p].vinv * e.j_point.transpose() * image_var;
    }
    let own = if image { image_var } else { 1.0 };
    let known = r.kind.known();
    let idx: Vec<usize> = (0..e.dim).filter(|&k| known[k]).collect();
    let n = idx.len();
    let mut m = nalgebra::DMatrix::zeros(n, n);
    let mut v = nalgebra::DVector::zeros(n);
    for (a, &ka) in idx.iter().enumerate() {
        v[a] = e.r[ka];
        for (b, &kb) in idx.iter().enumerate() {
            m[(a, b)] = q[(ka, kb)] + if a == b { own } else { 0.0 };
        }
    }
    match m.cholesky() {
        Some(c) => (v.dot(&c.solve(&v)), n),
        None => (f64::INFINITY, n),
    }
}

/// Redundancy number and standardised residual (largest component) of every residual
/// block; `None` for inactive blocks.
pub(crate) fn standardized(
    ev: &Evaluated,
    pts: &[PointInverse],
    sigma0: f64,
) -> Vec<Option<(f64, f64)>> {
    ev.res
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let (e, weight) = ev.at(i)?;
            let mut rmin = 1.0f64;
            let mut w = 0.0f64;
            let known = r.kind.known();
            for k in (0..e.dim).filter(|&k| known[k]) {
                let red = match r.point() {
                    Some(p) => {
                        let jx = e.j_point.row(k);
                        let h = (jx * pts[p].vinv * jx.transpose())[(0, 0)] * weight;
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

/// The cofactors of the reduced camera system's unknowns.
///
/// A dense system's blocks and columns come from its inverse; a sparse system's photo
/// blocks and diagonal from its selected inverse, its camera-side blocks' whole columns
/// (a few) from solves.
pub(crate) fn cofactors(
    st: &Structure,
    rows: &[Row],
    factor: &Factor,
    want_photos: bool,
) -> Cofactors {
    let n = st.n;
    let nb = st.free.len();
    let mut diag_blocks = vec![DMatrix::zeros(0, 0); nb];
    let mut columns = Vec::new();
    let mut diag = vec![f64::NAN; n];
    let selected = match factor {
        Factor::Sparse { .. } if want_photos => {
            solver::reduced_upper(st, rows).and_then(|s| SelectedInverse::new(s.as_ref()))
        }
        _ => None,
    };
    if let Some(inv) = want_photos.then(|| factor.dense_inverse()).flatten() {
        // Every block is wanted: one blocked inverse instead of n solves.
        for (b, q) in diag_blocks.iter_mut().enumerate() {
            let (o, m) = (st.offset[b], st.free[b].len());
            *q = DMatrix::from_fn(m, m, |i, j| inv[(o + i, o + j)]);
            if b >= st.n_photos {
                columns.extend((o..o + m).map(|g| (g, inv.col(g).iter().copied().collect())));
            }
        }
        for (g, d) in diag.iter_mut().enumerate() {
            *d = inv[(g, g)];
        }
        return Cofactors {
            diag_blocks,
            columns,
            diag,
        };
    }
    if let Some(z) = &selected {
        let at = |i: usize, j: usize| z.get(i, j).unwrap_or(f64::NAN);
        for (b, q) in diag_blocks.iter_mut().enumerate() {
            let (o, m) = (st.offset[b], st.free[b].len());
            *q = DMatrix::from_fn(m, m, |i, j| at(o + i, o + j));
        }
        for (g, d) in diag.iter_mut().enumerate() {
            *d = at(g, g);
        }
    }
    let blocks: Vec<usize> = (0..nb)
        .filter(|&b| b >= st.n_photos || (want_photos && selected.is_none()))
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
    refine_intersection(rays, a.try_inverse()? * b)
}

/// Gauss–Newton on the reprojection error of `rays` from `x` (the last step under 1 nm,
/// at most ten); `None` when the normal matrix is singular or the point leaves a camera.
/// A leave-one-out re-intersection starts from all rays' point: it is within the one
/// ray's pull of it, and skips the midpoint start.
pub(crate) fn refine_intersection(
    rays: &[(&Camera, &Pose, [f64; 2], f64)],
    mut x: Vector3<f64>,
) -> Option<Vector3<f64>> {
    if rays.len() < 2 {
        return None;
    }
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
pub(crate) fn sigma0(ev: &Evaluated, n_unknowns: usize) -> (f64, usize, usize) {
    let mut sum = 0.0;
    let mut n_obs = 0;
    ev.for_each_residual(|i, v| {
        if let Some(v) = v {
            sum += v.norm_squared();
            n_obs += ev.res[i].kind.dof();
        }
    });
    let redundancy = n_obs.saturating_sub(n_unknowns);
    let s0 = if redundancy > 0 {
        (sum / redundancy as f64).sqrt()
    } else {
        f64::NAN
    };
    (s0, n_obs, redundancy)
}

/// RMS image residual in pixels over active image observations.
pub(crate) fn image_rmse(ev: &Evaluated) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    ev.for_each_residual(|i, v| {
        if let (Kind::Image { sigma, .. }, Some(v)) = (&ev.res[i].kind, v) {
            s += v.norm_squared() * sigma * sigma;
            n += 2;
        }
    });
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
    let mut v = Vec::new();
    ev.for_each_residual(|i, r| {
        let (Some((red, _)), Some(r)) = (std_unit[i], r) else {
            return;
        };
        let known = ev.res[i].kind.known();
        v.extend(
            (0..ev.res[i].kind.rows())
                .filter(|&k| known[k])
                .map(|k| r[k].abs() / red.sqrt()),
        );
    });
    robust_scale(v)
}

/// 1.4826 × the median of absolute values: the σ of normal data, unaffected by a minority
/// of gross errors; NaN for no data.
pub(crate) fn robust_scale(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    let m = *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    1.4826 * m
}

/// Full cofactor matrix of an object point: V⁻¹ + V⁻¹WᵀS⁻¹WV⁻¹ through the factorised
/// reduced camera system (three right-hand sides).
pub(crate) fn point_cofactor(st: &Structure, factor: &Factor, ps: &PointSys) -> Matrix3<f64> {
    let mut x = DMatrix::zeros(st.n, 3);
    let wv: Vec<(usize, nalgebra::SMatrix<f64, 9, 3>)> =
        ps.w.iter().map(|(b, w)| (*b, w * ps.vinv)).collect();
    for (b, m) in &wv {
        for (i, &k) in st.free[*b].iter().enumerate() {
            for c in 0..3 {
                x[(st.offset[*b] + i, c)] = m[(k, c)];
            }
        }
    }
    let rhs = x.clone();
    factor.solve_in_place(&mut x);
    let mut q = ps.vinv;
    for r in 0..3 {
        for c in 0..3 {
            q[(r, c)] += (0..st.n).map(|g| rhs[(g, r)] * x[(g, c)]).sum::<f64>();
        }
    }
    q
}

/// Variance components per observation group. `redundancy` holds the local redundancy
/// numbers ([`redundancies`]); `exact` overrides them for single blocks (control and POS
/// priors).
pub(crate) fn variance_components(
    ev: &Evaluated,
    redundancy: &[Option<f64>],
    exact: &[(usize, f64)],
) -> Vec<super::VarianceComponent> {
    let groups = [
        "image",
        "control",
        "pos_center",
        "pos_attitude",
        "plane",
        "lidar_datum",
    ];
    let mut acc = vec![(0usize, 0usize, 0.0f64, 0.0f64); groups.len()];
    let exact: std::collections::BTreeMap<usize, f64> = exact.iter().copied().collect();
    ev.for_each_residual(|i, v| {
        let (Some(v), Some(red)) = (v, redundancy[i]) else {
            return;
        };
        let kind = &ev.res[i].kind;
        let g = groups
            .iter()
            .position(|g| *g == kind.group())
            .expect("group");
        acc[g].0 += 1;
        acc[g].1 += kind.dof();
        acc[g].2 += v.norm_squared();
        acc[g].3 += exact.get(&i).copied().unwrap_or(red);
    });
    groups
        .iter()
        .zip(acc)
        .filter(|(_, a)| a.0 > 0)
        .map(|(g, (n, c, vtpv, red))| super::VarianceComponent {
            group: g.to_string(),
            observations: n,
            components: c,
            vtpv,
            redundancy: red,
            sigma0: (red > 1e-9).then(|| (vtpv / red).sqrt()),
        })
        .collect()
}
