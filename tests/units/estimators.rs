//! Unit tests of `estimators`.

mod tests {
    use cloudcontrol::estimators::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// 2-D line y = a x + b, residual vertical distance.
    struct Line;
    impl Estimator for Line {
        type Sample = (f64, f64);
        type Model = (f64, f64);
        const MIN_SAMPLES: usize = 2;
        fn fit_minimal(&self, s: &[&(f64, f64)]) -> Vec<(f64, f64)> {
            let (p, q) = (s[0], s[1]);
            if (q.0 - p.0).abs() < 1e-12 {
                return vec![];
            }
            let a = (q.1 - p.1) / (q.0 - p.0);
            vec![(a, p.1 - a * p.0)]
        }
        fn residual_sq(&self, m: &(f64, f64), s: &(f64, f64)) -> f64 {
            (s.1 - (m.0 * s.0 + m.1)).powi(2)
        }
    }

    fn data() -> (Vec<(f64, f64)>, Vec<bool>) {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        use rand::Rng;
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for i in 0..200 {
            let x = i as f64 * 0.1;
            if i % 5 < 2 {
                // 40 % gross errors.
                pts.push((x, rng.gen_range(-50.0..50.0)));
                truth.push(false);
            } else {
                pts.push((x, 2.0 * x - 3.0 + rng.gen_range(-0.01..0.01)));
                truth.push(true);
            }
        }
        (pts, truth)
    }

    #[test]
    fn ransac_and_lmeds_recover_a_line_with_40_percent_outliers() {
        let (pts, truth) = data();
        let opts = RobustOptions {
            threshold: 0.05,
            ..Default::default()
        };
        for r in [
            RobustMethod::Ransac.estimate(&Line, &pts, &opts).unwrap(),
            RobustMethod::Lmeds.estimate(&Line, &pts, &opts).unwrap(),
        ] {
            assert!(
                (r.model.0 - 2.0).abs() < 0.01 && (r.model.1 + 3.0).abs() < 0.05,
                "{:?}",
                r.model
            );
            let wrong = r.inliers.iter().zip(&truth).filter(|(a, b)| a != b).count();
            assert!(wrong <= 2, "{wrong} misclassified");
        }
    }

    #[test]
    fn too_few_samples_is_an_error() {
        assert_eq!(
            RobustMethod::Ransac
                .estimate(&Line, &[(0.0, 0.0)], &RobustOptions::default())
                .unwrap_err(),
            RobustError::TooFewSamples { needed: 2, got: 1 }
        );
    }
}
