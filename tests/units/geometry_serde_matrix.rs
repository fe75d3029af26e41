//! Unit tests of `geometry::serde_matrix`.

mod tests {
    use cloudcontrol::geometry::rotation_from_vector;
    use cloudcontrol::geometry::serde_matrix::*;
    use nalgebra::Matrix3;
    use nalgebra::Vector3;
    use serde::{Deserialize, Serialize};

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Holder {
        #[serde(with = "row_major")]
        m: Matrix3<f64>,
        #[serde(default, with = "option_row_major")]
        o: Option<Matrix3<f64>>,
    }

    #[test]
    fn rotation_is_written_row_by_row_and_reads_back_exactly() {
        let r = rotation_from_vector(&Vector3::new(0.2, 0.5, -0.9));
        assert!(
            (r[(0, 1)] - r[(1, 0)]).abs() > 0.1,
            "test needs a non-symmetric R"
        );
        let h = Holder {
            m: r,
            o: Some(r.transpose()),
        };
        let v = serde_json::to_value(&h).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                assert_eq!(v["m"][i][j].as_f64().unwrap(), r[(i, j)]);
                assert_eq!(v["o"][i][j].as_f64().unwrap(), r[(j, i)]);
            }
        }
        let back: Holder = serde_json::from_str(&serde_json::to_string(&h).unwrap()).unwrap();
        assert_eq!(back, h);
    }

    #[test]
    fn hand_written_rows_read_as_rows() {
        let h: Holder =
            serde_json::from_str(r#"{"m": [[1, 2, 3], [4, 5, 6], [7, 8, 9]], "o": null}"#).unwrap();
        assert_eq!(h.m[(0, 1)], 2.0);
        assert_eq!(h.m[(1, 0)], 4.0);
        assert_eq!(h.m[(2, 0)], 7.0);
        assert_eq!(h.o, None);
        let h: Holder =
            serde_json::from_str(r#"{"m": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#).unwrap();
        assert_eq!(h.o, None);
    }

    #[test]
    fn flat_and_malformed_matrices_are_refused_with_a_reason() {
        let e = serde_json::from_str::<Holder>(r#"{"m": [1, 0, 0, 0, 1, 0, 0, 0, 1]}"#)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("three rows") && e.contains("flat array of 9"),
            "{e}"
        );
        let e = serde_json::from_str::<Holder>(
            r#"{"m": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "o": [1, 0, 0, 0, 1, 0, 0, 0, 1]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("flat array of 9"), "{e}");
        let e = serde_json::from_str::<Holder>(r#"{"m": [[1, 0], [0, 1]]}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("three rows of 3"), "{e}");
    }
}
