//! Unit tests of `control::strips`.

mod tests {
    use cloudcontrol::control::strips::*;
    use cloudcontrol::geometry::matrix_from_opk;
    use nalgebra::Vector3;

    #[test]
    fn kappa_follows_the_flight_direction() {
        // For every axis and flight direction, the chosen camera axis (rows of R are the
        // camera axes in world coordinates; pixel y runs down, as camera y) points along
        // the flight.
        for axis in [
            FlightAxis::PlusX,
            FlightAxis::MinusX,
            FlightAxis::PlusY,
            FlightAxis::MinusY,
        ] {
            for deg in [0.0, 30.0, 90.0, 135.0, 180.0, 250.0, 315.0] {
                let a = f64::to_radians(deg);
                let d = [a.cos(), a.sin()];
                let r = matrix_from_opk(0.0, 0.0, kappa_from_direction(d, axis));
                let forward = match axis {
                    FlightAxis::PlusX => r.row(0).transpose(),
                    FlightAxis::MinusX => -r.row(0).transpose(),
                    FlightAxis::PlusY => r.row(1).transpose(),
                    FlightAxis::MinusY => -r.row(1).transpose(),
                };
                assert!(
                    (forward - Vector3::new(d[0], d[1], 0.0)).norm() < 1e-12,
                    "{axis:?} flying {deg}°: forward axis {forward:?}"
                );
                // Nadir: camera z looks down.
                assert!((r.row(2)[2] + 1.0).abs() < 1e-12);
            }
        }
        // Flying east with image x along track: kappa 0 (image x east, image top north).
        assert!(kappa_from_direction([1.0, 0.0], FlightAxis::PlusX).abs() < 1e-12);
        // Flying north with image up along track: kappa 0 as well.
        assert!(kappa_from_direction([0.0, 1.0], FlightAxis::MinusY).abs() < 1e-12);
    }

    #[test]
    fn centres_are_interpolated_at_equal_base() {
        let strip = StripEnds {
            name: "S1".into(),
            photos: (0..5).map(|i| format!("p{i}")).collect(),
            first: [0.0, 0.0, 3000.0],
            last: [2000.0, 0.0, 3020.0],
            flight_axis: FlightAxis::PlusX,
        };
        let out = interpolate_strip(&strip, 0.1, 3f64.to_radians()).unwrap();
        assert_eq!(out.len(), 5);
        assert!((out[2].0.center - Vector3::new(1000.0, 0.0, 3010.0)).norm() < 1e-9);
        assert!(out[2].1.center_sigma[0] > out[1].1.center_sigma[0]);
        let bad = StripEnds {
            photos: vec!["a".into()],
            ..strip.clone()
        };
        assert!(interpolate_strip(&bad, 0.1, 0.05).is_err());
        let bad = StripEnds {
            last: strip.first,
            ..strip
        };
        assert!(interpolate_strip(&bad, 0.1, 0.05).is_err());
    }
}
