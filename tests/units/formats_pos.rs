//! Unit tests of `formats::pos`.

mod tests {
    use cloudcontrol::formats::pos::*;

    fn file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pos.csv");
        std::fs::write(&p, text).unwrap();
        (d, p)
    }

    #[test]
    fn pos_as_documented() {
        // Written by hand from formats/pos/README.md.
        let (_d, p) = file(
            "# POS of the 2024 flight, exported by hand\n\
             NAME, X, Y, Z, Omega, Phi, Kappa, Sigma_XYZ, Sigma_Angle\n\
             ref_000.tif,500120.512,4400210.330,1523.10,0.21,-0.35,90.12,10,3\n\
             \n\
             \"ref 001.tif\",500320.5,4400210.3,1524,0,0,-90,0.05,0.01\n",
        );
        let r = read_pos(&p).unwrap();
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].name, "ref_000.tif");
        assert_eq!(r[0].center, [500120.512, 4400210.330, 1523.10]);
        assert!((r[0].opk[2] - 90.12f64.to_radians()).abs() < 1e-15);
        assert_eq!(r[0].sigma_xyz, Some(10.0));
        assert!((r[0].sigma_angle.unwrap() - 3f64.to_radians()).abs() < 1e-15);
        assert_eq!(r[1].name, "ref 001.tif");
        // Without the σ pair.
        let (_d, p) = file("name,x,y,z,omega,phi,kappa\nref_000,1,2,3,0,0,0\n");
        let r = read_pos(&p).unwrap();
        assert_eq!((r[0].sigma_xyz, r[0].sigma_angle), (None, None));
    }

    #[test]
    fn pos_errors_name_line_and_column() {
        let err = |text: &str| read_pos(&file(text).1).unwrap_err().to_string();
        let h = "name,x,y,z,omega,phi,kappa";
        assert!(err(&format!("{h}\na.tif,1,2,3,0,0,zero\n"))
            .ends_with("pos.csv: line 2, column kappa: \"zero\" is not a number"));
        assert!(err(&format!("# c\n{h}\na.tif,1,2,nan,0,0,0\n"))
            .contains("line 3, column z: \"nan\" is not a finite number"));
        assert!(err("name,x,y,z,omega,phi\na,1,2,3,0,0\n")
            .contains("line 1: no column \"kappa\" in the header"));
        assert!(err(&format!("{h},sigma\na,1,2,3,0,0,0,1\n"))
            .contains("line 1: unknown column \"sigma\""));
        assert!(err(&format!("{h},sigma_xyz\na,1,2,3,0,0,0,1\n")).contains("come together"));
        assert!(
            err(&format!("{h},sigma_xyz,sigma_angle\na,1,2,3,0,0,0,0,1\n"))
                .contains("line 2, column sigma_xyz: σ must be positive")
        );
        assert!(err(&format!(
            "{h}\na.tif,1,2,3,0,0,0\nb,1,2,3,0,0,0\na.png,1,2,3,0,0,0\n"
        ))
        .contains("line 4, column name: photo \"a.png\" is already listed on line 2"));
        assert!(err(&format!("{h}\n")).contains("no photo listed"));
    }

    #[test]
    fn pos_round_trip() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pos.csv");
        let recs = vec![
            PosRecord {
                name: "a.tif".into(),
                center: [500100.0, 4400200.0, 1500.0],
                opk: [0.01, -0.02, 1.5],
                sigma_xyz: Some(10.0),
                sigma_angle: Some(3f64.to_radians()),
            },
            PosRecord {
                name: "b.tif".into(),
                center: [500300.0, 4400200.0, 1502.0],
                opk: [0.0, 0.0, 1.5],
                sigma_xyz: Some(10.0),
                sigma_angle: Some(3f64.to_radians()),
            },
        ];
        write_pos(&p, &recs).unwrap();
        let back = read_pos(&p).unwrap();
        for (a, b) in recs.iter().zip(&back) {
            assert_eq!(a.name, b.name);
            assert!((0..3)
                .all(|i| (a.center[i] - b.center[i]).abs() < 1e-4
                    && (a.opk[i] - b.opk[i]).abs() < 1e-9));
        }
    }

    #[test]
    fn photo_keys_match_file_names_and_stems() {
        assert_eq!(photo_key("ref_000.tif"), "ref_000");
        assert_eq!(photo_key("ref_000"), "ref_000");
        assert_eq!(photo_key("scans/1978/F1_001.TIFF"), "F1_001");
        assert_eq!(photo_key("c:\\scans\\f1.JPG"), "f1");
        assert_eq!(photo_key("p.2012.05"), "p.2012.05");
        assert_eq!(photo_key("p.2012.05.png"), "p.2012.05");
        assert_eq!(photo_key(".png"), ".png");
    }

    #[test]
    fn strips_as_documented() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("strips.csv");
        // Written by hand from formats/pos/README.md.
        std::fs::write(
            &p,
            "# flight index of 1978, read off the map\n\
             Strip,Photo,X,Y,Z,Flight_Axis\n\
             1,f1_001.tif,500000.0,4399800.0,3050,+x\n\
             1,f1_002.tif,,,,\n\
             1,\"f1_003.tif\",,,,image_x\n\
             1,f1_004.tif,501800.0,4399810.0,3060,+x\n\
             2,f2_001.tif,501800.0,4400900.0,3050,image_up\n\
             2,f2_002.tif,500000.0,4400910.0,3050,-y\n",
        )
        .unwrap();
        let s = read_strips(&p).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(
            s[0].photos,
            vec!["f1_001.tif", "f1_002.tif", "f1_003.tif", "f1_004.tif"]
        );
        assert_eq!(s[0].first, [500000.0, 4399800.0, 3050.0]);
        assert_eq!(s[0].last, [501800.0, 4399810.0, 3060.0]);
        assert_eq!(s[0].flight_axis, FlightAxis::PlusX);
        assert_eq!(s[1].flight_axis, FlightAxis::MinusY);
        assert_eq!(s[1].first, [501800.0, 4400900.0, 3050.0]);
        // Without the column: +x, the classic film convention.
        std::fs::write(
            &p,
            "strip,photo,x,y,z\n1,a,0,0,3000\n1,b,,,\n1,c,2000,0,3000\n",
        )
        .unwrap();
        let s = read_strips(&p).unwrap();
        assert_eq!(s[0].flight_axis, FlightAxis::PlusX);
        // Round trip through the writer.
        let all = [
            FlightAxis::PlusX,
            FlightAxis::MinusX,
            FlightAxis::PlusY,
            FlightAxis::MinusY,
        ];
        let strips: Vec<StripEnds> = all
            .iter()
            .enumerate()
            .map(|(i, &a)| StripEnds {
                name: format!("s{i}"),
                photos: (0..3).map(|k| format!("s{i}_{k}.png")).collect(),
                first: [i as f64, 0.0, 100.0],
                last: [i as f64, 50.0, 100.0],
                flight_axis: a,
            })
            .collect();
        write_strips(&p, &strips).unwrap();
        assert_eq!(read_strips(&p).unwrap(), strips);
    }

    #[test]
    fn strip_errors_name_the_line() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("strips.csv");
        let err = |text: &str| {
            std::fs::write(&p, text).unwrap();
            read_strips(&p).unwrap_err().to_string()
        };
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n");
        assert!(
            e.ends_with("strips.csv: line 3: strip 1: the last photo needs its centre"),
            "{e}"
        );
        let e =
            err("strip,photo,x,y,z,flight_axis\n1,f1,0,0,3000,-y\n1,f2,,,,\n1,f3,9,0,3000,+x\n");
        assert!(
            e.ends_with(
                "line 4, column flight_axis: strip 1: flight axis +x differs from -y given on line 2"
            ),
            "{e}"
        );
        let e = err("strip,photo,x,y,z,flight_axis\n1,f1,0,0,3000,up\n1,f2,1,0,3000,\n");
        assert!(
            e.contains("line 2, column flight_axis: unknown variant `up`"),
            "{e}"
        );
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n1,f3,1,x,3000\n");
        assert!(e.contains("line 4, column y: \"x\" is not a number"), "{e}");
        let e = err("strip,photo,x,y\n1,f1,0,0\n");
        assert!(e.contains("line 1: no column \"z\""), "{e}");
        let e = err("strip,photo,x,y,z,kappa\n1,f1,0,0,0,0\n");
        assert!(e.contains("unknown column \"kappa\""), "{e}");
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,5,,\n");
        assert!(e.contains("line 3: x, y and z are given together"), "{e}");
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f1.tif,5,0,3000\n");
        assert!(
            e.contains("line 3, column photo: photo \"f1.tif\" is already listed on line 2"),
            "{e}"
        );
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n");
        assert!(
            e.contains("line 2: strip 1: needs at least two photos"),
            "{e}"
        );
    }
}
