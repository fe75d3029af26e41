//! Problem assembly from a [`Block`], the solve–reject rounds and the report.

use super::precision::{self, cofactors, intersect};
use super::residual::{Kind, ResidualBlock, State};
use super::robust;
use super::solver::{self, LmOptions, Structure};
use super::{
    AdjustError, AdjustOptions, AdjustReport, CalibrationReport, CheckPointReport, CheckSummary,
    Loss, ObservationRef, PhotoPrecision, PlaneConstraint, PlaneRefitter, Rejected,
    RejectedSummary, Rejection, ResidualReport,
};
use crate::block::{Block, PhotoId, PointId, PointKind};
use nalgebra::{DMatrix, Vector2, Vector3};
use std::collections::BTreeMap;
use std::time::Instant;

/// Largest number of times the LiDAR planes are re-fitted.
const MAX_PLANE_REFITS: usize = 3;

pub(super) struct Problem {
    pub(super) photo_ids: Vec<PhotoId>,
    pub(super) camera_ids: Vec<u32>,
    pub(super) point_ids: Vec<PointId>,
    pub(super) point_index: BTreeMap<PointId, usize>,
    pub(super) res: Vec<ResidualBlock>,
    pub(super) refs: Vec<ObservationRef>,
    pub(super) photo_free: Vec<[bool; 6]>,
    pub(super) camera_free: Vec<Vec<usize>>,
    pub(super) state: State,
    pub(super) datum: String,
}

impl Problem {
    /// The sparsity structure of the normal equations over the current residual list.
    pub(super) fn structure(&self) -> Structure {
        Structure::new(
            &self.res,
            self.photo_ids.len(),
            self.point_ids.len(),
            &self.photo_free,
            &self.camera_free,
        )
    }
}

fn check_options(o: &AdjustOptions) -> Result<(), AdjustError> {
    let bad = |name: &str, message: String| {
        Err(AdjustError::InvalidOption {
            name: name.into(),
            message,
        })
    };
    match o.loss {
        Loss::Huber(c) | Loss::Cauchy(c) if !(c.is_finite() && c > 0.0) => {
            return bad(
                "loss",
                format!("scale must be positive and finite, got {c}"),
            )
        }
        _ => {}
    }
    match o.rejection {
        Rejection::Threshold(k) | Rejection::DataSnooping(k) if !(k.is_finite() && k >= 1.0) => {
            return bad(
                "rejection",
                format!("k must be a finite number ≥ 1 (2–3 is usual), got {k}"),
            )
        }
        _ => {}
    }
    if o.max_rounds == 0 || o.max_iterations == 0 {
        return bad(
            "max_rounds/max_iterations",
            "must be at least 1".to_string(),
        );
    }
    if !(o.max_correlation > 0.0 && o.max_correlation <= 1.0) {
        return bad(
            "max_correlation",
            format!("must be in (0, 1], got {}", o.max_correlation),
        );
    }
    Ok(())
}

fn plane_block(
    pl: &PlaneConstraint,
    point_index: &BTreeMap<PointId, usize>,
) -> Result<ResidualBlock, AdjustError> {
    let &p = point_index
        .get(&pl.point)
        .ok_or_else(|| AdjustError::UnknownId {
            what: "object point of a LiDAR plane constraint (not an adjusted tie/control point)"
                .into(),
            id: pl.point.to_string(),
        })?;
    let n = Vector3::from(pl.normal);
    if !(n.iter().all(|v| v.is_finite()) && pl.d.is_finite() && pl.weight.is_finite()) {
        return Err(AdjustError::NotFinite {
            what: format!("LiDAR plane of point {}", pl.point),
        });
    }
    if n.norm() < 1e-9 || pl.weight <= 0.0 {
        return Err(AdjustError::InvalidBlock(format!(
            "LiDAR plane of point {}: the normal must be non-zero and the weight positive",
            pl.point
        )));
    }
    let norm = n.norm();
    Ok(ResidualBlock {
        kind: Kind::Plane {
            normal: n / norm,
            d: pl.d / norm,
            sqrt_weight: pl.weight.sqrt(),
        },
        photo: None,
        camera: None,
        point: Some(p),
        active: true,
    })
}

fn build(block: &Block, planes: &[PlaneConstraint]) -> Result<Problem, AdjustError> {
    block
        .validate()
        .map_err(|e| AdjustError::InvalidBlock(e.to_string()))?;
    if block.photos.len() < 2 {
        return Err(AdjustError::Degenerate(format!(
            "the block has {} photo(s); a bundle adjustment needs at least two (orient a single photo by resection)",
            block.photos.len()
        )));
    }
    let photo_ids: Vec<PhotoId> = block.photos.keys().copied().collect();
    let photo_index: BTreeMap<PhotoId, usize> =
        photo_ids.iter().enumerate().map(|(i, &p)| (p, i)).collect();
    let camera_ids: Vec<u32> = block.cameras.keys().copied().collect();
    let camera_index: BTreeMap<u32, usize> = camera_ids
        .iter()
        .enumerate()
        .map(|(i, &c)| (c, i))
        .collect();
    let mut camera_free = Vec::new();
    for c in block.cameras.values() {
        let names = c.model.param_names();
        let mut free = Vec::new();
        for n in &c.free_params {
            let k = names
                .iter()
                .position(|m| m == n)
                .ok_or_else(|| AdjustError::UnknownId {
                    what: format!(
                        "interior parameter of camera {} (known: {})",
                        c.id,
                        names.join(", ")
                    ),
                    id: n.clone(),
                })?;
            free.push(k);
        }
        free.sort_unstable();
        free.dedup();
        camera_free.push(free);
    }
    let mut res = Vec::new();
    let mut refs = Vec::new();
    let mut point_ids = Vec::new();
    let mut points = Vec::new();
    let mut control_positions = Vec::new();
    let planned: std::collections::BTreeSet<PointId> = planes.iter().map(|p| p.point).collect();
    for pt in block.points.values() {
        if pt.kind == PointKind::Check {
            continue;
        }
        let n_obs = pt.observations.len();
        let prior = if pt.kind == PointKind::Control {
            let s = pt.sigma.ok_or_else(|| {
                AdjustError::InvalidBlock(format!(
                    "control point {} ({}) has no σ for its surveyed position",
                    pt.id, pt.name
                ))
            })?;
            if !s.iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(AdjustError::InvalidBlock(format!(
                    "control point {} ({}): σ {:?} must be positive and finite",
                    pt.id, pt.name, s
                )));
            }
            Some(Vector3::from(s))
        } else {
            None
        };
        // A tie point needs two rays (or one ray and a plane) to be intersected.
        let enough = match prior {
            Some(_) => n_obs >= 1,
            None => n_obs >= 2 || (n_obs >= 1 && planned.contains(&pt.id)),
        };
        if !enough {
            continue;
        }
        let p = points.len();
        points.push(pt.position);
        point_ids.push(pt.id);
        for o in &pt.observations {
            let ph = photo_index[&o.photo];
            res.push(ResidualBlock {
                kind: Kind::Image {
                    pixel: Vector2::new(o.pixel[0], o.pixel[1]),
                    sigma: o.sigma_px,
                },
                photo: Some(ph),
                camera: Some(camera_index[&block.photos[&o.photo].camera]),
                point: Some(p),
                active: true,
            });
            refs.push(ObservationRef::Image {
                point: pt.id,
                photo: o.photo,
            });
        }
        if let Some(sigma) = prior {
            control_positions.push(pt.position);
            res.push(ResidualBlock {
                kind: Kind::PointPrior {
                    value: pt.position,
                    sigma,
                },
                photo: None,
                camera: None,
                point: Some(p),
                active: true,
            });
            refs.push(ObservationRef::ControlPrior { point: pt.id });
        }
    }
    let point_index: BTreeMap<PointId, usize> =
        point_ids.iter().enumerate().map(|(i, &p)| (p, i)).collect();
    for pl in planes {
        res.push(plane_block(pl, &point_index)?);
        refs.push(ObservationRef::Plane { point: pl.point });
    }
    let mut n_pos = 0;
    for (i, ph) in block.photos.values().enumerate() {
        let Some(prior) = &ph.prior else { continue };
        let s = Vector3::from(prior.center_sigma);
        if !(prior.center.iter().all(|v| v.is_finite())
            && s.iter().all(|v| v.is_finite() && *v > 0.0))
        {
            return Err(AdjustError::InvalidBlock(format!(
                "POS prior of photo {} ({}): centre and σ must be finite, σ positive",
                ph.id, ph.name
            )));
        }
        n_pos += 1;
        res.push(ResidualBlock {
            kind: Kind::PosCenter {
                value: prior.center,
                sigma: s,
            },
            photo: Some(i),
            camera: None,
            point: None,
            active: true,
        });
        refs.push(ObservationRef::PosCenter { photo: ph.id });
        if let Some(r) = prior.rotation {
            if !(prior.rotation_sigma_rad.is_finite() && prior.rotation_sigma_rad > 0.0) {
                return Err(AdjustError::InvalidBlock(format!(
                    "POS prior of photo {} ({}): attitude σ must be positive",
                    ph.id, ph.name
                )));
            }
            res.push(ResidualBlock {
                kind: Kind::PosAttitude {
                    rotation: r,
                    sigma: prior.rotation_sigma_rad,
                },
                photo: Some(i),
                camera: None,
                point: None,
                active: true,
            });
            refs.push(ObservationRef::PosAttitude { photo: ph.id });
        }
    }
    // Every photo must see enough adjusted points to be resected within the block.
    let mut per_photo = vec![0usize; photo_ids.len()];
    for r in &res {
        if let (Kind::Image { .. }, Some(ph)) = (&r.kind, r.photo) {
            per_photo[ph] += 1;
        }
    }
    for (i, &n) in per_photo.iter().enumerate() {
        if n < 3 {
            let ph = &block.photos[&photo_ids[i]];
            return Err(AdjustError::TooFewObservations(format!(
                "photo {} ({}) observes {n} adjustable point(s); at least 3 are needed",
                ph.id, ph.name
            )));
        }
    }
    let mut datum = Vec::new();
    if !control_positions.is_empty() {
        datum.push("control");
    }
    if n_pos > 0 {
        datum.push("pos");
    }
    if !planes.is_empty() {
        datum.push("lidar_planes");
    }
    if datum == ["control"] {
        check_control_geometry(&control_positions)?;
    }
    let mut photo_free = vec![[true; 6]; photo_ids.len()];
    if datum.is_empty() {
        // Free network: hold the first photo and the largest centre coordinate
        // difference of the photo farthest from it (seven datum defects: 6 + scale).
        photo_free[0] = [false; 6];
        let c0 = block.photos[&photo_ids[0]].pose.center;
        let (far, d) = block
            .photos
            .values()
            .enumerate()
            .skip(1)
            .map(|(i, p)| (i, p.pose.center - c0))
            .max_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))
            .expect("two photos");
        if d.norm() <= 0.0 {
            return Err(AdjustError::Degenerate(
                "free network: all projection centres coincide, the scale is undefined".into(),
            ));
        }
        photo_free[far][3 + d.iamax()] = false;
        datum.push("free_network");
    }
    let state = State {
        poses: block.photos.values().map(|p| p.pose).collect(),
        cameras: block.cameras.values().map(|c| c.model.clone()).collect(),
        points,
    };
    Ok(Problem {
        photo_ids,
        camera_ids,
        point_ids,
        point_index,
        res,
        refs,
        photo_free,
        camera_free,
        state,
        datum: datum.join("+"),
    })
}

/// Control points alone fix the datum only when at least three of them span a plane.
fn check_control_geometry(c: &[Vector3<f64>]) -> Result<(), AdjustError> {
    if c.len() < 3 {
        return Err(AdjustError::Degenerate(format!(
            "{} control point(s) cannot fix the datum; at least 3 not on a line are needed (or POS / LiDAR planes)",
            c.len()
        )));
    }
    let mean = c.iter().fold(Vector3::zeros(), |a, b| a + b) / c.len() as f64;
    let mut m = DMatrix::zeros(c.len(), 3);
    for (i, p) in c.iter().enumerate() {
        for k in 0..3 {
            m[(i, k)] = p[k] - mean[k];
        }
    }
    let s = m.singular_values();
    let mut s: Vec<f64> = s.iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    if s[0] <= 0.0 || s[1] < 1e-3 * s[0] {
        return Err(AdjustError::Degenerate(format!(
            "the {} control points are collinear (spread {:.3} m across their line); they cannot fix the rotation about it",
            c.len(),
            s[1] / (c.len() as f64).sqrt()
        )));
    }
    Ok(())
}

fn n_unknowns(st: &Structure, res: &[ResidualBlock], n_points: usize) -> usize {
    let mut active = vec![false; n_points];
    for r in res.iter().filter(|r| r.active) {
        if let Some(p) = r.point {
            active[p] = true;
        }
    }
    st.n + 3 * active.iter().filter(|&&a| a).count()
}

/// Deactivates the remaining blocks of tie points left with fewer than two rays and
/// nothing else (they can no longer be intersected).
fn drop_orphans(res: &mut [ResidualBlock], n_points: usize) {
    let mut rays = vec![0usize; n_points];
    let mut other = vec![false; n_points];
    for r in res.iter().filter(|r| r.active) {
        if let Some(p) = r.point {
            match r.kind {
                Kind::Image { .. } => rays[p] += 1,
                _ => other[p] = true,
            }
        }
    }
    for r in res.iter_mut().filter(|r| r.active) {
        if let Some(p) = r.point {
            if rays[p] == 0 || (rays[p] < 2 && !other[p]) {
                r.active = false;
            }
        }
    }
}

/// Adjusts the block in place and reports the precision. `planes` are LiDAR
/// point-to-plane constraints of tie points; `refitter`, when given, re-fits them
/// between rounds. Rejected image observations are removed from the block (they are
/// listed in the report); check points are never changed.
pub fn adjust(
    block: &mut Block,
    planes: &[PlaneConstraint],
    mut refitter: Option<&mut dyn PlaneRefitter>,
    opts: &AdjustOptions,
) -> Result<AdjustReport, AdjustError> {
    let t0 = Instant::now();
    check_options(opts)?;
    let mut pb = build(block, planes)?;
    let n_points = pb.point_ids.len();
    let lm = LmOptions {
        max_iterations: opts.max_iterations,
        function_tolerance: opts.function_tolerance,
        parameter_tolerance: opts.parameter_tolerance,
    };
    let mut rejected: Vec<Rejected> = Vec::new();
    let mut iterations = 0;
    let mut converged;
    let mut refits = 0;
    let mut readmitted = false;
    let mut round = 0;
    loop {
        round += 1;
        let st = pb.structure();
        let out = solver::levenberg_marquardt(&st, &pb.res, &mut pb.state, opts.loss, &lm);
        iterations += out.iterations;
        converged = out.converged;
        tracing::info!(
            round,
            iterations = out.iterations,
            initial_cost = out.initial_cost,
            cost = out.final_cost,
            "adjustment round"
        );
        if round >= opts.max_rounds {
            break;
        }
        let mut changed = false;
        if let Some(rf) = refitter.as_deref_mut() {
            if refits < MAX_PLANE_REFITS {
                refits += 1;
                let pts: Vec<(PointId, Vector3<f64>)> = pb
                    .point_ids
                    .iter()
                    .zip(&pb.state.points)
                    .map(|(&id, x)| (id, *x))
                    .collect();
                let new_planes = rf.refit(&pts);
                let mut keep_res = Vec::new();
                let mut keep_refs = Vec::new();
                for (r, f) in pb.res.drain(..).zip(pb.refs.drain(..)) {
                    if !matches!(r.kind, Kind::Plane { .. }) {
                        keep_res.push(r);
                        keep_refs.push(f);
                    }
                }
                pb.res = keep_res;
                pb.refs = keep_refs;
                for pl in &new_planes {
                    pb.res.push(plane_block(pl, &pb.point_index)?);
                    pb.refs.push(ObservationRef::Plane { point: pl.point });
                }
                changed = true;
            }
        }
        // Re-fitted planes change the residual list: the structure must index the new one
        // before residuals are tested for rejection.
        let st = if changed { pb.structure() } else { st };
        let newly = robust::select_rejections(&st, &pb, opts, round, n_points);
        if !newly.is_empty() {
            for (i, rj) in newly {
                pb.res[i].active = false;
                rejected.push(rj);
            }
            drop_orphans(&mut pb.res, n_points);
            changed = true;
        } else if !readmitted && !rejected.is_empty() && !changed {
            // Observations rejected early, while larger gross errors still distorted the
            // solution, are tested again against the final one.
            readmitted = true;
            changed = robust::readmit(&mut pb, &mut rejected, opts);
        }
        if !changed {
            break;
        }
    }
    let st = pb.structure();
    let report = finish(
        block, &pb, &st, opts, rejected, iterations, round, converged, t0,
    )?;
    Ok(report)
}

#[allow(clippy::too_many_arguments)]
fn finish(
    block: &mut Block,
    pb: &Problem,
    st: &Structure,
    opts: &AdjustOptions,
    rejected: Vec<Rejected>,
    iterations: usize,
    rounds: usize,
    converged: bool,
    t0: Instant,
) -> Result<AdjustReport, AdjustError> {
    let n_points = pb.point_ids.len();
    let ev = solver::evaluate(&pb.res, &pb.state, opts.loss);
    let n_unk = n_unknowns(st, &pb.res, n_points);
    let (s0, n_obs, redundancy) = precision::sigma0(&pb.res, &ev, n_unk);
    let pts = solver::point_systems(st, &pb.res, &ev, 0.0);
    let std = precision::standardized(&pb.res, &ev, &pts, if s0.is_finite() { s0 } else { 1.0 });
    let rmse_px = precision::image_rmse(&pb.res, &ev);

    // Per-photo image RMS.
    let mut ph_sum = vec![(0.0, 0usize); pb.photo_ids.len()];
    let mut residuals = Vec::new();
    for (i, r) in pb.res.iter().enumerate() {
        let Some(e) = &ev.evals[i] else { continue };
        let scale: Vec<f64> = match &r.kind {
            Kind::Image { sigma, .. } => {
                let ph = r.photo.expect("image block has a photo");
                ph_sum[ph].0 += e.norm_sq() * sigma * sigma;
                ph_sum[ph].1 += 1;
                vec![*sigma; 2]
            }
            Kind::PointPrior { sigma, .. } | Kind::PosCenter { sigma, .. } => {
                sigma.iter().copied().collect()
            }
            Kind::PosAttitude { sigma, .. } => vec![*sigma; 3],
            Kind::Plane { sqrt_weight, .. } => vec![1.0 / sqrt_weight],
        };
        let (red, w) = std[i].unwrap_or((1.0, 0.0));
        residuals.push(ResidualReport {
            observation: pb.refs[i].clone(),
            residual: (0..e.dim).map(|k| e.r[k] * scale[k]).collect(),
            standardized: w,
            redundancy: red,
        });
    }

    // Precision from the undamped reduced camera system.
    let mut photo_precision = Vec::new();
    let mut calibration = Vec::new();
    let rows = solver::reduced_rows(st, &pb.res, &ev, &pts, 0.0);
    let mut cache = solver::SymbolicCache::default();
    let factor = solver::factorize(st, &rows, &mut cache);
    let var0 = if s0.is_finite() { s0 * s0 } else { 1.0 };
    let cof = factor.as_ref().map(|f| cofactors(st, f, opts.covariance));
    if factor.is_none() {
        tracing::warn!("the reduced camera system is singular at the solution: no precision");
    }
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
                format!(
                    "camera {} {}",
                    pb.camera_ids[ci],
                    pb.state.cameras[ci].param_names()[k]
                )
            }
        };
        for (ci, cb) in st.camera_block.iter().enumerate() {
            let Some(b) = cb else { continue };
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
                });
            }
        }
    }

    // Write back.
    for (i, &pid) in pb.photo_ids.iter().enumerate() {
        let ph = block.photos.get_mut(&pid).expect("photo");
        ph.pose = pb.state.poses[i];
        ph.status = crate::block::PhotoStatus::Oriented;
    }
    for (i, &cid) in pb.camera_ids.iter().enumerate() {
        block.cameras.get_mut(&cid).expect("camera").model = pb.state.cameras[i].clone();
    }
    let mut active_point = vec![false; n_points];
    for r in pb.res.iter().filter(|r| r.active) {
        if let Some(p) = r.point {
            active_point[p] = true;
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

    let check = check_points(block);
    let n_active_points = active_point.iter().filter(|&&a| a).count();
    Ok(AdjustReport {
        sigma0: s0,
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
        check,
        residuals,
    })
}

/// Intersects every check point with the adjusted orientations and compares.
pub(crate) fn check_points(block: &Block) -> Option<CheckSummary> {
    let mut pts = Vec::new();
    for pt in block.points.values().filter(|p| p.kind == PointKind::Check) {
        let rays: Vec<_> = pt
            .observations
            .iter()
            .filter_map(|o| {
                let ph = block.photos.get(&o.photo)?;
                let cam = &block.cameras.get(&ph.camera)?.model;
                Some((cam, &ph.pose, o.pixel, o.sigma_px))
            })
            .collect();
        let Some(x) = intersect(&rays) else {
            tracing::warn!(
                point = pt.id,
                "check point cannot be intersected (fewer than two usable rays)"
            );
            continue;
        };
        let e = x - pt.position;
        pts.push(CheckPointReport {
            point: pt.id,
            name: pt.name.clone(),
            error: [e.x, e.y, e.z],
            rays: rays.len(),
        });
    }
    if pts.is_empty() {
        return None;
    }
    let n = pts.len() as f64;
    let plan = (pts
        .iter()
        .map(|p| p.error[0].powi(2) + p.error[1].powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let height = (pts.iter().map(|p| p.error[2].powi(2)).sum::<f64>() / n).sqrt();
    let max = pts
        .iter()
        .map(|p| Vector3::from(p.error).norm())
        .fold(0.0, f64::max);
    Some(CheckSummary {
        count: pts.len(),
        rmse_plan_m: plan,
        rmse_height_m: height,
        max_m: max,
        points: pts,
    })
}
