//! Unit tests of the task form of an epoch's rounds (`control::rounds`): a store of chips
//! cut from photos, written and read back as a round's file holds it, matches exactly as
//! the store it was written from, whatever the photo's grey values.

mod tests {
    use cloudcontrol::control::chips::{
        ChipMatchOptions, ChipMatcher, ChipStore, ChipView, ControlPoint,
    };
    use cloudcontrol::control::orient::{ControlPatch, PatchMatcher};
    use cloudcontrol::control::predict::Prediction;
    use cloudcontrol::geometry::{self, Camera, FrameCamera, Pose};
    use cloudcontrol::matching::{GreyImage, Pyramid};
    use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

    /// A textured photo, shifted by (`dx`, `dy`) px, grey values `scale · texture` rounded
    /// or not.
    fn photo(dx: f64, dy: f64, scale: f32, round: bool) -> GreyImage {
        let (w, h) = (200usize, 200usize);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 - dx, y as f64 - dy);
                let t = 0.5
                    + 0.2 * (0.31 * u + 0.05 * v).sin()
                    + 0.15 * (0.11 * u - 0.27 * v).cos()
                    + 0.1 * (0.043 * u * v / 40.0).sin();
                let g = scale * t as f32;
                data.push(if round { g.round() } else { g });
            }
        }
        GreyImage::new(w, h, data).unwrap()
    }

    #[test]
    fn a_written_store_matches_as_the_store_it_was_written_from() {
        let cam = Camera::Frame(FrameCamera::pinhole(200, 200, 200.0));
        let pose = Pose::new(
            Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
            Vector3::new(0.0, 0.0, 100.0),
        );
        let mut sizes = Vec::new();
        // 8-bit photo, 16-bit photo, grey values with fractions (an RGB average).
        for (scale, round) in [(255.0, true), (60000.0, true), (255.0, false)] {
            let img = photo(0.0, 0.0, scale, round);
            let px = [100.0, 100.0];
            let ray = geometry::back_project(&cam, &pose, px).unwrap();
            let x = ray.origin + ray.direction * (-ray.origin.z / ray.direction.z);
            let view = ChipView::cut(&cam, &pose, &img, px, 38, Some(0)).unwrap();
            let point = ControlPoint {
                key: None,
                label: "tie:p:0".into(),
                position: x,
                sigma: [0.5, 0.5, 2.0],
                normal: Vector3::z(),
                views: vec![view],
            };
            let store = ChipStore::from_points(Vector3::new(1.0, 2.0, 3.0), vec![point]);
            let bytes = rmp_serde::to_vec_named(&store).unwrap();
            sizes.push(bytes.len());
            let back: ChipStore<'static> = rmp_serde::from_slice(&bytes).unwrap();
            // Written again, the same bytes: nothing was lost.
            assert_eq!(rmp_serde::to_vec_named(&back).unwrap(), bytes);
            assert_eq!(back.origin, store.origin);

            // The target: the same ground shifted by (3, 1) px.
            let target = Pyramid::from_image(photo(3.0, 1.0, scale, round), 6, 16);
            let opts = ChipMatchOptions::default();
            let patch = ControlPatch {
                id: 0,
                position: x,
                covariance: Matrix3::zeros(),
            };
            let pred = Prediction {
                pixel: Vector2::new(100.0, 100.0),
                covariance: Matrix2::identity(),
            };
            let found = |s: &ChipStore| {
                ChipMatcher::new(&cam, &target, s, &opts)
                    .find(&patch, &pose, &pred, [10.0, 10.0])
                    .map(|m| (m.pixel, m.sigma_px, m.ncc))
            };
            let (a, b) = (found(&store), found(&back));
            let (pixel, _, _) = a.expect("the chip is found in the shifted photo");
            assert!(
                (pixel - Vector2::new(103.0, 101.0)).norm() < 0.1,
                "scale {scale}: {pixel:?}"
            );
            assert_eq!(a, b, "scale {scale}, rounded {round}");
        }
        // 8-bit grey values take a byte a pixel, 16-bit two, others four.
        assert!(
            sizes[0] < sizes[1] && sizes[1] < sizes[2],
            "written sizes {sizes:?}"
        );
    }

    #[test]
    fn a_match_round_naming_points_or_photos_it_lacks_is_refused() {
        use cloudcontrol::control::epoch_ties::MatchRound;
        let part = |tracks: &str, photos: &str, ids: &str| -> MatchRound {
            serde_json::from_str(&format!(
                r#"{{"store": {{"origin": [0, 0, 0], "points": []}}, "tracks": {tracks},
                    "views": [null], "photos": {photos}, "band": null{ids}}}"#
            ))
            .unwrap()
        };
        let round = |tracks: &str, photos: &str| part(tracks, photos, "");
        assert!(round("[]", "[0]").check().is_ok());
        let e = round("[[3, [[0, 0, 0], []]]]", "[0]").check().unwrap_err();
        assert!(e.contains("point 3") && e.contains("0 points"), "{e}");
        let e = round("[]", "[2]").check().unwrap_err();
        assert!(e.contains("photo 2") && e.contains("1 views"), "{e}");
        // A photo's part names each track's index in the whole round.
        let e = part("[]", "[0]", r#", "ids": [4]"#).check().unwrap_err();
        assert!(e.contains("1 track indices for 0 tracks"), "{e}");
    }
}
