//! Time and memory of resampling one film scan into its fiducial frame (read, resample,
//! write), as the products of a film epoch do for each scan:
//! `/usr/bin/time -v cargo run --release --example frame_resample_timing -- SCAN BLOCK_JSON PHOTO_ID OUT.png`
//! with a `block.json` of an oriented film epoch (`run/epoch-<film>/block.json`); the
//! peak RSS of the process is that of one scan.
use cloudcontrol::block::Block;
use cloudcontrol::geometry::Camera;
use cloudcontrol::matching::fiducial::{write_frame_image, FiducialFrame};
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, scan, block, photo, out] = args.as_slice() else {
        eprintln!("usage: frame_resample_timing SCAN BLOCK_JSON PHOTO_ID OUT.png");
        std::process::exit(2);
    };
    let block: Block =
        serde_json::from_slice(&std::fs::read(block).expect("block.json")).expect("a block");
    let id: u32 = photo.parse().expect("a photo id");
    let p = &block.photos[&id];
    let Camera::Film(film) = &block.cameras[&p.camera].model else {
        panic!("photo {id} has no film camera");
    };
    let frame =
        FiducialFrame::new([230.0, 230.0], film.interior.mean_pixel_size_mm()).expect("a frame");
    let rep = write_frame_image(Path::new(scan), &film.interior, &frame, Path::new(out))
        .expect("frame image written");
    println!(
        "{}×{} scan → {}×{} frame at {:.2} µm: {:.2} s, {} masked pixels",
        film.width,
        film.height,
        frame.width,
        frame.height,
        frame.pixel_mm * 1000.0,
        rep.seconds,
        rep.masked_pixels
    );
}
