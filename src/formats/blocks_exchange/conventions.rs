//! BlocksExchange conventions that differ from ours: the camera axes of a photogroup's
//! `<CameraOrientation>`, the Omega/Phi/Kappa rotation form, and the pixel origin.

use nalgebra::Matrix3;

/// `O` of a CameraOrientation: rows map its axes onto ours (x right, y down, z forward).
pub fn camera_orientation_matrix(name: &str) -> Option<Matrix3<f64>> {
    let m = |a: [f64; 9]| Matrix3::from_row_slice(&a);
    Some(match name {
        "XRightYDown" => Matrix3::identity(),
        "XRightYUp" => m([1., 0., 0., 0., -1., 0., 0., 0., -1.]),
        "XLeftYDown" => m([-1., 0., 0., 0., 1., 0., 0., 0., -1.]),
        "XLeftYUp" => m([-1., 0., 0., 0., -1., 0., 0., 0., 1.]),
        "XDownYRight" => m([0., 1., 0., 1., 0., 0., 0., 0., -1.]),
        "XDownYLeft" => m([0., -1., 0., 1., 0., 0., 0., 0., 1.]),
        "XUpYLeft" => m([0., -1., 0., -1., 0., 0., 0., 0., -1.]),
        "XUpYRight" => m([0., 1., 0., -1., 0., 0., 0., 0., 1.]),
        _ => return None,
    })
}

/// BlocksExchange's Omega/Phi/Kappa (degrees): `M = R3(κ)·R2(φ)·R1(ω)` with passive
/// elementary rotations.
pub fn matrix_from_opk_degrees(omega: f64, phi: f64, kappa: f64) -> Matrix3<f64> {
    let (so, co) = omega.to_radians().sin_cos();
    let (sp, cp) = phi.to_radians().sin_cos();
    let (sk, ck) = kappa.to_radians().sin_cos();
    let r1 = Matrix3::new(1.0, 0.0, 0.0, 0.0, co, so, 0.0, -so, co);
    let r2 = Matrix3::new(cp, 0.0, -sp, 0.0, 1.0, 0.0, sp, 0.0, cp);
    let r3 = Matrix3::new(ck, sk, 0.0, -sk, ck, 0.0, 0.0, 0.0, 1.0);
    r3 * r2 * r1
}

/// Offset between BlocksExchange pixel coordinates (origin at the top-left pixel's centre)
/// and ours (origin at its corner).
pub(super) const HALF_PIXEL: f64 = 0.5;
