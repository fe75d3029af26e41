//! Unit tests of `pipeline::run`.

mod tests {
    use cloudcontrol::pipeline::run::footprint;

    #[test]
    fn footprint_widens_the_centres_by_what_the_camera_sees() {
        // Two centres 1000 m above ground at z = 100: each sees 1.85 × 1000 m around it.
        let fp = footprint(&[[0.0, 0.0, 1100.0], [500.0, 200.0, 1100.0]], 100.0, 1.85).unwrap();
        assert_eq!(fp, [-1850.0, -1850.0, 2350.0, 2050.0]);
        // Non-finite centres are ignored; none at all gives no footprint.
        assert_eq!(footprint(&[[f64::NAN, 0.0, 10.0]], 0.0, 1.0), None);
        assert_eq!(footprint(&[], 0.0, 1.0), None);
    }
}
