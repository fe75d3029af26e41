//! No network and no file access driven by data: data files whose CRS fields hold URLs
//! (pointing at a listener on 127.0.0.1) or file names are refused, naming the file and the
//! field, through the library, the CLI and the C ABI — and the listener is never contacted.
//! Every file is written here from the format documents (formats/dcp, formats/blocks-
//! exchange, formats/lidar, formats/project).

use crate::common;
use common::{cli_fails, last_error, says};
use std::ffi::CString;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A listener on 127.0.0.1 that counts the connections it accepts and closes each at once
/// (so that a client that did connect fails fast instead of waiting for a reply).
struct Listener {
    port: u16,
    accepted: Arc<AtomicUsize>,
}

impl Listener {
    fn start() -> Self {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let accepted = Arc::new(AtomicUsize::new(0));
        let count = accepted.clone();
        std::thread::spawn(move || {
            for s in l.incoming() {
                count.fetch_add(1, Ordering::SeqCst);
                drop(s);
            }
        });
        Self { port, accepted }
    }

    fn url(&self, path: &str) -> String {
        format!("http://127.0.0.1:{}/{path}", self.port)
    }

    /// Connections so far, after a short grace for one in flight.
    fn accepted(&self) -> usize {
        std::thread::sleep(Duration::from_millis(100));
        self.accepted.load(Ordering::SeqCst)
    }
}

fn c(p: &Path) -> CString {
    CString::new(p.to_str().unwrap()).unwrap()
}

/// A file naming a CRS by a local file: GDAL would read it and find a valid CRS.
fn crs_file(dir: &Path) -> PathBuf {
    let f = dir.join("puwg92.prj");
    let wkt = cloudcontrol::formats::crs::Crs::from_epsg(2180)
        .unwrap()
        .to_wkt()
        .unwrap();
    std::fs::write(&f, wkt).unwrap();
    f
}

/// The CRS fields tried in every format: a URL, a file, GDAL's `@file`, a PROJ string
/// whose grid is a URL, and WKT whose PROJ4 extension names a local grid.
fn hostile_crs(l: &Listener, dir: &Path) -> Vec<(String, &'static str)> {
    let file = crs_file(dir);
    vec![
        (l.url("crs.wkt"), "URL"),
        (format!("/vsicurl/{}", l.url("crs.wkt")), "URL"),
        (file.display().to_string(), "file name"),
        (format!("@{}", file.display()), "file name"),
        (
            format!(
                "+proj=utm +zone=33 +ellps=GRS80 +units=m +nadgrids=@{}",
                l.url("grid.tif")
            ),
            "+nadgrids",
        ),
        (
            format!(
                "PROJCS[\"x\",GEOGCS[\"GRS 1980\",DATUM[\"d\",SPHEROID[\"GRS 1980\",6378137,298.257222101]],\
                 PRIMEM[\"Greenwich\",0],UNIT[\"degree\",0.0174532925199433]],\
                 PROJECTION[\"Transverse_Mercator\"],UNIT[\"metre\",1],\
                 EXTENSION[\"PROJ4\",\"+proj=tmerc +ellps=GRS80 +geoidgrids={}\"]]",
                dir.join("geoid.gtx").display()
            ),
            "+geoidgrids",
        ),
    ]
}

// ---------------------------------------------------------------------------------------
// The files
// ---------------------------------------------------------------------------------------

/// A DCP package (formats/dcp/README.md) without photos or points, in `crs`.
fn dcp_package(dir: &Path, crs: &str) -> PathBuf {
    let pkg = dir.join("hostile.dcp");
    std::fs::create_dir_all(&pkg).unwrap();
    let manifest = serde_json::json!({
        "format": "cloudcontrol-dcp", "version": 1, "crs": crs,
        "epoch": {"name": "2019"}, "source": "hand-written", "gsd_m": 0.1,
        "accuracy": {"plan_m": 0.05, "height_m": 0.08},
        "photos": [], "points": [], "files": {},
    });
    std::fs::write(pkg.join("manifest.json"), manifest.to_string()).unwrap();
    pkg
}

/// A BlocksExchange file (formats/blocks-exchange/README.md) whose block is in SRS 1.
fn blocks_exchange(dir: &Path, crs: &str) -> PathBuf {
    let f = dir.join("hostile.xml");
    let crs = crs.replace('&', "&amp;").replace('<', "&lt;");
    std::fs::write(
        &f,
        format!(
            "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<BlocksExchange version=\"2.1\">\
             <SpatialReferenceSystems><SRS><Id>1</Id><Name>x</Name>\
             <Definition>{crs}</Definition></SRS></SpatialReferenceSystems>\
             <Block><Name>b</Name><SRSId>1</SRSId></Block></BlocksExchange>\n"
        ),
    )
    .unwrap();
    f
}

/// A LAS 1.4 file of one point (format 6) whose WKT VLR holds `wkt` (formats/lidar).
fn las_with_wkt(dir: &Path, wkt: &str) -> PathBuf {
    let f = dir.join("hostile.las");
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(6).unwrap();
    let mut header = b.into_header().unwrap();
    header.set_wkt_crs(wkt.as_bytes().to_vec()).unwrap();
    let mut w = las::Writer::from_path(&f, header).unwrap();
    w.write_point(las::Point {
        x: 1.0,
        y: 2.0,
        z: 3.0,
        gps_time: Some(0.0),
        ..Default::default()
    })
    .unwrap();
    w.close().unwrap();
    f
}

/// The example project (formats/project/example.toml) in `crs`.
fn project(dir: &Path, crs: &str) -> PathBuf {
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/project/example.toml");
    let text = std::fs::read_to_string(example).unwrap();
    let line = format!("crs = {}", toml::Value::String(crs.into()));
    let text = text.replacen("crs = \"EPSG:4547\"", &line, 1);
    assert!(text.contains(&line));
    let f = dir.join("project.toml");
    std::fs::write(&f, text).unwrap();
    f
}

// ---------------------------------------------------------------------------------------
// The loads
// ---------------------------------------------------------------------------------------

#[test]
fn gdal_itself_would_contact_the_listener() {
    // The control: the listener sees GDAL's catch-all parser fetch a URL definition, so a
    // zero count below means cloudcontrol did not ask, not that the test cannot see.
    let l = Listener::start();
    let _ = gdal::spatial_ref::SpatialRef::from_definition(&l.url("control.wkt"));
    assert!(l.accepted() >= 1, "the control request was not seen");
}

#[test]
fn dcp_manifest_crs_opens_nothing() {
    let l = Listener::start();
    let tmp = tempfile::tempdir().unwrap();
    for (crs, what) in hostile_crs(&l, tmp.path()) {
        let t = Instant::now();
        let pkg = dcp_package(tmp.path(), &crs);
        let e = cloudcontrol::control::dcp::DcpPackage::open(&pkg)
            .unwrap_err()
            .to_string();
        says(&e, &pkg, &["manifest.json: crs", what]);
        let store = tmp.path().join("store");
        let e = cli_fails(&[
            "dcp",
            "import",
            pkg.to_str().unwrap(),
            "--into",
            store.to_str().unwrap(),
        ]);
        says(&e, &pkg, &["manifest.json: crs", what]);
        assert!(
            !store.exists(),
            "the store was created for a refused package"
        );
        let e = cli_fails(&["dcp", "info", pkg.to_str().unwrap()]);
        says(&e, &pkg, &["manifest.json: crs", what]);
        let mut h = std::ptr::null_mut();
        let st = unsafe { cloudcontrol::ffi::ccp_dcp_open(c(&pkg).as_ptr(), &mut h) };
        assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
        assert!(h.is_null());
        says(&last_error(), &pkg, &["manifest.json: crs", what]);
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "{crs}: {:?}",
            t.elapsed()
        );
    }
    assert_eq!(l.accepted(), 0, "a DCP manifest made the library connect");
}

#[test]
fn blocks_exchange_srs_definition_opens_nothing() {
    let l = Listener::start();
    let tmp = tempfile::tempdir().unwrap();
    for (crs, what) in hostile_crs(&l, tmp.path()) {
        let f = blocks_exchange(tmp.path(), &crs);
        let e = cloudcontrol::formats::blocks_exchange::read(&f)
            .unwrap_err()
            .to_string();
        says(&e, &f, &["SRSId", what]);
        let out = tmp.path().join("colmap-out");
        let e = cli_fails(&["convert", f.to_str().unwrap(), out.to_str().unwrap()]);
        says(&e, &f, &["SRSId", what]);
        let mut counts = [0u64; 4];
        let st =
            unsafe { cloudcontrol::ffi::ccp_block_summary(c(&f).as_ptr(), counts.as_mut_ptr()) };
        assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
        says(&last_error(), &f, &["SRSId", what]);
    }
    assert_eq!(
        l.accepted(),
        0,
        "a BlocksExchange file made the library connect"
    );
}

#[test]
fn las_wkt_vlr_opens_nothing() {
    let l = Listener::start();
    let tmp = tempfile::tempdir().unwrap();
    for (crs, what) in hostile_crs(&l, tmp.path()) {
        let f = las_with_wkt(tmp.path(), &crs);
        let e = cloudcontrol::lidar::LasStream::open(&f)
            .err()
            .expect("refused")
            .to_string();
        says(&e, &f, &["WKT VLR", what]);
        let e = cli_fails(&["lidar", "catalogue", f.to_str().unwrap()]);
        says(&e, &f, &["WKT VLR", what]);
        let e = cli_fails(&["lidar", "info", f.to_str().unwrap()]);
        says(&e, &f, &["WKT VLR", what]);
        let paths = [c(&f)];
        let ptrs: Vec<_> = paths.iter().map(|p| p.as_ptr()).collect();
        let mut json = std::ptr::null_mut();
        let st = unsafe {
            cloudcontrol::ffi::ccp_lidar_catalogue_json(
                ptrs.as_ptr(),
                1,
                std::ptr::null(),
                &mut json,
            )
        };
        assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
        says(&last_error(), &f, &["WKT VLR", what]);
    }
    assert_eq!(l.accepted(), 0, "a LAS WKT VLR made the library connect");
}

#[test]
fn project_crs_opens_nothing() {
    let l = Listener::start();
    let tmp = tempfile::tempdir().unwrap();
    for (crs, what) in hostile_crs(&l, tmp.path()) {
        let f = project(tmp.path(), &crs);
        let e = cloudcontrol::pipeline::project::Project::load(&f)
            .unwrap_err()
            .to_string();
        says(&e, &f, &["crs", what]);
        let e = cli_fails(&["run", f.to_str().unwrap(), "--check"]);
        says(&e, &f, &["crs", what]);
        let mut json = std::ptr::null_mut();
        let st = unsafe { cloudcontrol::ffi::ccp_project_run(c(&f).as_ptr(), &mut json) };
        assert_ne!(st, cloudcontrol::ffi::CcpStatus::Ok);
        says(&last_error(), &f, &["crs", what]);
        assert!(
            !tmp.path().join("out").exists(),
            "output made for a refused project"
        );
    }
    assert_eq!(l.accepted(), 0, "a project file made the library connect");
}
