//! Unit tests of `estimators::similarity3`.

mod tests {
    use cloudcontrol::estimators::similarity3::*;
    use cloudcontrol::estimators::{RobustMethod, RobustOptions};
    use cloudcontrol::geometry::rotation_from_vector;
    use cloudcontrol::geometry::Similarity;
    use nalgebra::Vector3;

    #[test]
    fn finds_the_similarity_among_displaced_control() {
        let truth = Similarity {
            scale: 37.5,
            rotation: rotation_from_vector(&Vector3::new(0.1, -0.3, 2.0)),
            translation: Vector3::new(500.0, -200.0, 30.0),
        };
        let mut pairs = Vec::new();
        for i in 0..12 {
            let m = Vector3::new(
                (i as f64 * 1.3).sin() * 4.0,
                (i as f64 * 0.7).cos() * 3.0,
                0.2 * (i as f64).sin(),
            );
            let mut c = truth.apply(&m);
            // Four of twelve control points displaced by 2–8 m.
            if i % 3 == 0 {
                c += Vector3::new(2.0 + i as f64 * 0.5, -1.0, 1.5);
            }
            pairs.push(PointPair {
                model: m,
                control: c,
                sigma: Vector3::new(0.05, 0.05, 0.08),
            });
        }
        let r = RobustMethod::Ransac
            .estimate(
                &Similarity3Estimator,
                &pairs,
                &RobustOptions {
                    threshold: 16.27f64.sqrt(),
                    ..RobustOptions::default()
                },
            )
            .unwrap();
        let bad: Vec<usize> = (0..12).filter(|i| !r.inliers[*i]).collect();
        assert_eq!(bad, vec![0, 3, 6, 9]);
        assert!((r.model.scale - 37.5).abs() < 1e-6);
        assert!((r.model.translation - truth.translation).norm() < 1e-4);
    }
}
