use cloudcontrol::control::archive::{self, ArchiveOptions, EpochInput};
use cloudcontrol::control::dcp::DcpPackage;
use std::path::{Path, PathBuf};
#[test]
fn dbg() {
    let _ = tracing_subscriber::fmt().with_env_filter(tracing_subscriber::EnvFilter::new("cloudcontrol::control=debug")).with_writer(std::io::stderr).try_init();
    let root = Path::new("/tmp/orient_bench13c");
    let dir = root.join("block");
    let mut tiles: Vec<PathBuf> = std::fs::read_dir(dir.join("lidar")).unwrap().map(|e| e.unwrap().path()).collect();
    tiles.sort();
    let surface = archive::lidar_surfaces(&tiles, cloudcontrol::synth::ORIGIN, 1.0).unwrap();
    let pkg = DcpPackage::open(&root.join("reference.dcp")).unwrap();
    let (truth, _) = archive::synth_truth_block(&dir, "digital_2012").unwrap();
    let mut base = EpochInput::from_synth_epoch(&dir, "digital_2012").unwrap();
    base.photos.retain(|p| p.name == "digital_s02_001");
    let input = EpochInput { navigation: archive::perturbed_navigation(&truth, 5.0, 1f64.to_radians(), 3000), ..base };
    let mut opts = ArchiveOptions::default();
    opts.relaxed_retry = false;
    let r = archive::orient_epoch(&input, &[pkg], &surface.ground, &opts).unwrap();
    for p in &r.photos { eprintln!("{:?}", p); }
    // truth pixel of each DCP point
    let ph = truth.photos.values().find(|p| p.name == "digital_s02_001").unwrap();
    let cam = &truth.cameras[&ph.camera].model;
    let pkg = DcpPackage::open(&root.join("reference.dcp")).unwrap();
    for (i, pt) in pkg.manifest.points.iter().enumerate() {
        let x = nalgebra::Vector3::from(pt.xyz) - nalgebra::Vector3::from(truth.origin);
        if let Ok(p) = cloudcontrol::geometry::project(cam, &ph.pose, &x) { if p.pixel.x > 0.0 && p.pixel.y > 0.0 && p.pixel.x < 1000.0 && p.pixel.y < 666.0 { eprintln!("truth {} ({:.1},{:.1})", i, p.pixel.x, p.pixel.y); } }
    }
}
