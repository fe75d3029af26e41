//! Unit tests of `control::photo`.

mod tests {
    use cloudcontrol::control::photo::*;
    use cloudcontrol::control::predict;
    use cloudcontrol::geometry::Camera;
    use cloudcontrol::geometry::FrameCamera;
    use nalgebra::Vector2;

    /// Predicted pixels on a regular grid over a region of the image.
    fn grid(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<(Vector2<f64>, Vector2<f64>)> {
        let mut out = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                let p = Vector2::new(
                    x0 + (x1 - x0) * i as f64 / 4.0,
                    y0 + (y1 - y0) * j as f64 / 4.0,
                );
                out.push((p, p));
            }
        }
        out
    }

    #[test]
    fn alignment_tolerance_follows_the_camera_geometry() {
        let cov = predict::pos_covariance(10.0, 3f64.to_radians());
        // The digital archive camera of the synthetic blocks, candidates over the frame.
        let frame = Camera::Frame(FrameCamera::pinhole(1000, 666, 1200.0));
        let t_frame = alignment_tolerance(&frame, &grid(50.0, 50.0, 950.0, 616.0), &cov);
        // A 153 mm camera scanned at 42 µm (f = 3643 px), candidates in one corner
        // 600 px across, 2000 px from the centre.
        let film = Camera::Frame(FrameCamera::pinhole(5476, 5476, 153.0 / 0.042));
        let t_film = alignment_tolerance(&film, &grid(4300.0, 4300.0, 4900.0, 4900.0), &cov);
        // Same film, same spread, around the centre: only the spread matters then.
        let t_centre = alignment_tolerance(&film, &grid(2438.0, 2438.0, 3038.0, 3038.0), &cov);
        assert!((6.0..16.0).contains(&t_frame), "frame {t_frame}");
        assert!(
            t_film > t_centre + 2.0,
            "film corner {t_film}, centre {t_centre}"
        );
        assert!(
            t_centre < t_frame,
            "film centre {t_centre}, frame {t_frame}"
        );
        // A tenth of the attitude σ leaves little more than the matching allowance.
        let fine = predict::pos_covariance(1.0, 0.3f64.to_radians());
        let t_fine = alignment_tolerance(&frame, &grid(50.0, 50.0, 950.0, 616.0), &fine);
        assert!(t_fine < ALIGNMENT_MATCH_PX + 1.5, "fine {t_fine}");
    }
}
