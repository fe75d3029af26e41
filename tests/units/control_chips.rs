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

    #[test]
    fn spread_keeps_one_point_a_cell_over_the_points_extent() {
        use cloudcontrol::control::chips::{ChipStore, ControlPoint};
        use nalgebra::Vector3;
        // A 10 × 10 m grid of points every metre, with a second point beside each: a 5 × 5
        // spread keeps one point a 2 m cell, the first of each in the order given.
        let mut points = Vec::new();
        for y in 0..10 {
            for x in 0..10 {
                for d in [0.0, 0.1] {
                    points.push(ControlPoint {
                        key: None,
                        label: String::new(),
                        position: Vector3::new(x as f64 + d, y as f64 + d, 0.0),
                        sigma: [0.1; 3],
                        normal: Vector3::z(),
                        views: Vec::new(),
                    });
                }
            }
        }
        let store = ChipStore::from_points(Vector3::zeros(), points);
        let all: Vec<usize> = (0..store.points.len()).collect();
        let kept = store.spread(&all, 5);
        assert_eq!(kept.len(), 25);
        let mut cells: Vec<(i64, i64)> = kept
            .iter()
            .map(|&i| {
                let p = store.points[i].position;
                (
                    (p.x / 2.0).floor() as i64,
                    (p.y / 2.0).floor().min(4.0) as i64,
                )
            })
            .collect();
        cells.sort();
        cells.dedup();
        assert_eq!(cells.len(), 25);
        assert!(kept.windows(2).all(|w| w[0] < w[1]));
        // Points in cells of their own: all of them.
        assert_eq!(store.spread(&[0, 2, 4], 5), vec![0, 2, 4]);
    }
}
