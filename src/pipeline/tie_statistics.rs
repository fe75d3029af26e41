//! The tie points and control of an epoch's adjusted block, for the report: how many tie
//! points and how many photos each joins (multiplicity), the control points used, and per
//! photo how its tie points cover the nine standard positions.
//!
//! They are counted on the block after the adjustment, so rejected observations and the
//! tie points they left with a single ray are not counted: the figures describe the
//! geometry the orientations rest on, not what the matcher proposed.

use crate::block::{Block, Photo, PointKind};
use crate::control::predict::Plane;
use crate::geometry::{back_project, project, Camera};
use crate::matching::ties::{standard_position_counts, standard_positions};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Tie points wanted near each standard position that lies in an overlap: three, as in
/// the classical selection of tie points (seed 003) and the reference epoch's matching.
pub const MIN_PER_POSITION: usize = 3;

/// The epoch's tie points and control.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TieStatistics {
    /// Tie points with at least two image observations.
    pub points: usize,
    /// Their image observations.
    pub observations: usize,
    /// Tie points by the number of photos observing them (JSON keys are the counts).
    pub multiplicity: BTreeMap<usize, usize>,
    /// Control points measured in at least one photo (DCP patches, ground control).
    pub control_points: usize,
    /// Their image observations.
    pub control_observations: usize,
    /// Oriented photos with a required standard position holding fewer than
    /// [`MIN_PER_POSITION`] tie points.
    pub photos_short: usize,
    pub min_per_position: usize,
}

/// One photo's tie points and control.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PhotoTies {
    pub tie_observations: usize,
    pub control_observations: usize,
    /// Tie points near each standard position, in row order (top-left, top-centre, …,
    /// bottom-right); see `matching::ties::standard_position_counts`.
    pub positions: [usize; 9],
    /// Whether each position lies in the overlap with another oriented photo (its ray,
    /// met at the median height of the photo's points, projects into that photo).
    pub required: [bool; 9],
}

impl PhotoTies {
    /// Required positions with fewer than [`MIN_PER_POSITION`] tie points.
    pub fn short(&self) -> Vec<usize> {
        (0..9)
            .filter(|&k| self.required[k] && self.positions[k] < MIN_PER_POSITION)
            .collect()
    }
}

/// The statistics of the whole block and of each photo (keyed by photo name; photos
/// without a camera or not oriented get the default, all zero and nothing required).
pub fn tie_statistics(block: &Block) -> (TieStatistics, BTreeMap<String, PhotoTies>) {
    let mut stats = TieStatistics {
        min_per_position: MIN_PER_POSITION,
        ..Default::default()
    };
    // Per photo: tie pixels, control observations, heights of the points it sees.
    let mut pixels: BTreeMap<_, Vec<[f64; 2]>> = BTreeMap::new();
    let mut control: BTreeMap<_, usize> = BTreeMap::new();
    let mut heights: BTreeMap<_, Vec<f64>> = BTreeMap::new();
    for p in block.points.values() {
        match p.kind {
            PointKind::Tie => {
                if p.observations.len() < 2 {
                    continue;
                }
                stats.points += 1;
                stats.observations += p.observations.len();
                let mut photos: Vec<_> = p.observations.iter().map(|o| o.photo).collect();
                photos.sort_unstable();
                photos.dedup();
                *stats.multiplicity.entry(photos.len()).or_default() += 1;
                for o in &p.observations {
                    pixels.entry(o.photo).or_default().push(o.pixel);
                }
            }
            PointKind::Control => {
                if p.observations.is_empty() {
                    continue;
                }
                stats.control_points += 1;
                stats.control_observations += p.observations.len();
                for o in &p.observations {
                    *control.entry(o.photo).or_default() += 1;
                }
            }
            PointKind::Check => continue,
        }
        for o in &p.observations {
            heights.entry(o.photo).or_default().push(p.position.z);
        }
    }
    let oriented: Vec<&Photo> = block.photos.values().filter(|p| p.is_oriented()).collect();
    let mut per_photo = BTreeMap::new();
    for photo in block.photos.values() {
        let Some(cam) = block.camera_of(photo) else {
            continue;
        };
        let (w, h) = cam.model.image_size();
        let (w, h) = (w as usize, h as usize);
        let mine = pixels.get(&photo.id).map_or(&[][..], |v| &v[..]);
        let mut ties = PhotoTies {
            tie_observations: mine.len(),
            control_observations: control.get(&photo.id).copied().unwrap_or(0),
            positions: standard_position_counts(w, h, mine),
            required: [false; 9],
        };
        if photo.is_oriented() {
            if let Some(z) = heights.get_mut(&photo.id).and_then(|v| median(v)) {
                ties.required = required_positions(block, &cam.model, photo, &oriented, z);
            }
            if !ties.short().is_empty() {
                stats.photos_short += 1;
            }
        }
        per_photo.insert(photo.name.clone(), ties);
    }
    (stats, per_photo)
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let m = v.len() / 2;
    Some(*v.select_nth_unstable_by(m, f64::total_cmp).1)
}

/// Which of the photo's standard positions another oriented photo also sees: the ray of
/// each position is met by the horizontal plane at height `z` (block-local) and the ground
/// point projected, in front of the camera and inside the image, into the others.
fn required_positions(
    block: &Block,
    camera: &Camera,
    photo: &Photo,
    oriented: &[&Photo],
    z: f64,
) -> [bool; 9] {
    let mut required = [false; 9];
    let (w, h) = camera.image_size();
    let ground = Plane::through(&Vector3::new(0.0, 0.0, z), &Vector3::z());
    for (k, q) in standard_positions(w as usize, h as usize)
        .iter()
        .enumerate()
    {
        let Some(x) = back_project(camera, &photo.pose, *q)
            .ok()
            .and_then(|ray| ground.intersect(&ray).ok())
        else {
            continue;
        };
        required[k] = oriented.iter().any(|other| {
            if other.id == photo.id {
                return false;
            }
            let Some(oc) = block.camera_of(other) else {
                return false;
            };
            let (ow, oh) = oc.model.image_size();
            project(&oc.model, &other.pose, &x).is_ok_and(|p| {
                p.depth > 0.0
                    && (0.0..=ow as f64).contains(&p.pixel.x)
                    && (0.0..=oh as f64).contains(&p.pixel.y)
            })
        });
    }
    required
}
