//! Unit tests of `adjust::support`.

mod tests {
    use cloudcontrol::adjust::support::*;
    use cloudcontrol::block::{Block, Photo, PhotoId, PointKind};
    use cloudcontrol::block::{ObjectPoint, Observation};
    use cloudcontrol::geometry::Pose;
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
