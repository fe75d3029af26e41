//! 7-parameter similarity (Helmert) transforms: closed-form estimation (Umeyama) and their
//! application to points and exterior orientations.

use super::{check_finite, GeometryError, Pose, Result};
use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::{Deserialize, Serialize};

/// `X' = s·R·X + t`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Similarity {
    pub scale: f64,
    /// JSON: three rows.
    #[serde(with = "super::serde_matrix::row_major")]
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl Default for Similarity {
    fn default() -> Self {
        Self::identity()
    }
}

impl Similarity {
    pub fn identity() -> Self {
        Self {
            scale: 1.0,
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    pub fn new(scale: f64, rotation: Matrix3<f64>, translation: Vector3<f64>) -> Self {
        Self {
            scale,
            rotation,
            translation,
        }
    }

    #[inline]
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * x) + self.translation
    }

    /// Moves a photo with the object space: `C' = sR_mC + t`, `R' = R·R_mᵀ`.
    pub fn apply_pose(&self, pose: &Pose) -> Pose {
        Pose::new(
            pose.rotation * self.rotation.transpose(),
            self.apply(&pose.center),
        )
    }

    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        let s = 1.0 / self.scale;
        Self {
            scale: s,
            rotation: rt,
            translation: -s * (rt * self.translation),
        }
    }

    /// `self ∘ other` (apply `other` first).
    pub fn compose(&self, other: &Similarity) -> Self {
        Self {
            scale: self.scale * other.scale,
            rotation: self.rotation * other.rotation,
            translation: self.scale * (self.rotation * other.translation) + self.translation,
        }
    }

    /// Homogeneous 4×4 matrix.
    pub fn to_matrix4(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(self.scale * self.rotation));
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// Decomposes a homogeneous similarity matrix.
    pub fn from_matrix4(m: &Matrix4<f64>) -> Result<Self> {
        check_finite(m.as_slice(), "similarity matrix")?;
        let a = m.fixed_view::<3, 3>(0, 0).into_owned();
        let det = a.determinant();
        if det <= 0.0 {
            return Err(GeometryError::InvalidArgument(
                "similarity matrix has a non-positive determinant".into(),
            ));
        }
        let s = det.cbrt();
        Ok(Self {
            scale: s,
            rotation: super::orthonormalize(&(a / s)),
            translation: m.fixed_view::<3, 1>(0, 3).into_owned(),
        })
    }

    /// Least-squares similarity mapping `src` onto `dst` in closed form (Umeyama 1991),
    /// with optional weights. With `with_scale = false` the scale is held at 1 (rigid).
    pub fn estimate(
        src: &[Vector3<f64>],
        dst: &[Vector3<f64>],
        weights: Option<&[f64]>,
        with_scale: bool,
    ) -> Result<Self> {
        let n = src.len();
        if n != dst.len() {
            return Err(GeometryError::InvalidArgument(format!(
                "{n} source points but {} target points",
                dst.len()
            )));
        }
        if n < 3 {
            return Err(GeometryError::Degenerate(format!(
                "a similarity needs at least 3 point pairs, got {n}"
            )));
        }
        if let Some(w) = weights {
            if w.len() != n {
                return Err(GeometryError::InvalidArgument(format!(
                    "{} weights for {n} point pairs",
                    w.len()
                )));
            }
            check_finite(w, "weights")?;
        }
        for (a, b) in src.iter().zip(dst) {
            check_finite(a.as_slice(), "source point")?;
            check_finite(b.as_slice(), "target point")?;
        }
        let w = |i: usize| weights.map_or(1.0, |w| w[i]);
        let wsum: f64 = (0..n).map(w).sum();
        if wsum <= 0.0 {
            return Err(GeometryError::Degenerate("weights sum to zero".into()));
        }
        let mu_s = (0..n).fold(Vector3::zeros(), |a, i| a + src[i] * w(i)) / wsum;
        let mu_d = (0..n).fold(Vector3::zeros(), |a, i| a + dst[i] * w(i)) / wsum;
        let mut cov = Matrix3::zeros();
        let mut var_s = 0.0;
        for i in 0..n {
            let ds = src[i] - mu_s;
            let dd = dst[i] - mu_d;
            cov += w(i) * dd * ds.transpose();
            var_s += w(i) * ds.norm_squared();
        }
        cov /= wsum;
        var_s /= wsum;
        if var_s <= 0.0 {
            return Err(GeometryError::Degenerate("source points coincide".into()));
        }
        let svd = cov.svd(true, true);
        let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("vt"));
        let sv = svd.singular_values;
        let mut sorted = [sv[0], sv[1], sv[2]];
        sorted.sort_by(|a, b| b.total_cmp(a));
        if sorted[1] <= 1e-12 * sorted[0] {
            return Err(GeometryError::Degenerate(
                "point pairs are collinear".into(),
            ));
        }
        let mut d = Vector3::new(1.0, 1.0, 1.0);
        if (u * vt).determinant() < 0.0 {
            // Reflection: flip the axis of the smallest singular value.
            let imin = (0..3).min_by(|&a, &b| sv[a].total_cmp(&sv[b])).expect("3");
            d[imin] = -1.0;
        }
        let r = u * Matrix3::from_diagonal(&d) * vt;
        let s = if with_scale { sv.dot(&d) / var_s } else { 1.0 };
        let t = mu_d - s * (r * mu_s);
        Ok(Self {
            scale: s,
            rotation: r,
            translation: t,
        })
    }
}
