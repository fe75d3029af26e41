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
