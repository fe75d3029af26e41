//! OpenDroneMap's `gcp_list.txt` (formats/control-points/odm.md) on the real files of
//! shared/data/copr_kap_2009 (ODM's COPR dataset), the hand-written sample, and hostile
//! inputs written here: points grouped by name or coordinates, pixels shifted +0.5 to our
//! convention, errors naming file, line and problem.

use cloudcontrol::block::{Block, BlockCamera, Photo, PhotoStatus, PointKind};
use cloudcontrol::formats::control_points as cp;
use cloudcontrol::formats::crs::{Crs, Transformer};
use cloudcontrol::formats::odm_gcp::{read_odm_gcp, GcpFile, GcpOptions, MAX_FILE_BYTES};
use cloudcontrol::geometry::{Camera, FrameCamera, Pose};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn copr(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/copr_kap_2009")
        .join(name);
    if p.is_file() {
        Some(p)
    } else {
        println!("skipped: {} is missing", p.display());
        None
    }
}

fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/control-points/sample_gcp_list.txt")
}

fn read(path: &Path) -> GcpFile {
    read_odm_gcp(path, &GcpOptions::default())
        .unwrap_or_else(|e| panic!("{} should read: {e}", path.display()))
}

/// Measurements per point id: image names in file order.
fn images_of(g: &GcpFile) -> BTreeMap<String, Vec<String>> {
    let mut m: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for x in &g.measurements {
        m.entry(x.id.clone())
            .or_default()
            .push(x.image_name.clone());
    }
    m
}

/// The data lines of a tab-separated real file, split independently of the reader.
fn raw_lines(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split('\t').map(str::to_string).collect())
        .collect()
}

/// Every measurement is its line's pixel + 0.5 (OpenSfM's origin is the centre of the
/// top-left pixel, ours its corner), bit for bit, in file order.
fn assert_pixels_shifted(g: &GcpFile, path: &Path) {
    let raw = raw_lines(path);
    assert_eq!(raw.len(), g.measurements.len());
    for (m, r) in g.measurements.iter().zip(&raw) {
        let x: f64 = r[3].parse().unwrap();
        let y: f64 = r[4].parse().unwrap();
        assert_eq!(m.pixel, [x + 0.5, y + 0.5], "{r:?}");
        assert_eq!((m.image_name.as_str(), m.id.as_str()), (&*r[5], &*r[6]));
    }
}

/// The header's PROJ string is WGS 84 / UTM 11N: points map to EPSG:32611 unchanged.
fn assert_utm_11n(crs: &Crs) {
    assert!(crs.is_projected());
    let t = Transformer::new(crs, &Crs::from_epsg(32611).unwrap()).unwrap();
    let p = [235269.88, 3811198.11, 0.0];
    let q = t.transform_point(p).unwrap();
    assert!((0..3).all(|i| (p[i] - q[i]).abs() < 1e-6), "{p:?} → {q:?}");
}

#[test]
fn copr_subset_six_gcps_fourteen_measurements() {
    let Some(path) = copr("gcp_list_subset.txt") else {
        return;
    };
    let g = read(&path);
    assert_utm_11n(&g.crs);
    // Order of first appearance in the file.
    let ids: Vec<&str> = g.points.iter().map(|p| p.id.as_str()).collect();
    assert_eq!(ids, ["gcp02", "gcp04", "gcp05", "gcp03", "gcp01", "gcp00"]);
    assert_eq!(g.measurements.len(), 14);
    let by_point = images_of(&g);
    assert_eq!(by_point["gcp00"], ["IMG_0031.jpg"]);
    let counts: Vec<usize> = by_point.values().map(Vec::len).collect();
    assert_eq!(counts, [1, 2, 2, 3, 3, 3]); // gcp00 … gcp05
    assert!(g.heights_all_zero);
    assert!(g.unknown_heights.is_empty());
    let gcp02 = &g.points[0];
    assert_eq!(gcp02.xyz, [235269.88, 3811198.11, 0.0]);
    assert_eq!(
        (gcp02.sigma_xy, gcp02.sigma_z, gcp02.kind),
        (0.05, 0.05, PointKind::Control)
    );
    // gcp00 in IMG_0031.jpg: ODM 3484.090865093971 729.3199423440851.
    let m = g.measurements.iter().find(|m| m.id == "gcp00").unwrap();
    assert_eq!(m.pixel, [3484.590865093971, 729.8199423440851]);
    assert_eq!(m.sigma_px, 1.0);
    assert_pixels_shifted(&g, &path);
}

#[test]
fn copr_whole_block_ten_gcps_on_twenty_two_images() {
    let Some(path) = copr("gcp_list.txt") else {
        return;
    };
    assert_eq!(std::fs::read_to_string(&path).unwrap().lines().count(), 28);
    let g = read(&path);
    assert_utm_11n(&g.crs);
    // SOURCE.txt: 27 observations of 10 GCPs on 22 images.
    assert_eq!(g.points.len(), 10);
    assert_eq!(g.measurements.len(), 27);
    let images: BTreeSet<&str> = g
        .measurements
        .iter()
        .map(|m| m.image_name.as_str())
        .collect();
    assert_eq!(images.len(), 22);
    let ids: BTreeSet<&str> = g.points.iter().map(|p| p.id.as_str()).collect();
    let expect: BTreeSet<String> = (0..10).map(|i| format!("gcp{i:02}")).collect();
    assert_eq!(ids, expect.iter().map(String::as_str).collect());
    let gcp08 = g.points.iter().find(|p| p.id == "gcp08").unwrap();
    assert_eq!(gcp08.xyz, [235246.25, 3811220.6, 0.0]);
    assert!(g.heights_all_zero);
    assert_pixels_shifted(&g, &path);
}

#[test]
fn copr_files_that_are_not_gcp_lists_are_refused() {
    let (Some(nocoord), Some(noimg)) = (copr("gcp_list_nocoord.txt"), copr("gcp_list_noimg.txt"))
    else {
        return;
    };
    // Pixel and image only: no CRS, no coordinates.
    let e = read_odm_gcp(&nocoord, &GcpOptions::default())
        .unwrap_err()
        .to_string();
    for w in [
        "gcp_list_nocoord.txt",
        "line 1",
        "no CRS line",
        "starts with data",
    ] {
        assert!(e.contains(w), "{e:?} lacks {w:?}");
    }
    // EPSG:4326 then `name lon lat z`: coordinates without image measurements.
    let e = read_odm_gcp(&noimg, &GcpOptions::default())
        .unwrap_err()
        .to_string();
    for w in [
        "gcp_list_noimg.txt",
        "line 2",
        "4 words",
        "at least 6",
        "without image measurements",
    ] {
        assert!(e.contains(w), "{e:?} lacks {w:?}");
    }
}

#[test]
fn copr_subset_goes_into_a_block() {
    let Some(path) = copr("gcp_list_subset.txt") else {
        return;
    };
    let g = read(&path);
    let mut b = Block::new();
    b.crs = Some("EPSG:32611".into());
    b.origin = [235_000.0, 3_811_000.0, 0.0];
    b.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "xsi".into(),
            model: Camera::Frame(FrameCamera::pinhole(4272, 2848, 5770.0)),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for (id, n) in [31, 34, 37, 40, 43, 46, 49, 52, 55, 61, 64, 67]
        .into_iter()
        .enumerate()
    {
        let id = id as u32 + 1;
        b.photos.insert(
            id,
            Photo {
                id,
                // The block knows the photos by stem: matched like the CSV measurements.
                name: format!("IMG_00{n}"),
                camera: 1,
                pose: Pose::new(nalgebra::Matrix3::identity(), nalgebra::Vector3::zeros()),
                status: PhotoStatus::Oriented,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    let ids = cp::add_points(&mut b, &g.points, &g.crs).unwrap();
    cp::add_measurements(&mut b, &g.measurements, &path).unwrap();
    assert_eq!(ids.len(), 6);
    let obs: usize = b.points.values().map(|p| p.observations.len()).sum();
    assert_eq!(obs, 14);
    let gcp00 = b.points.values().find(|p| p.name == "gcp00").unwrap();
    let w = b.to_world(&gcp00.position);
    assert!((w.x - 235277.61).abs() < 1e-6 && (w.y - 3811190.36).abs() < 1e-6 && w.z == 0.0);
    assert_eq!(gcp00.observations.len(), 1);
    assert_eq!(b.photos[&gcp00.observations[0].photo].name, "IMG_0031");
    assert_eq!(
        gcp00.observations[0].pixel,
        [3484.590865093971, 729.8199423440851]
    );
}

#[test]
fn sample_reads_as_documented() {
    let g = read(&sample());
    assert_eq!(g.crs.epsg(), Some(32632)); // `WGS84 UTM 32N`
    let ids: Vec<&str> = g.points.iter().map(|p| p.id.as_str()).collect();
    // The unnamed point is named after the line of its first measurement.
    assert_eq!(ids, ["gcp_north", "gcp_9", "gcp_corner"]);
    let by_point = images_of(&g);
    assert_eq!(
        by_point["gcp_north"],
        ["DJI_0101.JPG", "DJI_0102.JPG", "DJI_0107.JPG"]
    );
    assert_eq!(by_point["gcp_9"], ["DJI_0102.JPG", "DJI_0103.JPG"]);
    assert_eq!(by_point["gcp_corner"], ["DJI_0103.JPG"]);
    assert_eq!(g.points[1].xyz, [481413.0, 5783008.1, 99.87]);
    // `NaN` height: unknown, read as 0.
    assert_eq!(g.points[2].xyz, [481350.75, 5783011.0, 0.0]);
    assert_eq!(g.unknown_heights, ["gcp_corner"]);
    assert!(!g.heights_all_zero);
    let pixels: Vec<[f64; 2]> = g.measurements.iter().map(|m| m.pixel).collect();
    assert_eq!(
        pixels,
        [
            [3045.0, 2622.5],
            [1012.5, 2588.75],
            [2980.5, 120.5],
            [1606.5, 2763.5],
            [3512.0, 2701.5],
            [4000.75, 3000.25],
        ]
    );
}

/// Writes `text` as a GCP file in a fresh folder and reads it.
fn parse(text: &[u8]) -> Result<GcpFile, String> {
    parse_with(text, &GcpOptions::default())
}

fn parse_with(text: &[u8], opts: &GcpOptions) -> Result<GcpFile, String> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gcp_list.txt");
    std::fs::write(&path, text).unwrap();
    read_odm_gcp(&path, opts).map_err(|e| e.to_string())
}

#[track_caller]
fn refused(text: &str, words: &[&str]) {
    let e = match parse(text.as_bytes()) {
        Ok(g) => panic!("accepted: {text:?} → {g:?}"),
        Err(e) => e,
    };
    for w in ["gcp_list.txt"].iter().chain(words) {
        assert!(e.contains(w), "{e:?} lacks {w:?}");
    }
}

const UTM: &str = "WGS84 UTM 11N\n";

#[test]
fn bad_numbers_are_refused_with_line_and_column() {
    refused(
        &format!("{UTM}NaN 3811198.11 0 10 10 a.jpg g1\n"),
        &["line 2, column geo_x", "not a finite number"],
    );
    refused(
        &format!("{UTM}235269.88 3811198.11 0 10 10 a.jpg g1\n1 2 3 10 inf b.jpg g2\n"),
        &["line 3, column im_y", "not a finite number"],
    );
    refused(
        &format!("{UTM}1 2 -infinity 10 10 a.jpg\n"),
        &["line 2, column geo_z", "not a finite number"],
    );
    refused(
        &format!("{UTM}1 abc 0 10 10 a.jpg\n"),
        &["line 2, column geo_y", "\"abc\" is not a number"],
    );
    refused(
        &format!("{UTM}1 2 0 nan 10 a.jpg\n"),
        &["line 2, column im_x"],
    );
}

#[test]
fn column_counts() {
    refused(
        &format!("{UTM}1 2 0 10 10\n"),
        &["line 2", "5 words", "at least 6"],
    );
    refused(&format!("{UTM}\n\n# c\n7\n"), &["line 5", "1 word where"]);
    // A word starting with `#` ends the data.
    refused(
        &format!("{UTM}1 2 0 10 10 #a.jpg g1\n"),
        &["line 2", "5 words"],
    );
    // Many extra columns are ODM's extras: read over.
    let extras: String = (0..10_000).map(|i| format!(" x{i}")).collect();
    let g = parse(
        format!("{UTM}1 2 0 10 10 a.jpg g1{extras}\n# n\n1 2 0 3 4 b.jpg g1 # note\n").as_bytes(),
    )
    .unwrap();
    assert_eq!(g.points.len(), 1);
    assert_eq!(g.points[0].id, "g1");
    assert_eq!(g.measurements.len(), 2);
    // A comment word in the name column leaves the line unnamed.
    let g = parse(format!("{UTM}1 2 0 10 10 a.jpg #gcp1\n").as_bytes()).unwrap();
    assert_eq!(g.points[0].id, "gcp_2");
}

#[test]
fn one_point_twice_in_one_image_is_refused() {
    refused(
        &format!("{UTM}1 2 0 10 10 a.jpg g1\n1 2 0 30 30 b.jpg g1\n1 2 0 11 11 a.jpg g1\n"),
        &[
            "line 4",
            "point \"g1\"",
            "second time",
            "\"a.jpg\"",
            "first on line 2",
        ],
    );
    // The same photo by another extension case: the same stem.
    refused(
        &format!("{UTM}1 2 0 10 10 IMG_1.jpg g1\n1 2 0 11 11 IMG_1.JPG g1\n"),
        &["line 3", "second time", "first on line 2"],
    );
    // Unnamed lines at one position are one point.
    refused(
        &format!("{UTM}1 2 0 10 10 a.jpg\n1 2 0 11 11 a.jpg\n"),
        &["line 3", "unnamed point of line 2", "second time"],
    );
    // Two points in one image are two measurements.
    let g = parse(format!("{UTM}1 2 0 10 10 a.jpg g1\n5 6 0 11 11 a.jpg g2\n").as_bytes()).unwrap();
    assert_eq!((g.points.len(), g.measurements.len()), (2, 2));
}

#[test]
fn one_name_at_two_places_is_refused() {
    refused(
        &format!("{UTM}235269.88 3811198.11 0 10 10 a.jpg g1\n235269.98 3811198.11 0 10 10 b.jpg g1\n"),
        &[
            "line 3",
            "point \"g1\" is at (235269.98 3811198.11 0) here but at (235269.88 3811198.11 0) on line 2",
        ],
    );
    refused(
        &format!("{UTM}1 2 0 10 10 a.jpg g1\n1 2 NaN 10 10 b.jpg g1\n"),
        &["line 3", "point \"g1\""],
    );
    // Rounding differences far below 1e-9 relative are the same place: the first line's.
    let g = parse(
        format!("{UTM}235269.88 3811198.11 0 10 10 a.jpg g1\n235269.8800000001 3811198.1100000003 0.0000000001 10 10 b.jpg g1\n")
            .as_bytes(),
    )
    .unwrap();
    assert_eq!(g.points.len(), 1);
    assert_eq!(g.points[0].xyz, [235269.88, 3811198.11, 0.0]);
}

#[test]
fn grouping_by_coordinates() {
    // Unnamed lines join the named point at their coordinates, whichever comes first.
    for text in [
        "1 2 3 10 10 a.jpg\n1 2 3 11 11 b.jpg g1\n1 2 3 12 12 c.jpg\n",
        "1 2 3 11 11 b.jpg g1\n1 2 3 10 10 a.jpg\n1 2 3 12 12 c.jpg\n",
    ] {
        let g = parse(format!("{UTM}{text}").as_bytes()).unwrap();
        assert_eq!(g.points.len(), 1, "{text}");
        assert_eq!(g.points[0].id, "g1");
        assert!(g.measurements.iter().all(|m| m.id == "g1"));
    }
    // Two names at one place stay two points; an unnamed line there cannot choose.
    let g = parse(format!("{UTM}1 2 3 10 10 a.jpg g1\n1 2 3 10 10 a.jpg g2\n").as_bytes()).unwrap();
    assert_eq!(g.points.len(), 2);
    refused(
        &format!("{UTM}1 2 3 10 10 a.jpg g1\n1 2 3 10 10 b.jpg g2\n1 2 3 10 10 c.jpg\n"),
        &[
            "line 4",
            "without a GCP name on line 4",
            "\"g1\" and \"g2\"",
        ],
    );
    refused(
        &format!("{UTM}1 2 3 10 10 c.jpg\n1 2 3 10 10 a.jpg g1\n1 2 3 10 10 b.jpg g2\n"),
        &[
            "line 4",
            "without a GCP name on line 2",
            "\"g1\" and \"g2\"",
        ],
    );
    // A generated name never takes a name the file gives: `gcp_2` is taken below.
    let g = parse(format!("{UTM}1 2 3 10 10 a.jpg\n5 6 7 10 10 a.jpg gcp_2\n").as_bytes()).unwrap();
    let ids: Vec<&str> = g.points.iter().map(|p| p.id.as_str()).collect();
    assert_eq!(ids, ["gcp_2_unnamed", "gcp_2"]);
    // -0 and 0 are one position.
    let g = parse(format!("{UTM}1 2 0 10 10 a.jpg\n1 2 -0 10 10 b.jpg\n").as_bytes()).unwrap();
    assert_eq!(g.points.len(), 1);
}

#[test]
fn crs_line_forms() {
    refused(
        "235269.88 3811198.11 0 10 10 a.jpg g1\n",
        &["line 1", "no CRS line"],
    );
    refused(
        "UTM 11N\n1 2 0 10 10 a.jpg\n",
        &["line 1", "none of the forms ODM reads"],
    );
    for bad in [
        "WGS84 UTM 61N",
        "WGS84 UTM 32",
        "WGS84 UTM 0S",
        "WGS84 UTM 3é",
        "WGS84 UTM",
    ] {
        refused(
            &format!("{bad}\n1 2 0 10 10 a.jpg\n"),
            &["line 1", "WGS84 UTM <zone 1-60><N|S>"],
        );
    }
    refused(
        "EPSG:999999\n1 2 0 10 10 a.jpg\n",
        &["line 1", "CRS line", "not a CRS GDAL/PROJ knows"],
    );
    // The one CRS parser's rules hold: no init files.
    refused(
        "+init=epsg:32611\n1 2 0 10 10 a.jpg\n",
        &["line 1", "CRS line", "init"],
    );
    for (header, epsg) in [
        ("WGS84 UTM 32N", 32632),
        ("wgs84 utm 19s", 32719),
        ("WGS84\tUTM\t1N", 32601),
        ("epsg:32611", 32611),
    ] {
        let g = parse(format!("{header}\n1 2 0 10 10 a.jpg\n").as_bytes()).unwrap();
        assert_eq!(g.crs.epsg(), Some(epsg), "{header}");
    }
    // ODM drops single quotes around a PROJ string; comments may precede the CRS line.
    let g = parse(
        b"# exported\n\n'+proj=utm +zone=11 +ellps=WGS84 +datum=WGS84 +units=m +no_defs'\t\n1 2 0 10 10 a.jpg\n",
    )
    .unwrap();
    assert_utm_11n(&g.crs);
}

/// `EPSG:4326` points are longitude, latitude (GIS order, as ODM); `add_points` converts
/// them. The COPR targets' WGS 84 positions (gcp_list_noimg.txt, which numbers them from
/// 1) land on the UTM coordinates of gcp_list.txt (which numbers them from 0).
#[test]
fn epsg_4326_points_are_lon_lat() {
    let g = parse(
        b"EPSG:4326\n-119.879992097 34.4082988202 0 3484.090865093971 729.3199423440851 IMG_0031.jpg gcp00\n\
          -119.879956611\t34.4083427222\t0\t730.4768180934701\t1019.9400517833574\tIMG_0031.jpg\tgcp01\n",
    )
    .unwrap();
    assert!(g.crs.is_geographic());
    assert_eq!(g.points[0].xyz, [-119.879992097, 34.4082988202, 0.0]);
    let mut b = Block::new();
    b.crs = Some("EPSG:32611".into());
    let ids = cp::add_points(&mut b, &g.points, &g.crs).unwrap();
    // `gdaltransform -s_srs EPSG:4326 -t_srs EPSG:32611`: 235277.613156651 3811190.35949077;
    // gcp_list.txt (2 decimals): gcp00 235277.61 3811190.36, gcp01 235281.01 3811195.14.
    let w0 = b.to_world(&b.points[&ids[0]].position);
    assert!((w0.x - 235277.613156651).abs() < 1e-6 && (w0.y - 3811190.35949077).abs() < 1e-6);
    let w1 = b.to_world(&b.points[&ids[1]].position);
    assert!(
        (w1.x - 235281.01).abs() < 0.01 && (w1.y - 3811195.14).abs() < 0.01,
        "{w1:?}"
    );
}

#[test]
fn empty_and_odd_files() {
    refused("", &["empty file"]);
    refused("# only a comment\n\n   \n", &["empty file"]);
    refused(UTM, &["line 1", "no GCP line after the CRS line"]);
    refused(&format!("\n# c\n{UTM}# none\n"), &["line 3", "no GCP line"]);
    // Not UTF-8 on line 3.
    let e = parse(b"WGS84 UTM 11N\n1 2 0 10 10 a.jpg\n1 2 0 10 10 \xff.jpg\n").unwrap_err();
    assert!(e.contains("line 3") && e.contains("not UTF-8"), "{e}");
    // A byte order mark and CRLF line ends are fine; the pixel origin moves half a pixel.
    let g = parse(b"\xef\xbb\xbfWGS84 UTM 11N\r\n1 2 0 0 0 a.jpg g1\r\n").unwrap();
    assert_eq!(g.measurements[0].pixel, [0.5, 0.5]);
    assert_eq!(g.measurements[0].image_name, "a.jpg");
    // σ come from the options, which must be positive.
    let opts = GcpOptions {
        sigma_xy: 0.02,
        sigma_z: 0.1,
        sigma_px: 0.5,
    };
    let g = parse_with(b"WGS84 UTM 11N\n1 2 0 0 0 a.jpg g1\n", &opts).unwrap();
    assert_eq!((g.points[0].sigma_xy, g.points[0].sigma_z), (0.02, 0.1));
    assert_eq!(g.measurements[0].sigma_px, 0.5);
    let e = parse_with(
        b"WGS84 UTM 11N\n1 2 0 0 0 a.jpg g1\n",
        &GcpOptions {
            sigma_px: 0.0,
            ..opts
        },
    )
    .unwrap_err();
    assert!(e.contains("sigma_px must be positive"), "{e}");
}

#[test]
fn a_file_over_the_limit_is_refused_before_parsing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gcp_list.txt");
    let f = std::fs::File::create(&path).unwrap();
    f.set_len(MAX_FILE_BYTES + 1).unwrap();
    let e = read_odm_gcp(&path, &GcpOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("gcp_list.txt") && e.contains(&format!("exceeds {MAX_FILE_BYTES}")),
        "{e}"
    );
}
