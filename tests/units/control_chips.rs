//! Unit tests of `control::chips`.

mod tests {
    use cloudcontrol::control::chips::chip_origin;

    #[test]
    fn a_grid_point_gets_one_chip_whatever_its_last_bits() {
        // Small seed 1's control point CC6 in photo 1, as two builds projected it back.
        let a = chip_origin([886.0, 458.0], 96);
        let b = chip_origin([885.999_999_999_999_8, 457.999_999_999_999_26], 96);
        let c = chip_origin([886.000_000_000_000_5, 458.000_000_000_000_74], 96);
        assert_eq!(a, (790, 362));
        assert_eq!(a, b);
        assert_eq!(a, c);
    }

    #[test]
    fn the_point_lies_in_the_centre_pixel() {
        for k in 0..100 {
            let p = 500.0 + k as f64 / 100.0;
            let (x0, y0) = chip_origin([p, p - 250.0], 7);
            assert_eq!(x0 + 7, 500, "{p}");
            assert_eq!(y0 + 7, 250, "{p}");
        }
    }
}
