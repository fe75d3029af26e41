//! Unit tests of `formats::ortho::tiles`.

mod tests {
    use cloudcontrol::formats::ortho::tiles::*;
    use cloudcontrol::geometry::Camera;
    use cloudcontrol::geometry::FrameCamera;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn hilbert_order_visits_every_tile_once_stepping_to_neighbours() {
        for (nx, ny) in [(1, 1), (8, 8), (5, 3), (13, 7)] {
            let o = hilbert_order(nx, ny);
            let mut seen = o.clone();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), nx * ny);
            if nx == ny && nx.is_power_of_two() {
                for w in o.windows(2) {
                    let d = w[0].0.abs_diff(w[1].0) + w[0].1.abs_diff(w[1].1);
                    assert_eq!(d, 1, "{:?}", w);
                }
            }
        }
    }

    #[test]
    fn footprint_holds_the_ground_the_frame_sees_and_refuses_the_horizon() {
        let cam = Camera::Frame(FrameCamera::pinhole(400, 300, 500.0));
        // Nadir at 100 m over terrain 0–20 m: the frame spans ±40 m × ±30 m at z = 0.
        let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
        let c = Vector3::new(10.0, 20.0, 100.0);
        let b = footprint(&cam, &nadir, &c, (0.0, 20.0)).unwrap();
        assert!(b[0] < 10.0 - 40.0 && b[2] > 10.0 + 40.0 && b[1] < 20.0 - 30.0);
        assert!(b[0] > 10.0 - 40.0 * 1.2 && b[3] < 20.0 + 30.0 * 1.2);
        // Tilted 80° the upper frame edge sees above the horizon.
        let tilt = cloudcontrol::geometry::rotation_from_vector(&Vector3::new(
            80f64.to_radians(),
            0.0,
            0.0,
        )) * nadir;
        assert!(footprint(&cam, &tilt, &c, (0.0, 20.0)).is_none());
    }
}
