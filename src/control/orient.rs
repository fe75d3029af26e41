//! Iterative orientation of one archive photo from control patches (seed 001 §2 (5)):
//! predict the DCP points in the photo from its approximate orientation, match the aligned
//! patches inside search windows sized by the orientation's uncertainty, resect the photo
//! once three or more patches match (with gross-error detection), and predict again with
//! the refined orientation and its smaller covariance — until no new patch matches.
//!
//! Matching and resection are supplied by the caller (matching and adjust modules), so
//! this loop is the strategy only, and is tested with exact stand-ins.

use super::predict::{self, Prediction};
use crate::estimators::similarity2::Similarity2;
use crate::geometry::{Camera, Pose};
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// A control point offered to the photo: object coordinates (block-local) with covariance,
/// and an identifier the matcher understands (which chip, which package).
#[derive(Debug, Clone)]
pub struct ControlPatch {
    pub id: usize,
    pub position: Vector3<f64>,
    pub covariance: Matrix3<f64>,
}

/// An accepted patch match in the photo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchMatch {
    pub pixel: Vector2<f64>,
    /// Standard deviation of the matched position (px), e.g. LSM's a-posteriori σ.
    pub sigma_px: f64,
    pub ncc: f64,
}

/// Finds a control patch in the photo: returns the match inside the search window centred
/// on `prediction.pixel` with half sizes `half_size`, or `None` (no match / rejected).
pub trait PatchMatcher {
    fn find(
        &mut self,
        patch: &ControlPatch,
        pose: &Pose,
        prediction: &Prediction,
        half_size: [f64; 2],
    ) -> Option<PatchMatch>;
}

/// Result of a single-photo resection.
#[derive(Debug, Clone)]
pub struct Resection {
    pub pose: Pose,
    /// 6×6 covariance in the local parameterisation (rotation vector, centre).
    pub covariance: SMatrix<f64, 6, 6>,
    /// Per observation: kept (true) or rejected as a gross error.
    pub inliers: Vec<bool>,
}

/// Single-photo resection with gross-error detection from object points and pixels.
pub trait Resector {
    fn resect(
        &mut self,
        camera: &Camera,
        approximate: &Pose,
        observations: &[(Vector3<f64>, Vector2<f64>, f64)],
    ) -> Result<Resection, String>;
}

#[derive(Debug, Clone)]
pub struct OrientOptions {
    /// Search window half size in σ of the predicted position.
    pub k_sigma: f64,
    /// Smallest and largest window half size (px); a window is also never wider than
    /// half the photo's shorter side (beyond that the prediction itself is meaningless).
    pub min_half_px: f64,
    pub max_half_px: f64,
    pub max_iterations: usize,
    /// Patches needed for a resection.
    pub min_matches: usize,
    /// Until the first resection, the patches are searched in an order spread over the
    /// photo, and the round ends once this many have matched (None: every patch). The
    /// first pose only has to shrink the windows from hundreds of pixels to a few, where
    /// every patch is searched again; a consensus, not precision, is what it needs. The
    /// large preset's film frames predict up to 15,839 patches each in windows of
    /// 700–900 px, and those first rounds were most of the epoch's 28 min.
    pub first_round_matches: Option<usize>,
}

impl Default for OrientOptions {
    fn default() -> Self {
        Self {
            k_sigma: 3.0,
            min_half_px: 4.0,
            max_half_px: 600.0,
            max_iterations: 6,
            min_matches: 3,
            // At the lowest share of right matches measured in a first round (16 %, a
            // medium digital photo over changed ground), 200 matches still hold about 30
            // inliers, five times the six a resection needs.
            first_round_matches: Some(200),
        }
    }
}

/// What happened in one round of prediction and matching.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct IterationRecord {
    pub iteration: usize,
    pub predicted: usize,
    /// Patches searched: all the predicted ones, or those searched before the first
    /// round's quota of matches was reached.
    #[serde(default)]
    pub searched: usize,
    pub matched: usize,
    pub success_ratio: f64,
    pub mean_window_px: f64,
    pub resected: bool,
    /// Matches rejected as gross errors by this round's resection.
    pub rejected: usize,
    /// Matches kept by the resection.
    pub accepted: usize,
}

#[derive(Debug, Clone)]
pub struct Oriented {
    pub pose: Pose,
    pub covariance: SMatrix<f64, 6, 6>,
    /// Accepted matches (patch id, pixel, σ) used by the final resection.
    pub matches: Vec<(usize, Vector2<f64>, f64)>,
    pub iterations: Vec<IterationRecord>,
    pub oriented: bool,
    /// The first round's matches before any resection: (predicted pixel, matched pixel).
    pub first_round: Vec<(Vector2<f64>, Vector2<f64>)>,
    /// A resected pose that a later round refuted: (round, why its resection failed).
    pub refuted: Option<(usize, String)>,
}

/// An image-space alignment of the predictions found beforehand (a 2-D similarity from
/// the predicted to the matched positions of a consistent set of patches): until the
/// first resection, every prediction is mapped through it and searched `half_px` around.
#[derive(Debug, Clone, Copy)]
pub struct Guide {
    pub map: Similarity2,
    pub half_px: f64,
}

/// Orients one photo. Patches outside the image are skipped; a patch rejected by the
/// resection is not offered again. With a `guide`, the predictions of the rounds before
/// the first resection are mapped through it.
#[allow(clippy::too_many_arguments)]
pub fn orient_photo(
    camera: &Camera,
    approximate: &Pose,
    covariance: &SMatrix<f64, 6, 6>,
    patches: &[ControlPatch],
    matcher: &mut dyn PatchMatcher,
    resector: &mut dyn Resector,
    opts: &OrientOptions,
    guide: Option<&Guide>,
) -> Oriented {
    let (w, h) = camera.image_size();
    // Never below the smallest window (clamp needs min ≤ max, even for a tiny image).
    let max_half = opts
        .max_half_px
        .min(0.5 * w.min(h) as f64)
        .max(opts.min_half_px);
    let mut pose = *approximate;
    let mut cov = *covariance;
    let mut oriented = false;
    let mut records = Vec::new();
    let mut banned = std::collections::BTreeSet::new();
    let mut kept: Vec<(usize, Vector2<f64>, f64)> = Vec::new();
    let mut previous_count = 0usize;
    let mut first_round = Vec::new();
    let mut refuted = None;
    for iteration in 0..opts.max_iterations {
        let guided = guide.filter(|_| !oriented);
        // Predictions first (a projection each), then the search in windows (the cost).
        let mut candidates: Vec<(usize, Prediction, [f64; 2])> = Vec::new();
        for (i, p) in patches.iter().enumerate() {
            if banned.contains(&p.id) {
                continue;
            }
            let Ok(mut pred) = predict::predict(camera, &pose, &cov, &p.position, &p.covariance)
            else {
                continue;
            };
            if let Some(g) = guided {
                pred.pixel = g.map.apply(&pred.pixel);
            }
            if pred.pixel.x < 0.0
                || pred.pixel.y < 0.0
                || pred.pixel.x > w as f64
                || pred.pixel.y > h as f64
            {
                continue;
            }
            let hs = pred.search_half_size(opts.k_sigma);
            let half = match guided {
                Some(g) => [g.half_px; 2],
                None => [
                    hs[0].clamp(opts.min_half_px, max_half),
                    hs[1].clamp(opts.min_half_px, max_half),
                ],
            };
            candidates.push((i, pred, half));
        }
        let predicted = candidates.len();
        let quota = opts.first_round_matches.filter(|_| !oriented);
        if quota.is_some_and(|q| q < predicted) {
            let pixels: Vec<Vector2<f64>> = candidates.iter().map(|c| c.1.pixel).collect();
            let order = spread_order(&pixels, w as f64, h as f64);
            candidates = order.into_iter().map(|k| candidates[k]).collect();
        }
        let mut found: Vec<(usize, PatchMatch)> = Vec::new();
        let (mut searched, mut window_sum) = (0usize, 0.0);
        for (i, pred, half) in &candidates {
            if quota.is_some_and(|q| found.len() >= q) {
                break;
            }
            searched += 1;
            window_sum += 0.5 * (half[0] + half[1]);
            if let Some(m) = matcher.find(&patches[*i], &pose, pred, *half) {
                found.push((*i, m));
                if iteration == 0 {
                    first_round.push((pred.pixel, m.pixel));
                }
            }
        }
        let mut record = IterationRecord {
            iteration,
            predicted,
            searched,
            matched: found.len(),
            success_ratio: if searched > 0 {
                found.len() as f64 / searched as f64
            } else {
                0.0
            },
            mean_window_px: if searched > 0 {
                window_sum / searched as f64
            } else {
                0.0
            },
            resected: false,
            rejected: 0,
            accepted: 0,
        };
        let resection = if found.len() >= opts.min_matches {
            let obs: Vec<(Vector3<f64>, Vector2<f64>, f64)> = found
                .iter()
                .map(|(i, m)| (patches[*i].position, m.pixel, m.sigma_px))
                .collect();
            resector.resect(camera, &pose, &obs)
        } else {
            Err(format!("{} are too few for a resection", found.len()))
        };
        match resection {
            Ok(r) => {
                record.resected = true;
                record.rejected = r.inliers.iter().filter(|b| !**b).count();
                for ((i, _), ok) in found.iter().zip(&r.inliers) {
                    if !ok {
                        banned.insert(patches[*i].id);
                    }
                }
                kept = found
                    .iter()
                    .zip(&r.inliers)
                    .filter(|(_, ok)| **ok)
                    .map(|((i, m), _)| (patches[*i].id, m.pixel, m.sigma_px))
                    .collect();
                record.accepted = kept.len();
                pose = r.pose;
                cov = r.covariance;
                oriented = true;
            }
            // A right pose predicts its patches within a few pixels, where the patches
            // that made it match again; a pose fitted to a consistent set of wrong
            // matches (repeated texture, ground that changed) predicts them where they
            // are not (small block, seed 10: 6 of 12 first-round matches gave a digital
            // photo a pose 21 m and 4.5° off; in ±6 px windows around its predictions 7
            // matched and no resection held).
            Err(message) if oriented => {
                refuted = Some((iteration, message));
                oriented = false;
            }
            Err(_) => {}
        }
        records.push(record);
        if refuted.is_some() {
            break;
        }
        // Stop when a round brings no new accepted match.
        if oriented && kept.len() <= previous_count {
            break;
        }
        previous_count = kept.len();
        if !oriented && iteration > 0 {
            break;
        }
    }
    Oriented {
        pose,
        covariance: cov,
        matches: kept,
        iterations: records,
        oriented,
        first_round,
        refuted,
    }
}

/// An order of image positions that covers the photo evenly at every prefix: one
/// position per cell of a 1 × 1 grid, then of 2 × 2, 4 × 4, … (the one nearest each cell's
/// centre not taken yet), the cells of a level in a scattered order so that a level cut
/// short is still spread; positions no level took come last, in their given order.
pub fn spread_order(pixels: &[Vector2<f64>], width: f64, height: f64) -> Vec<usize> {
    let n = pixels.len();
    let mut taken = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut side = 1usize;
    while order.len() < n && side * side <= 4 * n {
        let (cw, ch) = (width / side as f64, height / side as f64);
        let mut best: std::collections::HashMap<usize, (f64, usize)> = Default::default();
        for (k, p) in pixels.iter().enumerate() {
            if taken[k] {
                continue;
            }
            let cx = ((p.x / cw).floor().max(0.0) as usize).min(side - 1);
            let cy = ((p.y / ch).floor().max(0.0) as usize).min(side - 1);
            let centre = Vector2::new((cx as f64 + 0.5) * cw, (cy as f64 + 0.5) * ch);
            let d = (p - centre).norm_squared();
            let cell = cy * side + cx;
            let e = best.entry(cell).or_insert((d, k));
            if d < e.0 || (d == e.0 && k < e.1) {
                *e = (d, k);
            }
        }
        // A multiplicative hash of the cell index scatters the cells of a level.
        let mut level: Vec<(usize, usize)> = best.into_iter().map(|(c, (_, k))| (c, k)).collect();
        level.sort_by_key(|&(c, _)| ((c as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32, c));
        for (_, k) in level {
            taken[k] = true;
            order.push(k);
        }
        side *= 2;
    }
    order.extend((0..n).filter(|&k| !taken[k]));
    order
}
