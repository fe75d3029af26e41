//! Unit tests of `control::checkpoints`.

mod tests {
    use cloudcontrol::block::{Block, Photo};
    use cloudcontrol::control::checkpoints::*;
    use cloudcontrol::geometry::Pose;
    use nalgebra::Vector3;

    #[test]
    fn a_measurement_in_an_unknown_photo_is_named_with_its_line() {
        let mut block = Block::new();
        for (k, name) in ["ref_s01_003", "ref_s01_004.tif"].into_iter().enumerate() {
            let id = k as u32;
            block.photos.insert(
                id,
                Photo::new(
                    id,
                    name,
                    0,
                    Pose::new(nalgebra::Matrix3::identity(), Vector3::zeros()),
                ),
            );
        }
        let m = |line, photo: &str| CheckpointMeasurement {
            line,
            photo: photo.into(),
            id: "CP002".into(),
            pixel: [10.0, 20.0],
        };
        let known = [m(3, "ref_s01_003.tif"), m(5, "ref_s01_004")];
        let surveyed = [("CP002".to_string(), [0.0, 0.0, 0.0])];
        assert_eq!(
            evaluate_checkpoints(&block, &known, &surveyed, 0.1),
            Err(EvaluationError::TooFewRays)
        );
        // A measurement of a point the survey does not hold is named, not dropped.
        let e = evaluate_checkpoints(&block, &known, &[], 0.1).unwrap_err();
        assert_eq!(
            e,
            EvaluationError::UnknownPoint {
                line: 3,
                point: "CP002".into(),
                photo: "ref_s01_003.tif".into()
            }
        );
        assert!(e.to_string().contains("line 3"), "{e}");
        let e = evaluate_checkpoints(
            &block,
            &[known[0].clone(), m(6, "ref_s09_001.tif")],
            &surveyed,
            0.1,
        )
        .unwrap_err();
        assert_eq!(
            e,
            EvaluationError::UnknownPhoto {
                line: 6,
                point: "CP002".into(),
                photo: "ref_s09_001.tif".into()
            }
        );
        assert!(e.to_string().contains("line 6"), "{e}");
    }
}
