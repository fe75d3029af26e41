//! Unit tests of `adjust::resection`.

mod tests {
    use cloudcontrol::adjust::resection::*;
    use cloudcontrol::geometry::{Camera, FrameCamera, Pose};
    use nalgebra::Vector3;

    #[test]
    fn p3p_contains_the_true_pose() {
        let cam = Camera::Frame(FrameCamera::pinhole(4000, 3000, 3500.0));
        let truth = Pose::from_opk(0.05, -0.03, 0.7, Vector3::new(10.0, -5.0, 800.0));
        let xs = [
            Vector3::new(-100.0, 50.0, 12.0),
            Vector3::new(150.0, 80.0, -20.0),
            Vector3::new(30.0, -170.0, 40.0),
        ];
        let cs: Vec<Corr> = xs
            .iter()
            .map(|x| {
                let px = cloudcontrol::geometry::project(&cam, &truth, x)
                    .unwrap()
                    .pixel;
                Corr {
                    pixel: px,
                    bearing: cam.unproject([px.x, px.y]).unwrap(),
                    x: *x,
                }
            })
            .collect();
        let r: Vec<&Corr> = cs.iter().collect();
        let sols = p3p(&r);
        assert!(!sols.is_empty());
        let best = sols
            .iter()
            .map(|p| {
                (p.center - truth.center).norm() + rotation_angle(&p.rotation, &truth.rotation)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            best < 1e-6,
            "closest P3P solution is {best} away; {} solutions",
            sols.len()
        );
    }
}

mod leverage_tests {
    use cloudcontrol::adjust::resection::*;
    use cloudcontrol::estimators::{RobustMethod, RobustOptions};
    use cloudcontrol::geometry::{Brown, Camera, FrameCamera, Pose};
    use nalgebra::{Matrix3, Vector2, Vector3};

    /// A digital photo of the small block (seed 8) and its truth, with control as the
    /// patch matcher found it: points over the left 60 % of the photo, each off by up to
    /// 1.4 px as DCP points are, and two at the right edge on ground 1.9–2.4 m higher
    /// than their reference-epoch coordinates (6–7 px off). The first nine and the two are
    /// the photo's real matches; `extra` more are its other patches' true projections
    /// with the same size of error.
    /// A named control point: its measured pixel and its (reference-epoch) coordinates.
    type Measured = (&'static str, [f64; 2], [f64; 3]);

    fn photo(extra: usize) -> (Camera, Pose, Vec<Measured>) {
        let cam = Camera::Frame(FrameCamera {
            width: 1000,
            height: 666,
            fx: 1195.639,
            fy: 1195.639,
            cx: 501.550,
            cy: 332.401,
            distortion: Brown {
                k1: -0.054_813,
                k2: 0.000_881,
                ..Brown::default()
            },
        });
        #[rustfmt::skip]
        let truth = Pose {
            rotation: Matrix3::new(
                0.998_549_569, 0.052_178_865, -0.013_271_150,
                0.052_075_297, -0.998_610_847, -0.008_033_615,
                -0.013_671_899, 0.007_330_863, -0.999_879_662,
            ),
            center: Vector3::new(930.8993, 1049.1337, 367.3608),
        };
        #[rustfmt::skip]
        let mut obs = vec![
            ("CC11", [163.510, 576.216], [863.448, 999.021, 133.373]),
            ("CC12", [215.841, 598.277], [874.661, 995.932, 135.789]),
            ("CC13", [364.893, 536.387], [903.417, 1010.108, 136.832]),
            ("CC14", [339.326, 645.316], [899.596, 988.693, 137.758]),
            ("CC21", [198.546, 338.939], [867.665, 1046.505, 131.222]),
            ("CC22", [277.578, 300.512], [883.378, 1054.846, 133.244]),
            ("CC24", [410.049, 290.553], [909.782, 1058.008, 137.080]),
            ("CC25", [462.835, 307.003], [920.048, 1055.318, 138.049]),
            ("CC26", [466.143, 399.054], [921.658, 1037.685, 136.872]),
            ("CC38", [976.912, 451.925], [1023.605, 1032.192, 126.066]),
            ("CC40", [923.527, 419.132], [1012.056, 1038.269, 127.350]),
        ];
        // A fixed low-discrepancy scatter (golden-ratio sequence), errors ±1 px.
        for k in 0..extra {
            let (a, b) = (
                (k as f64 * 0.618_034).fract(),
                (k as f64 * 0.754_878).fract(),
            );
            let x = Vector3::new(870.0 + 75.0 * a, 985.0 + 80.0 * b, 133.0 + 4.0 * a * b);
            let p = cloudcontrol::geometry::project(&cam, &truth, &x)
                .unwrap()
                .pixel;
            let e = [(a * 7.0).fract() * 2.0 - 1.0, (b * 5.0).fract() * 2.0 - 1.0];
            obs.push(("extra", [p.x + e[0], p.y + e[1]], [x.x, x.y, x.z]));
        }
        (cam, truth, obs)
    }

    fn angle_and_shift(a: &Pose, b: &Pose) -> (f64, f64) {
        let c = ((a.rotation * b.rotation.transpose()).trace() - 1.0) / 2.0;
        (
            c.clamp(-1.0, 1.0).acos().to_degrees(),
            (a.center - b.center).norm(),
        )
    }

    /// The resection keeps the pose of the right points alone and flags the two; RANSAC's
    /// consensus alone is 1.1–1.3° from it. (That pose is itself 0.5–0.9° from the truth:
    /// the left points' DCP errors are correlated, which no rule in one photo can see.)
    #[test]
    fn two_wrong_points_at_the_edge_do_not_tilt_the_pose() {
        for extra in [0, 6, 10, 16] {
            let (cam, _, obs) = photo(extra);
            let pixels: Vec<[f64; 2]> = obs.iter().map(|o| o.1).collect();
            let points: Vec<[f64; 3]> = obs.iter().map(|o| o.2).collect();
            let opts = ResectionOptions {
                threshold_px: 3.0,
                ..ResectionOptions::default()
            };
            let r = resect(&cam, &pixels, &points, 0.3, &opts).unwrap();
            // What counting inliers alone makes of it.
            let cs: Vec<Corr> = pixels
                .iter()
                .zip(&points)
                .map(|(p, x)| Corr {
                    pixel: Vector2::new(p[0], p[1]),
                    bearing: cam.unproject(*p).unwrap(),
                    x: Vector3::from(*x),
                })
                .collect();
            let ro = RobustOptions {
                threshold: 3.0,
                confidence: opts.confidence,
                max_iterations: opts.max_iterations,
                min_iterations: 50,
                seed: opts.seed,
            };
            let ransac = RobustMethod::Ransac
                .estimate(&P3p { camera: &cam }, &cs, &ro)
                .unwrap();
            // The best any rule can do: the pose from the right points alone.
            let good: Vec<usize> = (0..obs.len())
                .filter(|&i| !matches!(obs[i].0, "CC38" | "CC40"))
                .collect();
            let pick = |v: &[[f64; 2]]| good.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let pick3 = |v: &[[f64; 3]]| good.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let oracle = resect(&cam, &pick(&pixels), &pick3(&points), 0.3, &opts).unwrap();
            let (angle, shift) = angle_and_shift(&r.pose, &oracle.pose);
            let (ra, rs) = angle_and_shift(&ransac.model, &oracle.pose);
            eprintln!("{extra}: from the right pose: resect {angle:.3}° {shift:.2} m, RANSAC {ra:.3}° {rs:.2} m");
            assert!(
                ra > 0.5,
                "{extra}: RANSAC alone is {ra:.3}° off: not the case of this test"
            );
            assert!(
                angle < 0.01 && shift < 0.05,
                "{extra}: {angle:.3}° and {shift:.2} m off"
            );
            for (o, inlier) in obs.iter().zip(&r.inliers) {
                assert_eq!(*inlier, !matches!(o.0, "CC38" | "CC40"), "{extra}: {}", o.0);
            }
        }
    }
}
