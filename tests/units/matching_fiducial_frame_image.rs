//! Unit tests of `matching::fiducial::frame_image`.

mod tests {
    use cloudcontrol::geometry::{Brown, Camera, InteriorTransformKind};
    use cloudcontrol::geometry::{FilmCamera, InteriorOrientation};
    use cloudcontrol::matching::fiducial::frame_image::*;
    use cloudcontrol::matching::GreyImage;
    use nalgebra::Matrix3;
    use nalgebra::{Matrix2, Vector2, Vector3};

    /// A camera-frame point's scan pixel (film camera) moved into the frame, and its pixel
    /// through the frame camera.
    fn frame_pixel_of(
        frame: &FiducialFrame,
        film: &FilmCamera,
        xc: &Vector3<f64>,
    ) -> ([f64; 2], [f64; 2]) {
        let scan = Camera::Film(film.clone()).project(xc).unwrap();
        let via_scan = frame.scan_to_frame(&film.interior, [scan.x, scan.y]);
        let direct = Camera::Frame(frame.frame_camera(film)).project(xc).unwrap();
        (via_scan, [direct.x, direct.y])
    }

    /// A scan interior orientation of a `w`×`h` scan: pixel → mm = R(rot) · M ·
    /// [[s, shear·s], [0, −1.003·s]] · (col, row) + t, M mirroring x when asked (a scan
    /// read from the emulsion side), with the scan centre at `centre_mm`.
    fn affine(
        (w, h): (f64, f64),
        s: f64,
        rot_deg: f64,
        shear: f64,
        centre_mm: [f64; 2],
        mirror: bool,
    ) -> InteriorOrientation {
        let (sn, cs) = rot_deg.to_radians().sin_cos();
        let m = if mirror { -1.0 } else { 1.0 };
        let a = Matrix2::new(cs, -sn, sn, cs)
            * Matrix2::new(m, 0.0, 0.0, 1.0)
            * Matrix2::new(s, shear * s, 0.0, -s * 1.003);
        let t = Vector2::from(centre_mm) - a * Vector2::new(w / 2.0, h / 2.0);
        InteriorOrientation::affine(&a, &t).unwrap()
    }

    /// Marks as Gaussian blobs (σ in mm) at known fiducial coordinates on a grey
    /// background, rendered into a scan through its interior orientation.
    fn render_scan(w: usize, h: usize, io: &InteriorOrientation, marks: &[[f64; 2]]) -> GreyImage {
        let sigma = 0.25;
        GreyImage::from_fn(w, h, |x, y| {
            let mm = io.pixel_to_mm(Vector2::new(x, y));
            40.0 + marks
                .iter()
                .map(|m| {
                    let d2 = (mm.x - m[0]).powi(2) + (mm.y - m[1]).powi(2);
                    180.0 * (-d2 / (2.0 * sigma * sigma)).exp()
                })
                .sum::<f64>()
        })
    }

    /// Background-subtracted centroid of the grey values within `r` px of `p`.
    fn centroid(img: &GreyImage, p: [f64; 2], r: f64) -> [f64; 2] {
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        let (c0, r0) = ((p[0] - r).floor() as usize, (p[1] - r).floor() as usize);
        for row in r0..=(p[1] + r).ceil() as usize {
            for col in c0..=(p[0] + r).ceil() as usize {
                let (x, y) = (col as f64 + 0.5, row as f64 + 0.5);
                if (x - p[0]).hypot(y - p[1]) > r {
                    continue;
                }
                let v = (img.at(col, row) as f64 - 40.0).max(0.0);
                sx += v * x;
                sy += v * y;
                s += v;
            }
        }
        [sx / s, sy / s]
    }

    #[test]
    fn a_mark_lands_at_its_predicted_frame_pixel_under_rotation_shear_and_offset() {
        // A 0.1 mm scan of a 40 × 30 mm format, turned 23° with 0.4 % shear and 0.3 %
        // scale difference, the frame centre off the scan centre, upright and mirrored;
        // resampled at 0.08 mm (finer than the scan).
        let marks = [[0.0, 0.0], [-14.3, 9.7], [15.1, -11.2], [6.55, 12.05]];
        for mirror in [false, true] {
            let io = affine((600.0, 560.0), 0.1, 23.0, 0.004, [1.3, -0.9], mirror);
            let scan = render_scan(600, 560, &io, &marks);
            let frame = FiducialFrame::new([40.0, 30.0], 0.08).unwrap();
            assert_eq!((frame.width, frame.height), (500, 375));
            let (img, masked) = resample_scan(&scan, &io, &frame).unwrap();
            assert_eq!(masked, 0, "the scan covers the format");
            for m in marks {
                let want = frame.mm_to_pixel(m);
                let got = centroid(&img, want, 12.0);
                let err = (got[0] - want[0]).hypot(got[1] - want[1]);
                assert!(
                    err < 0.05,
                    "mirror {mirror}: mark at {m:?} mm: {got:?} vs predicted {want:?} ({err:.4} px)"
                );
            }
        }
    }

    #[test]
    fn what_the_scan_does_not_cover_is_masked() {
        // The scan's pixel centres span x_mm −10.025 + 0.05 … and y_mm ±9.95; the
        // 30 × 19 mm format sticks out by about 5 mm left and right. Samples exist inside
        // the pixel-centre hull: frame columns c with 0.5 ≤ c + 0.5 − 49.75 ≤ 199.5, i.e.
        // 50..=248; the other 101 columns of all 190 rows are masked.
        let io = InteriorOrientation::new(
            InteriorTransformKind::Affine,
            Matrix3::new(0.1, 0.0, -10.025, 0.0, -0.1, 10.0, 0.0, 0.0, 1.0),
        )
        .unwrap();
        let scan = GreyImage::filled(200, 200, 100.0);
        let frame = FiducialFrame::new([30.0, 19.0], 0.1).unwrap();
        assert_eq!((frame.width, frame.height), (300, 190));
        let (img, masked) = resample_scan(&scan, &io, &frame).unwrap();
        assert_eq!(masked, 101 * 190);
        for r in [0, 95, 189] {
            assert_eq!(img.at(49, r), MASKED as f32);
            assert_eq!(img.at(249, r), MASKED as f32);
            assert!((img.at(50, r) - 100.0).abs() < 1e-4);
            assert!((img.at(248, r) - 100.0).abs() < 1e-4);
        }
    }

    #[test]
    fn the_frame_camera_projects_where_the_film_camera_does_moved_into_the_frame() {
        let io = affine((11000.0, 11000.0), 0.021, -91.0, 0.002, [0.4, -0.7], false);
        let film = FilmCamera {
            width: 11000,
            height: 11000,
            focal_mm: 152.865,
            principal_point_mm: [-0.03, 0.012],
            distortion: Brown {
                k1: -0.02,
                k2: 0.004,
                k3: -0.0007,
                p1: 2e-5,
                p2: -1e-5,
            },
            interior: io,
        };
        let frame = FiducialFrame::new([230.0, 230.0], 0.025).unwrap();
        assert_eq!((frame.width, frame.height), (9200, 9200));
        let cam = frame.frame_camera(&film);
        assert_eq!(cam.fx, 152.865 / 0.025);
        assert_eq!(cam.cx, 4600.0 - 0.03 / 0.025);
        assert_eq!(cam.cy, 4600.0 - 0.012 / 0.025);
        let mut worst: f64 = 0.0;
        for i in 0..50 {
            let t = i as f64;
            let xc = Vector3::new(
                700.0 * (t * 0.37).sin(),
                650.0 * (t * 0.91).cos(),
                1500.0 + 20.0 * t,
            );
            let (a, b) = frame_pixel_of(&frame, &film, &xc);
            worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
        }
        assert!(worst < 1e-7, "frame camera vs film camera: {worst} px");
    }

    #[test]
    fn implausible_frames_are_refused() {
        assert!(FiducialFrame::new([230.0, 230.0], 0.0).is_err());
        assert!(FiducialFrame::new([230.0, 230.0], 0.5).is_err()); // 500 µm
        assert!(FiducialFrame::new([f64::NAN, 230.0], 0.02).is_err());
        assert!(FiducialFrame::new([-1.0, 230.0], 0.02).is_err());
        // A unit mistake (format in µm) would make 10¹⁰ pixels: refused before anything.
        let e = FiducialFrame::new([230_000.0, 230_000.0], 0.02).unwrap_err();
        assert!(e.to_string().contains("exceeds"), "{e}");
    }
}
