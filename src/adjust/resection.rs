//! Single-photo resection: the exterior orientation of one photo from ≥ 3 control
//! points. Grunert's P3P (in Haralick et al.'s 1994 formulation, a quartic in the
//! distance ratio) is the minimal solver inside RANSAC or least median of squares
//! (src/estimators); the consensus is then refined by Levenberg–Marquardt on the
//! collinearity equations with the full camera model, gross errors are removed by data
//! snooping on the standardised residuals, and the pose covariance is σ0²·(AᵀA)⁻¹.

use super::AdjustError;
use crate::estimators::{selected, Estimator, RobustMethod, RobustOptions};
use crate::geometry::{project_with_jacobians, Camera, Pose};
use nalgebra::{DMatrix, Matrix3, Matrix6, SMatrix, Vector2, Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// Options of [`resect`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ResectionOptions {
    /// RANSAC inlier threshold on the reprojection error (px).
    pub threshold_px: f64,
    /// Least median of squares instead of RANSAC (no threshold needed, 50 % breakdown).
    pub lmeds: bool,
    pub confidence: f64,
    pub max_iterations: usize,
    pub seed: u64,
    /// Critical value of the standardised residual for data snooping after refinement.
    pub reject_k: f64,
    /// Approximate pose, used to choose among the P3P solutions of exactly three points.
    pub approximate: Option<Pose>,
}

impl Default for ResectionOptions {
    fn default() -> Self {
        Self {
            threshold_px: 4.0,
            lmeds: false,
            confidence: 0.9999,
            max_iterations: 10_000,
            seed: 7,
            reject_k: 3.5,
            approximate: None,
        }
    }
}

/// Result of [`resect`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ResectionResult {
    pub pose: Pose,
    /// Per control point: used in the final solution.
    pub inliers: Vec<bool>,
    pub num_inliers: usize,
    /// RMS reprojection error of the inliers (px).
    pub rmse_px: f64,
    /// A-posteriori σ0 (unit weight; a-priori σ = `sigma_px`). NaN with 3 points.
    pub sigma0: f64,
    /// Covariance of (δθ, δC): rotation vector (rad, left perturbation) and centre (m),
    /// scaled by σ0² when there is redundancy, else by 1 (a-priori).
    pub covariance: [[f64; 6]; 6],
    pub iterations: usize,
}

/// A correspondence as the minimal solver takes it: pixel, its bearing, the point.
#[doc(hidden)]
#[derive(Debug, Clone)]
pub struct Corr {
    pub pixel: Vector2<f64>,
    pub bearing: Vector3<f64>,
    pub x: Vector3<f64>,
}

/// The P3P estimator of the resection's RANSAC.
#[doc(hidden)]
pub struct P3p<'a> {
    pub camera: &'a Camera,
}

/// Real roots of a quartic a4 v⁴ + … + a0 from the companion matrix, polished by Newton.
fn quartic_roots(c: [f64; 5]) -> Vec<f64> {
    let [a4, a3, a2, a1, a0] = c;
    if a4.abs() < 1e-14 * (a3.abs() + a2.abs() + a1.abs() + a0.abs()) {
        return Vec::new();
    }
    let mut m = nalgebra::Matrix4::zeros();
    m[(0, 0)] = -a3 / a4;
    m[(0, 1)] = -a2 / a4;
    m[(0, 2)] = -a1 / a4;
    m[(0, 3)] = -a0 / a4;
    m[(1, 0)] = 1.0;
    m[(2, 1)] = 1.0;
    m[(3, 2)] = 1.0;
    let ev = m.complex_eigenvalues();
    let f = |v: f64| (((a4 * v + a3) * v + a2) * v + a1) * v + a0;
    let df = |v: f64| ((4.0 * a4 * v + 3.0 * a3) * v + 2.0 * a2) * v + a1;
    ev.iter()
        .filter(|z| z.im.abs() < 1e-6 * (1.0 + z.re.abs()))
        .map(|z| {
            let mut v = z.re;
            for _ in 0..5 {
                let d = df(v);
                if d.abs() < 1e-300 {
                    break;
                }
                v -= f(v) / d;
            }
            v
        })
        .collect()
}

/// Rigid transform Y = R X + t from three or more point pairs (Kabsch).
fn absolute_orientation(
    x: &[Vector3<f64>],
    y: &[Vector3<f64>],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let n = x.len() as f64;
    let cx = x.iter().sum::<Vector3<f64>>() / n;
    let cy = y.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (a, b) in x.iter().zip(y) {
        h += (a - cx) * (b - cy).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    Some((r, cy - r * cx))
}

/// Grunert's P3P: all poses consistent with three bearing/point pairs.
#[doc(hidden)]
pub fn p3p(s: &[&Corr]) -> Vec<Pose> {
    let (p1, p2, p3) = (s[0].x, s[1].x, s[2].x);
    let (j1, j2, j3) = (s[0].bearing, s[1].bearing, s[2].bearing);
    let a2 = (p2 - p3).norm_squared();
    let b2 = (p1 - p3).norm_squared();
    let c2 = (p1 - p2).norm_squared();
    if a2 < 1e-12 || b2 < 1e-12 || c2 < 1e-12 {
        return Vec::new();
    }
    let (ca, cb, cg) = (j2.dot(&j3), j1.dot(&j3), j1.dot(&j2));
    // Eliminating u from the three laws of cosines (Grunert): u = N(v)/D(v) from two of
    // them, substituted into the third, gives N² − 2cosγ·N·D − D²·E = 0, a quartic in v.
    let k = (a2 - c2) / b2;
    let n = [1.0 + k, -2.0 * k * cb, k - 1.0];
    let dd = [2.0 * cg, -2.0 * ca];
    let e = [c2 / b2 - 1.0, -2.0 * cb * c2 / b2, c2 / b2];
    let mul = |x: &[f64], y: &[f64]| {
        let mut r = vec![0.0; x.len() + y.len() - 1];
        for (i, a) in x.iter().enumerate() {
            for (j, b) in y.iter().enumerate() {
                r[i + j] += a * b;
            }
        }
        r
    };
    let nn = mul(&n, &n);
    let nd = mul(&n, &dd);
    let d2e = mul(&mul(&dd, &dd), &e);
    let mut poly = [0.0; 5];
    for (i, v) in nn.iter().enumerate() {
        poly[i] += v;
    }
    for (i, v) in nd.iter().enumerate() {
        poly[i] -= 2.0 * cg * v;
    }
    for (i, v) in d2e.iter().enumerate() {
        poly[i] -= v;
    }
    let amc = k;
    let mut out = Vec::new();
    for v in quartic_roots([poly[4], poly[3], poly[2], poly[1], poly[0]]) {
        if v <= 0.0 {
            continue;
        }
        let den = 2.0 * (cg - v * ca);
        if den.abs() < 1e-12 {
            continue;
        }
        let u = ((-1.0 + amc) * v * v - 2.0 * amc * cb * v + 1.0 + amc) / den;
        if u <= 0.0 {
            continue;
        }
        let q = 1.0 + v * v - 2.0 * v * cb;
        if q <= 0.0 {
            continue;
        }
        let s1 = (b2 / q).sqrt();
        let (s2, s3) = (u * s1, v * s1);
        let y = [j1 * s1, j2 * s2, j3 * s3];
        if let Some((r, t)) = absolute_orientation(&[p1, p2, p3], &y) {
            let pose = Pose::from_rotation_translation(r, t);
            if pose.is_finite() {
                out.push(pose);
            }
        }
    }
    out
}

fn reprojection_sq(camera: &Camera, pose: &Pose, c: &Corr) -> f64 {
    match crate::geometry::project(camera, pose, &c.x) {
        Ok(p) => (p.pixel - c.pixel).norm_squared(),
        Err(_) => f64::INFINITY,
    }
}

/// Levenberg–Marquardt on the six EO parameters; returns the pose, AᵀA and iterations.
fn refine_pose(camera: &Camera, start: &Pose, cs: &[&Corr]) -> (Pose, Matrix6<f64>, usize) {
    let cost = |p: &Pose| {
        cs.iter()
            .map(|c| reprojection_sq(camera, p, c))
            .sum::<f64>()
    };
    let mut pose = *start;
    let mut f = cost(&pose);
    let mut lambda = 1e-3;
    let mut n_mat = Matrix6::zeros();
    let mut it = 0;
    while it < 50 {
        it += 1;
        let mut n = Matrix6::zeros();
        let mut g = Vector6::zeros();
        for c in cs {
            let Ok((p, j)) = project_with_jacobians(camera, &pose, &c.x) else {
                continue;
            };
            let r = p.pixel - c.pixel;
            n += j.pose.transpose() * j.pose;
            g += j.pose.transpose() * r;
        }
        n_mat = n;
        let mut improved = false;
        while lambda < 1e10 {
            let mut a = n;
            for k in 0..6 {
                a[(k, k)] += lambda * n[(k, k)].max(1e-9);
            }
            let Some(d) = a.cholesky().map(|ch| ch.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            let trial = pose.perturbed(&d.fixed_rows::<3>(0).into(), &d.fixed_rows::<3>(3).into());
            let ft = cost(&trial);
            if ft <= f {
                let small = d.amax() < 1e-12 || (f - ft) <= 1e-14 * f.max(1e-300);
                pose = trial;
                f = ft;
                lambda = (lambda / 5.0).max(1e-12);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (pose, n_mat, it)
}

impl Estimator for P3p<'_> {
    type Sample = Corr;
    type Model = Pose;
    const MIN_SAMPLES: usize = 3;
    fn fit_minimal(&self, s: &[&Corr]) -> Vec<Pose> {
        p3p(s)
    }
    fn residual_sq(&self, m: &Pose, s: &Corr) -> f64 {
        reprojection_sq(self.camera, m, s)
    }
    fn refine(&self, m: &Pose, inliers: &[&Corr]) -> Option<Pose> {
        if inliers.len() < 4 {
            return Some(*m);
        }
        Some(refine_pose(self.camera, m, inliers).0)
    }
}

#[doc(hidden)]
pub fn rotation_angle(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    super::residual::rotation_vector(&(a * b.transpose())).norm()
}

/// Fewest consensus points for the least-median pass: below it the median is one of a
/// handful of residuals and says nothing a RANSAC consensus does not.
const MEDIAN_MIN_CONSENSUS: usize = 7;

/// The pose within a RANSAC consensus by least median of squares, and which consensus
/// points it keeps (|r| within the consensus threshold); None when the consensus is too
/// small.
///
/// A threshold of a few pixels (it must admit the control's own errors) lets RANSAC
/// prefer a pose tilted onto two wrong points at the far edge of a photo whose other
/// control sits in one corner: every point then fits within 2.5 px, the right pose fits
/// all but those two within 1.4 px (small block, seed 8, a digital photo whose two edge
/// points lay on ground 2 m higher than in the reference epoch: pose 1.1° and 3.3 m off,
/// checkpoints 3.35 GSD off in height). The median of the right pose is half the tilted
/// one's, so least median of squares, with its 50 % breakdown inside a consensus that is
/// mostly right, tells them apart where counting inliers cannot.
fn median_within_consensus(
    est: &P3p<'_>,
    cs: &[Corr],
    consensus: &[bool],
    opts: &ResectionOptions,
) -> Option<(Pose, Vec<bool>)> {
    let idx: Vec<usize> = (0..cs.len()).filter(|&i| consensus[i]).collect();
    if idx.len() < MEDIAN_MIN_CONSENSUS {
        return None;
    }
    let sub: Vec<Corr> = idx.iter().map(|&i| cs[i].clone()).collect();
    let ro = RobustOptions {
        threshold: opts.threshold_px,
        confidence: opts.confidence,
        max_iterations: opts.max_iterations,
        min_iterations: 200,
        seed: opts.seed,
    };
    let r = RobustMethod::Lmeds.estimate(est, &sub, &ro).ok()?;
    // The median chooses the pose; which points it keeps is the consensus threshold's
    // call, as before: a tighter rule here would drop the right points whose control is
    // a pixel off (DCP points carry their own errors) and erode a clean photo.
    let t2 = (2.5 * r.sigma).max(opts.threshold_px).powi(2);
    let mut keep = vec![false; cs.len()];
    for (&i, c) in idx.iter().zip(&sub) {
        keep[i] = reprojection_sq(est.camera, &r.model, c) <= t2;
    }
    (keep.iter().filter(|&&k| k).count() >= 3).then_some((r.model, keep))
}

/// Resects one photo from control points: `pixels[i]` observes world (block-local)
/// point `points[i]`, both with a-priori image σ `sigma_px`.
pub fn resect(
    camera: &Camera,
    pixels: &[[f64; 2]],
    points: &[[f64; 3]],
    sigma_px: f64,
    opts: &ResectionOptions,
) -> Result<ResectionResult, AdjustError> {
    camera
        .validate()
        .map_err(|e| AdjustError::InvalidBlock(format!("camera: {e}")))?;
    if pixels.len() != points.len() {
        return Err(AdjustError::InvalidBlock(format!(
            "{} pixels but {} control points",
            pixels.len(),
            points.len()
        )));
    }
    if points.len() < 3 {
        return Err(AdjustError::TooFewObservations(format!(
            "resection needs at least 3 control points, {} given",
            points.len()
        )));
    }
    if !(sigma_px.is_finite() && sigma_px > 0.0) {
        return Err(AdjustError::InvalidOption {
            name: "sigma_px".into(),
            message: format!("must be positive and finite, got {sigma_px}"),
        });
    }
    if !(opts.threshold_px.is_finite() && opts.threshold_px > 0.0) {
        return Err(AdjustError::InvalidOption {
            name: "threshold_px".into(),
            message: format!("must be positive and finite, got {}", opts.threshold_px),
        });
    }
    let mut cs = Vec::with_capacity(points.len());
    for (i, (px, x)) in pixels.iter().zip(points).enumerate() {
        if !px.iter().chain(x.iter()).all(|v| v.is_finite()) {
            return Err(AdjustError::NotFinite {
                what: format!("control point {i} (pixel or coordinates)"),
            });
        }
        let bearing = camera.unproject(*px).map_err(|e| {
            AdjustError::InvalidBlock(format!("control point {i}: pixel {px:?}: {e}"))
        })?;
        cs.push(Corr {
            pixel: Vector2::new(px[0], px[1]),
            bearing,
            x: Vector3::from(*x),
        });
    }
    // Degenerate control: all points on one line leave the rotation about it free.
    let mean = cs.iter().map(|c| c.x).sum::<Vector3<f64>>() / cs.len() as f64;
    let mut m = DMatrix::zeros(cs.len(), 3);
    for (i, c) in cs.iter().enumerate() {
        for k in 0..3 {
            m[(i, k)] = c.x[k] - mean[k];
        }
    }
    let mut sv: Vec<f64> = m.singular_values().iter().copied().collect();
    sv.sort_by(|a, b| b.total_cmp(a));
    if sv[0] <= 0.0 || sv[1] < 1e-3 * sv[0] {
        return Err(AdjustError::Degenerate(format!(
            "the {} control points are collinear (or coincide); a resection needs three not on a line",
            cs.len()
        )));
    }
    let est = P3p { camera };
    let (mut pose, mut inl) = if cs.len() == 3 {
        // Three points: every P3P solution fits exactly; choose by the approximate pose,
        // else the most nadir-looking camera (aerial photos).
        let refs: Vec<&Corr> = cs.iter().collect();
        let sols = p3p(&refs);
        let score = |p: &Pose| match &opts.approximate {
            Some(a) => {
                rotation_angle(&p.rotation, &a.rotation) + (p.center - a.center).norm() * 1e-3
            }
            None => {
                1.0 + p
                    .rotation
                    .row(2)
                    .transpose()
                    .dot(&Vector3::new(0.0, 0.0, 1.0))
            }
        };
        let best = sols
            .into_iter()
            .min_by(|a, b| score(a).total_cmp(&score(b)))
            .ok_or_else(|| {
                AdjustError::Degenerate("P3P has no solution for the three control points".into())
            })?;
        (best, vec![true; 3])
    } else {
        let ro = RobustOptions {
            threshold: opts.threshold_px,
            confidence: opts.confidence,
            max_iterations: opts.max_iterations,
            min_iterations: 50,
            seed: opts.seed,
        };
        let method = if opts.lmeds {
            RobustMethod::Lmeds
        } else {
            RobustMethod::Ransac
        };
        let r = method
            .estimate(&est, &cs, &ro)
            .map_err(|e| AdjustError::Degenerate(format!("resection: {e}")))?;
        let refined = match opts.lmeds {
            true => None,
            false => median_within_consensus(&est, &cs, &r.inliers, opts),
        };
        refined.unwrap_or((r.model, r.inliers))
    };
    // Refinement with the full camera model and data snooping on the inliers.
    let mut iterations = 0;
    let mut n_mat;
    loop {
        let used = selected(&cs, &inl);
        if used.len() < 3 {
            return Err(AdjustError::TooFewObservations(format!(
                "only {} control points remain after gross-error removal",
                used.len()
            )));
        }
        let (p, n, it) = refine_pose(camera, &pose, &used);
        pose = p;
        n_mat = n;
        iterations += it;
        let red = 2 * used.len() as i64 - 6;
        if red <= 1 {
            break;
        }
        let Some(q) = n.try_inverse() else { break };
        let ssr: f64 = used.iter().map(|c| reprojection_sq(camera, &pose, c)).sum();
        let s0 = (ssr / red as f64).sqrt().max(1e-3 * sigma_px);
        // Largest standardised residual among the inliers (exact hat matrix of 6 unknowns).
        let mut worst: Option<(usize, f64)> = None;
        for (i, c) in cs.iter().enumerate() {
            if !inl[i] {
                continue;
            }
            let Ok((p, j)) = project_with_jacobians(camera, &pose, &c.x) else {
                continue;
            };
            let h: SMatrix<f64, 2, 2> = j.pose * q * j.pose.transpose();
            let v = p.pixel - c.pixel;
            for k in 0..2 {
                let r = (1.0 - h[(k, k)]).max(0.05);
                let w = v[k].abs() / (s0 * r.sqrt());
                if worst.is_none_or(|(_, ww)| w > ww) {
                    worst = Some((i, w));
                }
            }
        }
        match worst {
            Some((i, w)) if w > opts.reject_k && s0 > 1.5 * sigma_px => inl[i] = false,
            _ => break,
        }
    }
    let used = selected(&cs, &inl);
    let ssr: f64 = used.iter().map(|c| reprojection_sq(camera, &pose, c)).sum();
    let red = 2 * used.len() as i64 - 6;
    let sigma0 = if red > 0 {
        (ssr / red as f64).sqrt() / sigma_px
    } else {
        f64::NAN
    };
    let scale = if sigma0.is_finite() {
        sigma0 * sigma0
    } else {
        1.0
    } * sigma_px
        * sigma_px;
    let q = n_mat
        .try_inverse()
        .ok_or_else(|| AdjustError::Singular("resection normal equations".into()))?
        * scale;
    let mut covariance = [[0.0; 6]; 6];
    for (r, row) in covariance.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = q[(r, c)];
        }
    }
    Ok(ResectionResult {
        pose,
        num_inliers: used.len(),
        rmse_px: (ssr / (2 * used.len()) as f64).sqrt(),
        inliers: inl,
        sigma0,
        covariance,
        iterations,
    })
}
