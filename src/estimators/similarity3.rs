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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::{RobustMethod, RobustOptions};
    use crate::geometry::rotation_from_vector;

    #[test]
    fn finds_the_similarity_among_displaced_control() {
        let truth = Similarity {
            scale: 37.5,
            rotation: rotation_from_vector(&Vector3::new(0.1, -0.3, 2.0)),
            translation: Vector3::new(500.0, -200.0, 30.0),
        };
        let mut pairs = Vec::new();
        for i in 0..12 {
            let m = Vector3::new(
                (i as f64 * 1.3).sin() * 4.0,
                (i as f64 * 0.7).cos() * 3.0,
                0.2 * (i as f64).sin(),
            );
            let mut c = truth.apply(&m);
            // Four of twelve control points displaced by 2–8 m.
            if i % 3 == 0 {
                c += Vector3::new(2.0 + i as f64 * 0.5, -1.0, 1.5);
            }
            pairs.push(PointPair {
                model: m,
                control: c,
                sigma: Vector3::new(0.05, 0.05, 0.08),
            });
        }
        let r = RobustMethod::Ransac
            .estimate(
                &Similarity3Estimator,
                &pairs,
                &RobustOptions {
                    threshold: 16.27f64.sqrt(),
                    ..RobustOptions::default()
                },
            )
            .unwrap();
        let bad: Vec<usize> = (0..12).filter(|i| !r.inliers[*i]).collect();
        assert_eq!(bad, vec![0, 3, 6, 9]);
        assert!((r.model.scale - 37.5).abs() < 1e-6);
        assert!((r.model.translation - truth.translation).norm() < 1e-4);
    }
}
