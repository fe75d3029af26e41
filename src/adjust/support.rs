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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::block::{ObjectPoint, Observation};
    use crate::geometry::Pose;
    use nalgebra::{Matrix3, Vector3};

    fn point(id: u64, kind: PointKind, photos: &[PhotoId]) -> ObjectPoint {
        ObjectPoint {
            id,
            name: String::new(),
            kind,
            position: Vector3::zeros(),
            sigma: (kind == PointKind::Control).then_some([0.1; 3]),
            color: [0; 3],
            observations: photos
                .iter()
                .map(|&photo| Observation {
                    photo,
                    pixel: [0.0, 0.0],
                    sigma_px: 1.0,
                    provenance: String::new(),
                })
                .collect(),
        }
    }

    #[test]
    fn cascade_and_control() {
        let mut b = Block::default();
        for id in 1..=4 {
            let pose = Pose::new(Matrix3::identity(), Vector3::zeros());
            b.photos
                .insert(id, Photo::new(id, format!("p{id}"), 1, pose));
        }
        // Photos 1 and 2 share three tie points; photo 3 shares two with photo 4 and one
        // with photo 1; photo 4 sees three control points besides.
        let mut id = 0;
        let mut add = |b: &mut Block, kind, photos: &[PhotoId]| {
            id += 1;
            b.points.insert(id, point(id, kind, photos));
        };
        for _ in 0..3 {
            add(&mut b, PointKind::Tie, &[1, 2]);
            add(&mut b, PointKind::Control, &[4]);
        }
        add(&mut b, PointKind::Tie, &[3, 4]);
        add(&mut b, PointKind::Tie, &[3, 4]);
        add(&mut b, PointKind::Tie, &[1, 3]);
        // A one-ray tie point is no support.
        add(&mut b, PointKind::Tie, &[3]);
        let lost = unsupported_photos(&b, 3);
        assert_eq!(lost.into_iter().collect::<Vec<_>>(), vec![]);
        // Without one of the photo-3 ties, photo 3 goes, and nobody else.
        let mut b2 = b.clone();
        let last_34 = *b2
            .points
            .iter()
            .find(|(_, p)| p.observations.len() == 2 && p.observations[0].photo == 3)
            .unwrap()
            .0;
        b2.points.remove(&last_34);
        let taken = take_unsupported(&mut b2, 3);
        assert_eq!(taken.len(), 1);
        assert_eq!((taken[0].0.id, taken[0].1), (3, 2));
        // No observation refers to the photo taken out.
        assert!(b2
            .points
            .values()
            .all(|p| p.observations.iter().all(|o| o.photo != 3)));
        // Photo 4 keeps its control points (one ray each is enough).
        assert!(b2.photos.contains_key(&4));
    }
}
