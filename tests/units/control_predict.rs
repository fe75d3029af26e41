//! Unit tests of `control::predict`.

mod tests {
    use cloudcontrol::control::predict::*;
    use cloudcontrol::geometry::FrameCamera;
    use cloudcontrol::geometry::{self, Camera, Dem, Pose};
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn transfer_rotates_and_rescales_through_the_ground_plane() {
        // Source: 0.1 m GSD, flying north. Target: 0.5 m GSD, flying east (κ = −90°).
        let src_cam = Camera::Frame(FrameCamera::pinhole(4000, 3000, 10000.0));
        let tgt_cam = Camera::Frame(FrameCamera::pinhole(2000, 2000, 3000.0));
        let src_pose = Pose::from_opk(0.0, 0.0, 0.0, Vector3::new(0.0, 0.0, 1000.0));
        let tgt_pose = Pose::from_opk(
            0.0,
            0.0,
            -std::f64::consts::FRAC_PI_2,
            Vector3::new(30.0, -20.0, 1500.0),
        );
        let x = Vector3::new(5.0, 3.0, 0.0);
        let plane = Plane::through(&x, &Vector3::z());
        let t_px = geometry::project(&tgt_cam, &tgt_pose, &x).unwrap().pixel;
        let s_px = geometry::project(&src_cam, &src_pose, &x).unwrap().pixel;
        let (t, s) = (
            View {
                camera: &tgt_cam,
                pose: &tgt_pose,
            },
            View {
                camera: &src_cam,
                pose: &src_pose,
            },
        );
        let got = transfer(t, s, &plane, [t_px.x, t_px.y]).unwrap();
        assert!((got - s_px).norm() < 1e-8);
        let a = transfer_affine(t, s, &plane, [t_px.x, t_px.y]).unwrap();
        // Scale 0.5 m / 0.1 m = 5 source pixels per target pixel, rotated by 90°.
        let lin = a.fixed_view::<2, 2>(0, 0);
        assert!((lin.determinant().abs().sqrt() - 5.0).abs() < 1e-3, "{lin}");
        assert!(lin[(0, 0)].abs() < 1e-3 && lin[(1, 1)].abs() < 1e-3);
        assert_eq!(pyramid_level(&a), 2);
    }

    #[test]
    fn search_window_grows_with_pos_uncertainty() {
        let cam = Camera::Frame(FrameCamera::pinhole(3000, 3000, 3000.0));
        let pose = Pose::from_opk(0.0, 0.0, 0.0, Vector3::new(0.0, 0.0, 1500.0));
        let x = Vector3::new(100.0, 50.0, 0.0);
        let good = predict(
            &cam,
            &pose,
            &pos_covariance(1.0, 1f64.to_radians() / 60.0),
            &x,
            &Matrix3::zeros(),
        )
        .unwrap();
        let rough = predict(
            &cam,
            &pose,
            &pos_covariance(10.0, 3f64.to_radians()),
            &x,
            &Matrix3::zeros(),
        )
        .unwrap();
        // 10 m at 0.5 m GSD is 20 px; 3° of attitude at f = 3000 px is ~157 px: attitude dominates.
        let r = rough.search_half_size(1.0);
        assert!(r[0] > 150.0 && r[0] < 170.0, "{r:?}");
        assert!(good.search_half_size(3.0)[0] < 10.0);
        // Monte Carlo check of the propagation for the rough case.
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (na, nc) = (
            Normal::new(0.0, 3f64.to_radians()).unwrap(),
            Normal::new(0.0, 10.0).unwrap(),
        );
        let mut sx = 0.0;
        let n = 4000;
        for _ in 0..n {
            let dt = Vector3::new(
                na.sample(&mut rng),
                na.sample(&mut rng),
                na.sample(&mut rng),
            );
            let dc = Vector3::new(
                nc.sample(&mut rng),
                nc.sample(&mut rng),
                nc.sample(&mut rng),
            );
            let p = geometry::project(&cam, &pose.perturbed(&dt, &dc), &x)
                .unwrap()
                .pixel;
            sx += (p.x - rough.pixel.x).powi(2);
        }
        let mc = (sx / n as f64).sqrt();
        assert!(
            (mc / r[0] - 1.0).abs() < 0.1,
            "Monte Carlo σx {mc} vs propagated {}",
            r[0]
        );
    }

    #[test]
    fn footprint_covers_the_photo_on_relief() {
        let cam = Camera::Frame(FrameCamera::pinhole(2000, 1000, 2000.0));
        let pose = Pose::from_opk(0.0, 0.0, 0.0, Vector3::new(0.0, 0.0, 1000.0));
        let dem = Dem::from_fn(-2000.0, 2000.0, 5.0, 800, 800, |x, y| {
            50.0 + 0.02 * x + 0.01 * y
        })
        .unwrap();
        let fp = footprint(&cam, &pose, &dem, 4).unwrap();
        assert_eq!(fp.len(), 16);
        // Nadir, flat-ish: x extent ≈ ±(1000 − 50)·0.5 m.
        let xmax = fp.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        assert!((xmax - 475.0).abs() < 15.0, "{xmax}");
        // The photo's own centre ray lands inside.
        assert!(cloudcontrol::control::dcp::point_in_polygon(
            [0.0, 0.0],
            &fp
        ));
    }
}
