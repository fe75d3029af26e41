//! Unit tests of `formats::csv`.

mod tests {
    use cloudcontrol::formats::csv::*;
    use cloudcontrol::formats::Result;
    use serde::Deserialize;
    use std::path::Path;

    #[derive(Debug, Deserialize, PartialEq)]
    struct Row {
        id: String,
        z: f64,
        n: Option<u32>,
        note: Option<String>,
    }

    const LAYOUT: Layout = Layout {
        required: &["id", "z"],
        optional: &["n", "note"],
        extra: Extra::Refuse,
    };

    fn parse(text: &str) -> Result<Table<Row>> {
        parse_records(Path::new("t.csv"), text, &LAYOUT)
    }

    #[test]
    fn comments_blanks_case_quotes_and_line_numbers() {
        let t = parse(
            "# written by hand\n\n  ID , Z ,Note\r\na, 1.5 ,\"x, y\"\n   # inside\n\nb,-2e3\n",
        )
        .unwrap();
        assert_eq!(t.header_line, 3);
        assert_eq!(t.columns, vec!["id", "z", "note"]);
        assert!(t.has("note") && !t.has("n"));
        assert_eq!(
            t.rows,
            vec![
                (
                    4,
                    Row {
                        id: "a".into(),
                        z: 1.5,
                        n: None,
                        note: Some("x, y".into())
                    }
                ),
                (
                    7,
                    Row {
                        id: "b".into(),
                        z: -2000.0,
                        n: None,
                        note: None
                    }
                ),
            ]
        );
    }

    #[test]
    fn errors_name_the_line_and_column() {
        let e = |text: &str| parse(text).unwrap_err().to_string();
        assert_eq!(
            e("id,z\na,1\n#\nb,abc\n"),
            "t.csv: line 4, column z: \"abc\" is not a number"
        );
        assert_eq!(
            e("id,z\na,NaN\n"),
            "t.csv: line 2, column z: \"NaN\" is not a finite number"
        );
        assert_eq!(
            e("id,z\na,inf\n"),
            "t.csv: line 2, column z: \"inf\" is not a finite number"
        );
        assert_eq!(
            e("id,z,n\na,1,-3\n"),
            "t.csv: line 2, column n: \"-3\" is not an integer"
        );
        assert_eq!(
            e("id,z\na,\n"),
            "t.csv: line 2, column z: empty, a number is needed"
        );
        assert!(e("id,z\na,1,2\n").contains("line 2: 3 fields, the header has 2"));
        assert!(e("id,n\na,1\n").contains("line 1: no column \"z\" in the header"));
        assert!(e("# c\nid,z,zz\n").contains("line 2: unknown column \"zz\""));
        assert!(e("id,z,Z\n").contains("line 1, column z: the column appears twice"));
        assert!(e("\n# only a comment\n").contains("empty file: no header line"));
        // A missing trailing optional cell reads as empty.
        assert_eq!(parse("id,z,n\na,1\n").unwrap().rows[0].1.n, None);
    }

    #[test]
    fn unknown_columns_can_be_read_over() {
        let t: Table<Row> = parse_records(
            Path::new("t.csv"),
            "id,extra,z\na,whatever,3\n",
            &Layout {
                extra: Extra::Ignore,
                ..LAYOUT
            },
        )
        .unwrap();
        assert_eq!(t.rows[0].1.z, 3.0);
    }
}
