//! Unit tests of `pipeline::bench`.

mod tests {
    use cloudcontrol::pipeline::bench::*;
    use cloudcontrol::pipeline::report::EpochReport;

    fn row(reference: bool, plan: f64, height: f64, truth: f64) -> (EpochScore, EpochReport) {
        let e: EpochReport = serde_json::from_value(serde_json::json!({
            "name": "e", "date": "2000", "gsd_m": 0.1, "photos_total": 20,
            "photos_oriented": 19, "check_rmse_plan_m": plan * 0.1,
            "check_rmse_height_m": height * 0.1, "check_max_m": 0.0, "sigma0": 1.0,
            "rmse_px": 0.2, "time_s": 1.0,
            "checkpoints": [{"id": "c", "x": 0.0, "y": 0.0, "dx": 0.0, "dy": 0.0, "dz": 0.0}]
        }))
        .unwrap();
        let r = EpochScore {
            seed: 1,
            epoch: "e".into(),
            reference,
            photos_total: 20,
            photos_oriented: 19,
            checkpoints: 1,
            gsd_m: 0.1,
            plan_gsd: plan,
            height_gsd: height,
            truth_plan_gsd: truth,
            truth_height_gsd: truth,
            time_s: 1.0,
            misses: Vec::new(),
        };
        (r, e)
    }

    #[test]
    fn targets_per_epoch_kind() {
        let t = Targets::default();
        // 19 of 20 is 95 %: met.
        let (r, e) = row(true, 0.9, 0.9, 0.5);
        assert!(misses(&r, &e, &t).is_empty());
        // A reference height of 1.2 GSD where the truth scores 1.15 is the checkpoints'.
        let (r, e) = row(true, 0.9, 1.2, 1.15);
        assert!(misses(&r, &e, &t).is_empty());
        // ... but not where the truth scores 1.0.
        let (r, e) = row(true, 0.9, 1.2, 1.0);
        assert_eq!(misses(&r, &e, &t).len(), 1);
        // Archive: height up to 1.5, and no truth allowance.
        let (r, e) = row(false, 0.9, 1.4, 0.2);
        assert!(misses(&r, &e, &t).is_empty());
        let (r, e) = row(false, 1.2, 1.4, 1.2);
        assert_eq!(misses(&r, &e, &t).len(), 1);
        let (mut r, e) = row(false, 0.5, 0.5, 0.2);
        r.photos_oriented = 18;
        assert!(misses(&r, &e, &t)[0].contains("18 of 20"));
    }
}
