//! Geometry core against independent formulas and finite differences.

use cloudcontrol::geometry::*;
use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn brown_camera() -> Camera {
    Camera::Frame(FrameCamera {
        width: 6000,
        height: 4000,
        fx: 8000.0,
        fy: 8010.0,
        cx: 3010.5,
        cy: 1990.25,
        distortion: Brown {
            k1: -0.12,
            k2: 0.05,
            k3: -0.01,
            p1: 3e-4,
            p2: -2e-4,
        },
    })
}

fn film_camera(kind: InteriorTransformKind) -> Camera {
    // Scan of a 230 mm frame at ~21 µm with scale difference, shear and rotation.
    let a = 0.021;
    let (s, c) = (0.01_f64.sin(), 0.01_f64.cos());
    let mut m = Matrix3::new(
        a * c * 1.0008,
        a * (s + 0.0004),
        -115.2,
        a * s,
        -a * c,
        114.9,
        0.0,
        0.0,
        1.0,
    );
    if kind == InteriorTransformKind::Projective {
        m[(2, 0)] = 2e-7;
        m[(2, 1)] = -1e-7;
    }
    Camera::Film(FilmCamera {
        width: 11000,
        height: 11000,
        focal_mm: 153.12,
        principal_point_mm: [0.012, -0.008],
        distortion: Brown {
            k1: 1e-3,
            k2: -2e-4,
            k3: 0.0,
            p1: 1e-5,
            p2: 2e-5,
        },
        interior: InteriorOrientation::new(kind, m).unwrap(),
    })
}

fn rel_err(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(1.0)
}

/// Central differences of the projection, compared with the analytic Jacobians.
fn check_jacobians(camera: &Camera, pose: &Pose, x: &Vector3<f64>) {
    let (_, j) = project_with_jacobians(camera, pose, x).unwrap();
    let px = |cam: &Camera, p: &Pose, x: &Vector3<f64>| project(cam, p, x).unwrap().pixel;
    // Pose: rotation vector (left) then centre.
    for k in 0..6 {
        let h = if k < 3 { 1e-7 } else { 1e-5 };
        let mut d = [0.0; 6];
        d[k] = h;
        let plus = pose.perturbed(
            &Vector3::new(d[0], d[1], d[2]),
            &Vector3::new(d[3], d[4], d[5]),
        );
        d[k] = -h;
        let minus = pose.perturbed(
            &Vector3::new(d[0], d[1], d[2]),
            &Vector3::new(d[3], d[4], d[5]),
        );
        let fd = (px(camera, &plus, x) - px(camera, &minus, x)) / (2.0 * h);
        for r in 0..2 {
            let e = rel_err(j.pose[(r, k)], fd[r]);
            assert!(
                e < 1e-6,
                "pose column {k} row {r}: analytic {} vs fd {}",
                j.pose[(r, k)],
                fd[r]
            );
        }
    }
    for k in 0..3 {
        let h = 1e-4;
        let mut e = Vector3::zeros();
        e[k] = h;
        let fd = (px(camera, pose, &(x + e)) - px(camera, pose, &(x - e))) / (2.0 * h);
        for r in 0..2 {
            assert!(rel_err(j.point[(r, k)], fd[r]) < 1e-6, "point column {k}");
        }
    }
    let p0 = camera.params();
    for k in 0..camera.num_params() {
        // Pixels are linear in most interior parameters, so a large step costs no
        // truncation error and keeps round-off small.
        let h = 1e-4 * p0[k].abs().max(1.0);
        let mut cp = camera.clone();
        let mut cm = camera.clone();
        let mut v = p0.clone();
        v[k] += h;
        cp.set_params(&v).unwrap();
        v[k] -= 2.0 * h;
        cm.set_params(&v).unwrap();
        let fd = (px(&cp, pose, x) - px(&cm, pose, x)) / (2.0 * h);
        for r in 0..2 {
            let e = rel_err(j.intrinsics[(r, k)], fd[r]);
            assert!(
                e < 1e-6,
                "intrinsic {} row {r}: analytic {} vs fd {}",
                camera.param_names()[k],
                j.intrinsics[(r, k)],
                fd[r]
            );
        }
    }
}

#[test]
fn collinearity_jacobians_match_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let cams = [
        brown_camera(),
        film_camera(InteriorTransformKind::Affine),
        film_camera(InteriorTransformKind::Projective),
    ];
    for cam in &cams {
        for _ in 0..20 {
            let pose = Pose::from_opk(
                rng.gen_range(-0.1..0.1),
                rng.gen_range(-0.1..0.1),
                rng.gen_range(-3.1..3.1),
                Vector3::new(
                    rng.gen_range(-50.0..50.0),
                    rng.gen_range(-50.0..50.0),
                    1500.0,
                ),
            );
            // A ground point inside the field of view.
            let d = pose.direction_to_world(&Vector3::new(
                rng.gen_range(-0.3..0.3),
                rng.gen_range(-0.2..0.2),
                1.0,
            ));
            let t = (pose.center.z - rng.gen_range(0.0..200.0)) / -d.z;
            let x = pose.center + d * t;
            check_jacobians(cam, &pose, &x);
        }
    }
}

/// The classic element formulas of the photogrammetric rotation matrix (e.g. Kraus,
/// Photogrammetry vol. 1, eq. B.3-4), written out independently of the implementation.
fn opk_elements(o: f64, p: f64, k: f64) -> Matrix3<f64> {
    let (so, co, sp, cp, sk, ck) = (o.sin(), o.cos(), p.sin(), p.cos(), k.sin(), k.cos());
    Matrix3::new(
        cp * ck,
        co * sk + so * sp * ck,
        so * sk - co * sp * ck,
        -cp * sk,
        co * ck - so * sp * sk,
        so * ck + co * sp * sk,
        sp,
        -so * cp,
        co * cp,
    )
}

#[test]
fn rotation_conventions_round_trip_and_match_independent_formulas() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    for _ in 0..1000 {
        let (o, p, k) = (
            rng.gen_range(-3.1..3.1),
            rng.gen_range(-1.5..1.5),
            rng.gen_range(-3.1..3.1),
        );
        let r = matrix_from_opk(o, p, k);
        assert!((r - flip * opk_elements(o, p, k)).abs().max() < 1e-14);
        let (o2, p2, k2) = opk_from_matrix(&r);
        assert!((o - o2).abs() < 1e-12 && (p - p2).abs() < 1e-12 && (k - k2).abs() < 1e-12);

        let q = quaternion_wxyz_from_matrix(&r);
        let r2 = matrix_from_quaternion_wxyz(q);
        assert!((r - r2).abs().max() < 1e-12);
        // Independent quaternion → matrix formula (Hamilton, w first).
        let [w, x, y, z] = q;
        let rq = Matrix3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        );
        assert!((r - rq).abs().max() < 1e-12);

        let (ya, pi, ro) = (
            rng.gen_range(-3.1..3.1),
            rng.gen_range(-1.5..1.5),
            rng.gen_range(-3.1..3.1),
        );
        let ry = matrix_from_ypr(ya, pi, ro);
        let (ya2, pi2, ro2) = ypr_from_matrix(&ry);
        assert!((ya - ya2).abs() < 1e-12 && (pi - pi2).abs() < 1e-12 && (ro - ro2).abs() < 1e-12);
    }
    // Nadir photo, image top towards north: OPK = 0 and heading 0 give the same camera.
    assert!(
        (matrix_from_opk(0.0, 0.0, 0.0) - matrix_from_ypr(0.0, 0.0, 0.0))
            .abs()
            .max()
            < 1e-15
    );
    // Heading east (yaw = 90°): the image top points east, so image x points south.
    let r = matrix_from_ypr(90f64.to_radians(), 0.0, 0.0);
    assert!((r.row(0).transpose() - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
    assert!((r.row(1).transpose() - Vector3::new(-1.0, 0.0, 0.0)).norm() < 1e-12);
    // Nose up (pitch > 0): the belly, and with it the optical axis, swings forward (north
    // when heading north); right wing down (roll > 0) swings it to the left (west).
    let r = matrix_from_ypr(0.0, 10f64.to_radians(), 0.0);
    assert!(r.row(2)[1] > 0.0 && r.row(2)[2] < 0.0 && r.row(2)[0].abs() < 1e-15);
    let r = matrix_from_ypr(0.0, 0.0, 10f64.to_radians());
    assert!(r.row(2)[0] < 0.0 && r.row(2)[2] < 0.0 && r.row(2)[1].abs() < 1e-15);
}

#[test]
fn distortion_inverse_converges_to_a_micro_pixel() {
    let cam = brown_camera();
    let mut worst: f64 = 0.0;
    for r in (0..4000).step_by(97) {
        for c in (0..6000).step_by(131) {
            let px = [c as f64 + 0.5, r as f64 + 0.5];
            let d = cam.unproject(px).unwrap();
            let back = cam.project(&d).unwrap();
            worst = worst.max((back - Vector2::new(px[0], px[1])).norm());
        }
    }
    assert!(worst < 1e-6, "worst distortion round trip {worst} px");
    let film = film_camera(InteriorTransformKind::Projective);
    for r in (0..11000).step_by(500) {
        for c in (0..11000).step_by(500) {
            let px = [c as f64 + 0.5, r as f64 + 0.5];
            let back = film.project(&film.unproject(px).unwrap()).unwrap();
            assert!((back - Vector2::new(px[0], px[1])).norm() < 1e-6);
        }
    }
}

#[test]
fn interior_orientation_is_recovered_from_fiducials() {
    let film = film_camera(InteriorTransformKind::Affine);
    let Camera::Film(f) = &film else {
        unreachable!()
    };
    // Eight fiducials of a typical metric camera (corners and side midpoints, mm).
    let mm: Vec<[f64; 2]> = vec![
        [-106.0, -106.0],
        [106.0, 106.0],
        [-106.0, 106.0],
        [106.0, -106.0],
        [-110.0, 0.0],
        [110.0, 0.0],
        [0.0, 110.0],
        [0.0, -110.0],
    ];
    let px: Vec<[f64; 2]> = mm
        .iter()
        .map(|m| {
            let p = f.interior.mm_to_pixel(Vector2::new(m[0], m[1]));
            [p.x, p.y]
        })
        .collect();
    for kind in [
        InteriorTransformKind::Affine,
        InteriorTransformKind::Projective,
    ] {
        let (io, res) = InteriorOrientation::estimate(kind, &px, &mm).unwrap();
        assert!(
            res.iter().all(|r| r[0].abs() < 1e-6 && r[1].abs() < 1e-6),
            "{res:?}"
        );
        let m = io.pixel_to_mm / io.pixel_to_mm[(2, 2)];
        assert!((m - f.interior.pixel_to_mm).abs().max() < 1e-9);
    }
    assert!(
        InteriorOrientation::estimate(InteriorTransformKind::Projective, &px[..3], &mm[..3])
            .is_err()
    );
    // Collinear fiducials cannot define an affine transform.
    let line_mm = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]];
    let line_px = [[0.0, 0.0], [10.0, 10.0], [20.0, 20.0]];
    assert!(
        InteriorOrientation::estimate(InteriorTransformKind::Affine, &line_px, &line_mm).is_err()
    );
}

#[test]
fn similarity_is_recovered_exactly_and_to_the_noise_level() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let truth = Similarity::new(
        1.0123,
        matrix_from_opk(0.02, -0.05, 1.2),
        Vector3::new(512.3, -80.1, 12.7),
    );
    let src: Vec<Vector3<f64>> = (0..200)
        .map(|_| {
            Vector3::new(
                rng.gen_range(-500.0..500.0),
                rng.gen_range(-500.0..500.0),
                rng.gen_range(0.0..80.0),
            )
        })
        .collect();
    let dst: Vec<Vector3<f64>> = src.iter().map(|p| truth.apply(p)).collect();
    let est = Similarity::estimate(&src[..3], &dst[..3], None, true).unwrap();
    assert!((est.scale - truth.scale).abs() < 1e-12);
    assert!((est.rotation - truth.rotation).abs().max() < 1e-12);
    assert!((est.translation - truth.translation).norm() < 1e-9);

    let sigma = 0.05;
    let noisy: Vec<Vector3<f64>> = dst
        .iter()
        .map(|p| {
            p + Vector3::new(
                rng.sample::<f64, _>(rand_distr::StandardNormal) * sigma,
                rng.sample::<f64, _>(rand_distr::StandardNormal) * sigma,
                rng.sample::<f64, _>(rand_distr::StandardNormal) * sigma,
            )
        })
        .collect();
    let est = Similarity::estimate(&src, &noisy, None, true).unwrap();
    let rms = (src
        .iter()
        .zip(&noisy)
        .map(|(s, d)| (est.apply(s) - d).norm_squared())
        .sum::<f64>()
        / src.len() as f64
        / 3.0)
        .sqrt();
    assert!(
        (rms - sigma).abs() < 0.2 * sigma,
        "residual rms {rms} vs noise {sigma}"
    );
    // Over 1000 m, the scale error of 200 points at 5 cm is a few 1e-5.
    assert!((est.scale - truth.scale).abs() < 5e-5);
    let rigid = Similarity::estimate(&src, &dst, None, false).unwrap();
    assert_eq!(rigid.scale, 1.0);

    // Applying the transform to a pose keeps every projection.
    let cam = brown_camera();
    let pose = Pose::from_opk(0.01, 0.02, 0.3, Vector3::new(10.0, 20.0, 1500.0));
    let moved = truth.apply_pose(&pose);
    let x = Vector3::new(40.0, -30.0, 50.0);
    let a = project(&cam, &pose, &x).unwrap().pixel;
    let b = project(&cam, &moved, &truth.apply(&x)).unwrap().pixel;
    assert!((a - b).norm() < 1e-9);
    // 4×4 matrix round trip and inverse.
    let back = Similarity::from_matrix4(&truth.to_matrix4()).unwrap();
    assert!(
        (back.scale - truth.scale).abs() < 1e-12
            && (back.translation - truth.translation).norm() < 1e-9
    );
    let id = truth.compose(&truth.inverse());
    assert!(
        (id.to_matrix4() - nalgebra::Matrix4::identity())
            .abs()
            .max()
            < 1e-9
    );

    // Degenerate input.
    let line: Vec<Vector3<f64>> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
    assert!(matches!(
        Similarity::estimate(&line, &line, None, true),
        Err(GeometryError::Degenerate(_))
    ));
    assert!(Similarity::estimate(&src[..2], &dst[..2], None, true).is_err());
    let mut bad = src.clone();
    bad[0].x = f64::NAN;
    assert!(matches!(
        Similarity::estimate(&bad, &dst, None, true),
        Err(GeometryError::NotFinite { .. })
    ));
}

fn relief(x: f64, y: f64) -> f64 {
    // Steep ridges: 80 m amplitude over ~60 m wavelength.
    300.0 + 80.0 * (x / 10.0).sin() * (y / 12.0).cos() + 0.3 * x
}

#[test]
fn ray_dem_intersection_hits_the_true_point_on_steep_relief() {
    let dem = Dem::from_fn(-400.0, 400.0, 2.0, 400, 400, relief).unwrap();
    let cam = brown_camera();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut worst: f64 = 0.0;
    for _ in 0..300 {
        // Oblique views make occlusion matter: the first surface along the ray wins.
        let pose = Pose::from_opk(
            rng.gen_range(-0.35..0.35),
            rng.gen_range(-0.35..0.35),
            rng.gen_range(-3.0..3.0),
            Vector3::new(
                rng.gen_range(-100.0..100.0),
                rng.gen_range(-100.0..100.0),
                1200.0,
            ),
        );
        let px = [rng.gen_range(500.0..5500.0), rng.gen_range(500.0..3500.0)];
        let ray = back_project(&cam, &pose, px).unwrap();
        let hit = match dem.intersect(&ray) {
            Ok(h) => h,
            Err(GeometryError::NoIntersection(_)) => continue,
            Err(e) => panic!("{e}"),
        };
        // The hit is on the surface, on the ray, and nothing nearer along the ray is below ground.
        let h = dem.height_at(hit.x, hit.y).unwrap();
        assert!((hit.z - h).abs() < 1e-3);
        let along = (hit - ray.origin).dot(&ray.direction);
        assert!((ray.at(along) - hit).norm() < 1e-6);
        for i in 1..200 {
            let p = ray.at(along * i as f64 / 200.0 * 0.999);
            if let Some(hh) = dem.height_at(p.x, p.y) {
                assert!(
                    p.z >= hh - 1e-3,
                    "ray passes below the surface before the hit"
                );
            }
        }
        // Re-projection of the hit lands on the pixel.
        let back = project(&cam, &pose, &hit).unwrap().pixel;
        worst = worst.max((back - Vector2::new(px[0], px[1])).norm());
    }
    assert!(worst < 1e-4, "{worst}");

    // The true ground point: a point on the surface, projected then intersected, to 1 mm.
    let pose = Pose::from_opk(0.2, -0.1, 0.5, Vector3::new(0.0, 0.0, 1500.0));
    for i in 0..200 {
        let (x, y) = (-150.0 + 1.5 * i as f64, 100.0 - 1.1 * i as f64);
        let truth = Vector3::new(x, y, dem.height_at(x, y).unwrap());
        let px = project(&cam, &pose, &truth).unwrap().pixel;
        let hit = dem.intersect(&back_project(&cam, &pose, [px.x, px.y]).unwrap());
        if let Ok(hit) = hit {
            // Occluded points hit an earlier ridge; visible ones must be exact.
            if (hit - truth).norm() < 1.0 {
                assert!((hit - truth).norm() < 1e-3, "{}", (hit - truth).norm());
            } else {
                assert!((hit - pose.center).norm() < (truth - pose.center).norm());
            }
        }
    }
    // A ray pointing up misses.
    let up = Ray {
        origin: Vector3::new(0.0, 0.0, 1000.0),
        direction: Vector3::new(0.0, 0.0, 1.0),
    };
    assert!(dem.intersect(&up).is_err());
}

#[test]
fn invalid_cameras_and_points_behind_are_refused() {
    let mut cam = FrameCamera::pinhole(100, 100, 50.0);
    cam.fx = -1.0;
    assert!(Camera::Frame(cam).validate().is_err());
    let cam = Camera::Frame(FrameCamera::pinhole(0, 100, 50.0));
    assert!(cam.validate().is_err());
    let cam = brown_camera();
    assert!(matches!(
        cam.project(&Vector3::new(0.0, 0.0, -5.0)),
        Err(GeometryError::BehindCamera { .. })
    ));
    assert!(cam.unproject([f64::NAN, 1.0]).is_err());
    let pose = Pose::new(
        Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0),
        Vector3::zeros(),
    );
    assert!(pose.validate(1e-9).is_err());
    let json = serde_json::to_string(&film_camera(InteriorTransformKind::Affine)).unwrap();
    let back: Camera = serde_json::from_str(&json).unwrap();
    assert_eq!(back, film_camera(InteriorTransformKind::Affine));
}
