//! Tie points between overlapping photos (seed 003 §3.2–3.3): Förstner points of one
//! photo are matched into the other by NCC + LSM inside a search window around a
//! predicted position; the relative orientation (fundamental matrix) is estimated
//! robustly — least median of squares or RANSAC through the one `Estimator` interface —
//! and matches off their epipolar lines are rejected; the pairwise matches are linked
//! into multi-photo tracks, and each photo's coverage of the standard (von Gruber)
//! positions is reported.

use super::forstner::{forstner, ForstnerOptions};
use super::matcher::{match_template, MatchOptions};
use super::ncc::{ncc_search, Window};
use super::resample::{warp_patch, Interpolation, PatchWarp};
use super::{GreyImage, MatchingError, Pyramid, Result};
use crate::estimators::{Estimator, RobustOptions};
use crate::geometry::{dlt_null_matrix, hartley_normalisation};
use nalgebra::{DMatrix, Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The robust driver of the relative orientation (RANSAC uses `ro_threshold_px`).
pub use crate::estimators::RobustMethod;

#[derive(Debug, Clone)]
pub struct TieOptions {
    pub forstner: ForstnerOptions,
    pub matching: MatchOptions,
    /// Template half-size (template is 2·h + 1 px).
    pub template_half: usize,
    pub robust: RobustMethod,
    /// Epipolar (Sampson) distance threshold for RANSAC and the final inlier test (px).
    pub ro_threshold_px: f64,
    pub seed: u64,
    /// Observations of one photo closer than this are the same tie point (px).
    pub merge_px: f64,
}

impl Default for TieOptions {
    fn default() -> Self {
        Self {
            forstner: ForstnerOptions {
                border: 12,
                ..ForstnerOptions::default()
            },
            matching: MatchOptions {
                ncc_threshold: 0.75,
                max_ambiguity: 0.9,
                ..MatchOptions::default()
            },
            template_half: 10,
            robust: RobustMethod::Lmeds,
            ro_threshold_px: 1.0,
            seed: 7,
            merge_px: 1.0,
        }
    }
}

/// Predicted transfer from photo `a` to photo `b`: a plane homography (pixels of a →
/// pixels of b, from approximate orientations or a global shift) and the search radius
/// that covers relief parallax and the prediction's uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairPrediction {
    pub a: usize,
    pub b: usize,
    pub homography: Matrix3<f64>,
    pub search_radius_px: f64,
}

impl PairPrediction {
    pub fn transfer(&self, p: [f64; 2]) -> [f64; 2] {
        let v = self.homography * Vector3::new(p[0], p[1], 1.0);
        [v.x / v.z, v.y / v.z]
    }
}

/// One candidate correspondence.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TieCandidate {
    pub a: [f64; 2],
    pub b: [f64; 2],
    pub ncc: f64,
    pub sigma_px: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairMatches {
    pub a: usize,
    pub b: usize,
    pub candidates: Vec<TieCandidate>,
    /// Consistent with the relative orientation.
    pub inliers: Vec<bool>,
    /// Row-major fundamental matrix (x_bᵀ F x_a = 0), when estimated.
    pub fundamental: Option<[f64; 9]>,
    /// Robust σ of the epipolar distances (px).
    pub sigma_px: f64,
}

impl PairMatches {
    pub fn accepted(&self) -> impl Iterator<Item = &TieCandidate> {
        self.candidates
            .iter()
            .zip(&self.inliers)
            .filter(|(_, &i)| i)
            .map(|(c, _)| c)
    }
}

/// Fundamental matrix from the normalised 8-point algorithm, rank 2 enforced; residual
/// is the squared Sampson (first-order epipolar) distance in px².
pub struct FundamentalEstimator;

fn eight_point(samples: &[&([f64; 2], [f64; 2])]) -> Option<Matrix3<f64>> {
    let a: Vec<[f64; 2]> = samples.iter().map(|s| s.0).collect();
    let b: Vec<[f64; 2]> = samples.iter().map(|s| s.1).collect();
    let (ta, na) = hartley_normalisation(&a);
    let (tb, nb) = hartley_normalisation(&b);
    let n = samples.len();
    let mut m = DMatrix::<f64>::zeros(n.max(9), 9);
    for i in 0..n {
        let (p, q) = (na[i], nb[i]);
        let row = [
            q[0] * p[0],
            q[0] * p[1],
            q[0],
            q[1] * p[0],
            q[1] * p[1],
            q[1],
            p[0],
            p[1],
            1.0,
        ];
        for (j, v) in row.iter().enumerate() {
            m[(i, j)] = *v;
        }
    }
    let fm = dlt_null_matrix(m)?;
    let svd = fm.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut s = svd.singular_values;
    // nalgebra sorts singular values in descending order.
    s[2] = 0.0;
    let f2 = u * Matrix3::from_diagonal(&s) * vt;
    let f = tb.transpose() * f2 * ta;
    let norm = f.norm();
    (norm > 0.0 && norm.is_finite()).then(|| f / norm)
}

impl Estimator for FundamentalEstimator {
    type Sample = ([f64; 2], [f64; 2]);
    type Model = Matrix3<f64>;
    const MIN_SAMPLES: usize = 8;
    fn fit_minimal(&self, samples: &[&Self::Sample]) -> Vec<Self::Model> {
        eight_point(samples).into_iter().collect()
    }
    fn residual_sq(&self, f: &Self::Model, s: &Self::Sample) -> f64 {
        let x1 = Vector3::new(s.0[0], s.0[1], 1.0);
        let x2 = Vector3::new(s.1[0], s.1[1], 1.0);
        let fx1 = f * x1;
        let ftx2 = f.transpose() * x2;
        let e = x2.dot(&fx1);
        let d = fx1.x * fx1.x + fx1.y * fx1.y + ftx2.x * ftx2.x + ftx2.y * ftx2.y;
        if d > 0.0 {
            e * e / d
        } else {
            f64::INFINITY
        }
    }
    fn refine(&self, _m: &Self::Model, inliers: &[&Self::Sample]) -> Option<Self::Model> {
        eight_point(inliers)
    }
}

/// NCC + LSM candidates of `points` (pixels of photo a) in photo b, each searched
/// around its transfer through the pair's plane homography.
pub fn candidates(
    a: &GreyImage,
    b: &Pyramid,
    pred: &PairPrediction,
    points: &[[f64; 2]],
    opts: &TieOptions,
) -> Vec<TieCandidate> {
    let search: Vec<SearchPoint> = points
        .iter()
        .map(|&p| SearchPoint {
            a: p,
            predicted_b: pred.transfer(p),
            affine: None,
        })
        .collect();
    search_candidates(a, b, &search, pred.search_radius_px, opts)
}

/// A point of photo a to be found in photo b: its predicted position in b and, when
/// known, the local affine shape of the a → b transfer (row-major 2×2, b offsets per a
/// offset), e.g. from approximate orientations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchPoint {
    pub a: [f64; 2],
    pub predicted_b: [f64; 2],
    pub affine: Option<[f64; 4]>,
}

/// Largest deviation of a transfer shape from the identity that still matches with an
/// unwarped template: over a 21 px template it displaces the corners by ≤ 0.3 px.
const SHAPE_TOLERANCE: f64 = 0.03;

/// NCC + LSM candidates of each search point within `radius` px of its prediction. When
/// the transfer shape departs from the identity (rotated or differently scaled photos)
/// the template is resampled into b's geometry first, so that NCC, which is not
/// rotation invariant, still sees the same pattern; its centre is then exactly `a`.
pub fn search_candidates(
    a: &GreyImage,
    b: &Pyramid,
    points: &[SearchPoint],
    radius: f64,
    opts: &TieOptions,
) -> Vec<TieCandidate> {
    let h = opts.template_half;
    let n = 2 * h + 1;
    let bimg = &b.levels[0];
    points
        .par_iter()
        .filter_map(|sp| {
            let p = sp.a;
            let shape = sp.affine.filter(|m| {
                (m[0] - 1.0)
                    .abs()
                    .max(m[1].abs())
                    .max(m[2].abs())
                    .max((m[3] - 1.0).abs())
                    > SHAPE_TOLERANCE
            });
            let (tpl, ca) = match shape {
                None => {
                    let (c0, r0) = (
                        (p[0] - 0.5).round() as isize - h as isize,
                        (p[1] - 0.5).round() as isize - h as isize,
                    );
                    if c0 < 0 || r0 < 0 {
                        return None;
                    }
                    let tpl = a.crop(c0 as usize, r0 as usize, n, n).ok()?;
                    // Template centre in a (corner origin) is the pixel centre cropped.
                    (
                        tpl,
                        [c0 as f64 + h as f64 + 0.5, r0 as f64 + h as f64 + 0.5],
                    )
                }
                Some(m) => {
                    let det = m[0] * m[3] - m[1] * m[2];
                    if det.abs() < 1e-6 {
                        return None;
                    }
                    // a offset = shape⁻¹ · (template offset from the template centre).
                    let inv = [m[3] / det, -m[1] / det, -m[2] / det, m[0] / det];
                    let c = h as f64 + 0.5;
                    let warp = PatchWarp::Affine([
                        inv[0],
                        inv[1],
                        p[0] - inv[0] * c - inv[1] * c,
                        inv[2],
                        inv[3],
                        p[1] - inv[2] * c - inv[3] * c,
                    ]);
                    let (tpl, outside) = warp_patch(a, &warp, n, n, Interpolation::Bicubic);
                    if outside > 0 {
                        return None;
                    }
                    (tpl, p)
                }
            };
            let q = match shape {
                // The crop moved the centre by < 0.5 px; move the prediction with it.
                None => {
                    let m = sp.affine.unwrap_or([1.0, 0.0, 0.0, 1.0]);
                    let (dx, dy) = (ca[0] - p[0], ca[1] - p[1]);
                    [
                        sp.predicted_b[0] + m[0] * dx + m[1] * dy,
                        sp.predicted_b[1] + m[2] * dx + m[3] * dy,
                    ]
                }
                Some(_) => sp.predicted_b,
            };
            let half = radius + h as f64 + 1.0;
            let w = Window::around(bimg, q[0], q[1], half, half)?;
            let m = match_template(b, &tpl, w, None, &opts.matching).ok()?;
            m.accepted.then_some(TieCandidate {
                a: ca,
                b: [m.x, m.y],
                ncc: m.ncc,
                sigma_px: m.sigma_x.hypot(m.sigma_y),
            })
        })
        .collect()
}

/// Robust relative orientation of a pair's candidates; marks the inliers.
pub fn relative_orientation(
    a: usize,
    b: usize,
    cands: Vec<TieCandidate>,
    opts: &TieOptions,
) -> Result<PairMatches> {
    let samples: Vec<([f64; 2], [f64; 2])> = cands.iter().map(|c| (c.a, c.b)).collect();
    let ro = RobustOptions {
        threshold: opts.ro_threshold_px,
        seed: opts.seed,
        max_iterations: 5000,
        ..RobustOptions::default()
    };
    let est = FundamentalEstimator;
    let res = opts
        .robust
        .estimate(&est, &samples, &ro)
        .map_err(|e| MatchingError::Relative {
            a: a.to_string(),
            b: b.to_string(),
            message: format!("{e} ({} candidates)", samples.len()),
        })?;
    // Whatever the driver, the final inliers obey the same geometric tolerance: an LMS
    // σ can be tiny on clean data, and the tolerance reflects the measurement precision.
    let f = res.model;
    let t2 = opts.ro_threshold_px.powi(2);
    let inliers: Vec<bool> = samples
        .iter()
        .map(|s| est.residual_sq(&f, s) <= t2)
        .collect();
    let mut r: Vec<f64> = samples
        .iter()
        .zip(&inliers)
        .filter(|(_, &i)| i)
        .map(|(s, _)| est.residual_sq(&f, s).sqrt())
        .collect();
    r.sort_by(f64::total_cmp);
    let sigma = r.get(r.len() / 2).map_or(f64::NAN, |m| 1.4826 * m);
    Ok(PairMatches {
        a,
        b,
        candidates: cands,
        inliers,
        fundamental: Some([
            f[(0, 0)],
            f[(0, 1)],
            f[(0, 2)],
            f[(1, 0)],
            f[(1, 1)],
            f[(1, 2)],
            f[(2, 0)],
            f[(2, 1)],
            f[(2, 2)],
        ]),
        sigma_px: sigma,
    })
}

/// Förstner points of a, matched into b, filtered by robust relative orientation.
pub fn match_pair(
    a: &GreyImage,
    b: &Pyramid,
    pred: &PairPrediction,
    opts: &TieOptions,
) -> Result<PairMatches> {
    let pts: Vec<[f64; 2]> = forstner(a, &opts.forstner)
        .iter()
        .map(|p| [p.x, p.y])
        .collect();
    let bimg = &b.levels[0];
    // Only points whose prediction falls inside b can match.
    let pts: Vec<[f64; 2]> = pts
        .into_iter()
        .filter(|p| {
            let q = pred.transfer(*p);
            q[0] > 0.0 && q[1] > 0.0 && q[0] < bimg.width as f64 && q[1] < bimg.height as f64
        })
        .collect();
    let c = candidates(a, b, pred, &pts, opts);
    tracing::debug!(
        a = pred.a,
        b = pred.b,
        points = pts.len(),
        candidates = c.len(),
        "tie candidates"
    );
    relative_orientation(pred.a, pred.b, c, opts)
}

/// A tie point: its observations (photo index, pixel) and each observation's σ (px,
/// from the match that produced it).
#[derive(Debug, Clone, Serialize)]
pub struct Track {
    pub observations: Vec<(usize, [f64; 2])>,
    pub sigma_px: Vec<f64>,
}

/// Links the accepted pairwise matches into tracks: observations of one photo within
/// `merge_px` of each other are one image point; connected image points form a track.
/// Tracks that end up with two distinct image points in the same photo are contradictory
/// and dropped.
pub fn link_tracks(pairs: &[PairMatches], merge_px: f64) -> Vec<Track> {
    let mut nodes: Vec<(usize, [f64; 2])> = Vec::new();
    // σ of each node: the first match that created it (merged ones are the same point).
    let mut sigmas: Vec<f64> = Vec::new();
    let mut edges = Vec::new();
    let cell = merge_px.max(1e-6);
    let mut grid: std::collections::HashMap<(usize, i64, i64), Vec<usize>> = Default::default();
    let mut node_of = |photo: usize, p: [f64; 2], nodes: &mut Vec<(usize, [f64; 2])>| -> usize {
        let (gx, gy) = ((p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64);
        for dy in -1..=1 {
            for dx in -1..=1 {
                if let Some(v) = grid.get(&(photo, gx + dx, gy + dy)) {
                    for &k in v {
                        let q = nodes[k].1;
                        if (q[0] - p[0]).hypot(q[1] - p[1]) <= merge_px {
                            return k;
                        }
                    }
                }
            }
        }
        nodes.push((photo, p));
        grid.entry((photo, gx, gy))
            .or_default()
            .push(nodes.len() - 1);
        nodes.len() - 1
    };
    for pm in pairs {
        for c in pm.accepted() {
            let i = node_of(pm.a, c.a, &mut nodes);
            let j = node_of(pm.b, c.b, &mut nodes);
            // New nodes get this match's σ.
            sigmas.resize(nodes.len(), c.sigma_px);
            edges.push((i, j));
        }
    }
    let mut parent: Vec<usize> = (0..nodes.len()).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    for (i, j) in edges {
        let (ri, rj) = (find(&mut parent, i), find(&mut parent, j));
        if ri != rj {
            parent[ri.max(rj)] = ri.min(rj);
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for k in 0..nodes.len() {
        let r = find(&mut parent, k);
        groups.entry(r).or_default().push(k);
    }
    groups
        .into_values()
        .filter_map(|g| {
            let mut g = g;
            g.sort_by_key(|&k| nodes[k].0);
            let distinct = g.windows(2).all(|w| nodes[w[0]].0 != nodes[w[1]].0);
            (distinct && g.len() >= 2).then(|| Track {
                observations: g.iter().map(|&k| nodes[k]).collect(),
                sigma_px: g.iter().map(|&k| sigmas[k]).collect(),
            })
        })
        .collect()
}

/// The nine standard (von Gruber) positions of a photo: the image centre column and the
/// two columns near the edges of the stereo overlap (1/6 and 5/6 of the width), each at
/// the top, centre and bottom (1/6, 1/2, 5/6 of the height).
pub fn standard_positions(width: usize, height: usize) -> [[f64; 2]; 9] {
    let f = [1.0 / 6.0, 0.5, 5.0 / 6.0];
    let mut out = [[0.0; 2]; 9];
    for (r, fy) in f.iter().enumerate() {
        for (c, fx) in f.iter().enumerate() {
            out[r * 3 + c] = [fx * width as f64, fy * height as f64];
        }
    }
    out
}

/// How many of `pixels` lie near each standard position: within one sixth of the image's
/// shorter side of it in both axes (a point can count for two neighbouring positions).
pub fn standard_position_counts(width: usize, height: usize, pixels: &[[f64; 2]]) -> [usize; 9] {
    let pos = standard_positions(width, height);
    let rad = (width.min(height) as f64) / 6.0;
    let mut counts = [0usize; 9];
    for p in pixels {
        for (k, q) in pos.iter().enumerate() {
            if (p[0] - q[0]).abs() <= rad && (p[1] - q[1]).abs() <= rad {
                counts[k] += 1;
            }
        }
    }
    counts
}

/// Per-photo coverage of the standard positions: for each photo, each of the nine
/// positions, whether it is required (it lies in the overlap with some other photo,
/// judged with the pair predictions) and how many tie points lie within one sixth of the
/// image of it.
#[derive(Debug, Clone, Serialize)]
pub struct Coverage {
    pub photo: usize,
    pub required: [bool; 9],
    pub counts: [usize; 9],
    pub total: usize,
}

impl Coverage {
    /// Required positions with fewer than `min` points.
    pub fn missing(&self, min: usize) -> Vec<usize> {
        (0..9)
            .filter(|&k| self.required[k] && self.counts[k] < min)
            .collect()
    }
}

pub fn coverage(
    sizes: &[(usize, usize)],
    preds: &[PairPrediction],
    tracks: &[Track],
) -> Vec<Coverage> {
    sizes
        .iter()
        .enumerate()
        .map(|(i, &(w, h))| {
            let pos = standard_positions(w, h);
            let mut required = [false; 9];
            for p in preds {
                let (other, hm) = if p.a == i {
                    (p.b, Some(p.homography))
                } else if p.b == i {
                    (p.a, p.homography.try_inverse())
                } else {
                    continue;
                };
                let Some(hm) = hm else { continue };
                let (ow, oh) = sizes[other];
                for (k, q) in pos.iter().enumerate() {
                    let v = hm * Vector3::new(q[0], q[1], 1.0);
                    let (x, y) = (v.x / v.z, v.y / v.z);
                    if x >= 0.0 && y >= 0.0 && x <= ow as f64 && y <= oh as f64 {
                        required[k] = true;
                    }
                }
            }
            let mine: Vec<[f64; 2]> = tracks
                .iter()
                .flat_map(|t| &t.observations)
                .filter(|(ph, _)| *ph == i)
                .map(|(_, p)| *p)
                .collect();
            let counts = standard_position_counts(w, h, &mine);
            let total = mine.len();
            Coverage {
                photo: i,
                required,
                counts,
                total,
            }
        })
        .collect()
}

/// A global shift from a to b found at a coarse pyramid level, for photos without any
/// approximate orientation (consecutive photos of a strip, for instance): the central
/// parts of a are correlated over all of b and the least ambiguous peak wins.
pub fn predict_shift(a: &Pyramid, b: &Pyramid, ia: usize, ib: usize) -> Option<PairPrediction> {
    let level = a
        .levels
        .iter()
        .zip(&b.levels)
        .rposition(|(x, y)| x.width.min(x.height) >= 96 && y.width.min(y.height) >= 96)?;
    let (la, lb) = (&a.levels[level], &b.levels[level]);
    let s = (1usize << level) as f64;
    let ps = la.width.min(la.height) / 4;
    let mut best: Option<(f64, f64, f64)> = None;
    let mut corr: Vec<([f64; 2], [f64; 2])> = Vec::new();
    for fy in [0.25, 0.5, 0.75] {
        for fx in [0.25, 0.5, 0.75] {
            let c0 = (fx * la.width as f64) as usize - ps / 2;
            let r0 = (fy * la.height as f64) as usize - ps / 2;
            let Ok(t) = la.crop(c0, r0, ps, ps) else {
                continue;
            };
            let Ok(pk) = ncc_search(lb, &t, Window::whole(lb), false) else {
                continue;
            };
            let q = pk.ncc * (1.0 - pk.ratio);
            let ca = [c0 as f64 + ps as f64 / 2.0, r0 as f64 + ps as f64 / 2.0];
            if pk.ncc > 0.5 && pk.ratio < 0.8 {
                corr.push((ca, [pk.x, pk.y]));
            }
            if pk.ncc > 0.5 && best.is_none_or(|b| q > b.0) {
                best = Some((q, (pk.x - ca[0]) * s, (pk.y - ca[1]) * s));
            }
        }
    }
    let (_, dx, dy) = best?;
    let mut h = Matrix3::new(1.0, 0.0, dx, 0.0, 1.0, dy, 0.0, 0.0, 1.0);
    let mut radius = 4.0 * s;
    // With three or more consistent patches an affine transfer absorbs the rotation and
    // scale between photos (a drone or a crab-angled strip); the patch with the largest
    // residual is dropped while it is inconsistent with the others.
    while corr.len() >= 4 {
        let n = corr.len();
        let mut m = DMatrix::<f64>::zeros(2 * n, 6);
        let mut v = nalgebra::DVector::<f64>::zeros(2 * n);
        for (k, (pa, pb)) in corr.iter().enumerate() {
            m.row_mut(2 * k)
                .copy_from_slice(&[pa[0], pa[1], 1.0, 0.0, 0.0, 0.0]);
            m.row_mut(2 * k + 1)
                .copy_from_slice(&[0.0, 0.0, 0.0, pa[0], pa[1], 1.0]);
            v[2 * k] = pb[0];
            v[2 * k + 1] = pb[1];
        }
        let Ok(x) = m.clone().svd(true, true).solve(&v, 1e-9) else {
            break;
        };
        let r = &m * &x - &v;
        let res: Vec<f64> = (0..n).map(|k| r[2 * k].hypot(r[2 * k + 1])).collect();
        let (worst, wv) = res
            .iter()
            .enumerate()
            .fold((0, 0.0), |a, (k, &e)| if e > a.1 { (k, e) } else { a });
        if wv > 3.0 {
            corr.remove(worst);
            continue;
        }
        // Level coordinates scale by s in both photos, so only the shift scales.
        h = Matrix3::new(x[0], x[1], x[2] * s, x[3], x[4], x[5] * s, 0.0, 0.0, 1.0);
        radius = (4.0 + 2.0 * wv) * s;
        break;
    }
    Some(PairPrediction {
        a: ia,
        b: ib,
        homography: h,
        search_radius_px: radius,
    })
}

/// Tie points of a set of photos for the given pairs: pairwise matching, robust
/// relative orientation, tracks and coverage.
#[derive(Debug, Clone, Serialize)]
pub struct TieResult {
    /// The pairs that gave verified matches.
    pub matches: Vec<PairMatches>,
    pub tracks: Vec<Track>,
    pub coverage: Vec<Coverage>,
}

impl TieResult {
    /// Links the verified matches of photos of `sizes` (width, height) into tracks and
    /// counts the coverage of the predicted pairs `preds`.
    pub(crate) fn link(
        matches: Vec<PairMatches>,
        sizes: &[(usize, usize)],
        preds: &[PairPrediction],
        merge_px: f64,
    ) -> Self {
        let tracks = link_tracks(&matches, merge_px);
        let coverage = coverage(sizes, preds, &tracks);
        TieResult {
            matches,
            tracks,
            coverage,
        }
    }
}

pub fn tie_points(
    photos: &[GreyImage],
    preds: &[PairPrediction],
    opts: &TieOptions,
) -> Result<TieResult> {
    let pyrs: Vec<Pyramid> = photos.par_iter().map(|p| Pyramid::new(p, 6, 32)).collect();
    let mut pairs = Vec::new();
    for p in preds {
        if p.a >= photos.len() || p.b >= photos.len() {
            return Err(super::invalid(
                "pair prediction",
                format!("photo index {}–{} out of range", p.a, p.b),
            ));
        }
        pairs.push(match_pair(&photos[p.a], &pyrs[p.b], p, opts)?);
    }
    let sizes: Vec<(usize, usize)> = photos.iter().map(|p| (p.width, p.height)).collect();
    Ok(TieResult::link(pairs, &sizes, preds, opts.merge_px))
}
