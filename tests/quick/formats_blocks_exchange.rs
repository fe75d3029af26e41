//! BlocksExchange XML against the synthetic block with known truth, the real iTwin
//! sample, and COLMAP models (conversion both ways reproduces projections).

use cloudcontrol::block::{Block, PointKind};
use cloudcontrol::formats::blocks_exchange::{self as bx, Document, WriteOptions};
use cloudcontrol::formats::colmap;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}
fn synthetic() -> PathBuf {
    root().join(
        "formats/blocks-exchange/synthetic_historical_with_dcp/synthetic_historical_with_dcp.xml",
    )
}

/// Largest |projection − measurement| over all observations (points with a known height).
fn max_residual(b: &Block) -> f64 {
    let mut worst: f64 = 0.0;
    for p in b.points.values() {
        if p.sigma.is_some_and(|s| s[2].is_infinite()) {
            continue;
        }
        for o in &p.observations {
            let ph = &b.photos[&o.photo];
            let cam = &b.cameras[&ph.camera].model;
            let px = cam.project(&ph.pose.to_camera(&p.position)).unwrap();
            worst = worst.max((px.x - o.pixel[0]).abs().max((px.y - o.pixel[1]).abs()));
        }
    }
    worst
}

/// Projections of every point in every photo (pixels), keyed by (photo, point name/order).
fn projections(b: &Block) -> Vec<(u32, [f64; 2])> {
    let mut out = Vec::new();
    for p in b.points.values() {
        for o in &p.observations {
            let ph = &b.photos[&o.photo];
            let cam = &b.cameras[&ph.camera].model;
            let px = cam.project(&ph.pose.to_camera(&p.position)).unwrap();
            out.push((o.photo, [px.x, px.y]));
        }
    }
    out
}

#[test]
fn synthetic_block_matches_its_truth() {
    let b = bx::read(&synthetic()).unwrap();
    assert_eq!(b.crs.as_deref(), Some("EPSG:25833"));
    assert_eq!(b.cameras.len(), 2);
    assert_eq!(b.photos.len(), 5);
    // Film camera: f = 153.456 mm / 0.015 mm; PP from xmm/ymm with y up; +0.5 px shift.
    let film = b.cameras[&1].model.params();
    assert!((film[0] - 10230.4).abs() < 1e-9);
    assert!((film[2] - (7680.3 + 0.5)).abs() < 1e-9, "{film:?}");
    assert!((film[3] - (7680.033333333334 + 0.5)).abs() < 1e-9);
    // P1/P2 swapped into OpenCV order (k1 k2 k3 p1 p2 in our params).
    assert_eq!(&film[4..], &[-0.021, 0.004, 0.0, -2e-5, 1.5e-5]);
    // Measurements (4 decimals in the file) equal the projections of the true points.
    let r = max_residual(&b);
    assert!(r < 2e-3, "max residual {r} px");
    let kinds: Vec<_> = b
        .points
        .values()
        .map(|p| (p.name.as_str(), p.kind))
        .collect();
    assert!(kinds.contains(&("CHK_field_corner", PointKind::Check)));
    assert!(kinds.contains(&("GCP_church_tower", PointKind::Control)));
    assert!(kinds.contains(&("tp1", PointKind::Tie)));
    let hcp = b
        .points
        .values()
        .find(|p| p.name == "HCP_road_cross")
        .unwrap();
    assert!(hcp.sigma.unwrap()[2].is_infinite());
    // OPK photo 1: centre and matrix of truth.json.
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(synthetic().with_file_name("truth.json")).unwrap(),
    )
    .unwrap();
    let m = &truth["photos"]["1"]["M_world_to_camaxes"];
    let r = b.photos[&1].pose.rotation;
    for i in 0..3 {
        for j in 0..3 {
            // XRightYUp: our R = diag(1,−1,−1)·M.
            let s = if i == 0 { 1.0 } else { -1.0 };
            assert!((r[(i, j)] - s * m[i][j].as_f64().unwrap()).abs() < 1e-12);
        }
    }
    let c = b.to_world(&b.photos[&1].pose.center);
    assert!((c - nalgebra::Vector3::new(499050.0, 5800010.0, 2350.0)).norm() < 1e-9);
}

#[test]
fn synthetic_block_equals_its_colmap_equivalent() {
    let b = bx::read(&synthetic()).unwrap();
    let c = colmap::read(&root().join("formats/colmap/synthetic_from_blocksexchange_txt")).unwrap();
    for (id, cam) in &c.cameras {
        let (p, q) = (cam.model.params(), b.cameras[id].model.params());
        for (x, y) in p.iter().zip(&q) {
            assert!(
                (x - y).abs() <= 1e-9 * x.abs().max(1.0),
                "camera {id}: {p:?} vs {q:?}"
            );
        }
    }
    for (id, ph) in &c.photos {
        let q = &b.photos[id];
        assert!((ph.pose.rotation - q.pose.rotation).abs().max() < 1e-12);
        assert!((ph.pose.center - b.to_world(&q.pose.center)).abs().max() < 1e-6);
    }
}

#[test]
fn written_xml_reimports_equal() {
    let b = bx::read(&synthetic()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.xml");
    bx::write(&out, &b, &WriteOptions::default()).unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    for tag in [
        "<BlocksExchange version=\"2.1\">",
        "<FocalLengthPixels>",
        "<CameraOrientation>XRightYDown</CameraOrientation>",
        "<M_00>",
        "<Category>Horizontal</Category>",
        "<CheckPoint>true</CheckPoint>",
    ] {
        assert!(text.contains(tag), "missing {tag}");
    }
    let back = bx::read(&out).unwrap();
    assert_eq!(back.crs, b.crs);
    assert_eq!(back.photos.len(), b.photos.len());
    for (k, p) in &b.photos {
        let q = &back.photos[k];
        assert_eq!(p.name, q.name);
        assert!((p.pose.rotation - q.pose.rotation).abs().max() < 1e-15);
        assert!(
            (b.to_world(&p.pose.center) - back.to_world(&q.pose.center))
                .abs()
                .max()
                < 1e-9
        );
    }
    for (k, c) in &b.cameras {
        let (p, q) = (c.model.params(), back.cameras[k].model.params());
        for (x, y) in p.iter().zip(&q) {
            assert!((x - y).abs() <= 1e-12 * x.abs().max(1.0));
        }
    }
    for (k, p) in &b.points {
        let q = &back.points[k];
        assert_eq!(
            (&p.name, p.kind, p.sigma, p.color),
            (&q.name, q.kind, q.sigma, q.color)
        );
        assert!(
            (b.to_world(&p.position) - back.to_world(&q.position))
                .abs()
                .max()
                < 1e-9
        );
        for (o, r) in p.observations.iter().zip(&q.observations) {
            assert_eq!(o.photo, r.photo);
            assert!(
                (o.pixel[0] - r.pixel[0]).abs() < 1e-9 && (o.pixel[1] - r.pixel[1]).abs() < 1e-9
            );
        }
    }
    assert!(max_residual(&back) < 2e-3);
}

#[test]
fn real_bulkphotos_sample_round_trips_at_the_xml_level() {
    let path = root()
        .join("formats/blocks-exchange/itwin_reality-capture_Orientations_bulkphotos_v3.2.xml");
    let text = std::fs::read_to_string(&path).unwrap();
    let doc = Document::parse(&text, &path).unwrap();
    assert_eq!(doc.version(), "3.2");
    assert!(doc.num_photos() > 5);
    let again = Document::parse(&doc.to_xml().unwrap(), Path::new("rewritten")).unwrap();
    assert_eq!(doc, again);
    // A block needs cameras: BulkPhotos have none, and the error says so.
    let e = bx::read(&path).unwrap_err().to_string();
    assert!(
        e.contains("BulkPhotos") && e.contains("Orientations_bulkphotos"),
        "{e}"
    );
}

#[test]
fn colmap_to_blocks_exchange_and_back_reproduces_projections() {
    for sample in [
        "kapture_maupertuis_txt",
        "synthetic_from_blocksexchange_txt",
    ] {
        let c = colmap::read(&root().join("formats/colmap").join(sample)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let xml = dir.path().join("block.xml");
        bx::write(&xml, &c, &WriteOptions::default()).unwrap();
        let b = bx::read(&xml).unwrap();
        let model = dir.path().join("model");
        colmap::write(&model, &b, &colmap::WriteOptions::default()).unwrap();
        let back = colmap::read(&model).unwrap();
        let (p, q) = (projections(&c), projections(&back));
        assert_eq!(p.len(), q.len());
        let worst = p
            .iter()
            .zip(&q)
            .map(|(a, b)| {
                assert_eq!(a.0, b.0);
                (a.1[0] - b.1[0]).abs().max((a.1[1] - b.1[1]).abs())
            })
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "{sample}: {worst} px");
        // Measurements too.
        let (mo, mb): (Vec<_>, Vec<_>) = (
            c.points
                .values()
                .flat_map(|p| p.observations.iter().map(|o| o.pixel))
                .collect(),
            back.points
                .values()
                .flat_map(|p| p.observations.iter().map(|o| o.pixel))
                .collect(),
        );
        for (a, b) in mo.iter().zip(&mb) {
            assert!((a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9);
        }
    }
}

#[test]
fn control_point_categories_survive_a_trip_through_colmap() {
    let b = bx::read(&synthetic()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    colmap::write(dir.path(), &b, &colmap::WriteOptions::default()).unwrap();
    let c = colmap::read(dir.path()).unwrap();
    assert_eq!(c.crs, b.crs);
    assert_eq!(c.origin, b.origin);
    for (k, p) in &b.points {
        assert_eq!(
            (&p.name, p.kind, p.sigma),
            (&c.points[k].name, c.points[k].kind, c.points[k].sigma)
        );
    }
    assert!(max_residual(&c) < 2e-3);
}

#[test]
fn bad_input_names_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(synthetic()).unwrap();
    let case = |name: &str, s: String| {
        let p = dir.path().join(name);
        std::fs::write(&p, s).unwrap();
        bx::read(&p).unwrap_err().to_string()
    };
    let e = case("malformed.xml", text.replace("</Photogroups>", ""));
    assert!(
        e.contains("malformed.xml") && e.contains("not valid BlocksExchange XML"),
        "{e}"
    );
    let e = case(
        "nopath.xml",
        text.replace("<ImagePath>dcp/2021_0871.tif</ImagePath>", ""),
    );
    assert!(
        e.contains("nopath.xml")
            && e.contains("Photo Id 101")
            && e.contains("ImagePath is missing"),
        "{e}"
    );
    let e = case("srs.xml", text.replace("EPSG:25833", "EPSG:999999"));
    assert!(e.contains("srs.xml") && e.contains("EPSG:999999"), "{e}");
    let e = case(
        "model.xml",
        text.replacen(
            "<CameraModelType>Perspective",
            "<CameraModelType>Fisheye",
            1,
        ),
    );
    assert!(
        e.contains("model.xml") && e.contains("Fisheye") && e.contains("RC30"),
        "{e}"
    );
    let e = case(
        "photo.xml",
        text.replace("<PhotoId>102</PhotoId>", "<PhotoId>777</PhotoId>"),
    );
    assert!(e.contains("GCP_church_tower") && e.contains("777"), "{e}");
    let e = case(
        "hpr.xml",
        text.replacen("<Omega>0.350000</Omega>", "<Heading>1</Heading>", 1),
    );
    assert!(e.contains("Photo Id 1") && e.contains("Heading"), "{e}");
}

#[test]
fn write_is_atomic_and_refuses_unwritable_blocks() {
    let mut b = bx::read(&synthetic()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("block.xml");
    std::fs::write(&out, "previous").unwrap();
    b.photos.get_mut(&1).unwrap().name = " ".into();
    assert!(bx::write(&out, &b, &WriteOptions::default()).is_err());
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "previous");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

/// A film epoch as its products write it: the frame camera of an RC10 scan resampled into
/// its fiducial frame (42 µm), with its calibrated distortion, two dated photos and a
/// checkpoint measured in both.
fn film_frame_block() -> (Block, f64) {
    use cloudcontrol::block::{BlockCamera, ObjectPoint, Observation, Photo};
    use cloudcontrol::geometry::{Brown, Camera, FilmCamera, InteriorOrientation, Pose};
    use cloudcontrol::matching::fiducial::FiducialFrame;
    use nalgebra::{Matrix3, Vector3};
    let p = 0.042;
    let frame = FiducialFrame::new([230.0, 230.0], p).unwrap();
    let film = FilmCamera {
        width: 5714,
        height: 5714,
        focal_mm: 152.865,
        principal_point_mm: [-0.03, -0.001],
        distortion: Brown {
            k1: -1.2e-3,
            k2: 3e-4,
            k3: 0.0,
            p1: 1e-6,
            p2: -2e-6,
        },
        interior: InteriorOrientation::ideal(5714, 5714, p),
    };
    let mut b = Block::new();
    b.crs = Some("EPSG:4547".into());
    b.origin = [499_000.0, 4_399_000.0, 0.0];
    b.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "Wild RC10 (film_1978)".into(),
            model: Camera::Frame(frame.frame_camera(&film)),
            free_params: Vec::new(),
            calibration_group: None,
        },
    );
    let nadir = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    for (id, x) in [(1u32, 0.0), (2, 1200.0)] {
        let mut ph = Photo::new(
            id,
            format!("resampled/film_{id}.png"),
            1,
            Pose::new(nadir, Vector3::new(x, 30.0, 2000.0)),
        )
        .oriented();
        ph.date = Some("1978-06-06".into());
        b.photos.insert(id, ph);
    }
    let position = Vector3::new(640.0, -120.0, 110.0);
    let observations = b
        .photos
        .values()
        .map(|ph| {
            let px = b.cameras[&1]
                .model
                .project(&ph.pose.to_camera(&position))
                .unwrap();
            Observation {
                photo: ph.id,
                pixel: [px.x, px.y],
                sigma_px: 1.0,
                provenance: String::new(),
            }
        })
        .collect();
    b.points.insert(
        1,
        ObjectPoint {
            id: 1,
            name: "CP001".into(),
            kind: PointKind::Check,
            position,
            sigma: Some([0.05, 0.05, 0.05]),
            color: [255, 0, 0],
            observations,
        },
    );
    (b, p)
}

/// The film photogroup as ContextCapture expects it (formats/blocks-exchange/README.md):
/// FocalLength and SensorSize of the frame in mm, written in the element order of real
/// v3.x exports; the photos' resampled images, dates and the check point; read back to
/// the same camera and projections.
#[test]
fn film_photogroup_states_mm_in_the_order_of_real_exports_and_reads_back() {
    let (b, p) = film_frame_block();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("film.xml");
    let opts = WriteOptions {
        pixel_mm: [(1, p)].into_iter().collect(),
        ..WriteOptions::default()
    };
    bx::write(&out, &b, &opts).unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    let value = |tag: &str| -> f64 {
        let open = format!("<{tag}>");
        let s = &text[text.find(&open).unwrap_or_else(|| panic!("no {tag}")) + open.len()..];
        s[..s.find('<').unwrap()].parse().unwrap()
    };
    assert!((value("FocalLength") - 152.865).abs() < 1e-9);
    assert!((value("SensorSize") - 5476.0 * p).abs() < 1e-9);
    assert!(!text.contains("<FocalLengthPixels>"));
    // Photogroup children in the order of the real ContextCapture 3.2 export
    // (formats/blocks-exchange/README.md), then the photo's.
    let order = [
        "<Name>",
        "<ImageDimensions>",
        "<CameraModelType>Perspective</CameraModelType>",
        "<CameraModelBand>Visible</CameraModelBand>",
        "<FocalLength>",
        "<SensorSize>",
        "<CameraOrientation>XRightYDown</CameraOrientation>",
        "<PrincipalPoint>",
        "<Distortion>",
        "<AspectRatio>",
        "<Skew>",
        "<Photo>",
        "<Id>1</Id>",
        "<ImagePath>resampled/film_1.png</ImagePath>",
        "<Component>1</Component>",
        "<Pose>",
        "<ExifData>",
        "<DateTimeOriginal>1978-06-06</DateTimeOriginal>",
        "<ControlPoints>",
        "<Name>CP001</Name>",
        "<CheckPoint>true</CheckPoint>",
        "<Measurement>",
    ];
    let group = text.find("<Photogroup>").unwrap();
    let mut at = group;
    for tag in order {
        let k = text[at..]
            .find(tag)
            .unwrap_or_else(|| panic!("{tag} missing or out of order"));
        at += k + tag.len();
    }
    let back = bx::read(&out).unwrap();
    let (pa, pb) = (
        b.cameras[&1].model.params(),
        back.cameras[&1].model.params(),
    );
    for (x, y) in pa.iter().zip(&pb) {
        assert!(
            (x - y).abs() <= 1e-12 * x.abs().max(1.0),
            "{pa:?} vs {pb:?}"
        );
    }
    assert_eq!(back.photos[&2].date.as_deref(), Some("1978-06-06"));
    assert_eq!(back.points[&1].kind, PointKind::Check);
    let worst = projections(&b)
        .iter()
        .zip(&projections(&back))
        .map(|(a, c)| (a.1[0] - c.1[0]).abs().max((a.1[1] - c.1[1]).abs()))
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "{worst} px");
}
