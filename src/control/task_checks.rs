//! Checks of the values a task file brings back (`pipeline::tasks`: a distributed run's
//! per-photo and per-round results, MessagePack written by any process that sees the
//! output folder): numbers finite where the work needs them so, sizes and counts bounded,
//! indices inside what they index. A damaged or crafted file is then an error naming it,
//! never a panic, a runaway allocation or a NaN carried silently into an adjustment.
//! Each check returns what is wrong, naming the field; the reader adds the file.

use crate::geometry::{Camera, Pose};
use nalgebra::{SMatrix, Vector2, Vector3};

/// Every value of `v` finite.
pub fn finite(what: &str, v: &[f64]) -> Result<(), String> {
    match v.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) if v.len() == 1 => Err(format!("{what} = {} is not finite", v[i])),
        Some(i) => Err(format!("{what}[{i}] = {} is not finite", v[i])),
    }
}

/// A σ or other non-negative statistic: finite and ≥ 0, or NaN (unknown).
pub fn sigma(what: &str, v: f64) -> Result<(), String> {
    if v.is_nan() || (v.is_finite() && v >= 0.0) {
        Ok(())
    } else {
        Err(format!(
            "{what} = {v} is neither a non-negative number nor unknown"
        ))
    }
}

/// A pose: rotation and centre finite, the rotation a rotation (orthonormal to 1e-6).
pub fn pose(what: &str, p: &Pose) -> Result<(), String> {
    finite(&format!("{what} rotation"), p.rotation.as_slice())?;
    finite(&format!("{what} centre"), p.center.as_slice())?;
    let off = (p.rotation * p.rotation.transpose() - nalgebra::Matrix3::identity()).amax();
    if off > 1e-6 {
        return Err(format!(
            "{what} rotation is not a rotation (R·Rᵀ differs from I by {off:e})"
        ));
    }
    Ok(())
}

/// A camera within the plausible ranges of formats/cameras/README.md.
pub fn camera(what: &str, c: &Camera) -> Result<(), String> {
    c.validate().map_err(|e| format!("{what}: {e}"))
}

/// An index into `n` things.
pub fn index(what: &str, i: usize, n: usize) -> Result<(), String> {
    if i < n {
        Ok(())
    } else {
        Err(format!("{what} {i} is out of range (there are {n})"))
    }
}

/// A pixel (finite).
pub fn pixel(what: &str, p: &Vector2<f64>) -> Result<(), String> {
    finite(what, p.as_slice())
}

/// A point (finite).
pub fn point(what: &str, p: &Vector3<f64>) -> Result<(), String> {
    finite(what, p.as_slice())
}

/// A 6×6 covariance: finite.
pub fn covariance(what: &str, c: &SMatrix<f64, 6, 6>) -> Result<(), String> {
    finite(what, c.as_slice())
}

/// A count that must not exceed `max` (a statistic summed later).
pub fn at_most(what: &str, v: usize, max: usize) -> Result<(), String> {
    if v <= max {
        Ok(())
    } else {
        Err(format!("{what} = {v}, more than {max}"))
    }
}

/// A chip view: camera, pose, pixel and the chip's place in its photo.
pub fn chip_view(what: &str, v: &super::chips::ChipView) -> Result<(), String> {
    camera(&format!("{what} camera"), &v.camera)?;
    pose(&format!("{what} pose"), &v.pose)?;
    finite(&format!("{what} pixel"), &v.pixel)?;
    let (w, h) = v.camera.image_size();
    if u64::from(v.x0) + u64::from(v.width) > u64::from(w)
        || u64::from(v.y0) + u64::from(v.height) > u64::from(h)
    {
        return Err(format!(
            "{what}: a {}×{} chip at ({}, {}) leaves its {w}×{h} photo",
            v.width, v.height, v.x0, v.y0
        ));
    }
    Ok(())
}

/// A control (or tie) point with its views.
pub fn control_point(what: &str, p: &super::chips::ControlPoint) -> Result<(), String> {
    point(&format!("{what} position"), &p.position)?;
    for s in p.sigma {
        sigma(&format!("{what} σ"), s)?;
    }
    point(&format!("{what} normal"), &p.normal)?;
    for v in &p.views {
        chip_view(&format!("{what} view"), v)?;
    }
    Ok(())
}
