//! The normalised direct linear transform of the plane fits (projective interior
//! orientation, homography, fundamental matrix): Hartley's normalisation, so that the
//! design matrices are well conditioned, and the 3×3 matrix from their null vector.

use nalgebra::{DMatrix, Matrix3, Vector2};

/// Similarity that moves the centroid to the origin and scales the mean distance to √2,
/// and the points it maps to. Coincident points are only shifted.
pub(crate) fn hartley_normalisation(pts: &[[f64; 2]]) -> (Matrix3<f64>, Vec<Vector2<f64>>) {
    let n = pts.len() as f64;
    let c = pts
        .iter()
        .fold(Vector2::zeros(), |a, p| a + Vector2::new(p[0], p[1]))
        / n;
    let d = pts
        .iter()
        .map(|p| (Vector2::new(p[0], p[1]) - c).norm())
        .sum::<f64>()
        / n;
    let s = if d > 0.0 {
        std::f64::consts::SQRT_2 / d
    } else {
        1.0
    };
    let t = Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0);
    let out = pts
        .iter()
        .map(|p| (Vector2::new(p[0], p[1]) - c) * s)
        .collect();
    (t, out)
}

/// The 3×3 matrix (row-major) of the right singular vector of the smallest singular value
/// of a DLT design matrix with nine columns; `None` when the SVD fails.
pub(crate) fn dlt_null_matrix(design: DMatrix<f64>) -> Option<Matrix3<f64>> {
    let svd = design.svd(false, true);
    let vt = svd.v_t?;
    let (imin, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = vt.row(imin);
    Some(Matrix3::new(
        h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8],
    ))
}
