//! Which photos a bundle adjustment can hold: a photo is adjusted only when it observes
//! enough adjustable points (a control point seen at least once, a tie point seen by two
//! photos). One photo without support must not stop the adjustment of the others; it is
//! taken out of the block beforehand, with its count, and reported by the caller.

use crate::block::{Block, Photo, PhotoId, PointKind};
use std::collections::{BTreeMap, BTreeSet};

/// Least number of adjustable points a photo must observe: three rays fix its six
/// parameters; fewer leave its normal equations singular.
pub const MIN_POINTS_PER_PHOTO: usize = 3;

/// The photos of `block` that observe fewer than `min_points` adjustable points, with the
/// number they do observe. Found iteratively: taking a photo out can leave a tie point
/// with one ray, and its other photos with less support.
pub fn unsupported_photos(block: &Block, min_points: usize) -> BTreeMap<PhotoId, usize> {
    let mut out: BTreeMap<PhotoId, usize> = BTreeMap::new();
    loop {
        let mut count: BTreeMap<PhotoId, usize> = block
            .photos
            .keys()
            .filter(|k| !out.contains_key(k))
            .map(|k| (*k, 0))
            .collect();
        for p in block.points.values() {
            if p.kind == PointKind::Check {
                continue;
            }
            let rays: BTreeSet<PhotoId> = p
                .observations
                .iter()
                .map(|o| o.photo)
                .filter(|ph| count.contains_key(ph))
                .collect();
            let adjustable = match p.kind {
                PointKind::Control => !rays.is_empty(),
                _ => rays.len() >= 2,
            };
            if adjustable {
                for ph in rays {
                    *count.entry(ph).or_default() += 1;
                }
            }
        }
        let lost: Vec<(PhotoId, usize)> =
            count.into_iter().filter(|(_, n)| *n < min_points).collect();
        if lost.is_empty() {
            return out;
        }
        out.extend(lost);
    }
}

/// Takes the photos of [`unsupported_photos`] out of `block` with their observations
/// (points left without any are removed too) and returns them with the number of points
/// they observed.
pub fn take_unsupported(block: &mut Block, min_points: usize) -> Vec<(Photo, usize)> {
    let lost = unsupported_photos(block, min_points);
    if lost.is_empty() {
        return Vec::new();
    }
    for p in block.points.values_mut() {
        p.observations.retain(|o| !lost.contains_key(&o.photo));
    }
    block.points.retain(|_, p| !p.observations.is_empty());
    lost.into_iter()
        .filter_map(|(id, n)| block.photos.remove(&id).map(|ph| (ph, n)))
        .collect()
}
