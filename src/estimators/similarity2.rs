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
