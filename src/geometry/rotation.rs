//! Rotation conventions. Internally every rotation is a world→camera matrix in the
//! x-right/y-down/z-forward camera frame; the other conventions exist at the boundaries.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// The axis flip between the classic photogrammetric image frame (x right, y up, z towards
/// the viewer) and ours (x right, y down, z forward).
fn flip_yz() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// Skew-symmetric matrix `[v]×` with `[v]× w = v × w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation matrix of a rotation vector (axis × angle), by Rodrigues' formula.
pub fn rotation_from_vector(v: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = v.norm_squared();
    let k = skew(v);
    if theta2 < 1e-16 {
        // Second-order Taylor expansion keeps the map smooth for the Jacobian tests.
        return Matrix3::identity() + k + 0.5 * k * k;
    }
    let theta = theta2.sqrt();
    Matrix3::identity() + (theta.sin() / theta) * k + ((1.0 - theta.cos()) / theta2) * k * k
}

/// Nearest rotation matrix (polar decomposition through the SVD).
pub fn orthonormalize(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let u = svd.u.expect("svd u");
    let vt = svd.v_t.expect("svd vt");
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    u * d * vt
}

/// World→camera rotation from photogrammetric omega, phi, kappa (radians).
///
/// `M = R3(κ)·R2(φ)·R1(ω)` with passive (coordinate-frame) rotations is the classic
/// photogrammetric matrix for an image frame with y up and z towards the viewer; our
/// camera frame has y down and z forward, so `R = diag(1,−1,−1)·M`. A nadir photo with
/// image x pointing east has ω = φ = κ = 0.
pub fn matrix_from_opk(omega: f64, phi: f64, kappa: f64) -> Matrix3<f64> {
    let (so, co) = omega.sin_cos();
    let (sp, cp) = phi.sin_cos();
    let (sk, ck) = kappa.sin_cos();
    let r1 = Matrix3::new(1.0, 0.0, 0.0, 0.0, co, so, 0.0, -so, co);
    let r2 = Matrix3::new(cp, 0.0, -sp, 0.0, 1.0, 0.0, sp, 0.0, cp);
    let r3 = Matrix3::new(ck, sk, 0.0, -sk, ck, 0.0, 0.0, 0.0, 1.0);
    flip_yz() * r3 * r2 * r1
}

/// Inverse of [`matrix_from_opk`]; phi in [−π/2, π/2]. At phi = ±π/2 (gimbal lock) omega
/// is set to zero and kappa absorbs the rotation.
pub fn opk_from_matrix(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let m = flip_yz() * r;
    // M = R3 R2 R1 gives m31 = sin φ, m32 = −sin ω cos φ, m33 = cos ω cos φ,
    // m21 = −cos φ sin κ, m11 = cos φ cos κ.
    let sp = m[(2, 0)].clamp(-1.0, 1.0);
    let phi = sp.asin();
    if sp.abs() < 1.0 - 1e-12 {
        let omega = (-m[(2, 1)]).atan2(m[(2, 2)]);
        let kappa = (-m[(1, 0)]).atan2(m[(0, 0)]);
        (omega, phi, kappa)
    } else {
        // With ω = 0: m12 = sin κ, m22 = cos κ.
        let kappa = m[(0, 1)].atan2(m[(1, 1)]);
        (0.0, phi, kappa)
    }
}

/// Body→camera mounting of a nadir camera: image x along the right wing, image top
/// towards the nose (image y down = towards the tail), optical axis down.
fn camera_from_body() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
}

/// North-east-down from the projected east-north-up world frame (grid north; meridian
/// convergence is the caller's business).
fn ned_from_enu() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

/// World→camera rotation from navigation yaw (heading, clockwise from grid north), pitch
/// (nose up) and roll (right wing down), radians, for a nadir camera mounted as in
/// [`camera_from_body`]. Body→NED is `Rz(yaw)·Ry(pitch)·Rx(roll)` (aerospace sequence).
pub fn matrix_from_ypr(yaw: f64, pitch: f64, roll: f64) -> Matrix3<f64> {
    let c_nb = UnitQuaternion::from_euler_angles(roll, pitch, yaw).to_rotation_matrix();
    camera_from_body() * c_nb.matrix().transpose() * ned_from_enu()
}

/// Inverse of [`matrix_from_ypr`].
pub fn ypr_from_matrix(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let c_nb_t = camera_from_body().transpose() * r * ned_from_enu().transpose();
    let c_nb = c_nb_t.transpose();
    // c_nb = Rz(y)Ry(p)Rx(r): c31 = −sin p, c32 = cos p sin r, c33 = cos p cos r,
    // c21 = cos p sin y, c11 = cos p cos y.
    let sp = (-c_nb[(2, 0)]).clamp(-1.0, 1.0);
    let pitch = sp.asin();
    if sp.abs() < 1.0 - 1e-12 {
        let roll = c_nb[(2, 1)].atan2(c_nb[(2, 2)]);
        let yaw = c_nb[(1, 0)].atan2(c_nb[(0, 0)]);
        (yaw, pitch, roll)
    } else {
        let yaw = (-c_nb[(0, 1)]).atan2(c_nb[(1, 1)]);
        (yaw, pitch, 0.0)
    }
}

/// Rotation matrix from a unit quaternion stored w first (COLMAP's QW QX QY QZ, Hamilton).
pub fn matrix_from_quaternion_wxyz(q: [f64; 4]) -> Matrix3<f64> {
    let uq = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
    *uq.to_rotation_matrix().matrix()
}

/// Unit quaternion, w first, with w ≥ 0 (COLMAP writes either sign; we pick one so that
/// round trips are exact).
pub fn quaternion_wxyz_from_matrix(r: &Matrix3<f64>) -> [f64; 4] {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(*r);
    let q = UnitQuaternion::from_rotation_matrix(&rot);
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    if w < 0.0 {
        [-w, -x, -y, -z]
    } else {
        [w, x, y, z]
    }
}
