//! Approximate exterior orientation of archive photos without POS (seed 000): each strip's
//! first and last projection centres are known (e.g. from a flight map); the centres in
//! between are interpolated, kappa follows the strip direction, the photos are taken as
//! nadir, and the uncertainty is stated so that patch prediction can size its windows.

use crate::block::PosPrior;
pub use crate::formats::pos::{FlightAxis, StripEnds};
use crate::geometry::{matrix_from_opk, GeometryError, Pose};
use nalgebra::Vector3;

/// Kappa of a nadir photo whose `axis` points along the horizontal direction `d`.
///
/// With `R = diag(1,−1,−1)·R3(κ)` the camera x axis (row 0 of R) lies along (cos κ, sin κ)
/// and the camera y axis (row 1) along (sin κ, −cos κ) on the ground.
pub fn kappa_from_direction(d: [f64; 2], axis: FlightAxis) -> f64 {
    match axis {
        FlightAxis::PlusX => d[1].atan2(d[0]),
        FlightAxis::MinusX => (-d[1]).atan2(-d[0]),
        FlightAxis::PlusY => d[0].atan2(-d[1]),
        FlightAxis::MinusY => (-d[0]).atan2(d[1]),
    }
}

/// Interpolated approximate orientation and its prior for every photo of a strip.
///
/// Photos of a strip are exposed at nearly equal air base, so equal spacing between the
/// ends is the best guess; the along-track σ grows towards the middle of the strip, where
/// speed variations accumulate (`base_sigma_fraction` of the base per √photo from the
/// nearer end), the across-track σ is a drift of the same order, the attitude σ covers
/// crab and tilt of a nadir photo.
pub fn interpolate_strip(
    strip: &StripEnds,
    base_sigma_fraction: f64,
    attitude_sigma_rad: f64,
) -> Result<Vec<(Pose, PosPrior)>, GeometryError> {
    let n = strip.photos.len();
    if n < 2 {
        return Err(GeometryError::InvalidArgument(format!(
            "strip {}: needs at least its first and last photo, has {n}",
            strip.name
        )));
    }
    let (a, b) = (Vector3::from(strip.first), Vector3::from(strip.last));
    if !a.iter().chain(b.iter()).all(|v| v.is_finite()) {
        return Err(GeometryError::NotFinite {
            what: format!("strip {} end points", strip.name),
        });
    }
    let d = b - a;
    let horizontal = (d.x * d.x + d.y * d.y).sqrt();
    if horizontal < 1e-6 {
        return Err(GeometryError::Degenerate(format!(
            "strip {}: first and last centres coincide",
            strip.name
        )));
    }
    let kappa = kappa_from_direction([d.x / horizontal, d.y / horizontal], strip.flight_axis);
    let rotation = matrix_from_opk(0.0, 0.0, kappa);
    let base = horizontal / (n - 1) as f64;
    Ok((0..n)
        .map(|i| {
            let t = i as f64 / (n - 1) as f64;
            let c = a + d * t;
            let from_end = i.min(n - 1 - i) as f64;
            let s_along = (base * base_sigma_fraction * from_end.sqrt()).max(1e-3);
            let s_across = s_along;
            let s_height = (0.01 * c.z.abs()).max(1.0);
            (
                Pose::new(rotation, c),
                PosPrior {
                    center: c,
                    center_sigma: [s_along.max(s_across), s_along.max(s_across), s_height],
                    rotation: Some(rotation),
                    rotation_sigma_rad: attitude_sigma_rad,
                },
            )
        })
        .collect())
}
