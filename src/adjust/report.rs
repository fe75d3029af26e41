//! The adjustment's report and the write-back of the solution into the block: precision,
//! self-calibration, variance components, check points, and a clean output model (no
//! rejected observation, no tie point left with fewer than two rays).

use super::chi2;
use super::evaluated::Evaluated;
use super::precision::{self, cofactors};
use super::problem::{n_unknowns, Problem};
use super::rays::{intersect_snooped, Ray};
use super::residual::Kind;
use super::robust::RejectionTest;
use super::solver::{self, Structure};
use super::{
    AdjustError, AdjustOptions, AdjustReport, CalibrationReport, CheckPointReport, CheckSummary,
    LidarDatumReport, Loss, ObservationRef, PhotoPrecision, ReducedSystemReport, Rejected,
    RejectedCheckRay, RejectedSummary, ResidualReport,
};
use crate::block::{Block, PointKind};
use nalgebra::Vector3;
use std::time::Instant;

#[allow(clippy::too_many_arguments)]
pub(super) fn finish(
    block: &mut Block,
    pb: &Problem,
    st: &Structure,
    opts: &AdjustOptions,
    loss: Loss,
    test: &RejectionTest,
    rejected: Vec<Rejected>,
    iterations: usize,
    rounds: usize,
    converged: bool,
    t0: Instant,
) -> Result<AdjustReport, AdjustError> {
    let n_points = pb.point_ids.len();
    let t = Instant::now();
    let ev = Evaluated::new(&pb.res, &pb.state, loss);
    let n_unk = n_unknowns(st, &pb.res, n_points);
    let (s0, n_obs, redundancy) = precision::sigma0(&ev, n_unk);
    let pts = solver::point_inverses(&ev, st, 0.0);
    let std = precision::standardized(&ev, &pts, if s0.is_finite() { s0 } else { 1.0 });
    let rmse_px = precision::image_rmse(&ev);

    // Per-photo image RMS.
    let mut ph_sum = vec![(0.0, 0usize); pb.photo_ids.len()];
    // Sized once: grown by doubling, the listing held up to twice its size at the
    // report's peak.
    let mut residuals = Vec::with_capacity(pb.res.len());
    ev.for_each_residual(|i, v| {
        let Some(v) = v else { return };
        let r = &pb.res[i];
        let scale: Vec<f64> = match &r.kind {
            Kind::Image { sigma, .. } => {
                let ph = r.photo().expect("image block has a photo");
                ph_sum[ph].0 += v.norm_squared() * sigma * sigma;
                ph_sum[ph].1 += 1;
                vec![*sigma; 2]
            }
            Kind::PointPrior { sigma, .. }
            | Kind::PosCenter { sigma, .. }
            | Kind::LidarDatum { sigma } => sigma.iter().copied().collect(),
            Kind::PosAttitude { sigma, .. } => vec![*sigma; 3],
            Kind::Plane { sqrt_weight, .. } => vec![1.0 / sqrt_weight],
        };
        let (red, w) = std[i].unwrap_or((1.0, 0.0));
        // An axis without prior (σ = ∞) reports the adjusted minus the given coordinate.
        let unweighted = |k: usize| match (&r.kind, r.point()) {
            (Kind::PointPrior { value, .. }, Some(p)) => pb.state.points[p][k] - value[k],
            _ => 0.0,
        };
        residuals.push(ResidualReport {
            observation: pb.refs[i].clone(),
            residual: (0..r.kind.rows())
                .map(|k| {
                    if scale[k].is_finite() {
                        v[k] * scale[k]
                    } else {
                        unweighted(k)
                    }
                })
                .collect(),
            standardized: w,
            redundancy: red,
        });
    });
    // Read into the listing: freed before the reduced system is assembled, the report's
    // peak (24 bytes an observation).
    drop(std);

    let t_residuals = t.elapsed().as_secs_f64();
    // Precision from the undamped reduced camera system.
    let mut photo_precision = Vec::new();
    let mut calibration = Vec::new();
    let rows = solver::reduced_rows(&ev, st, &solver::diagonal(&ev, st), 0.0);
    let mut cache = solver::SymbolicCache::default();
    let factor = solver::factorize(st, &rows, &mut cache);
    let var0 = if s0.is_finite() { s0 * s0 } else { 1.0 };
    let cof = factor
        .as_ref()
        .map(|f| cofactors(st, &rows, f, opts.covariance));
    if factor.is_none() {
        tracing::warn!("the reduced camera system is singular at the solution: no precision");
    }
    let reduced_system = factor.as_ref().map(|f| ReducedSystemReport {
        unknowns: st.n,
        ordering: f.ordering().into(),
        nonzeros: solver::reduced_nonzeros(st),
        factor_nonzeros: f.nonzeros(),
    });
    tracing::debug!(
        t_residuals,
        t_cofactors = t.elapsed().as_secs_f64() - t_residuals,
        "report: residuals and cofactors"
    );
    for (i, &pid) in pb.photo_ids.iter().enumerate() {
        let mut sr = [f64::NAN; 3];
        let mut sc = [f64::NAN; 3];
        if let Some(c) = &cof {
            let q = &c.diag_blocks[i];
            for (j, &k) in st.free[i].iter().enumerate() {
                if q.nrows() > j {
                    let s = (q[(j, j)] * var0).max(0.0).sqrt();
                    if k < 3 {
                        sr[k] = s;
                    } else {
                        sc[k - 3] = s;
                    }
                }
            }
            for k in 0..6 {
                if !st.free[i].contains(&k) {
                    if k < 3 {
                        sr[k] = 0.0;
                    } else {
                        sc[k - 3] = 0.0;
                    }
                }
            }
        }
        let (s, n) = ph_sum[i];
        photo_precision.push(PhotoPrecision {
            photo: pid,
            name: block.photos[&pid].name.clone(),
            sigma_rotation_rad: sr,
            sigma_center_m: sc,
            rmse_px: if n > 0 {
                (s / (2 * n) as f64).sqrt()
            } else {
                0.0
            },
            observations: n,
        });
    }
    if let (Some(c), Some(f)) = (&cof, &factor) {
        let _ = f;
        // Reduced-system diagonal (1 / conditional variance) for the multiple correlation.
        let mut sdiag = vec![0.0; st.n];
        for (b, row) in rows.iter().enumerate() {
            for (j, &k) in st.free[b].iter().enumerate() {
                sdiag[st.offset[b] + j] = row.blocks[0][(k, k)];
            }
        }
        let name_of = |g: usize| -> String {
            let b = st.offset.partition_point(|&o| o <= g) - 1;
            let k = st.free[b][g - st.offset[b]];
            if b < st.n_photos {
                let n = ["rx", "ry", "rz", "cx", "cy", "cz"][k];
                format!("photo {} {n}", pb.photo_ids[b])
            } else {
                let ci = st
                    .camera_block
                    .iter()
                    .position(|x| *x == Some(b))
                    .expect("camera");
                if ci >= pb.state.cameras.len() {
                    return format!("LiDAR datum d{}", ["x", "y", "z"][k]);
                }
                format!(
                    "camera {} {}",
                    pb.camera_ids[ci],
                    pb.state.cameras[ci].param_names()[k]
                )
            }
        };
        // The slots after the cameras are not cameras (the LiDAR datum).
        for (ci, cb) in st
            .camera_block
            .iter()
            .enumerate()
            .take(pb.state.cameras.len())
        {
            let Some(b) = cb else { continue };
            // A calibration group is reported once, under its first camera.
            if pb.camera_leader[ci] != ci {
                continue;
            }
            let params = pb.state.cameras[ci].params();
            for (j, &k) in st.free[*b].iter().enumerate() {
                let g = st.offset[*b] + j;
                let Some((_, col)) = c.columns.iter().find(|(gg, _)| *gg == g) else {
                    continue;
                };
                let qkk = col[g];
                let mut best = (0.0f64, String::new());
                for (h, &qh) in col.iter().enumerate() {
                    let d = c.diag[h];
                    if h == g || !d.is_finite() || d <= 0.0 {
                        continue;
                    }
                    // fx and fy are one physical focal length for square pixels: their
                    // mutual correlation says nothing about the block geometry.
                    let pair = st.free[*b].get(h.wrapping_sub(st.offset[*b])).copied();
                    if matches!((k, pair), (0, Some(1)) | (1, Some(0))) {
                        continue;
                    }
                    let rho = (qh / (qkk * d).sqrt()).abs();
                    if rho > best.0 {
                        best = (rho, name_of(h));
                    }
                }
                // Multiple correlation with all other camera-side unknowns.
                let multiple = (1.0 - 1.0 / (qkk * sdiag[g])).max(0.0).sqrt();
                tracing::debug!(multiple, pairwise = best.0, "self-calibration correlation");
                let (corr, with) = best;
                let determinable = corr < opts.max_correlation;
                if !determinable {
                    tracing::warn!(
                        camera = pb.camera_ids[ci],
                        param = pb.state.cameras[ci].param_names()[k],
                        corr,
                        "self-calibration parameter is not determinable by this block"
                    );
                }
                calibration.push(CalibrationReport {
                    camera: pb.camera_ids[ci],
                    param: pb.state.cameras[ci].param_names()[k].to_string(),
                    value: params[k],
                    sigma: (qkk * var0).max(0.0).sqrt(),
                    max_correlation: corr,
                    correlated_with: with,
                    determinable,
                    fixed: false,
                    held_because: None,
                    t_prior: None,
                });
            }
        }
    }

    let variance_components =
        group_variances(pb, st, opts, loss, &ev, &pts, factor.as_ref(), cof.as_ref());
    let lidar_datum = pb.lidar_datum.map(|slot| {
        let q = lidar_datum_cofactor(st, cof.as_ref(), slot);
        let prior = pb
            .res
            .iter()
            .find_map(|r| match r.kind {
                Kind::LidarDatum { sigma } => Some(sigma),
                _ => None,
            })
            .expect("the LiDAR datum slot has its prior");
        LidarDatumReport {
            shift_m: pb.state.lidar_shift.into(),
            sigma_m: [0, 1, 2].map(|k| q.map_or(f64::NAN, |q| (q[(k, k)] * var0).max(0.0).sqrt())),
            prior_sigma_m: prior.into(),
        }
    });

    // Write back.
    for (i, &pid) in pb.photo_ids.iter().enumerate() {
        let ph = block.photos.get_mut(&pid).expect("photo");
        ph.pose = pb.state.poses[i];
        ph.status = crate::block::PhotoStatus::Oriented;
    }
    for (i, &cid) in pb.camera_ids.iter().enumerate() {
        block.cameras.get_mut(&cid).expect("camera").model = pb.state.cameras[i].clone();
    }
    // A tie point is written back with its adjusted position when at least two of its
    // image observations are in the solution; a tie point left with fewer (its other rays
    // rejected) cannot be intersected and leaves the block, so the output model holds no
    // point whose position its observations do not determine. Control points stay: one
    // ray of a surveyed point still constrains its photo.
    let mut rays = vec![0usize; n_points];
    let mut active_point = vec![false; n_points];
    for r in pb.res.iter().filter(|r| r.active) {
        if let Some(p) = r.point() {
            active_point[p] = true;
            if matches!(r.kind, Kind::Image { .. }) {
                rays[p] += 1;
            }
        }
    }
    for (i, &id) in pb.point_ids.iter().enumerate() {
        let pt = block.points.get_mut(&id).expect("point");
        if pt.kind == PointKind::Tie && active_point[i] {
            pt.position = pb.state.points[i];
        }
    }
    for rj in &rejected {
        if let ObservationRef::Image { point, photo } = rj.observation {
            if let Some(pt) = block.points.get_mut(&point) {
                pt.observations.retain(|o| o.photo != photo);
            }
        }
    }
    let in_solution: std::collections::BTreeMap<_, usize> = pb
        .point_ids
        .iter()
        .zip(&rays)
        .map(|(&id, &n)| (id, n))
        .collect();
    let before = block.points.len();
    block.points.retain(|id, p| {
        p.kind != PointKind::Tie
            || in_solution.get(id).copied().unwrap_or(p.observations.len()) >= 2
    });
    let removed_tie_points = before - block.points.len();
    if removed_tie_points > 0 {
        tracing::info!(
            removed_tie_points,
            "tie points with fewer than two image observations left the block"
        );
    }

    let check = check_points(block, s0);
    let n_active_points = active_point.iter().filter(|&&a| a).count();
    Ok(AdjustReport {
        sigma0: s0,
        rejection_test: test.describe(),
        control_sigma_scale: test.control_scale,
        tie_point_prior: test.tie_prior,
        variance_components,
        removed_tie_points,
        rmse_px,
        iterations,
        rounds,
        converged,
        datum: pb.datum.clone(),
        photos: pb.photo_ids.len(),
        points: n_active_points,
        observations: n_obs,
        redundancy,
        rejected: RejectedSummary {
            count: rejected.len(),
            list: rejected,
        },
        time_s: t0.elapsed().as_secs_f64(),
        photo_precision,
        calibration,
        lidar_datum,
        reduced_system,
        check,
        residuals,
    })
}

/// Intersects every check point with the adjusted orientations, its measurements tested
/// as the adjustment tests tie points and control (data snooping at α0 = 0.1 % against
/// the a-priori σ, scaled by `sigma0` where the adjustment found it too optimistic), and
/// compares with its surveyed position.
pub(crate) fn check_points(block: &Block, sigma0: f64) -> Option<CheckSummary> {
    let f2 = sigma0.max(1.0).powi(2);
    let mut pts = Vec::new();
    let mut rejected = Vec::new();
    let mut not_evaluated = 0;
    for pt in block.points.values().filter(|p| p.kind == PointKind::Check) {
        let (obs, rays): (Vec<_>, Vec<_>) = pt
            .observations
            .iter()
            .filter_map(|o| {
                let ph = block.photos.get(&o.photo)?;
                let cam = &block.cameras.get(&ph.camera)?.model;
                Some((
                    o,
                    Ray {
                        camera: cam,
                        pose: ph.pose,
                        pixel: o.pixel,
                        sigma_px: o.sigma_px,
                    },
                ))
            })
            .unzip();
        if rays.len() < 2 {
            tracing::warn!(
                point = pt.id,
                "check point cannot be intersected (fewer than two usable rays)"
            );
            continue;
        }
        let s = intersect_snooped(&rays, f2, 0.001);
        let reject = |i: usize, residual_px: Option<f64>, reason: String| RejectedCheckRay {
            point: pt.id,
            name: pt.name.clone(),
            photo: obs[i].photo,
            pixel: obs[i].pixel,
            residual_px,
            reason,
        };
        for r in &s.rejected {
            rejected.push(reject(
                r.index,
                Some(r.residual_px).filter(|v| v.is_finite()),
                format!(
                    "data snooping: leaving it out lowers the rays' χ² by {:.1} > χ²(2, 0.1 %) = {:.1}",
                    r.statistic,
                    chi2::critical(2, 0.001)
                ),
            ));
        }
        let Some(x) = s.position else {
            not_evaluated += 1;
            let reason = format!(
                "the point's {} remaining rays disagree (χ² {:.1} with {} degrees of freedom) and no single ray explains it: the point is not evaluated",
                s.kept.len(),
                s.ssr,
                s.dof
            );
            for &i in &s.kept {
                rejected.push(reject(i, None, reason.clone()));
            }
            tracing::warn!(point = pt.id, "{reason}");
            continue;
        };
        let e = x - pt.position;
        pts.push(CheckPointReport {
            point: pt.id,
            name: pt.name.clone(),
            error: [e.x, e.y, e.z],
            rays: s.kept.len(),
        });
    }
    if pts.is_empty() && rejected.is_empty() {
        return None;
    }
    let [plan, height, max] = checkpoint_rmse(pts.iter().map(|p| p.error));
    Some(CheckSummary {
        count: pts.len(),
        rmse_plan_m: plan,
        rmse_height_m: height,
        max_m: max,
        points: pts,
        not_evaluated,
        rejected,
    })
}

/// RMSE in plan and height and the largest 3-D error of check point errors (m): the one
/// checkpoint statistic of the adjustment report and the epoch evaluation. Zeros for none.
pub fn checkpoint_rmse(errors: impl IntoIterator<Item = [f64; 3]>) -> [f64; 3] {
    let (mut plan, mut height, mut max, mut n) = (0.0, 0.0, 0.0f64, 0usize);
    for e in errors {
        plan += e[0] * e[0] + e[1] * e[1];
        height += e[2] * e[2];
        max = max.max(Vector3::from(e).norm());
        n += 1;
    }
    let n = n.max(1) as f64;
    [(plan / n).sqrt(), (height / n).sqrt(), max]
}

/// Variance components per observation group, with exact redundancy numbers for control
/// priors (the point's full cofactor) and POS priors (the photo's EO cofactor, when the
/// EO covariances were computed).
#[allow(clippy::too_many_arguments)]
fn group_variances(
    pb: &Problem,
    st: &Structure,
    opts: &AdjustOptions,
    loss: Loss,
    ev: &Evaluated,
    pts: &[solver::PointInverse],
    factor: Option<&solver::Factor>,
    cof: Option<&precision::Cofactors>,
) -> Vec<super::VarianceComponent> {
    // The redundancy numbers are least squares'; the solution's own when it is.
    let ev_ls = Evaluated::new(&pb.res, &pb.state, Loss::None);
    let ls = (loss != Loss::None).then(|| solver::point_inverses(&ev_ls, st, 0.0));
    let (ev_ls, pts_ls) = ls.as_ref().map_or((ev, pts), |p| (&ev_ls, p.as_slice()));
    let red = precision::redundancies(ev_ls, pts_ls);
    let mut exact = Vec::new();
    for (i, r) in pb.res.iter().enumerate() {
        // Image observations, the bulk, have no exact redundancy: not evaluated for it.
        if !r.active || matches!(r.kind, Kind::Image { .. } | Kind::Plane { .. }) {
            continue;
        }
        if ev.residual(i).is_none() {
            continue;
        }
        let (q, sigma) = match (&r.kind, r.point(), r.photo()) {
            (Kind::PointPrior { sigma, .. }, Some(p), _) => match factor {
                Some(f) => (
                    precision::point_cofactor(st, f, &solver::point_system(ev, st, p, 0.0)),
                    *sigma,
                ),
                None => continue,
            },
            (Kind::PosCenter { sigma, .. }, _, Some(ph)) if opts.covariance => {
                match eo_cofactor(st, cof, ph, 3) {
                    Some(q) => (q, *sigma),
                    None => continue,
                }
            }
            (Kind::PosAttitude { sigma, .. }, _, Some(ph)) if opts.covariance => {
                match eo_cofactor(st, cof, ph, 0) {
                    Some(q) => (q, Vector3::repeat(*sigma)),
                    None => continue,
                }
            }
            (Kind::LidarDatum { sigma }, _, _) => {
                match r.camera().and_then(|c| lidar_datum_cofactor(st, cof, c)) {
                    Some(q) => (q, *sigma),
                    None => continue,
                }
            }
            _ => continue,
        };
        let red: f64 = (0..3)
            .filter(|&k| sigma[k].is_finite())
            .map(|k| (1.0 - q[(k, k)] / (sigma[k] * sigma[k])).max(0.0))
            .sum();
        exact.push((i, red));
    }
    precision::variance_components(ev_ls, &red, &exact)
}

/// 3×3 cofactor of the LiDAR datum shift in camera slot `slot` (its block is always
/// among the cofactors computed: they cover every block after the photos).
fn lidar_datum_cofactor(
    st: &Structure,
    cof: Option<&precision::Cofactors>,
    slot: usize,
) -> Option<nalgebra::Matrix3<f64>> {
    let b = (*st.camera_block.get(slot)?)?;
    let q = &cof?.diag_blocks[b];
    (q.nrows() == 3).then(|| nalgebra::Matrix3::from_fn(|i, j| q[(i, j)]))
}

/// 3×3 cofactor of a photo's rotation (`first` 0) or centre (3); a parameter held fixed
/// by the datum has cofactor 0.
fn eo_cofactor(
    st: &Structure,
    cof: Option<&precision::Cofactors>,
    photo: usize,
    first: usize,
) -> Option<nalgebra::Matrix3<f64>> {
    let q = &cof?.diag_blocks[photo];
    let free = &st.free[photo];
    if q.nrows() != free.len() {
        return None;
    }
    let mut m = nalgebra::Matrix3::zeros();
    for (a, &ka) in free.iter().enumerate() {
        for (b, &kb) in free.iter().enumerate() {
            if (first..first + 3).contains(&ka) && (first..first + 3).contains(&kb) {
                m[(ka - first, kb - first)] = q[(a, b)];
            }
        }
    }
    Some(m)
}
