//! Unit tests of `control::epoch`.

mod tests {
    use cloudcontrol::control::epoch::*;

    #[test]
    fn the_origin_is_the_south_west_kilometre() {
        assert_eq!(
            block_origin([[500123.4, 4400999.0], [499999.9, 4401500.0]]),
            [499000.0, 4400000.0, 0.0]
        );
        assert_eq!(block_origin([[f64::NAN, 1.0]]), [0.0; 3]);
    }
}
