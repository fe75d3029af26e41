//! A 2-D similarity (scale, rotation, shift) between two sets of image positions, as an
//! [`Estimator`]: two correspondences fix it. It aligns the predicted positions of a
//! photo's control patches with their candidate matches when the approximate orientation
//! is rough: over a few hundred pixels, the error of a navigation pose is close to a
//! shift, a swing and a scale of the whole photo.

use super::Estimator;
use nalgebra::{Matrix4, Vector2, Vector4};

/// `to = [a −b; b a]·from + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity2 {
    pub a: f64,
    pub b: f64,
    pub t: Vector2<f64>,
}

impl Similarity2 {
    pub fn apply(&self, p: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.a * p.x - self.b * p.y + self.t.x,
            self.b * p.x + self.a * p.y + self.t.y,
        )
    }

    /// `self ∘ first`: `first` applied, then `self`.
    pub fn after(&self, first: &Similarity2) -> Similarity2 {
        Similarity2 {
            a: self.a * first.a - self.b * first.b,
            b: self.b * first.a + self.a * first.b,
            t: self.apply(&first.t),
        }
    }

    /// Scale factor of the similarity.
    pub fn scale(&self) -> f64 {
        self.a.hypot(self.b)
    }

    /// Least squares over the pairs (`None` with fewer than two distinct points).
    pub fn fit(pairs: &[&(Vector2<f64>, Vector2<f64>)]) -> Option<Self> {
        // Unknowns (a, b, tx, ty): x' = a·x − b·y + tx, y' = b·x + a·y + ty.
        let mut n = Matrix4::<f64>::zeros();
        let mut r = Vector4::<f64>::zeros();
        for (f, t) in pairs {
            for (row, obs) in [
                (Vector4::new(f.x, -f.y, 1.0, 0.0), t.x),
                (Vector4::new(f.y, f.x, 0.0, 1.0), t.y),
            ] {
                n += row * row.transpose();
                r += row * obs;
            }
        }
        let x = n.try_inverse()? * r;
        x.iter().all(|v| v.is_finite()).then(|| Self {
            a: x[0],
            b: x[1],
            t: Vector2::new(x[2], x[3]),
        })
    }
}

/// Samples: (predicted position, candidate match) in pixels; residuals in pixels.
pub struct Similarity2Estimator;

impl Estimator for Similarity2Estimator {
    type Sample = (Vector2<f64>, Vector2<f64>);
    type Model = Similarity2;
    const MIN_SAMPLES: usize = 2;

    fn fit_minimal(&self, samples: &[&Self::Sample]) -> Vec<Similarity2> {
        if (samples[0].0 - samples[1].0).norm() < 1.0 {
            return Vec::new();
        }
        Similarity2::fit(samples).into_iter().collect()
    }

    fn residual_sq(&self, m: &Similarity2, s: &Self::Sample) -> f64 {
        (m.apply(&s.0) - s.1).norm_squared()
    }

    fn refine(&self, _m: &Similarity2, inliers: &[&Self::Sample]) -> Option<Similarity2> {
        Similarity2::fit(inliers)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::{RobustMethod, RobustOptions};

    #[test]
    fn finds_the_alignment_among_wrong_candidates() {
        let truth = Similarity2 {
            a: 1.03 * 0.1f64.cos(),
            b: 1.03 * 0.1f64.sin(),
            t: Vector2::new(-60.0, 140.0),
        };
        let mut samples = Vec::new();
        // Seven right candidates (±1 px), thirteen wrong ones spread over the photo.
        for i in 0..20 {
            let p = Vector2::new(
                50.0 + 47.0 * (i as f64 * 1.7).sin().abs() * 18.0,
                40.0 + 31.0 * (i as f64 * 0.9).cos().abs() * 18.0,
            );
            let q = if i % 3 == 0 {
                truth.apply(&p) + Vector2::new((i as f64).sin(), (i as f64).cos())
            } else {
                Vector2::new((i * 373 % 1000) as f64, (i * 211 % 660) as f64)
            };
            samples.push((p, q));
        }
        let r = RobustMethod::Ransac
            .estimate(
                &Similarity2Estimator,
                &samples,
                &RobustOptions {
                    threshold: 5.0,
                    ..RobustOptions::default()
                },
            )
            .unwrap();
        assert_eq!(r.num_inliers, 7, "{:?}", r.inliers);
        assert!((r.model.scale() - 1.03).abs() < 0.01);
        assert!((r.model.t - truth.t).norm() < 5.0);
        let p = Vector2::new(310.0, -42.0);
        let composed = truth.after(&r.model).apply(&p);
        assert!((composed - truth.apply(&r.model.apply(&p))).norm() < 1e-9);
    }
}
