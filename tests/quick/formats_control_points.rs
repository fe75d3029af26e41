//! Control/check point CSV: PROJ conversion to the block CRS, refusal of geographic CRSs,
//! measurements attached by image name, errors naming file, line and element.

use cloudcontrol::block::{Block, BlockCamera, Photo, PointKind};
use cloudcontrol::formats::control_points as cp;
use cloudcontrol::formats::crs::Crs;
use cloudcontrol::geometry::{Camera, FrameCamera, Pose};
use std::path::PathBuf;

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("formats/control-points")
        .join(name)
}

fn block() -> Block {
    let mut b = Block::new();
    b.crs = Some("EPSG:32650".into());
    b.origin = [450_000.0, 4_400_000.0, 0.0];
    b.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "c".into(),
            model: Camera::Frame(FrameCamera::pinhole(2048, 1536, 2000.0)),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for (id, name) in [(1, "IMG_0001.tif"), (2, "IMG_0002.tif")] {
        b.photos.insert(
            id,
            Photo {
                id,
                name: name.into(),
                camera: 1,
                pose: Pose::new(nalgebra::Matrix3::identity(), nalgebra::Vector3::zeros()),
                status: cloudcontrol::block::PhotoStatus::Oriented,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    b
}

#[test]
fn wgs84_points_are_converted_to_the_projected_block_crs() {
    let pts = cp::read_points(&sample("sample_points_wgs84.csv")).unwrap();
    assert_eq!(pts.len(), 3);
    assert_eq!(pts[1].kind, PointKind::Control);
    assert_eq!(pts[2].kind, PointKind::Check);
    let mut b = block();
    let ids = cp::add_points(&mut b, &pts, &Crs::from_epsg(4326).unwrap()).unwrap();
    // Independent reference: `gdaltransform -s_srs EPSG:4326 -t_srs EPSG:32650`.
    let expect = [
        [500000.0, 4427757.21873837, 50.0],
        [457195.795080273, 4405679.11306364, 45.0],
    ];
    for (id, e) in ids.iter().zip(expect) {
        let w = b.to_world(&b.points[id].position);
        assert!(
            (w.x - e[0]).abs() < 1e-6 && (w.y - e[1]).abs() < 1e-6 && (w.z - e[2]).abs() < 1e-9,
            "{w:?} vs {e:?}"
        );
    }
    assert_eq!(b.points[&ids[0]].sigma, Some([0.02, 0.02, 0.05]));

    cp::add_measurements(
        &mut b,
        &cp::read_measurements(&sample("sample_measurements.csv")).unwrap(),
        &sample("sample_measurements.csv"),
    )
    .unwrap();
    let gcp1 = b.points.values().find(|p| p.name == "GCP1").unwrap();
    assert_eq!(gcp1.observations.len(), 1);
    assert_eq!(
        (
            gcp1.observations[0].photo,
            gcp1.observations[0].pixel,
            gcp1.observations[0].sigma_px
        ),
        (1, [1024.5, 768.25], 0.5)
    );

    // Written back in the block CRS and re-read: same points.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("points.csv");
    cp::write_points(&out, &b).unwrap();
    let again = cp::read_points(&out).unwrap();
    let mut b2 = block();
    cp::add_points(&mut b2, &again, &Crs::from_epsg(32650).unwrap()).unwrap();
    for (p, q) in b.points.values().zip(b2.points.values()) {
        assert_eq!((&p.name, p.kind, p.sigma), (&q.name, q.kind, q.sigma));
        assert!((p.position - q.position).norm() < 1e-9);
    }
}

#[test]
fn geographic_block_crs_is_refused_naming_a_projected_one() {
    let pts = cp::read_points(&sample("sample_points_wgs84.csv")).unwrap();
    let mut b = block();
    b.crs = Some("EPSG:4326".into());
    let e = cp::add_points(&mut b, &pts, &Crs::from_epsg(4326).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("not projected") && e.contains("EPSG:32650"),
        "{e}"
    );
    b.crs = Some("EPSG:4490".into()); // CGCS2000 geographic
    let e = cp::add_points(&mut b, &pts, &Crs::from_epsg(4326).unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("EPSG:32650"), "{e}");
    let e = Crs::parse("EPSG:12345678").unwrap_err().to_string();
    assert!(e.contains("EPSG:12345678"), "{e}");
}

#[test]
fn bad_csv_names_file_line_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let case = |name: &str, s: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, s).unwrap();
        cp::read_points(&p).unwrap_err().to_string()
    };
    let e = case("h.csv", "name,x,y,z\n");
    assert!(e.contains("h.csv") && e.contains("header"), "{e}");
    let e = case("n.csv", "id,x,y,z,sigma_xy,sigma_z\nA,1,2,abc,0.1,0.1\n");
    assert!(
        e.contains("n.csv: line 2, column z: \"abc\" is not a number"),
        "{e}"
    );
    let e = case(
        "k.csv",
        "id,x,y,z,sigma_xy,sigma_z,kind\nA,1,2,3,0.1,0.1,tie\n",
    );
    assert!(e.contains("line 2") && e.contains("tie"), "{e}");
    let e = case(
        "d.csv",
        "id,x,y,z,sigma_xy,sigma_z\nA,1,2,3,0.1,0.1\nA,1,2,3,0.1,0.1\n",
    );
    assert!(e.contains("line 3") && e.contains("line 2"), "{e}");

    let mut b = block();
    cp::add_points(
        &mut b,
        &cp::read_points(&sample("sample_points_wgs84.csv")).unwrap(),
        &Crs::from_epsg(4326).unwrap(),
    )
    .unwrap();
    let p = dir.path().join("m.csv");
    std::fs::write(&p, "id,image_name,x,y\nGCP1,missing.tif,1,2\n").unwrap();
    let e = cp::add_measurements(&mut b, &cp::read_measurements(&p).unwrap(), &p)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("m.csv") && e.contains("missing.tif") && e.contains("GCP1"),
        "{e}"
    );
}

/// The three files written by hand from formats/control-points/README.md, with what the
/// common CSV rules allow: comments before the header, upper-case names in another order,
/// quoted fields, file names with extensions.
#[test]
fn hand_written_files_as_documented() {
    let dir = tempfile::tempdir().unwrap();
    let points = dir.path().join("points.csv");
    std::fs::write(
        &points,
        "# surveyed 2024-05, UTM 50N\n\
         \n\
         ID, X, Y, Z, Sigma_XY, Sigma_Z, Kind\n\
         GCP1,500000.0,4427757.2,50.0,0.02,0.05,\n\
         \"CP 2\",457195.8,4405679.1,45.0,0.03,0.06,CHECK\n\
         # a point dropped in the field\n\
         CP3,457000,4405000,44,0.03,0.06\n",
    )
    .unwrap();
    let pts = cp::read_points(&points).unwrap();
    assert_eq!(
        pts.iter().map(|p| p.id.as_str()).collect::<Vec<_>>(),
        ["GCP1", "CP 2", "CP3"]
    );
    assert_eq!(pts[0].xyz, [500000.0, 4427757.2, 50.0]);
    assert_eq!(
        (pts[0].kind, pts[1].kind, pts[2].kind),
        (PointKind::Control, PointKind::Check, PointKind::Control)
    );
    assert_eq!((pts[1].sigma_xy, pts[1].sigma_z), (0.03, 0.06));

    let meas = dir.path().join("measurements.csv");
    std::fs::write(
        &meas,
        "# pixels, top-left corner origin\nX,Y,ID,IMAGE_NAME\n1024.5,768.25,GCP1,IMG_0001\n10,20,GCP1,\"IMG_0002.tif\"\n",
    )
    .unwrap();
    let m = cp::read_measurements(&meas).unwrap();
    assert_eq!(m[0].image_name, "IMG_0001");
    assert_eq!((m[0].pixel, m[0].sigma_px), ([1024.5, 768.25], 1.0));
    // The stem designates the photo IMG_0001.tif of the block.
    let mut b = block();
    cp::add_points(&mut b, &pts, &Crs::from_epsg(32650).unwrap()).unwrap();
    cp::add_measurements(&mut b, &m, &meas).unwrap();
    let gcp1 = b.points.values().find(|p| p.name == "GCP1").unwrap();
    let mut photos: Vec<u32> = gcp1.observations.iter().map(|o| o.photo).collect();
    photos.sort();
    assert_eq!(photos, [1, 2]);

    let cpi = dir.path().join("checkpoint_images.csv");
    std::fs::write(
        &cpi,
        "# checkpoint targets measured in the photos\n\
         Epoch,Photo,ID,Col,Row\n\
         reference_2024,ref_s01_003.tif,CP001,812.40,233.75\n\
         film_1978,film_s01_002.tif,CP001,1530.2,1011.9\n\
         reference_2024,\"ref_s01_004\",CP002,10,20\n\
         reference_2024,ref_s09_001.tif,CP002,11,21\n",
    )
    .unwrap();
    let r = cp::read_checkpoint_measurements(&cpi, "reference_2024").unwrap();
    assert_eq!(r.len(), 3);
    assert_eq!(
        r[0],
        cp::CheckpointMeasurement {
            line: 3,
            photo: "ref_s01_003.tif".into(),
            id: "CP001".into(),
            pixel: [812.40, 233.75],
        }
    );
    assert_eq!((r[1].line, r[1].photo.as_str()), (5, "ref_s01_004"));
    assert_eq!(
        cp::read_checkpoint_measurements(&cpi, "film_1978").unwrap()[0].pixel,
        [1530.2, 1011.9]
    );
    assert!(cp::read_checkpoint_measurements(&cpi, "other")
        .unwrap()
        .is_empty());
    // A row naming a photo the epoch does not have is refused with its line when the
    // epoch is evaluated (control::checkpoints).
    assert_eq!((r[2].line, r[2].photo.as_str()), (6, "ref_s09_001.tif"));
}

#[test]
fn hand_written_files_with_mistakes_name_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let e = cp::read_points(&write("p1.csv", "# c\nid,x,y,z,sigma_xy\nA,1,2,3,0.1\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("p1.csv: line 2: no column \"sigma_z\""), "{e}");
    let e = cp::read_points(&write(
        "p2.csv",
        "id,x,y,z,sigma_xy,sigma_z,note\nA,1,2,3,0.1,0.1,x\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("p2.csv: line 1: unknown column \"note\""), "{e}");
    let e = cp::read_points(&write(
        "p3.csv",
        "id,x,y,z,sigma_xy,sigma_z\nA,1,2,3,0,0.1\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("p3.csv: line 2, column sigma_xy: σ must be positive"),
        "{e}"
    );
    let e = cp::read_points(&write(
        "p4.csv",
        "id,x,y,z,sigma_xy,sigma_z\nA,1,2,3,0.1,NaN\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("p4.csv: line 2, column sigma_z:"), "{e}");
    // σ_z = inf: a plan control point (its height unknown).
    let pts = cp::read_points(&write(
        "p5.csv",
        "id,x,y,z,sigma_xy,sigma_z\nA,1,2,0,0.1,inf\n",
    ))
    .unwrap();
    assert_eq!((pts[0].sigma_xy, pts[0].sigma_z), (0.1, f64::INFINITY));
    let e = cp::read_points(&write(
        "p6.csv",
        "id,x,y,z,sigma_xy,sigma_z\nA,1,2,0,inf,inf\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("p6.csv: line 2, column sigma_z: point A: σ_xy and σ_z both inf"),
        "{e}"
    );
    let e = cp::read_measurements(&write(
        "m1.csv",
        "id,image_name,x,y\n\n# c\nA,a.tif,1,inf\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("m1.csv: line 4, column y: \"inf\" is not a finite number"),
        "{e}"
    );
    let e = cp::read_checkpoint_measurements(
        &write("c1.csv", "epoch,photo,id,col\ne,a.tif,CP1,1\n"),
        "e",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("c1.csv: line 1: no column \"row\""), "{e}");
    let e = cp::read_checkpoint_measurements(
        &write("c2.csv", "epoch,photo,id,col,row\nold,a.tif,CP1,1,1O\n"),
        "e",
    )
    .unwrap_err()
    .to_string();
    // Rows of other epochs are checked too.
    assert!(
        e.contains("c2.csv: line 2, column row: \"1O\" is not a number"),
        "{e}"
    );
    let e = cp::read_checkpoint_measurements(
        &write(
            "c3.csv",
            "epoch,photo,id,col,row\ne,a.tif,CP1,1,1\ne,a,CP1,2,2\n",
        ),
        "e",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("c3.csv: line 3") && e.contains("line 2"), "{e}");
}
