//! Interior orientation of a film scan: the plane transform from scan pixels to the
//! fiducial coordinate system of the camera's calibration certificate (mm).

use super::{check_finite, dlt_null_matrix, hartley_normalisation, GeometryError, Result};
use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InteriorTransformKind {
    /// 6 parameters: scan scale differences, shear, rotation, shift (≥ 3 fiducials).
    Affine,
    /// 8 parameters: adds the projective terms of a tilted scanner platen (≥ 4 fiducials).
    Projective,
}

/// Homogeneous pixel→mm transform and its inverse. For the affine kind the last row is
/// (0, 0, 1).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(from = "InteriorOrientationRepr", into = "InteriorOrientationRepr")]
pub struct InteriorOrientation {
    pub kind: InteriorTransformKind,
    /// 3×3 homogeneous matrix mapping (col, row, 1) in pixels to (x, y, w) in mm; JSON:
    /// three rows.
    pub pixel_to_mm: Matrix3<f64>,
    mm_to_pixel: Option<Matrix3<f64>>,
}

/// Serialised form: the forward matrix only; the inverse is derived on load.
#[derive(Serialize, Deserialize)]
struct InteriorOrientationRepr {
    kind: InteriorTransformKind,
    #[serde(with = "super::serde_matrix::row_major")]
    pixel_to_mm: Matrix3<f64>,
}

impl From<InteriorOrientationRepr> for InteriorOrientation {
    fn from(r: InteriorOrientationRepr) -> Self {
        let inv = r.pixel_to_mm.try_inverse();
        Self {
            kind: r.kind,
            pixel_to_mm: r.pixel_to_mm,
            mm_to_pixel: inv,
        }
    }
}

impl From<InteriorOrientation> for InteriorOrientationRepr {
    fn from(io: InteriorOrientation) -> Self {
        Self {
            kind: io.kind,
            pixel_to_mm: io.pixel_to_mm,
        }
    }
}

impl PartialEq for InteriorOrientation {
    fn eq(&self, other: &Self) -> bool {
        self.kind == other.kind && self.pixel_to_mm == other.pixel_to_mm
    }
}

fn apply_h(h: &Matrix3<f64>, p: Vector2<f64>) -> Vector2<f64> {
    let v = h * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(v.x / v.z, v.y / v.z)
}

impl InteriorOrientation {
    pub fn new(kind: InteriorTransformKind, pixel_to_mm: Matrix3<f64>) -> Result<Self> {
        let mut io = Self {
            kind,
            pixel_to_mm,
            mm_to_pixel: None,
        };
        io.validate()?;
        io.mm_to_pixel = pixel_to_mm.try_inverse();
        Ok(io)
    }

    /// The affine interior orientation x_mm = `a`·pixel + `t`.
    pub fn affine(a: &Matrix2<f64>, t: &Vector2<f64>) -> Result<Self> {
        #[rustfmt::skip]
        let m = Matrix3::new(
            a[(0, 0)], a[(0, 1)], t.x,
            a[(1, 0)], a[(1, 1)], t.y,
            0.0, 0.0, 1.0,
        );
        Self::new(InteriorTransformKind::Affine, m)
    }

    /// Affine transform for a scan whose pixel size is `pixel_mm`, with the fiducial centre
    /// at the scan centre and y up (the ideal scan, for tests and synthetic data).
    pub fn ideal(width: u32, height: u32, pixel_mm: f64) -> Self {
        let m = Matrix3::new(
            pixel_mm,
            0.0,
            -pixel_mm * width as f64 / 2.0,
            0.0,
            -pixel_mm,
            pixel_mm * height as f64 / 2.0,
            0.0,
            0.0,
            1.0,
        );
        Self::new(InteriorTransformKind::Affine, m).expect("ideal interior orientation")
    }

    pub fn validate(&self) -> Result<()> {
        check_finite(self.pixel_to_mm.as_slice(), "interior orientation")?;
        let det = self.pixel_to_mm.determinant();
        if det.abs() < 1e-18 {
            return Err(GeometryError::InvalidCamera(
                "interior orientation transform is singular".into(),
            ));
        }
        if self.kind == InteriorTransformKind::Affine {
            let r = self.pixel_to_mm.row(2);
            if r[0] != 0.0 || r[1] != 0.0 || r[2] != 1.0 {
                return Err(GeometryError::InvalidCamera(
                    "affine interior orientation must have last row (0, 0, 1)".into(),
                ));
            }
        }
        Ok(())
    }

    fn inverse(&self) -> Matrix3<f64> {
        self.mm_to_pixel
            .or_else(|| self.pixel_to_mm.try_inverse())
            .unwrap_or_else(Matrix3::identity)
    }

    pub fn pixel_to_mm(&self, p: Vector2<f64>) -> Vector2<f64> {
        apply_h(&self.pixel_to_mm, p)
    }

    pub fn mm_to_pixel(&self, mm: Vector2<f64>) -> Vector2<f64> {
        apply_h(&self.inverse(), mm)
    }

    /// Pixel of a fiducial-system point and ∂pixel/∂mm.
    pub fn mm_to_pixel_with_jacobian(&self, mm: Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let h = self.inverse();
        let v = h * Vector3::new(mm.x, mm.y, 1.0);
        let iw = 1.0 / v.z;
        let p = Vector2::new(v.x * iw, v.y * iw);
        let j = Matrix2::new(
            (h[(0, 0)] - p.x * h[(2, 0)]) * iw,
            (h[(0, 1)] - p.x * h[(2, 1)]) * iw,
            (h[(1, 0)] - p.y * h[(2, 0)]) * iw,
            (h[(1, 1)] - p.y * h[(2, 1)]) * iw,
        );
        (p, j)
    }

    /// Mean scan pixel size in mm (square root of the Jacobian determinant at the centre).
    pub fn mean_pixel_size_mm(&self) -> f64 {
        let a = self.pixel_to_mm.fixed_view::<2, 2>(0, 0);
        (a[(0, 0)] * a[(1, 1)] - a[(0, 1)] * a[(1, 0)]).abs().sqrt()
    }

    /// Least-squares estimate from fiducial marks measured in pixels and their calibrated
    /// coordinates in mm. Returns the transform and each mark's residual in µm (mm-space,
    /// calibrated minus transformed).
    pub fn estimate(
        kind: InteriorTransformKind,
        pixels: &[[f64; 2]],
        mm: &[[f64; 2]],
    ) -> Result<(Self, Vec<[f64; 2]>)> {
        if pixels.len() != mm.len() {
            return Err(GeometryError::InvalidArgument(format!(
                "{} pixel positions but {} calibrated fiducials",
                pixels.len(),
                mm.len()
            )));
        }
        let need = match kind {
            InteriorTransformKind::Affine => 3,
            InteriorTransformKind::Projective => 4,
        };
        if pixels.len() < need {
            return Err(GeometryError::Degenerate(format!(
                "{kind:?} interior orientation needs at least {need} fiducials, got {}",
                pixels.len()
            )));
        }
        for (p, m) in pixels.iter().zip(mm) {
            check_finite(p, "fiducial pixel position")?;
            check_finite(m, "fiducial calibrated coordinate")?;
        }
        // Normalise both point sets (Hartley) so the design matrix is well conditioned.
        let (tp, np) = hartley_normalisation(pixels);
        let (tm, nm) = hartley_normalisation(mm);
        let n = pixels.len();
        let h_norm = match kind {
            InteriorTransformKind::Affine => {
                let mut a = DMatrix::<f64>::zeros(2 * n, 6);
                let mut b = DVector::<f64>::zeros(2 * n);
                for i in 0..n {
                    let (p, m) = (np[i], nm[i]);
                    a.row_mut(2 * i)
                        .copy_from_slice(&[p.x, p.y, 1.0, 0.0, 0.0, 0.0]);
                    a.row_mut(2 * i + 1)
                        .copy_from_slice(&[0.0, 0.0, 0.0, p.x, p.y, 1.0]);
                    b[2 * i] = m.x;
                    b[2 * i + 1] = m.y;
                }
                let svd = a.svd(true, true);
                let x = svd
                    .solve(&b, 1e-12)
                    .map_err(|e| GeometryError::Degenerate(format!("fiducial geometry: {e}")))?;
                if svd.singular_values.min() < 1e-9 * svd.singular_values.max() {
                    return Err(GeometryError::Degenerate("fiducials are collinear".into()));
                }
                Matrix3::new(x[0], x[1], x[2], x[3], x[4], x[5], 0.0, 0.0, 1.0)
            }
            InteriorTransformKind::Projective => {
                // DLT: nullspace of the 2n×9 system.
                let mut a = DMatrix::<f64>::zeros((2 * n).max(9), 9);
                for i in 0..n {
                    let (p, m) = (np[i], nm[i]);
                    a.row_mut(2 * i).copy_from_slice(&[
                        p.x,
                        p.y,
                        1.0,
                        0.0,
                        0.0,
                        0.0,
                        -m.x * p.x,
                        -m.x * p.y,
                        -m.x,
                    ]);
                    a.row_mut(2 * i + 1).copy_from_slice(&[
                        0.0,
                        0.0,
                        0.0,
                        p.x,
                        p.y,
                        1.0,
                        -m.y * p.x,
                        -m.y * p.y,
                        -m.y,
                    ]);
                }
                dlt_null_matrix(a).ok_or_else(|| GeometryError::Degenerate("DLT SVD".into()))?
            }
        };
        let tm_inv = tm
            .try_inverse()
            .ok_or_else(|| GeometryError::Degenerate("fiducials coincide".into()))?;
        let mut h = tm_inv * h_norm * tp;
        h /= h[(2, 2)];
        if kind == InteriorTransformKind::Affine {
            h[(2, 0)] = 0.0;
            h[(2, 1)] = 0.0;
            h[(2, 2)] = 1.0;
        }
        let io = Self::new(kind, h)?;
        let residuals_um = pixels
            .iter()
            .zip(mm)
            .map(|(p, m)| {
                let t = io.pixel_to_mm(Vector2::new(p[0], p[1]));
                [(m[0] - t.x) * 1000.0, (m[1] - t.y) * 1000.0]
            })
            .collect();
        Ok((io, residuals_um))
    }
}
