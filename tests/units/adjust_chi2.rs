//! Unit tests of `adjust::chi2`.

mod tests {
    use cloudcontrol::adjust::chi2::*;

    #[test]
    fn critical_values_match_the_tables() {
        // χ² tables at α = 0.001: 10.828 (1), 13.816 (2), 16.266 (3); at 0.05: 3.841, 5.991, 7.815.
        for (d, a, c) in [
            (1, 0.001, 10.828),
            (2, 0.001, 13.816),
            (3, 0.001, 16.266),
            (1, 0.05, 3.841),
            (2, 0.05, 5.991),
            (3, 0.05, 7.815),
            // Beyond three dimensions (a checkpoint's rays: 2n - 3 degrees of freedom).
            (5, 0.001, 20.515),
            (9, 0.001, 27.877),
            (17, 0.05, 27.587),
        ] {
            assert!(
                (critical(d, a) - c).abs() < 2e-3,
                "d {d} α {a}: {}",
                critical(d, a)
            );
        }
        assert!((alpha_of_k(3.29) - 0.001002).abs() < 1e-6);
        assert!((k_of_alpha(0.001) - 3.2905).abs() < 1e-3);
        assert!((erfc(-1.0) - 1.842_700_79).abs() < 1e-6);
        for d in 1..30 {
            for a in [0.05, 0.001, 1e-6] {
                let c = critical(d, a);
                assert!((upper_tail(d, c) / a - 1.0).abs() < 1e-6, "d {d} α {a}");
            }
        }
    }
}
