//! Georeferencing a block onto ground control, with its blunders found as measurements
//! before the bundle adjustment sees them.
//!
//! A control point given with a wrong image measurement, or with wrong coordinates, must
//! not drag the solution: a strong prior absorbs its error into the image residuals of
//! good rays, and the adjustment then rejects the wrong thing (whole points, good
//! measurements). So the control is checked in the block's own shape first:
//! 1. the block is adjusted as a free network on its tie points (its shape, no datum);
//! 2. each control point is intersected from its rays robustly (RANSAC over ray pairs,
//!    a ray's residual in units of its σ): a ray that misses the consensus is a wrong
//!    measurement, removed as that measurement;
//! 3. the 7-parameter similarity from the model onto the control is estimated robustly
//!    (least median of squares for the scale of the misfits, then RANSAC at the test
//!    level): a point whose coordinates disagree with its consistent rays is rejected as
//!    a whole, and its rays stay as a tie point;
//! 4. points that could not take part (one ray, two rays that miss each other, unknown
//!    height) are checked ray by ray against their coordinates through the similarity.
//!
//! The block is then moved onto the control by the similarity, so the adjustment starts
//! at the solution.

use super::chi2;
use super::rays::{intersect_rays, intersect_robust, intersection_cofactor, Ray};
use super::{adjust, AdjustError, AdjustOptions, ObservationRef, Rejected};
use crate::block::{Block, Observation, PhotoId, PointId, PointKind};
use crate::estimators::similarity3::{PointPair, Similarity3Estimator};
use crate::estimators::{RobustMethod, RobustOptions};
use crate::geometry::{project, Similarity};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// A surveyed point as the adjustment takes it: the block point that carries its image
/// measurements, its coordinates in the block's local frame and their σ per axis (m; an
/// infinite σ_z is a 2-D control point). Check points are given with kind `Check`.
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyedInput {
    pub point: PointId,
    pub position: Vector3<f64>,
    pub sigma: [f64; 3],
    pub kind: PointKind,
}

#[derive(Debug, Clone)]
pub struct GeorefOptions {
    /// Test level of every decision (a good measurement or point is rejected with this
    /// probability).
    pub alpha: f64,
    /// Options of the free-network adjustment of the block's shape.
    pub adjust: AdjustOptions,
    pub seed: u64,
}

impl Default for GeorefOptions {
    fn default() -> Self {
        Self {
            alpha: 0.001,
            adjust: AdjustOptions {
                covariance: false,
                ..AdjustOptions::default()
            },
            seed: 1,
        }
    }
}

/// An image measurement of a control point removed as a blunder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedMeasurement {
    pub point: PointId,
    pub name: String,
    pub photo: PhotoId,
    pub photo_name: String,
    pub pixel: [f64; 2],
    /// Distance from where the consensus (or the control through the similarity) projects.
    pub residual_px: f64,
    pub reason: String,
}

/// A control point whose coordinates disagree with its consistent rays.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedControl {
    pub point: PointId,
    pub name: String,
    /// Surveyed minus intersected (through the similarity), m.
    pub misfit_m: [f64; 3],
    /// The misfit in units of its σ (√ of the χ²(3) statistic).
    pub normalized: f64,
    pub rays: usize,
    pub reason: String,
}

/// What the georeferencing found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Georeference {
    /// Model frame → block-local frame.
    pub similarity: Similarity,
    /// σ0 of the free-network adjustment of the block's shape.
    pub free_network_sigma0: f64,
    /// Control points that fixed the similarity.
    pub control_used: Vec<String>,
    /// Control points measured in one photo (they constrain that photo alone).
    pub single_ray: Vec<String>,
    /// Variance factor of the control misfits (≥ 1): the model's deformation or a
    /// too optimistic control σ widen the test by its square root.
    pub misfit_variance_factor: f64,
    pub rejected_measurements: Vec<RejectedMeasurement>,
    pub rejected_points: Vec<RejectedControl>,
    /// The image observations the free-network adjustment rejected as gross errors, for
    /// [`adjust_with_rejected`](super::adjust_with_rejected) to start without them
    /// (they are tested again on its final solution, and its report lists them).
    #[serde(skip)]
    pub free_network_rejected: Vec<Rejected>,
}

/// The rays of `observations` with the orientations of `frame`.
fn rays_of<'a>(
    frame: &'a Block,
    observations: &[Observation],
) -> Vec<(PhotoId, [f64; 2], Ray<'a>)> {
    observations
        .iter()
        .filter_map(|o| {
            let ph = frame.photos.get(&o.photo)?;
            let cam = frame.cameras.get(&ph.camera)?;
            Some((
                o.photo,
                o.pixel,
                Ray {
                    camera: &cam.model,
                    pose: ph.pose,
                    pixel: o.pixel,
                    sigma_px: o.sigma_px,
                },
            ))
        })
        .collect()
}

/// The block's shape as a free network of its tie points (control and check points
/// enter as tie points when they have two rays, without their coordinates; POS priors
/// are left out so that nothing but the images shapes the model).
fn free_network(
    block: &Block,
    opts: &AdjustOptions,
) -> Result<(Block, f64, Vec<Rejected>), AdjustError> {
    let mut shape = block.clone();
    for ph in shape.photos.values_mut() {
        ph.prior = None;
    }
    shape.points.retain(|_, p| p.kind != PointKind::Check);
    let ids: Vec<PointId> = shape.points.keys().copied().collect();
    for id in ids {
        let pt = &shape.points[&id];
        if pt.kind == PointKind::Tie {
            continue;
        }
        let x = {
            let rays = rays_of(&shape, &pt.observations);
            let refs: Vec<&Ray> = rays.iter().map(|r| &r.2).collect();
            intersect_rays(&refs)
        };
        match x {
            Some(x) => {
                let p = shape.points.get_mut(&id).expect("listed");
                p.position = x;
                p.kind = PointKind::Tie;
                p.sigma = None;
            }
            None => {
                shape.points.remove(&id);
            }
        }
    }
    let rep = adjust(&mut shape, &[], None, opts)?;
    let images = rep
        .rejected
        .list
        .into_iter()
        .filter(|r| matches!(r.observation, ObservationRef::Image { .. }))
        .collect();
    Ok((shape, rep.sigma0, images))
}

/// Finds the blunders of the control, moves the block onto the control and enters the
/// control and check points with their coordinates (see the module documentation).
/// Rejected measurements are removed from the block; a rejected control point stays as
/// a tie point. Errors when fewer than three control points with heights have two
/// consistent rays and coordinates that agree.
pub fn georeference(
    block: &mut Block,
    surveyed: &[SurveyedInput],
    opts: &GeorefOptions,
) -> Result<Georeference, AdjustError> {
    if !(opts.alpha > 0.0 && opts.alpha < 0.5) {
        return Err(AdjustError::InvalidOption {
            name: "alpha".into(),
            message: format!("test level {} must be in (0, 0.5)", opts.alpha),
        });
    }
    for s in surveyed {
        if !block.points.contains_key(&s.point) {
            return Err(AdjustError::UnknownId {
                what: "surveyed point".into(),
                id: s.point.to_string(),
            });
        }
        if !s.position.iter().all(|v| v.is_finite()) {
            return Err(AdjustError::NotFinite {
                what: format!("coordinates of point {}", block.points[&s.point].name),
            });
        }
    }
    let (shape, sigma0, free_network_rejected) = free_network(block, &opts.adjust)?;
    // Rays are tested on w = √(χ²(2)), the normalised length of the 2-D residual.
    let ray_critical = chi2::critical(2, opts.alpha).sqrt();
    let name = |p: PointId| block.points[&p].name.clone();
    let photo_name = |ph: PhotoId| block.photos[&ph].name.clone();
    let mut rejected_measurements = Vec::new();
    let mut pairs: Vec<(PointId, PointPair, usize)> = Vec::new();
    // Points decided ray by ray against the similarity.
    let mut by_ray: Vec<PointId> = Vec::new();
    let mut single_ray = Vec::new();
    let control: Vec<&SurveyedInput> = surveyed
        .iter()
        .filter(|s| s.kind == PointKind::Control)
        .collect();
    for s in &control {
        let rays = rays_of(&shape, &block.points[&s.point].observations);
        if rays.len() == 1 {
            single_ray.push(name(s.point));
        }
        let plain: Vec<Ray> = rays.iter().map(|r| r.2).collect();
        let Some(ri) = intersect_robust(&plain, ray_critical, opts.seed ^ s.point) else {
            by_ray.push(s.point);
            continue;
        };
        for (k, (photo, pixel, _)) in rays.iter().enumerate() {
            if !ri.inliers[k] {
                rejected_measurements.push(RejectedMeasurement {
                    point: s.point,
                    name: name(s.point),
                    photo: *photo,
                    photo_name: photo_name(*photo),
                    pixel: *pixel,
                    residual_px: ri.residuals_px[k],
                    reason: format!(
                        "misses the intersection of the point's other {} ray(s) by {:.1} px",
                        ri.inliers.iter().filter(|b| **b).count(),
                        ri.residuals_px[k]
                    ),
                });
            }
        }
        if !s.sigma[2].is_finite() {
            by_ray.push(s.point);
            continue;
        }
        let good: Vec<&Ray> = plain
            .iter()
            .zip(&ri.inliers)
            .filter(|(_, b)| **b)
            .map(|(r, _)| r)
            .collect();
        let q = intersection_cofactor(&good, &ri.position).unwrap_or_else(nalgebra::Matrix3::zeros);
        // The model σ is scaled into control units once the scale is known (below).
        let model_sigma = Vector3::new(q[(0, 0)], q[(1, 1)], q[(2, 2)]).map(|v| v.max(0.0).sqrt());
        pairs.push((
            s.point,
            PointPair {
                model: ri.position,
                control: s.position,
                sigma: model_sigma,
            },
            good.len(),
        ));
    }
    if pairs.len() < 3 {
        return Err(AdjustError::TooFewObservations(format!(
            "{} control point(s) with a height are intersected from two consistent rays; \
             georeferencing the block needs at least 3",
            pairs.len()
        )));
    }
    // LMedS first: it needs no threshold and gives the scale that brings the model's
    // intersection σ into control units.
    let sigma_of = |pair: &PointPair, s: &SurveyedInput, scale: f64| PointPair {
        sigma: Vector3::from_fn(|k, _| {
            (s.sigma[k].powi(2) + (scale * pair.sigma[k]).powi(2))
                .sqrt()
                .max(1e-9)
        }),
        ..*pair
    };
    let find = |p: PointId| *control.iter().find(|s| s.point == p).expect("control");
    let unit: Vec<PointPair> = pairs
        .iter()
        .map(|(p, pair, _)| sigma_of(pair, find(*p), 0.0))
        .collect();
    let robust = RobustOptions {
        seed: opts.seed,
        ..RobustOptions::default()
    };
    let lmeds = RobustMethod::Lmeds
        .estimate(&Similarity3Estimator, &unit, &robust)
        .map_err(|e| AdjustError::Degenerate(format!("similarity onto the control: {e}")))?;
    let scale = lmeds.model.scale;
    let scaled: Vec<PointPair> = pairs
        .iter()
        .map(|(p, pair, _)| sigma_of(pair, find(*p), scale))
        .collect();
    // The model's deformation (a free network bends) and a too optimistic control σ
    // show as misfits larger than σ for every point: the median misfit of the LMedS
    // solution estimates that factor (median of χ²(3) = 2.366), and the test widens by
    // it, never narrows.
    let mut med: Vec<f64> = scaled
        .iter()
        .map(|p| p.normalized_sq(&lmeds.model))
        .collect();
    med.sort_by(f64::total_cmp);
    let factor = (med[med.len() / 2] / 2.366).max(1.0);
    let point_critical = (chi2::critical(3, opts.alpha) * factor).sqrt();
    let ransac = RobustMethod::Ransac
        .estimate(
            &Similarity3Estimator,
            &scaled,
            &RobustOptions {
                threshold: point_critical,
                min_iterations: 200,
                ..robust
            },
        )
        .map_err(|e| AdjustError::Degenerate(format!("similarity onto the control: {e}")))?;
    if ransac.num_inliers < 3 {
        return Err(AdjustError::TooFewObservations(format!(
            "only {} control point(s) agree with each other; the similarity onto the control needs 3",
            ransac.num_inliers
        )));
    }
    let sim = ransac.model;
    let mut rejected_points = Vec::new();
    let mut control_used = Vec::new();
    for (k, (p, pair, rays)) in pairs.iter().enumerate() {
        if ransac.inliers[k] {
            control_used.push(name(*p));
            continue;
        }
        let d = pair.control - sim.apply(&pair.model);
        let w = scaled[k].normalized_sq(&sim).sqrt();
        rejected_points.push(RejectedControl {
            point: *p,
            name: name(*p),
            misfit_m: [d.x, d.y, d.z],
            normalized: w,
            rays: *rays,
            reason: format!(
                "coordinates {:.2} m ({w:.1} σ) from the intersection of its {rays} consistent rays",
                d.norm()
            ),
        });
    }
    // Points without a consensus of their own: each ray against the coordinates.
    let inv = sim.inverse();
    for p in by_ray {
        let s = find(p);
        if !s.sigma[2].is_finite() {
            // A 2-D point cannot be projected without a height; the adjustment tests it.
            continue;
        }
        let x = inv.apply(&s.position);
        for (photo, pixel, ray) in rays_of(&shape, &block.points[&p].observations) {
            let r = ray.residual_px(&x);
            let sigma_ctrl_px = project(ray.camera, &ray.pose, &x)
                .map(|q| ray.camera.focal_px() * s.sigma[0] / (sim.scale * q.depth))
                .unwrap_or(0.0);
            let tol = ray_critical
                * factor.sqrt()
                * (ray.sigma_px.powi(2) + sigma_ctrl_px.powi(2)).sqrt();
            if r > tol {
                rejected_measurements.push(RejectedMeasurement {
                    point: p,
                    name: name(p),
                    photo,
                    photo_name: photo_name(photo),
                    pixel,
                    residual_px: r,
                    reason: format!(
                        "misses where the control point projects through the similarity by {r:.1} px (limit {tol:.1} px)"
                    ),
                });
            }
        }
    }
    apply(
        block,
        &shape,
        &sim,
        surveyed,
        &rejected_measurements,
        &rejected_points,
    );
    Ok(Georeference {
        similarity: sim,
        free_network_sigma0: sigma0,
        control_used,
        single_ray,
        misfit_variance_factor: factor,
        rejected_measurements,
        rejected_points,
        free_network_rejected,
    })
}

/// Moves the block onto the control and enters the surveyed points.
fn apply(
    block: &mut Block,
    shape: &Block,
    sim: &Similarity,
    surveyed: &[SurveyedInput],
    measurements: &[RejectedMeasurement],
    points: &[RejectedControl],
) {
    for (id, ph) in block.photos.iter_mut() {
        ph.pose = sim.apply_pose(&shape.photos[id].pose);
    }
    for (id, cam) in block.cameras.iter_mut() {
        cam.model = shape.cameras[id].model.clone();
    }
    for (id, pt) in block.points.iter_mut() {
        pt.position = match shape.points.get(id) {
            Some(q) => sim.apply(&q.position),
            None => sim.apply(&pt.position),
        };
    }
    for m in measurements {
        if let Some(pt) = block.points.get_mut(&m.point) {
            pt.observations.retain(|o| o.photo != m.photo);
        }
    }
    for s in surveyed {
        let pt = block.points.get_mut(&s.point).expect("checked");
        if points.iter().any(|r| r.point == s.point) {
            pt.kind = PointKind::Tie;
            pt.sigma = None;
            continue;
        }
        pt.kind = s.kind;
        pt.position = s.position;
        pt.sigma = (s.kind == PointKind::Control).then_some(s.sigma);
    }
}
