//! Unit tests of `adjust::tie_prior`.

mod tests {
    use cloudcontrol::adjust::tie_prior::*;
    use rand::SeedableRng;
    use rand_distr::{ChiSquared, Distribution};

    /// Points of 2–6 rays with λ·s0² ~ d0 s0²/χ²(d0) (λ = s0² for d0 infinite), their
    /// sums of squares drawn as the model has them; `bad`: share of points with one ray
    /// displaced by `shift` σ (its q grows by shift²).
    fn sample(d0: f64, s02: f64, n: usize, bad: f64, shift: f64, seed: u64) -> Vec<PointLoo> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut u = move || rand::Rng::gen::<f64>(&mut rng);
        let mut rng2 = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 1000);
        let mut chi = move |d: f64| ChiSquared::new(d).unwrap().sample(&mut rng2);
        (0..n)
            .map(|i| {
                let rays = 2 + i % 5;
                let lambda = if d0.is_finite() {
                    s02 * d0 / chi(d0)
                } else {
                    s02
                };
                let dm = (2 * rays) as f64 - 5.0;
                let base = if rays >= 3 { lambda * chi(dm) } else { 0.0 };
                let loo: Vec<f64> = if rays >= 3 {
                    // One ray's q on top of the others' (the others share `base` here:
                    // enough for the fit's statistics).
                    (0..rays).map(|_| base).collect()
                } else {
                    Vec::new()
                };
                let mut q = lambda * chi(2.0);
                if u() < bad {
                    q += shift * shift;
                }
                let ss = if rays >= 3 {
                    base + q
                } else {
                    lambda * chi(1.0)
                };
                PointLoo::new((0..rays).collect(), ss, loo)
            })
            .collect()
    }

    #[test]
    fn one_variance_gives_no_prior() {
        for seed in 0..3 {
            assert_eq!(
                fit(
                    &sample(f64::INFINITY, 1.0, 5000, 0.0, 0.0, seed),
                    0.001,
                    None
                ),
                None
            );
        }
    }

    #[test]
    fn gross_errors_are_not_read_as_spread() {
        // A tenth of the points with a ray displaced 20 σ: still one variance.
        let p = fit(&sample(f64::INFINITY, 1.0, 5000, 0.1, 20.0, 4), 0.001, None);
        assert_eq!(p, None, "{p:?}");
    }

    #[test]
    fn a_scale_mixture_is_recovered_and_tested() {
        let pts = sample(3.0, 0.5, 20_000, 0.0, 0.0, 7);
        let p = fit(&pts, 0.001, None).expect("spread");
        assert!((2.0..=4.0).contains(&p.dof), "{p:?}");
        assert!((p.factor / 0.5 - 1.0).abs() < 0.15, "{p:?}");
        // Under the model a ray fails at the test's level: one in a thousand.
        let fails = pts
            .iter()
            .filter(|q| q.rays.len() >= 3)
            .filter(|q| p.ray_tail(q, 0) < 0.001)
            .count() as f64;
        let tested = pts.iter().filter(|q| q.rays.len() >= 3).count() as f64;
        assert!(fails / tested < 0.002, "{fails} of {tested}");
    }

    #[test]
    fn tails_and_blame() {
        let p = TiePrior {
            dof: 4.0,
            factor: 1.0,
            outlier_share: 0.01,
            points: 100,
        };
        // Three rays, ray 0 displaced: leaving it out fits, leaving out another does not.
        let pt = PointLoo::new(vec![0, 1, 2], 400.0, vec![1.0, 390.0, 395.0]);
        let (k, tail) = p.worst(&pt).unwrap();
        assert_eq!(k, 0);
        assert!(tail < 1e-4, "{tail}");
        assert!(p.blame(&pt, 0) > LOCALISE);
        // The F(2, ν) tail against its closed form.
        let nu: f64 = 4.0 + 1.0;
        let s2 = (4.0 + 1.0) / nu;
        let want = (1.0 + 399.0 / (nu * s2)).powf(-nu / 2.0);
        assert!((tail - want).abs() < 1e-15);
    }
}
