//! Readers that went to the project's crates and mechanisms (issue 52, item 10): PLY
//! through `ply-rs-bw` (bounded before the crate reads), `lidar eval --checkpoints`
//! through the control points reader, and `resect --points` through the one CSV reader,
//! its columns `col,row,X,Y,Z` (the old header `x,y,X,Y,Z` still read).

use crate::common::{cli, exe, says};
use crate::lidar_synth::{ground, two_strips, write_las, CrsVlr, E0, EPSG, N0};
use cloudcontrol::lidar::points_io::read_xyz;
use cloudcontrol::lidar::LidarError;
use std::path::Path;

fn ply_header(format: &str, count: &str, props: &str) -> Vec<u8> {
    format!("ply\nformat {format} 1.0\nelement vertex {count}\n{props}end_header\n").into_bytes()
}

/// The crate alone, given a header of 4·10⁹ vertices over one vertex of data, fails at
/// the end of the file without sizing anything from the count (a vector of 4·10⁹
/// elements would abort the process); `read_xyz` refuses it from the header before the
/// crate reads the data.
#[test]
fn a_ply_header_of_four_billion_vertices_in_a_tiny_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let props = "property float x\nproperty float y\nproperty float z\n";
    for format in ["binary_little_endian", "ascii"] {
        let mut b = ply_header(format, "4000000000", props);
        if format == "ascii" {
            b.extend(b"1 2 3\n");
        } else {
            for v in [1.0f32, 2.0, 3.0] {
                b.extend(v.to_le_bytes());
            }
        }
        let mut r = std::io::BufReader::new(&b[..]);
        let crate_alone =
            ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new().read_ply(&mut r);
        assert!(crate_alone.is_err(), "{format}");
        let f = tmp.path().join(format!("{format}.ply"));
        std::fs::write(&f, &b).unwrap();
        let e = read_xyz(&f).unwrap_err();
        assert!(matches!(e, LidarError::TooLarge { .. }), "{e}");
        says(
            &e.to_string(),
            &f,
            &["PLY element vertex count", "4000000000", "exceeds 1,"],
        );
    }
    // An element before the vertices is bounded too.
    let f = tmp.path().join("faces_first.ply");
    let mut b =
        b"ply\nformat ascii 1.0\nelement face 4000000000\nproperty list uchar int vertex_indices\n"
            .to_vec();
    b.extend(
        b"element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    );
    b.extend(b"0\n1 2 3\n");
    std::fs::write(&f, b).unwrap();
    let e = read_xyz(&f).unwrap_err();
    assert!(matches!(e, LidarError::TooLarge { .. }), "{e}");
    says(
        &e.to_string(),
        &f,
        &["PLY element face count", "4000000000"],
    );
}

#[test]
fn ply_files_read_through_the_crate() {
    let tmp = tempfile::tempdir().unwrap();
    let pts: [[f64; 3]; 2] = [
        [500_001.25, 4_400_002.5, 98.75],
        [500_010.0, 4_400_020.0, -3.5],
    ];
    // Binary, both byte orders, doubles among other properties.
    let props = "property uchar red\nproperty double x\nproperty double y\nproperty double z\n\
                 property float intensity\n";
    for (format, le) in [("binary_little_endian", true), ("binary_big_endian", false)] {
        let mut b = ply_header(format, "2", props);
        for p in &pts {
            b.push(7);
            for v in p {
                b.extend(if le { v.to_le_bytes() } else { v.to_be_bytes() });
            }
            b.extend(if le {
                0.5f32.to_le_bytes()
            } else {
                0.5f32.to_be_bytes()
            });
        }
        let f = tmp.path().join(format!("{format}.ply"));
        std::fs::write(&f, b).unwrap();
        assert_eq!(read_xyz(&f).unwrap(), pts, "{format}");
    }
    // Ascii, after a face element of none, with a comment.
    let f = tmp.path().join("ascii.ply");
    let text = "ply\nformat ascii 1.0\ncomment made by hand\nelement face 0\n\
                property list uchar int vertex_indices\nelement vertex 2\nproperty double x\n\
                property double y\nproperty double z\nend_header\n\
                500001.25 4400002.5 98.75\n500010 4400020 -3.5\n";
    std::fs::write(&f, text).unwrap();
    assert_eq!(read_xyz(&f).unwrap(), pts);
    // Refusals, each naming the file.
    let cases: [(&str, &[u8], &str); 5] = [
        ("no_magic.ply", b"plx\nformat ascii 1.0\n", "not a PLY file"),
        (
            "no_end.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
            "no end_header",
        ),
        (
            "no_z.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
            "no z property",
        ),
        (
            "truncated.ply",
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
            "truncated",
        ),
        (
            "nan.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\nnan 2 3\n",
            "PLY element vertex",
        ),
    ];
    for (name, bytes, words) in cases {
        let f = tmp.path().join(name);
        std::fs::write(&f, bytes).unwrap();
        let e = read_xyz(&f).unwrap_err().to_string();
        says(&e, &f, &[words]);
        assert!(!e.contains('\n'), "{e}");
    }
    // A coordinate that is not finite (binary NaN) is refused naming its vertex.
    let f = tmp.path().join("nan_binary.ply");
    let mut b = ply_header(
        "binary_little_endian",
        "1",
        "property float x\nproperty float y\nproperty float z\n",
    );
    for v in [1.0f32, f32::NAN, 3.0] {
        b.extend(v.to_le_bytes());
    }
    std::fs::write(&f, b).unwrap();
    says(
        &read_xyz(&f).unwrap_err().to_string(),
        &f,
        &["vertex 0 is not finite"],
    );
}

/// `lidar eval --checkpoints` reads the control points CSV as the pipeline does: columns
/// in any order and any case, comments, quoted ids, σ columns; errors name line and
/// column.
#[test]
fn lidar_eval_reads_its_checkpoints_with_the_control_points_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let (pts, _) = two_strips(2.0, 0.0, 0.0, 3);
    let las = tmp.path().join("ground.las");
    write_las(&las, &pts, 4, CrsVlr::Wkt(EPSG), false);
    let at = [(30.0, 40.0), (60.0, 70.0)];
    let mut csv = String::from("# surveyed 2024\nZ, X, Y, Id, sigma_xy, sigma_z\n");
    for (k, (dx, dy)) in at.iter().enumerate() {
        let (x, y) = (E0 + dx, N0 + dy);
        csv.push_str(&format!(
            "{},{x},{y},\"CP {k}, left\",0.01,0.01\n",
            ground(x, y)
        ));
    }
    let cps = tmp.path().join("cps.csv");
    std::fs::write(&cps, csv).unwrap();
    let o = std::process::Command::new(exe())
        .args(["--json", "lidar", "eval", "--lidar"])
        .arg(&las)
        .arg("--checkpoints")
        .arg(&cps)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ids: Vec<&str> = v["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["CP 0, left", "CP 1, left"]);
    assert!(v["rmse_m"].as_f64().unwrap() < 0.1, "{v}");
    // A missing cell and a header without ids, each named.
    for (text, words) in [
        ("id,x,y,z\nA,1,2,\n", &["line 2", "z"][..]),
        ("x,y,z\n1,2,3\n", &["id"][..]),
    ] {
        std::fs::write(&cps, text).unwrap();
        let (ok, _, err) = cli(&[
            "lidar",
            "eval",
            "--lidar",
            las.to_str().unwrap(),
            "--checkpoints",
            cps.to_str().unwrap(),
        ]);
        assert!(!ok);
        says(&err, &cps, words);
    }
}

/// Projects `world` with a nadir frame camera at `centre` (focal `f` px, principal point
/// `c`): x right, y down in the image.
fn project(world: [f64; 3], centre: [f64; 3], f: f64, c: [f64; 2]) -> [f64; 2] {
    let d = [
        world[0] - centre[0],
        -(world[1] - centre[1]),
        centre[2] - world[2],
    ];
    [c[0] + f * d[0] / d[2], c[1] + f * d[1] / d[2]]
}

fn resect(dir: &Path, name: &str, header: &str, rows: &[String]) -> (bool, String, String) {
    let f = dir.join(name);
    std::fs::write(&f, format!("{header}\n{}\n", rows.join("\n"))).unwrap();
    cli(&[
        "--json",
        "resect",
        "--camera",
        "1000,1000,500,500",
        "--width",
        "1000",
        "--height",
        "1000",
        "--points",
        f.to_str().unwrap(),
    ])
}

#[test]
fn resect_points_are_read_by_the_csv_reader_with_the_new_and_the_old_header() {
    let tmp = tempfile::tempdir().unwrap();
    let centre = [500_100.0, 4_400_050.0, 1000.0];
    let mut rows = Vec::new();
    for (dx, dy, z) in [
        (-200.0, -150.0, 10.0),
        (180.0, -160.0, 35.0),
        (210.0, 170.0, 5.0),
        (-190.0, 190.0, 60.0),
        (0.0, 10.0, 80.0),
        (90.0, -40.0, 20.0),
        (-60.0, 80.0, 0.0),
        (130.0, 60.0, 45.0),
    ] {
        let w = [centre[0] + dx, centre[1] + dy, z];
        let p = project(w, centre, 1000.0, [500.0, 500.0]);
        rows.push(format!("{},{},{},{},{}", p[0], p[1], w[0], w[1], w[2]));
    }
    let mut centres = Vec::new();
    for (name, header) in [("new.csv", "col,row,X,Y,Z"), ("old.csv", "x,y,X,Y,Z")] {
        let (ok, out, err) = resect(tmp.path(), name, header, &rows);
        assert!(ok, "{name}: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let c: Vec<f64> = v["pose"]["center"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        for k in 0..3 {
            assert!((c[k] - centre[k]).abs() < 0.01, "{name}: centre {c:?}");
        }
        centres.push(c);
    }
    assert_eq!(centres[0], centres[1]);
    // The new layout in any order and case; errors name the line and the column.
    let reordered: Vec<String> = rows
        .iter()
        .map(|r| {
            let v: Vec<&str> = r.split(',').collect();
            format!("{},{},{},{},{}", v[2], v[3], v[4], v[0], v[1])
        })
        .collect();
    let (ok, _, err) = resect(tmp.path(), "reordered.csv", "X,Y,Z,Col,Row", &reordered);
    assert!(ok, "{err}");
    let mut bad = rows.clone();
    bad[2] = "1,2,abc,4,5".into();
    let (ok, _, err) = resect(tmp.path(), "bad.csv", "col,row,X,Y,Z", &bad);
    assert!(!ok);
    says(
        &err,
        &tmp.path().join("bad.csv"),
        &["line 4", "column x", "abc"],
    );
    // Names that differ only in case are the old header only as written so.
    let (ok, _, err) = resect(tmp.path(), "mixed.csv", "X,Y,X,Y,Z", &rows);
    assert!(!ok);
    says(&err, &tmp.path().join("mixed.csv"), &["appears twice"]);
}
