//! The 7-parameter spatial similarity between a model and control coordinates, as a
//! robust estimator: three point pairs are its minimal sample, the residual of a pair is
//! its misfit normalised by the pair's σ per axis (χ²(3)-distributed for a good pair),
//! and the refinement is the weighted closed-form solution on the inliers.

use super::Estimator;
use crate::geometry::Similarity;
use nalgebra::Vector3;

/// A model point, its control coordinates and the σ of their difference per axis in
/// control units (the control's σ and the model point's σ scaled to control units).
/// An infinite σ leaves that axis out of the residual (a 2-D control point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointPair {
    pub model: Vector3<f64>,
    pub control: Vector3<f64>,
    pub sigma: Vector3<f64>,
}

impl PointPair {
    /// Misfit of the pair under `s` in units of its σ, squared and summed over the axes.
    pub fn normalized_sq(&self, s: &Similarity) -> f64 {
        let d = s.apply(&self.model) - self.control;
        (0..3)
            .filter(|&k| self.sigma[k].is_finite())
            .map(|k| (d[k] / self.sigma[k]).powi(2))
            .sum()
    }

    /// Weight of the pair in the closed-form fit: the plan σ, because the closed form
    /// takes one weight per pair (the heights of control with an unknown height must not
    /// enter the fit at all, so such pairs are left out of the sample by the caller).
    fn weight(&self) -> f64 {
        let s = self.sigma.x.min(self.sigma.y);
        if s.is_finite() && s > 0.0 {
            1.0 / (s * s)
        } else {
            0.0
        }
    }
}

/// Samples: [`PointPair`]; residual: the normalised misfit (σ units).
pub struct Similarity3Estimator;

impl Similarity3Estimator {
    /// Weighted least-squares similarity of the given pairs (at least three).
    pub fn fit(pairs: &[&PointPair]) -> Option<Similarity> {
        let src: Vec<Vector3<f64>> = pairs.iter().map(|p| p.model).collect();
        let dst: Vec<Vector3<f64>> = pairs.iter().map(|p| p.control).collect();
        let w: Vec<f64> = pairs.iter().map(|p| p.weight()).collect();
        Similarity::estimate(&src, &dst, Some(&w), true).ok()
    }
}

impl Estimator for Similarity3Estimator {
    type Sample = PointPair;
    type Model = Similarity;
    const MIN_SAMPLES: usize = 3;

    fn fit_minimal(&self, samples: &[&PointPair]) -> Vec<Similarity> {
        Self::fit(samples).into_iter().collect()
    }

    fn residual_sq(&self, m: &Similarity, s: &PointPair) -> f64 {
        s.normalized_sq(m)
    }

    fn refine(&self, _m: &Similarity, inliers: &[&PointPair]) -> Option<Similarity> {
        Self::fit(inliers)
    }
}
