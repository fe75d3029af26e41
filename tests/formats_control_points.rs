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
        e.contains("n.csv") && e.contains("line 2") && e.contains("z \"abc\""),
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
