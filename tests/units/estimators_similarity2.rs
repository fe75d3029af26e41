//! Unit tests of `estimators::similarity2`.

mod tests {
    use cloudcontrol::estimators::similarity2::*;
    use cloudcontrol::estimators::{RobustMethod, RobustOptions};
    use nalgebra::Vector2;

    #[test]
    fn finds_the_alignment_among_wrong_candidates() {
        let truth = Similarity2 {
            a: 1.03 * 0.1f64.cos(),
            b: 1.03 * 0.1f64.sin(),
            t: Vector2::new(-60.0, 140.0),
        };
        let mut samples = Vec::new();
        // Seven right candidates (±1 px), thirteen wrong ones spread over the photo.
        for i in 0..20 {
            let p = Vector2::new(
                50.0 + 47.0 * (i as f64 * 1.7).sin().abs() * 18.0,
                40.0 + 31.0 * (i as f64 * 0.9).cos().abs() * 18.0,
            );
            let q = if i % 3 == 0 {
                truth.apply(&p) + Vector2::new((i as f64).sin(), (i as f64).cos())
            } else {
                Vector2::new((i * 373 % 1000) as f64, (i * 211 % 660) as f64)
            };
            samples.push((p, q));
        }
        let r = RobustMethod::Ransac
            .estimate(
                &Similarity2Estimator,
                &samples,
                &RobustOptions {
                    threshold: 5.0,
                    ..RobustOptions::default()
                },
            )
            .unwrap();
        assert_eq!(r.num_inliers, 7, "{:?}", r.inliers);
        assert!((r.model.scale() - 1.03).abs() < 0.01);
        assert!((r.model.t - truth.t).norm() < 5.0);
        let p = Vector2::new(310.0, -42.0);
        let composed = truth.after(&r.model).apply(&p);
        assert!((composed - truth.apply(&r.model.apply(&p))).norm() < 1e-9);
    }
}
