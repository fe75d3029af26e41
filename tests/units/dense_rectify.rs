//! Unit tests of `dense` rectification: object points land on one rectified row in both
//! views, the maps to and from the photos invert each other, triangulation agrees with
//! the adjustment's ray intersection, and rendered rows carry the photo's grey values.

mod tests {
    use cloudcontrol::adjust::rays::{intersect_rays, Ray};
    use cloudcontrol::dense::{RectifiedPair, Side};
    use cloudcontrol::geometry::{
        project, Brown, Camera, FilmCamera, FrameCamera, InteriorOrientation, Pose,
    };
    use cloudcontrol::matching::GreyImage;
    use nalgebra::{Matrix2, Vector2, Vector3};

    fn frame(width: u32, height: u32, f: f64, k1: f64) -> Camera {
        Camera::Frame(FrameCamera {
            width,
            height,
            fx: f,
            fy: f * 1.0003,
            cx: width as f64 / 2.0 + 3.7,
            cy: height as f64 / 2.0 - 2.1,
            distortion: Brown {
                k1,
                k2: -0.3 * k1,
                k3: 0.0,
                p1: 2e-4,
                p2: -1e-4,
            },
        })
    }

    /// Two nadir photos 40 m apart along a flight line at azimuth `az`, tilted a little.
    fn poses(az: f64) -> (Pose, Pose) {
        let (s, c) = az.sin_cos();
        let z = 250.0;
        let left = Pose::from_opk(
            0.02,
            -0.015,
            az + 0.03,
            Vector3::new(-20.0 * c, -20.0 * s, z),
        );
        let right = Pose::from_opk(
            -0.01,
            0.025,
            az - 0.02,
            Vector3::new(20.0 * c, 20.0 * s, z + 1.5),
        );
        (left, right)
    }

    /// Deterministic pseudo-random numbers in [0, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Object points on uneven ground seen by both photos.
    fn points(left: (&Camera, &Pose), right: (&Camera, &Pose), n: usize) -> Vec<Vector3<f64>> {
        let mut s = 7u64;
        let mut out = Vec::new();
        while out.len() < n {
            let x = Vector3::new(
                -60.0 + 120.0 * lcg(&mut s),
                -60.0 + 120.0 * lcg(&mut s),
                30.0 * lcg(&mut s),
            );
            let inside = |cam: &Camera, pose: &Pose| {
                project(cam, pose, &x).is_ok_and(|p| {
                    let (w, h) = cam.image_size();
                    p.pixel.x > 0.0
                        && p.pixel.y > 0.0
                        && p.pixel.x < w as f64
                        && p.pixel.y < h as f64
                })
            };
            if inside(left.0, left.1) && inside(right.0, right.1) {
                out.push(x);
            }
        }
        out
    }

    fn check_pair(cl: &Camera, pl: &Pose, cr: &Camera, pr: &Pose) {
        let pair = RectifiedPair::new((cl, pl), (cr, pr)).unwrap();
        assert!(pair.height > 100 && pair.left.width > 100 && pair.right.width > 100);
        let mut worst_row = 0.0f64;
        let mut worst_point = 0.0f64;
        let mut worst_lsq = 0.0f64;
        let mut worst_inverse = 0.0f64;
        for x in points((cl, pl), (cr, pr), 300) {
            // Through the photos: measured pixels (distorted) mapped to rectified positions.
            let ml = project(cl, pl, &x).unwrap().pixel;
            let mr = project(cr, pr, &x).unwrap().pixel;
            let l = pair.from_source(Side::Left, [ml.x, ml.y]).unwrap();
            let r = pair.from_source(Side::Right, [mr.x, mr.y]).unwrap();
            worst_row = worst_row.max((l[1] - r[1]).abs());
            // Same as projecting with the rectified cameras.
            let (lp, d) = pair.disparity_of(&x).unwrap();
            assert!((lp[0] - l[0]).abs() < 1e-6 && (lp[1] - l[1]).abs() < 1e-6);
            assert!((d - (l[0] - r[0])).abs() < 1e-6);
            // The rectified cameras as frame cameras project there too.
            let (cam, pose) = pair.camera(Side::Right);
            let q = project(&cam, &pose, &x).unwrap().pixel;
            assert!((q.x - r[0]).abs() < 1e-6 && (q.y - r[1]).abs() < 1e-6);
            // Triangulation returns the point, as the adjustment's intersection does.
            let t = pair.triangulate(l, l[0] - r[0]).unwrap();
            worst_point = worst_point.max((t - x).norm());
            let rays = [
                Ray {
                    camera: cl,
                    pose: *pl,
                    pixel: [ml.x, ml.y],
                    sigma_px: 1.0,
                },
                Ray {
                    camera: cr,
                    pose: *pr,
                    pixel: [mr.x, mr.y],
                    sigma_px: 1.0,
                },
            ];
            let lsq = intersect_rays(&rays.iter().collect::<Vec<_>>()).unwrap();
            worst_lsq = worst_lsq.max((lsq - t).norm());
            // Rectified → photo → rectified.
            let back = pair.to_source(Side::Left, l).unwrap();
            worst_inverse = worst_inverse
                .max((back[0] - ml.x).abs())
                .max((back[1] - ml.y).abs());
        }
        assert!(worst_row <= 0.01, "rows differ by {worst_row:.2e} px");
        assert!(worst_point < 1e-6, "triangulated {worst_point:.2e} m off");
        assert!(
            worst_lsq < 1e-6,
            "{worst_lsq:.2e} m from the adjustment's intersection"
        );
        assert!(
            worst_inverse < 1e-6,
            "inverse map {worst_inverse:.2e} px off"
        );
    }

    #[test]
    fn object_points_share_a_row_in_both_views() {
        let cam = frame(1200, 900, 1500.0, -0.08);
        for az in [0.0, 0.7, 2.0, -2.6] {
            let (pl, pr) = poses(az);
            check_pair(&cam, &pl, &cam, &pr);
            // The right photo on the left: the rectified pair is turned, not broken.
            check_pair(&cam, &pr, &cam, &pl);
        }
        // Two cameras of different focal length and distortion.
        let (pl, pr) = poses(0.3);
        check_pair(&cam, &pl, &frame(1000, 1000, 1300.0, 0.05), &pr);
    }

    #[test]
    fn film_cameras_rectify_through_their_interior_orientation() {
        // A 153 mm camera scanned at 100 µm: 2300 px over 230 mm, scan rotated a little.
        let (a, b) = (0.1 * 0.9998, 0.1 * 0.012);
        let io =
            InteriorOrientation::affine(&Matrix2::new(a, b, b, -a), &Vector2::new(-115.0, 115.0))
                .unwrap();
        let cam = Camera::Film(FilmCamera {
            width: 2300,
            height: 2300,
            focal_mm: 153.0,
            principal_point_mm: [0.01, -0.02],
            distortion: Brown {
                k1: 0.02,
                ..Default::default()
            },
            interior: io,
        });
        let (pl, pr) = poses(0.4);
        let scale = |p: &Pose| Pose::new(p.rotation, p.center * 6.0);
        check_pair(&cam, &scale(&pl), &cam, &scale(&pr));
    }

    #[test]
    fn degenerate_pairs_are_refused() {
        let cam = frame(800, 600, 1000.0, 0.0);
        let (pl, _) = poses(0.0);
        assert!(RectifiedPair::new((&cam, &pl), (&cam, &pl)).is_err());
        // Moving along the optical axis: the epipole is the principal point.
        let forward = Pose::new(
            pl.rotation,
            pl.center - 30.0 * pl.rotation.row(2).transpose(),
        );
        assert!(RectifiedPair::new((&cam, &pl), (&cam, &forward)).is_err());
    }

    #[test]
    fn rendered_rows_carry_the_photos_grey_values() {
        let cam = frame(640, 480, 800.0, -0.05);
        let (pl, pr) = poses(0.5);
        let pair = RectifiedPair::new((&cam, &pl), (&cam, &pr)).unwrap();
        // A smooth photo: its value at any position is known exactly.
        let f = |x: f64, y: f64| 100.0 + 40.0 * (x / 23.0).sin() + 30.0 * (y / 17.0).cos();
        let photo = GreyImage::from_fn(640, 480, f);
        let rows = 100..180;
        let tile = pair
            .render_rows(Side::Left, &photo, [0, 0], rows.clone())
            .unwrap();
        assert_eq!(tile.image.height, rows.len());
        let mut worst = 0.0f64;
        let mut covered = 0;
        for r in 0..tile.image.height {
            for c in 0..tile.image.width {
                if !tile.valid[r * tile.image.width + c] {
                    continue;
                }
                covered += 1;
                let s = pair
                    .to_source(Side::Left, [c as f64 + 0.5, (r + rows.start) as f64 + 0.5])
                    .unwrap();
                let v = tile.image.at(c, r) as f64;
                worst = worst.max((v - f(s[0], s[1])).abs());
            }
        }
        assert!(covered > tile.image.width * rows.len() / 2);
        // Bilinear interpolation of the sinusoids: error ≤ (1/8)·|f''| ≈ 0.2 grey values.
        assert!(worst < 0.25, "rendered value {worst} off");
        // A window of the photo gives the same rows.
        let win = pair.source_window(Side::Left, rows.clone()).unwrap();
        let crop = photo.crop(win[0], win[1], win[2], win[3]).unwrap();
        let part = pair
            .render_rows(Side::Left, &crop, [win[0], win[1]], rows)
            .unwrap();
        assert_eq!(part.valid, tile.valid);
        assert_eq!(part.image.data, tile.image.data);
    }
}
