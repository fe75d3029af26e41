//! Patch prediction (seed 001 §2 (1)–(3)): where a control patch will appear in a photo
//! whose orientation is only approximately known, how far to search for it, and how to
//! warp the patch into the photo's geometry through the ground plane so that NCC compares
//! equivalent ground elements.

use crate::geometry::{self, Camera, Dem, GeometryError, Pose, Result};
use nalgebra::{Matrix2, Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

/// Ground footprint of a photo: the image border back-projected onto the DEM, as a
/// closed polygon in world XY (block-local). Rays that miss the DEM (off its extent) are
/// intersected with the horizontal plane at the DEM's mean height instead, so the
/// footprint is always complete.
pub fn footprint(
    camera: &Camera,
    pose: &Pose,
    dem: &Dem,
    samples_per_edge: usize,
) -> Result<Vec<[f64; 2]>> {
    let (w, h) = camera.image_size();
    let (w, h) = (w as f64, h as f64);
    let n = samples_per_edge.max(1);
    let (z0, z1) = dem.z_range();
    let mean_z = 0.5 * (z0 + z1);
    let mut out = Vec::with_capacity(4 * n);
    let border = (0..4).flat_map(|side| {
        (0..n).map(move |i| {
            let t = i as f64 / n as f64;
            match side {
                0 => [t * w, 0.0],
                1 => [w, t * h],
                2 => [w - t * w, h],
                _ => [0.0, h - t * h],
            }
        })
    });
    for px in border {
        let ray = geometry::back_project(camera, pose, px)?;
        let p = match dem.intersect(&ray) {
            Ok(p) => p,
            Err(_) => {
                if ray.direction.z.abs() < 1e-9 {
                    return Err(GeometryError::NoIntersection(
                        "image border ray is horizontal".into(),
                    ));
                }
                let t = (mean_z - ray.origin.z) / ray.direction.z;
                if t <= 0.0 {
                    return Err(GeometryError::NoIntersection(
                        "image border looks above the terrain".into(),
                    ));
                }
                ray.at(t)
            }
        };
        out.push([p.x, p.y]);
    }
    Ok(out)
}

/// Predicted position of an object point in a photo with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    pub pixel: Vector2<f64>,
    /// Covariance of the predicted pixel (px²), propagated from the exterior orientation
    /// and object point covariances through the collinearity equations.
    pub covariance: Matrix2<f64>,
}

impl Prediction {
    /// Half sizes (px) of the axis-aligned search window that holds the `k`-σ error ellipse.
    pub fn search_half_size(&self, k: f64) -> [f64; 2] {
        [
            k * self.covariance[(0, 0)].max(0.0).sqrt(),
            k * self.covariance[(1, 1)].max(0.0).sqrt(),
        ]
    }
}

/// Predicts an object point in a photo. `eo_covariance` is the 6×6 covariance of the
/// exterior orientation in the local parameterisation of [`Pose::perturbed`] (rotation
/// vector in rad, then centre in m); `point_covariance` that of the object point (m²).
pub fn predict(
    camera: &Camera,
    pose: &Pose,
    eo_covariance: &SMatrix<f64, 6, 6>,
    point: &Vector3<f64>,
    point_covariance: &Matrix3<f64>,
) -> Result<Prediction> {
    let (p, j) = geometry::project_with_jacobians(camera, pose, point)?;
    let cov = j.pose * eo_covariance * j.pose.transpose()
        + j.point * point_covariance * j.point.transpose();
    Ok(Prediction {
        pixel: p.pixel,
        covariance: cov,
    })
}

/// EO covariance of a POS of the given quality: σ of the centre (m) and of each attitude
/// angle (rad), uncorrelated.
pub fn pos_covariance(center_sigma_m: f64, attitude_sigma_rad: f64) -> SMatrix<f64, 6, 6> {
    let mut c = SMatrix::<f64, 6, 6>::zeros();
    for i in 0..3 {
        c[(i, i)] = attitude_sigma_rad * attitude_sigma_rad;
        c[(i + 3, i + 3)] = center_sigma_m * center_sigma_m;
    }
    c
}

/// A plane `n·X = d` (unit normal) in block-local coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    pub normal: Vector3<f64>,
    pub d: f64,
}

impl Plane {
    pub fn through(point: &Vector3<f64>, normal: &Vector3<f64>) -> Self {
        let n = normal.normalize();
        Self {
            normal: n,
            d: n.dot(point),
        }
    }

    pub fn intersect(&self, ray: &geometry::Ray) -> Result<Vector3<f64>> {
        let den = self.normal.dot(&ray.direction);
        if den.abs() < 1e-12 {
            return Err(GeometryError::NoIntersection(
                "ray parallel to the patch plane".into(),
            ));
        }
        let t = (self.d - self.normal.dot(&ray.origin)) / den;
        if t <= 0.0 {
            return Err(GeometryError::NoIntersection(
                "patch plane behind the camera".into(),
            ));
        }
        Ok(ray.at(t))
    }
}

/// One side of a patch transfer: a camera and its orientation.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    pub camera: &'a Camera,
    pub pose: &'a Pose,
}

/// Maps pixels of a target photo to pixels of the source photo a control patch was cut
/// from, through the patch's ground plane (exact, distortion included): the "equivalent
/// ground elements" of seed 001 — resampling the source at these positions rotates and
/// rescales the patch into the target's geometry.
pub fn transfer(
    target: View,
    source: View,
    plane: &Plane,
    target_pixel: [f64; 2],
) -> Result<Vector2<f64>> {
    let ray = geometry::back_project(target.camera, target.pose, target_pixel)?;
    let x = plane.intersect(&ray)?;
    Ok(geometry::project(source.camera, source.pose, &x)?.pixel)
}

/// Local affine approximation of [`transfer`] around a target pixel, mapping the offset
/// (dx, dy) from `target_pixel` to a source pixel: `[A | s]·(dx, dy, 1)ᵀ`. Its determinant
/// is the area ratio (source pixels per target pixel), which tells the pyramid level to
/// resample from; it is also the initial affine of least-squares matching.
pub fn transfer_affine(
    target: View,
    source: View,
    plane: &Plane,
    target_pixel: [f64; 2],
) -> Result<Matrix2x3<f64>> {
    let c = transfer(target, source, plane, target_pixel)?;
    let h = 2.0;
    let px = transfer(
        target,
        source,
        plane,
        [target_pixel[0] + h, target_pixel[1]],
    )?;
    let mx = transfer(
        target,
        source,
        plane,
        [target_pixel[0] - h, target_pixel[1]],
    )?;
    let py = transfer(
        target,
        source,
        plane,
        [target_pixel[0], target_pixel[1] + h],
    )?;
    let my = transfer(
        target,
        source,
        plane,
        [target_pixel[0], target_pixel[1] - h],
    )?;
    let dx = (px - mx) / (2.0 * h);
    let dy = (py - my) / (2.0 * h);
    Ok(Matrix2x3::new(dx.x, dy.x, c.x, dx.y, dy.y, c.y))
}

/// Pyramid level of the source image that best matches the target's ground pixel: the
/// source is reduced by 2^level so that one target pixel covers about one source pixel.
pub fn pyramid_level(affine: &Matrix2x3<f64>) -> u32 {
    let scale = affine.fixed_view::<2, 2>(0, 0).determinant().abs().sqrt();
    if scale <= 1.0 {
        0
    } else {
        scale.log2().round().max(0.0) as u32
    }
}
