//! Problem assembly from a [`Block`] and the solve–reject rounds.

use super::residual::{Kind, ResidualBlock, State};
use super::robust::RejectionTest;
use super::solver::{self, LmOptions, Structure};
use super::{
    AdjustError, AdjustOptions, AdjustReport, Loss, ObservationRef, PlaneConstraint, PlaneRefitter,
    Rejected, Rejection,
};
use crate::block::{Block, BlockCamera, PhotoId, PointId, PointKind};
use nalgebra::{Vector2, Vector3};
use std::collections::BTreeMap;
use std::time::Instant;

/// Largest number of times the LiDAR planes are re-fitted.
const MAX_PLANE_REFITS: usize = 3;

/// Largest number of final sweeps (reject every exceedance, re-solve) after the rounds.
const MAX_SWEEPS: usize = 3;

/// A robust round (its loss not the final one) ends once a step moves the orientations by
/// less than this in squared units of their own precision (δᵀSδ, S the reduced camera
/// system): every function of them, a ray's predicted image point among them, then
/// moves by under 1 % of its σ. Its solution only feeds the rejection test, which
/// re-intersects each point by least squares with the orientations held, and the final
/// round, which starts from it. What such a round does after that is the IRLS crawl of
/// the points whose rays the loss weighs linearly (a blunder's point of two rays sits in
/// a valley of constant cost, every split of the discrepancy between its rays costing
/// the same): 0.2–0.7 of cost an iteration against a relative tolerance of 10⁻⁶ at 10⁵,
/// so a round ran to its 50 iterations with δᵀSδ below 10⁻⁵ from the 25th on (the
/// 200-photo control bench's free network).
const ROBUST_ROUND_TOLERANCE: f64 = 1e-4;

pub(super) struct Problem {
    pub(super) photo_ids: Vec<PhotoId>,
    pub(super) camera_ids: Vec<u32>,
    pub(super) point_ids: Vec<PointId>,
    pub(super) point_index: BTreeMap<PointId, usize>,
    pub(super) res: Vec<ResidualBlock>,
    pub(super) refs: Vec<ObservationRef>,
    pub(super) photo_free: Vec<[bool; 6]>,
    pub(super) camera_free: Vec<Vec<usize>>,
    /// Camera index → the first camera of its calibration group (itself when it has none):
    /// the cameras of a group share one set of free interior parameters.
    pub(super) camera_leader: Vec<usize>,
    pub(super) state: State,
    pub(super) datum: String,
    /// The camera slot (after the cameras) holding the LiDAR datum shift, when the
    /// adjustment estimates it (its prior is the slot's `Kind::LidarDatum` residual).
    pub(super) lidar_datum: Option<usize>,
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
            &self.camera_leader,
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
        Rejection::Threshold(k) if !(k.is_finite() && k >= 1.0) => {
            return bad(
                "rejection",
                format!("k must be a finite number ≥ 1 (2–3 is usual), got {k}"),
            )
        }
        Rejection::DataSnooping(k) if !(k.is_finite() && k >= 1.0) => {
            return bad(
                "rejection",
                format!(
                    "data snooping: the one-dimensional critical value k must be finite and ≥ 1 (3.29 for α0 = 0.1 %; α0 between 0 and 0.32), got {k}"
                ),
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
    lidar_datum: Option<usize>,
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
    Ok(ResidualBlock::new(
        Kind::Plane {
            normal: n / norm,
            d: pl.d / norm,
            sqrt_weight: pl.weight.sqrt(),
        },
        None,
        lidar_datum,
        Some(p),
    ))
}

fn build(
    block: &Block,
    planes: &[PlaneConstraint],
    lidar_datum_sigma: Option<[f64; 3]>,
) -> Result<Problem, AdjustError> {
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
    let cameras: Vec<&BlockCamera> = block.cameras.values().collect();
    let mut camera_leader: Vec<usize> = cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            c.calibration_group.as_ref().map_or(i, |g| {
                cameras
                    .iter()
                    .position(|o| o.calibration_group.as_ref() == Some(g))
                    .unwrap_or(i)
            })
        })
        .collect();
    for (i, &l) in camera_leader.iter().enumerate() {
        let (c, lc) = (cameras[i], cameras[l]);
        if c.model.param_names() != lc.model.param_names() || camera_free[i] != camera_free[l] {
            return Err(AdjustError::InvalidBlock(format!(
                "camera {} is in calibration group {:?} with camera {} but differs in kind or free parameters ({:?} against {:?})",
                c.id,
                c.calibration_group.as_deref().unwrap_or(""),
                lc.id,
                c.free_params,
                lc.free_params
            )));
        }
    }
    // Reserved for every observation and prior: grown by doubling, the blocks' vector
    // held up to twice what it used.
    let upper = block
        .points
        .values()
        .filter(|p| p.kind != PointKind::Check)
        .map(|p| p.observations.len() + usize::from(p.kind == PointKind::Control))
        .sum::<usize>()
        + planes.len()
        + 1
        + 2 * block.photos.len();
    let mut res = Vec::with_capacity(upper);
    let mut refs = Vec::with_capacity(upper);
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
            // σ = +∞ on an axis: no prior there (a GCP of unknown height).
            if !s.iter().all(|v| *v > 0.0 && !v.is_nan()) {
                return Err(AdjustError::InvalidBlock(format!(
                    "control point {} ({}): σ {:?} must be positive (finite, or +∞ for an unknown axis)",
                    pt.id, pt.name, s
                )));
            }
            if s.iter().all(|v| v.is_infinite()) {
                return Err(AdjustError::InvalidBlock(format!(
                    "control point {} ({}): σ is infinite on every axis, no coordinate is known (make it a tie point)",
                    pt.id, pt.name
                )));
            }
            Some(Vector3::from(s))
        } else {
            None
        };
        // A tie point needs two rays (or one ray and a plane) to be intersected; a control
        // point one ray when its whole position is known, else two (one ray meets a
        // vertical line at a glancing angle in a near-nadir photo).
        let enough = match prior {
            Some(s) if s.iter().all(|v| v.is_finite()) => n_obs >= 1,
            Some(_) => n_obs >= 2,
            None => n_obs >= 2 || (n_obs >= 1 && planned.contains(&pt.id)),
        };
        if !enough {
            if prior.is_some() {
                tracing::warn!(
                    point = pt.id,
                    name = %pt.name,
                    rays = n_obs,
                    "control point left out: too few image observations for its unknown axes"
                );
            }
            continue;
        }
        let p = points.len();
        points.push(pt.position);
        point_ids.push(pt.id);
        for o in &pt.observations {
            let ph = photo_index[&o.photo];
            res.push(ResidualBlock::new(
                Kind::Image {
                    pixel: Vector2::new(o.pixel[0], o.pixel[1]),
                    sigma: o.sigma_px,
                },
                Some(ph),
                Some(camera_index[&block.photos[&o.photo].camera]),
                Some(p),
            ));
            refs.push(ObservationRef::Image {
                point: pt.id,
                photo: o.photo,
            });
        }
        if let Some(sigma) = prior {
            control_positions.push((pt.position, [0, 1, 2].map(|k| sigma[k].is_finite())));
            res.push(ResidualBlock::new(
                Kind::PointPrior {
                    value: pt.position,
                    sigma,
                },
                None,
                None,
                Some(p),
            ));
            refs.push(ObservationRef::ControlPrior { point: pt.id });
        }
    }
    let point_index: BTreeMap<PointId, usize> =
        point_ids.iter().enumerate().map(|(i, &p)| (p, i)).collect();
    // The LiDAR datum shift is the camera slot after the cameras; it exists only with
    // planes to shift.
    let lidar_datum = match lidar_datum_sigma.filter(|_| !planes.is_empty()) {
        Some(s) if s.iter().all(|v| v.is_finite() && *v > 0.0) => {
            Some((camera_ids.len(), Vector3::from(s)))
        }
        Some(s) => {
            return Err(AdjustError::InvalidOption {
                name: "lidar_datum_sigma_m".into(),
                message: format!("σ {s:?} must be finite and positive on every axis"),
            })
        }
        None => None,
    };
    for pl in planes {
        res.push(plane_block(
            pl,
            &point_index,
            lidar_datum.map(|(slot, _)| slot),
        )?);
        refs.push(ObservationRef::Plane { point: pl.point });
    }
    if let Some((slot, sigma)) = lidar_datum {
        res.push(ResidualBlock::new(
            Kind::LidarDatum { sigma },
            None,
            Some(slot),
            None,
        ));
        refs.push(ObservationRef::LidarDatum);
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
        res.push(ResidualBlock::new(
            Kind::PosCenter {
                value: prior.center,
                sigma: s,
            },
            Some(i),
            None,
            None,
        ));
        refs.push(ObservationRef::PosCenter { photo: ph.id });
        if let Some(r) = prior.rotation {
            if !(prior.rotation_sigma_rad.is_finite() && prior.rotation_sigma_rad > 0.0) {
                return Err(AdjustError::InvalidBlock(format!(
                    "POS prior of photo {} ({}): attitude σ must be positive",
                    ph.id, ph.name
                )));
            }
            res.push(ResidualBlock::new(
                Kind::PosAttitude {
                    rotation: Box::new(r),
                    sigma: prior.rotation_sigma_rad,
                },
                Some(i),
                None,
                None,
            ));
            refs.push(ObservationRef::PosAttitude { photo: ph.id });
        }
    }
    // Every photo must see enough adjusted points to be resected within the block.
    let mut per_photo = vec![0usize; photo_ids.len()];
    for r in &res {
        if let (Kind::Image { .. }, Some(ph)) = (&r.kind, r.photo()) {
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
    let plan = control_positions.iter().any(|(_, k)| k[0] && k[1]);
    let height = control_positions.iter().any(|(_, k)| k[2]);
    if !control_positions.is_empty() {
        datum.push(match (plan, height) {
            (true, true) => "control",
            (true, false) => "control_plan",
            _ => "control_height",
        });
    }
    if n_pos > 0 {
        datum.push("pos");
    }
    if !planes.is_empty() {
        datum.push("lidar_planes");
    }
    if datum.len() == 1 && !control_positions.is_empty() {
        super::datum::check_control_geometry(&control_positions)?;
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
        lidar_shift: Vector3::zeros(),
    };
    // One value per group: a member's free parameters start at its group's first camera's.
    let mut state = state;
    for (i, &l) in camera_leader.iter().enumerate() {
        if l == i {
            continue;
        }
        let lead = state.cameras[l].params();
        let mut p = state.cameras[i].params();
        for &k in &camera_free[i] {
            p[k] = lead[k];
        }
        state.cameras[i]
            .set_params(&p)
            .map_err(|e| AdjustError::InvalidBlock(format!("camera {}: {e}", cameras[i].id)))?;
    }
    if let Some((slot, _)) = lidar_datum {
        camera_free.push(vec![0, 1, 2]);
        camera_leader.push(slot);
    }
    Ok(Problem {
        lidar_datum: lidar_datum.map(|(slot, _)| slot),
        photo_ids,
        camera_ids,
        point_ids,
        point_index,
        res,
        refs,
        photo_free,
        camera_free,
        camera_leader,
        state,
        datum: datum.join("+"),
    })
}

pub(super) fn n_unknowns(st: &Structure, res: &[ResidualBlock], n_points: usize) -> usize {
    let mut active = vec![false; n_points];
    for r in res.iter().filter(|r| r.active) {
        if let Some(p) = r.point() {
            active[p] = true;
        }
    }
    st.n + 3 * active.iter().filter(|&&a| a).count()
}

/// Deactivates the remaining blocks of points left with fewer than two rays and no
/// full position of their own (a 3-D control prior, or a plane with its one ray): they can
/// no longer be intersected.
fn drop_orphans(res: &mut [ResidualBlock], n_points: usize) {
    let mut rays = vec![0usize; n_points];
    let mut other = vec![false; n_points];
    for r in res.iter().filter(|r| r.active) {
        if let Some(p) = r.point() {
            match r.kind {
                Kind::Image { .. } => rays[p] += 1,
                Kind::PointPrior { .. } if r.kind.dof() < 3 => {}
                _ => other[p] = true,
            }
        }
    }
    for r in res.iter_mut().filter(|r| r.active) {
        if let Some(p) = r.point() {
            if rays[p] == 0 || (rays[p] < 2 && !other[p]) {
                r.active = false;
            }
        }
    }
}

/// Adjusts the block in place and reports the precision. `planes` are LiDAR
/// point-to-plane constraints of tie points; `refitter`, when given, re-fits them
/// between rounds. Rejected image observations are removed from the block (they are
/// listed in the report), and so are tie points left with fewer than two image
/// observations (counted in the report); control points keep even a single ray; check
/// points are never changed. A control point's σ may be +∞ on an axis it does not know
/// (a GCP of unknown height); such a point needs two rays.
pub fn adjust(
    block: &mut Block,
    planes: &[PlaneConstraint],
    refitter: Option<&mut dyn PlaneRefitter>,
    opts: &AdjustOptions,
) -> Result<AdjustReport, AdjustError> {
    adjust_with_rejected(block, planes, refitter, opts, &[])
}

/// [`adjust`] starting with the tie points' image observations an earlier adjustment of
/// the same block's images rejected (the georeferencing's free network,
/// [`Georeference::free_network_rejected`](super::georef::Georeference)) left out: the
/// first round then starts where those rounds ended instead of finding every gross error
/// again through the robust loss, whose IRLS tail they drag out. They count as rejected in round 0 and are tested again on the final solution like the
/// rounds' own rejections (re-admission), so none is lost for having been judged on the
/// block's shape without its control. Observations no longer in the block (a control
/// measurement the georeferencing removed) are passed over.
pub fn adjust_with_rejected(
    block: &mut Block,
    planes: &[PlaneConstraint],
    mut refitter: Option<&mut dyn PlaneRefitter>,
    opts: &AdjustOptions,
    earlier: &[Rejected],
) -> Result<AdjustReport, AdjustError> {
    let t0 = Instant::now();
    check_options(opts)?;
    let mut pb = build(block, planes, opts.lidar_datum_sigma_m)?;
    let n_points = pb.point_ids.len();
    let mut rejected = start_rejected(&mut pb, earlier);
    let lm = LmOptions {
        max_iterations: opts.max_iterations,
        function_tolerance: opts.function_tolerance,
        parameter_tolerance: opts.parameter_tolerance,
        camera_tolerance: 0.0,
    };
    let robust_lm = LmOptions {
        camera_tolerance: ROBUST_ROUND_TOLERANCE,
        ..lm.clone()
    };
    let mut test = RejectionTest::new(opts.rejection);
    // Data snooping is a least-squares test: the robust loss brings the first rounds
    // through the gross errors, the final solution of the observations kept is least
    // squares (they are taken as clean) and passes the test once more.
    let final_loss = match opts.rejection {
        Rejection::DataSnooping(_) => Loss::None,
        _ => opts.loss,
    };
    let mut loss = opts.loss;
    let mut iterations = 0;
    let mut converged;
    let mut refits = 0;
    let mut readmitted = false;
    let mut round = 0;
    let mut exhausted = false;
    loop {
        round += 1;
        let st = pb.structure();
        let round_lm = if loss == final_loss { &lm } else { &robust_lm };
        let out = solver::levenberg_marquardt(&st, &pb.res, &mut pb.state, loss, round_lm);
        iterations += out.iterations;
        converged = out.converged;
        tracing::info!(
            round,
            iterations = out.iterations,
            initial_cost = out.initial_cost,
            cost = out.final_cost,
            "adjustment round"
        );
        // A re-weighted control group is solved again before anything is tested.
        if round == 1 && test.calibrate(&st, &mut pb) {
            continue;
        }
        if round >= opts.max_rounds {
            exhausted = true;
            break;
        }
        let mut changed = false;
        if let Some(rf) = refitter.as_deref_mut() {
            if refits < MAX_PLANE_REFITS {
                refits += 1;
                refit_planes(&mut pb, rf)?;
                test.forget();
                changed = true;
            }
        }
        // Re-fitted planes change the residual list: the structure must index the new one
        // before residuals are tested for rejection.
        let st = if changed { pb.structure() } else { st };
        let newly = test.select(&st, &pb, loss, round, false);
        tracing::debug!(round, newly = newly.len(), "rejection test");
        if !newly.is_empty() {
            for (i, rj) in newly {
                tracing::trace!(round, observation = ?rj.observation, reason = %rj.reason, "rejected");
                pb.res[i].active = false;
                rejected.push(rj);
            }
            drop_orphans(&mut pb.res, n_points);
            changed = true;
            // After the re-admission every observation has been tested against a robust
            // solution of the kept ones: what this round rejects is the last of it (on a
            // clean 200-photo block at σ = 0.5 px, the one re-admitted observation again,
            // w² 13.92 against 13.82), and the final loss solves without it. One robust
            // round fewer (five rounds were four); the final round tests again. Kite block
            // and the small bench's 30 epochs: the same results.
            if readmitted {
                loss = final_loss;
            }
        } else if !readmitted && !rejected.is_empty() && !changed {
            // Observations rejected early, while larger gross errors still distorted the
            // solution, are tested again against the final one.
            readmitted = true;
            let before = rejected.len();
            changed = test.readmit(&mut pb, &mut rejected, loss);
            tracing::debug!(round, readmitted = before - rejected.len(), "re-admission");
        }
        if !changed && loss != final_loss {
            // Where the robust loss weighs every residual fully, its solution is a
            // stationary point of least squares too: a clean block needs no round more
            // (at 200 photos that round cost 0.11 s of a 1.5 s adjustment).
            changed = !out.fully_weighted;
            loss = final_loss;
        }
        if !changed {
            break;
        }
    }
    // The rounds ran out with exceedances left: reject them all at once and solve again,
    // so that no observation of the output model fails the test (bounded: a sweep's
    // re-solve rarely pushes another over).
    if exhausted {
        for _ in 0..MAX_SWEEPS {
            let st = pb.structure();
            let newly = test.select(&st, &pb, loss, round, true);
            if newly.is_empty() && loss == final_loss {
                break;
            }
            test.swept += newly.len();
            for (i, rj) in newly {
                pb.res[i].active = false;
                rejected.push(rj);
            }
            drop_orphans(&mut pb.res, n_points);
            loss = final_loss;
            let st = pb.structure();
            let out = solver::levenberg_marquardt(&st, &pb.res, &mut pb.state, loss, &lm);
            iterations += out.iterations;
            converged = out.converged;
        }
        let st = pb.structure();
        let left = test.select(&st, &pb, loss, round, true).len();
        if left > 0 {
            tracing::warn!(
                left,
                "observations still fail the rejection test after the final sweeps"
            );
        }
    }
    let st = pb.structure();
    let report = super::report::finish(
        block, &pb, &st, opts, loss, &test, rejected, iterations, round, converged, t0,
    )?;
    Ok(report)
}

/// Deactivates the image observations of tie points in `earlier` found in the problem and
/// lists them as rejected in round 0 (see [`adjust_with_rejected`]).
fn start_rejected(pb: &mut Problem, earlier: &[Rejected]) -> Vec<Rejected> {
    let index: BTreeMap<(PointId, PhotoId), usize> = pb
        .refs
        .iter()
        .enumerate()
        .filter_map(|(i, r)| match *r {
            ObservationRef::Image { point, photo } => Some(((point, photo), i)),
            _ => None,
        })
        .collect();
    // A control point's rays were judged there as a tie point's, without the prior that
    // tells them apart (two rays went with their point): the rounds test them here.
    let held: std::collections::BTreeSet<usize> = pb
        .res
        .iter()
        .filter(|r| matches!(r.kind, Kind::PointPrior { .. }))
        .filter_map(|r| r.point())
        .collect();
    let mut out = Vec::new();
    for rj in earlier {
        let ObservationRef::Image { point, photo } = rj.observation else {
            continue;
        };
        let Some(&i) = index.get(&(point, photo)) else {
            continue;
        };
        if !pb.res[i].active || pb.res[i].point().is_some_and(|p| held.contains(&p)) {
            continue;
        }
        pb.res[i].active = false;
        out.push(Rejected {
            round: 0,
            reason: format!("free network: {}", rj.reason),
            ..rj.clone()
        });
    }
    if !out.is_empty() {
        drop_orphans(&mut pb.res, pb.point_ids.len());
    }
    out
}

/// Replaces the LiDAR plane constraints by the refitter's planes at the current points.
fn refit_planes(pb: &mut Problem, rf: &mut dyn PlaneRefitter) -> Result<(), AdjustError> {
    let pts: Vec<(PointId, Vector3<f64>)> = pb
        .point_ids
        .iter()
        .zip(&pb.state.points)
        .map(|(&id, x)| (id, *x))
        .collect();
    let new_planes = rf.refit(&pts);
    // In place: copies of the blocks and their references were a second 88 bytes an
    // observation.
    let plane = |r: &ResidualBlock| matches!(r.kind, Kind::Plane { .. });
    let mut kept = pb
        .res
        .iter()
        .map(|r| !plane(r))
        .collect::<Vec<_>>()
        .into_iter();
    pb.refs.retain(|_| kept.next().unwrap_or(true));
    pb.res.retain(|r| !plane(r));
    for pl in &new_planes {
        pb.res
            .push(plane_block(pl, &pb.point_index, pb.lidar_datum)?);
        pb.refs.push(ObservationRef::Plane { point: pl.point });
    }
    Ok(())
}
