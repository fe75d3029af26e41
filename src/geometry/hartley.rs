//! Hartley's normalisation of plane points, so that the design matrices of the linear
//! plane fits (interior orientation, homography, fundamental matrix) are well conditioned.

use nalgebra::{Matrix3, Vector2};

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
