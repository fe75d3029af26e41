//! Unit tests of `adjust::rays`.

mod tests {
    use cloudcontrol::adjust::rays::*;
    use cloudcontrol::geometry::{project, Camera, Pose};
    use cloudcontrol::geometry::{rotation_from_vector, FrameCamera};
    use nalgebra::Vector3;

    #[test]
    fn a_wrong_measurement_among_five_rays_is_found() {
        let cam = Camera::Frame(FrameCamera {
            width: 4000,
            height: 3000,
            fx: 3000.0,
            fy: 3000.0,
            cx: 2000.0,
            cy: 1500.0,
            distortion: Default::default(),
        });
        let x = Vector3::new(12.0, -7.0, 3.0);
        let nadir = rotation_from_vector(&Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        let rays: Vec<Ray> = (0..5)
            .map(|i| {
                let pose = Pose::new(nadir, Vector3::new(i as f64 * 40.0 - 80.0, 5.0, 300.0));
                let mut px = project(&cam, &pose, &x).unwrap().pixel;
                if i == 3 {
                    px.x += 25.0;
                }
                Ray {
                    camera: &cam,
                    pose,
                    pixel: [px.x + 0.3, px.y - 0.2],
                    sigma_px: 1.0,
                }
            })
            .collect();
        let r = intersect_robust(&rays, 13.82f64.sqrt(), 1).unwrap();
        assert_eq!(r.inliers, vec![true, true, true, false, true]);
        assert!((r.position - x).norm() < 0.1, "{:?}", r.position);
        assert!(r.residuals_px[3] > 20.0);
    }
}
