//! Flight plans: strips over the area at a given forward and side overlap, the true
//! exterior orientation of each exposure (aircraft attitude and track deviations), and
//! the navigation data a pipeline gets (POS with noise, or only strip end points).

use crate::geometry::{opk_from_matrix, Pose};
use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

#[derive(Debug, Clone, Serialize)]
pub struct PlannedPhoto {
    pub name: String,
    pub strip: usize,
    pub index: usize,
    #[serde(skip)]
    pub pose: Pose,
}

/// Geometry of a block: footprint of one photo on the ground (m) and the flying height.
#[derive(Debug, Clone, Copy)]
pub struct FlightGeometry {
    /// Footprint across track (image x) and along track (image y), metres.
    pub across_m: f64,
    pub along_m: f64,
    pub forward_overlap: f64,
    pub side_overlap: f64,
    /// Projection centre height above the mean ground (m).
    pub height_m: f64,
}

/// Strips run north–south, alternating direction (kappa 0 flying north, π flying south),
/// centred on the area and extending one base past each end so every ground point is in
/// stereo.
pub fn plan(
    area: [f64; 4],
    geo: &FlightGeometry,
    mean_ground: f64,
    prefix: &str,
    rng: &mut ChaCha8Rng,
) -> Vec<PlannedPhoto> {
    let w = area[2] - area[0];
    let h = area[3] - area[1];
    let spacing = geo.across_m * (1.0 - geo.side_overlap);
    let base = geo.along_m * (1.0 - geo.forward_overlap);
    let strips = (((w - geo.across_m) / spacing).ceil().max(0.0) as usize) + 1;
    let per_strip = (((h - geo.along_m) / base).ceil().max(0.0) as usize) + 1;
    let cx = 0.5 * (area[0] + area[2]);
    let cy = 0.5 * (area[1] + area[3]);
    let att = Normal::new(0.0, 0.8f64.to_radians()).expect("sigma");
    let drift = Normal::new(0.0, 1.5f64.to_radians()).expect("sigma");
    let track = Normal::new(0.0, 2.0).expect("sigma");
    let alt = Normal::new(0.0, 0.02 * geo.height_m).expect("sigma");
    let mut photos = Vec::new();
    for s in 0..strips {
        let x = cx + (s as f64 - (strips as f64 - 1.0) / 2.0) * spacing;
        let north = s % 2 == 0;
        let strip_alt = alt.sample(rng);
        for k in 0..per_strip {
            let along = (k as f64 - (per_strip as f64 - 1.0) / 2.0) * base;
            let y = if north { cy + along } else { cy - along };
            let kappa = if north { 0.0 } else { std::f64::consts::PI } + drift.sample(rng);
            let center = Vector3::new(
                x + track.sample(rng),
                y + track.sample(rng),
                mean_ground + geo.height_m + strip_alt + rng.gen_range(-0.5..0.5),
            );
            photos.push(PlannedPhoto {
                name: format!("{prefix}_s{:02}_{:03}", s + 1, k + 1),
                strip: s + 1,
                index: k + 1,
                pose: Pose::from_opk(att.sample(rng), att.sample(rng), kappa, center),
            });
        }
    }
    photos
}

/// Omega, phi, kappa in degrees of a pose.
pub fn opk_deg(pose: &Pose) -> [f64; 3] {
    let (o, p, k) = opk_from_matrix(&pose.rotation);
    [o.to_degrees(), p.to_degrees(), k.to_degrees()]
}

/// A POS record: the true pose with centre noise σ_xyz (m) and attitude noise σ_att (rad).
pub fn noisy_pose(pose: &Pose, sigma_xyz: f64, sigma_att: f64, rng: &mut ChaCha8Rng) -> Pose {
    let n = Normal::new(0.0, 1.0).expect("unit normal");
    let dtheta = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng)) * sigma_att;
    let dc = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng)) * sigma_xyz;
    pose.perturbed(&dtheta, &dc)
}
