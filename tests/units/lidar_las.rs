//! Unit tests of `lidar::las`.

mod tests {
    use cloudcontrol::lidar::las::*;

    #[test]
    fn gps_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(date_of_standard_gps_time(-1e9).unwrap(), "1980-01-06");
        // 2020-01-01T00:00:00 UTC is GPS second 1_261_872_018 (18 leap seconds).
        assert_eq!(
            date_of_standard_gps_time(1_261_872_000.0 - 1e9 + 3600.0).unwrap(),
            "2020-01-01"
        );
    }
}
