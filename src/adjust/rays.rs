//! Robust intersection of one object point from its rays: which image measurements of a
//! control point agree with each other, and where they meet. Two rays are the minimal
//! sample; a ray's residual is its reprojection error in units of its σ, so a good ray's
//! squared residual is χ²(2)-distributed and the inlier threshold is a test level, not a
//! number of pixels chosen for one block.

use super::precision::intersect;
use crate::estimators::{Estimator, RobustMethod, RobustOptions};
use crate::geometry::{project, Camera, Pose};
use nalgebra::{Matrix3, Vector2, Vector3};

/// One image measurement of the point: the photo's camera and exterior orientation, the
/// measured pixel and its σ (px).
#[derive(Debug, Clone, Copy)]
pub struct Ray<'a> {
    pub camera: &'a Camera,
    pub pose: Pose,
    pub pixel: [f64; 2],
    pub sigma_px: f64,
}

impl Ray<'_> {
    /// Reprojection error of `x` (px); infinite behind the camera.
    pub fn residual_px(&self, x: &Vector3<f64>) -> f64 {
        project(self.camera, &self.pose, x)
            .map(|p| (p.pixel - Vector2::new(self.pixel[0], self.pixel[1])).norm())
            .unwrap_or(f64::INFINITY)
    }

    fn as_tuple(&self) -> (&Camera, &Pose, [f64; 2], f64) {
        (self.camera, &self.pose, self.pixel, self.sigma_px)
    }
}

/// Least-squares intersection of the rays (at least two, not parallel).
pub fn intersect_rays(rays: &[&Ray<'_>]) -> Option<Vector3<f64>> {
    let t: Vec<_> = rays.iter().map(|r| r.as_tuple()).collect();
    intersect(&t)
}

/// Cofactor matrix of an intersected point (σ² of unit weight 1, the rays' own σ):
/// the inverse of the point's normal matrix.
pub fn intersection_cofactor(rays: &[&Ray<'_>], x: &Vector3<f64>) -> Option<Matrix3<f64>> {
    let mut n = Matrix3::zeros();
    for r in rays {
        let (_, j) = crate::geometry::project_with_jacobians(r.camera, &r.pose, x).ok()?;
        let jx = j.point / r.sigma_px;
        n += jx.transpose() * jx;
    }
    n.try_inverse()
}

struct RayIntersection<'a>(std::marker::PhantomData<&'a ()>);

impl<'a> Estimator for RayIntersection<'a> {
    type Sample = Ray<'a>;
    type Model = Vector3<f64>;
    const MIN_SAMPLES: usize = 2;

    fn fit_minimal(&self, samples: &[&Ray<'a>]) -> Vec<Vector3<f64>> {
        intersect_rays(samples).into_iter().collect()
    }

    fn residual_sq(&self, x: &Vector3<f64>, r: &Ray<'a>) -> f64 {
        (r.residual_px(x) / r.sigma_px).powi(2)
    }

    fn refine(&self, _x: &Vector3<f64>, inliers: &[&Ray<'a>]) -> Option<Vector3<f64>> {
        intersect_rays(inliers)
    }
}

/// The consensus of a point's rays.
#[derive(Debug, Clone)]
pub struct RobustIntersection {
    pub position: Vector3<f64>,
    /// Per ray: agrees with the consensus.
    pub inliers: Vec<bool>,
    /// Per ray: reprojection error of the consensus position (px).
    pub residuals_px: Vec<f64>,
}

/// Intersects `rays` robustly: the largest set of rays that meet within the test level
/// `critical` (a bound on the normalised residual, e.g. √χ²₂(0.999) = 3.72). `None`
/// when fewer than two rays agree (a two-ray point whose rays miss each other has no
/// consensus: which one is wrong is decided against the control afterwards).
pub fn intersect_robust(rays: &[Ray<'_>], critical: f64, seed: u64) -> Option<RobustIntersection> {
    if rays.len() < 2 {
        return None;
    }
    let opts = RobustOptions {
        threshold: critical,
        // A control point has a few dozen rays at most: every pair can be tried.
        min_iterations: (rays.len() * (rays.len() - 1) / 2).min(1000),
        seed,
        ..RobustOptions::default()
    };
    let r = RobustMethod::Ransac
        .estimate(&RayIntersection(std::marker::PhantomData), rays, &opts)
        .ok()?;
    if r.num_inliers < 2 {
        return None;
    }
    let residuals_px = rays.iter().map(|ray| ray.residual_px(&r.model)).collect();
    Some(RobustIntersection {
        position: r.model,
        inliers: r.inliers,
        residuals_px,
    })
}

/// A measurement of a point that data snooping rejected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RejectedRay {
    /// Index into the rays given.
    pub index: usize,
    /// Its reprojection error at the intersection of the rays kept (px).
    pub residual_px: f64,
    /// Its test statistic: how much the rays' sum of squared normalised residuals falls
    /// when it is left out (χ²(2) under the hypothesis that it is good).
    pub statistic: f64,
}

/// The intersection of a point's rays after data snooping.
#[derive(Debug, Clone, PartialEq)]
pub struct SnoopedIntersection {
    /// None when the rays kept do not determine a point (fewer than two), or when the
    /// rays disagree in a way no test can localise (two rays that miss each other; three
    /// along one base line): then no ray can be trusted and the point is not evaluated.
    pub position: Option<Vector3<f64>>,
    /// Indices of the rays the position is intersected from.
    pub kept: Vec<usize>,
    pub rejected: Vec<RejectedRay>,
    /// The rays' sum of squared normalised residuals at the position, and its degrees of
    /// freedom (2 per ray − 3).
    pub ssr: f64,
    pub dof: usize,
}

/// Intersects a point from its rays with the orientations held, testing the rays as the
/// adjustment tests tie points and control measurements (Baarda data snooping at level
/// `alpha`, `f2` the variance factor of the rays' σ): while the rays' sum of squared
/// normalised residuals fails its χ² test, the ray whose removal lowers it most is
/// rejected — when that drop passes the χ²(2) test of one blundered ray and the rest then
/// agree better than with any other ray left out — and the rest are intersected again.
/// With two rays a disagreement cannot be localised: the point gets no position; nor does
/// a point left with two rays after a rejection.
///
/// This is what a checkpoint deserves before its error is believed: one ray measured in
/// the wrong place otherwise moves the intersection by metres and reads as an orientation
/// error.
pub fn intersect_snooped(rays: &[Ray<'_>], f2: f64, alpha: f64) -> SnoopedIntersection {
    let ssr_at = |idx: &[usize], x: &Vector3<f64>| -> f64 {
        idx.iter()
            .map(|&i| (rays[i].residual_px(x) / rays[i].sigma_px).powi(2))
            .sum::<f64>()
            / f2
    };
    let solve = |idx: &[usize]| -> Option<(Vector3<f64>, f64)> {
        let r: Vec<&Ray<'_>> = idx.iter().map(|&i| &rays[i]).collect();
        let x = intersect_rays(&r)?;
        let s = ssr_at(idx, &x);
        s.is_finite().then_some((x, s))
    };
    let mut kept: Vec<usize> = (0..rays.len()).collect();
    let mut rejected = Vec::new();
    let unresolved = |kept: Vec<usize>, rejected: Vec<RejectedRay>, ssr: f64| {
        let dof = (2 * kept.len()).saturating_sub(3);
        SnoopedIntersection {
            position: None,
            kept,
            rejected,
            ssr,
            dof,
        }
    };
    loop {
        let Some((x, ssr)) = solve(&kept) else {
            return unresolved(kept, rejected, f64::NAN);
        };
        let dof = 2 * kept.len() - 3;
        if ssr <= super::chi2::critical(dof, alpha) {
            return SnoopedIntersection {
                position: Some(x),
                kept,
                rejected,
                ssr,
                dof,
            };
        }
        if kept.len() < 3 {
            return unresolved(kept, rejected, ssr);
        }
        // Leave each ray out in turn; the blunder is the ray whose absence explains most.
        let mut loo: Vec<(f64, usize)> = kept
            .iter()
            .map(|&skip| {
                let others: Vec<usize> = kept.iter().copied().filter(|&i| i != skip).collect();
                (solve(&others).map_or(f64::INFINITY, |(_, s)| s), skip)
            })
            .collect();
        loo.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (best_ssr, worst_ray) = loo[0];
        let drop = ssr - best_ssr;
        // Three rays along one base line share one redundant component: leaving out any
        // of them leaves a consistent pair, and which one is wrong cannot be told.
        let ambiguous = kept.len() == 3 && loo[1].0 <= super::chi2::critical(1, alpha);
        // A NaN drop (rays that cannot be solved without one) is not a localised blunder.
        let localised = drop > super::chi2::critical(2, alpha);
        if !localised || ambiguous {
            return unresolved(kept, rejected, ssr);
        }
        kept.retain(|&i| i != worst_ray);
        let x_rest = solve(&kept).map(|(x, _)| x);
        rejected.push(RejectedRay {
            index: worst_ray,
            residual_px: x_rest.map_or(f64::NAN, |x| rays[worst_ray].residual_px(&x)),
            statistic: drop,
        });
        // Two rays left check each other across the base only: a second gross error
        // along it (x-parallax) would pass and move the height by metres. A point that
        // has shown one gross error is kept only while three rays confirm the rest.
        if kept.len() < 3 {
            let ssr = solve(&kept).map_or(f64::NAN, |(_, s)| s);
            return unresolved(kept, rejected, ssr);
        }
    }
}
