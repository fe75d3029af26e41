//! Orthophoto of a rendered block over relief with a building: markers land within one
//! ground pixel of their true coordinates, occlusion is handled, GeoTIFF metadata right.

use cloudcontrol::block::{Block, BlockCamera, Photo};
use cloudcontrol::formats::crs::Crs;
use cloudcontrol::formats::ortho::{write_orthophoto, OrthoOptions, PhotoImages, RgbImage};
use cloudcontrol::geometry::{
    back_project, rotation_from_vector, Brown, Camera, Dem, FrameCamera, Pose, Ray,
};
use gdal::{Dataset, Metadata};
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

const E0: f64 = 500_000.0;
const N0: f64 = 4_000_000.0;
/// Markers (world E, N); the first sits on the hilltop, the last beside the building.
const MARKERS: [(f64, f64); 6] = [
    (E0 + 20.0, N0 + 10.0),
    (E0 - 100.0, N0 - 80.0),
    (E0 + 100.0, N0 + 90.0),
    (E0 - 50.0, N0 + 80.0),
    (E0 + 80.0, N0 - 70.0),
    (E0 + 10.0, N0 + 45.0),
];
const MARKER_RADIUS: f64 = 2.0;

fn building(x: f64, y: f64) -> bool {
    (E0 + 16.0..E0 + 26.0).contains(&x) && (N0 + 38.0..N0 + 52.0).contains(&y)
}

fn terrain(x: f64, y: f64) -> f64 {
    let (dx, dy) = (x - MARKERS[0].0, y - MARKERS[0].1);
    let hill = 25.0 * (-(dx * dx + dy * dy) / (2.0 * 60.0f64.powi(2))).exp();
    let slope = 0.03 * (x - E0) + 4.0 * ((y - N0) / 40.0).sin();
    100.0 + hill + slope + if building(x, y) { 40.0 } else { 0.0 }
}

fn texture(x: f64, y: f64) -> [u8; 3] {
    if MARKERS
        .iter()
        .any(|m| (x - m.0).powi(2) + (y - m.1).powi(2) <= MARKER_RADIUS.powi(2))
    {
        return [10, 10, 10];
    }
    if building(x, y) {
        return [250, 80, 80];
    }
    let v = 0.5 + 0.25 * (x / 3.1).sin() * (y / 2.3).cos() + 0.2 * ((x + y) / 11.0).sin();
    [
        (90.0 + 120.0 * v) as u8,
        (110.0 + 100.0 * v) as u8,
        (80.0 + 90.0 * v) as u8,
    ]
}

/// Two photos of 500² px at 450 m over the hill and the building.
fn scene() -> (Block, Dem, BTreeMap<u32, RgbImage>) {
    let centres = [
        (-70.0, 0.0, 450.0, [0.01, -0.02, 0.03]),
        (70.0, 5.0, 455.0, [-0.015, 0.01, -0.02]),
    ];
    rendered_block(&centres, 500, 520.0)
}

/// Photos of `size`² px (focal `f` px, slight distortion) rendered from the textured DEM
/// at the given centres (block frame) and rotation vectors off nadir.
fn rendered_block(
    centres: &[(f64, f64, f64, [f64; 3])],
    size: u32,
    f: f64,
) -> (Block, Dem, BTreeMap<u32, RgbImage>) {
    let dem = Dem::from_fn(E0 - 200.0, N0 + 200.0, 2.0, 200, 200, terrain).unwrap();
    let mut block = Block::new();
    block.crs = Some("EPSG:32650".into());
    block.origin = [E0, N0, 0.0];
    let cam = FrameCamera {
        distortion: Brown {
            k1: -0.04,
            k2: 0.01,
            ..Default::default()
        },
        cx: size as f64 / 2.0 + 1.3,
        cy: size as f64 / 2.0 - 1.1,
        ..FrameCamera::pinhole(size, size, f)
    };
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "cam".into(),
            model: Camera::Frame(cam.clone()),
            free_params: vec![],
            calibration_group: None,
        },
    );
    let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut images = BTreeMap::new();
    for (i, (x, y, z, w)) in centres.iter().enumerate() {
        let id = i as u32 + 1;
        let pose = Pose::new(
            rotation_from_vector(&Vector3::from(*w)) * nadir,
            Vector3::new(*x, *y, *z),
        );
        let camera = Camera::Frame(cam.clone());
        let mut data = Vec::with_capacity((size * size * 3) as usize);
        for r in 0..size {
            for c in 0..size {
                let ray = back_project(&camera, &pose, [c as f64 + 0.5, r as f64 + 0.5]).unwrap();
                let world = Ray {
                    origin: block.to_world(&ray.origin),
                    direction: ray.direction,
                };
                let rgb = dem
                    .intersect(&world)
                    .map(|p| texture(p.x, p.y))
                    .unwrap_or([0, 0, 0]);
                data.extend_from_slice(&rgb);
            }
        }
        images.insert(id, RgbImage::new(size, size, data).unwrap());
        block.photos.insert(
            id,
            Photo {
                id,
                name: format!("p{id}.tif"),
                camera: 1,
                pose,
                status: cloudcontrol::block::PhotoStatus::Oriented,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    (block, dem, images)
}

/// Centroid (world) of dark, opaque ortho pixels within `radius` of `near`.
fn find_marker(ds: &Dataset, near: (f64, f64), radius: f64) -> Option<(f64, f64, usize)> {
    let gt = ds.geo_transform().unwrap();
    let (w, h) = ds.raster_size();
    let c0 = ((near.0 - radius - gt[0]) / gt[1]).floor().max(0.0) as usize;
    let r0 = ((near.1 + radius - gt[3]) / gt[5]).floor().max(0.0) as usize;
    let c1 = (((near.0 + radius - gt[0]) / gt[1]).ceil() as usize).min(w);
    let r1 = (((near.1 - radius - gt[3]) / gt[5]).ceil() as usize).min(h);
    let (ww, hh) = (c1 - c0, r1 - r0);
    let band = |b| {
        ds.rasterband(b)
            .unwrap()
            .read_as::<u8>((c0 as isize, r0 as isize), (ww, hh), (ww, hh), None)
            .unwrap()
            .into_shape_and_vec()
            .1
    };
    let (red, alpha) = (band(1), band(4));
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
    for r in 0..hh {
        for c in 0..ww {
            let k = r * ww + c;
            if alpha[k] == 255 && red[k] < 60 {
                sx += gt[0] + (c0 + c) as f64 * gt[1] + 0.5 * gt[1];
                sy += gt[3] + (r0 + r) as f64 * gt[5] + 0.5 * gt[5];
                n += 1;
            }
        }
    }
    (n > 0).then(|| (sx / n as f64, sy / n as f64, n))
}

#[test]
fn orthophoto_places_markers_within_one_ground_pixel_and_handles_occlusion() {
    let (block, dem, images) = scene();
    let crs = Crs::from_epsg(32650).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let gsd = 0.5;
    let opts = OrthoOptions {
        gsd: Some(gsd),
        extent: Some((E0 - 130.0, N0 - 110.0, E0 + 130.0, N0 + 120.0)),
        tile: 128,
        ..Default::default()
    };
    let out = dir.path().join("ortho.tif");
    let report = write_orthophoto(
        &out,
        &block,
        &dem,
        PhotoImages::Decoded(&images),
        &crs,
        &opts,
    )
    .unwrap();
    assert_eq!(report.per_photo.len(), 2);
    assert!(
        report.occluded_fallbacks > 0,
        "the building hides ground from photo 2"
    );
    let ds = Dataset::open(&out).unwrap();
    let expected_area = std::f64::consts::PI * MARKER_RADIUS.powi(2) / (gsd * gsd);
    let mut worst: f64 = 0.0;
    for m in MARKERS {
        let (x, y, n) =
            find_marker(&ds, m, 6.0).unwrap_or_else(|| panic!("marker {m:?} not found"));
        let e = ((x - m.0).powi(2) + (y - m.1).powi(2)).sqrt() / gsd;
        assert!(
            (n as f64 - expected_area).abs() < 0.35 * expected_area,
            "marker {m:?}: {n} px vs {expected_area:.0}"
        );
        worst = worst.max(e);
    }
    eprintln!("worst marker error: {worst:.3} ground pixels");
    assert!(worst < 1.0, "worst marker error {worst} px");

    // Without the visibility test the hidden marker is painted with the building's wall/roof.
    let naive = dir.path().join("naive.tif");
    write_orthophoto(
        &naive,
        &block,
        &dem,
        PhotoImages::Decoded(&images),
        &crs,
        &OrthoOptions {
            occlusion: false,
            ..opts.clone()
        },
    )
    .unwrap();
    let ds2 = Dataset::open(&naive).unwrap();
    let hidden = MARKERS[5];
    let ok = find_marker(&ds2, hidden, 6.0)
        .map(|(x, y, n)| {
            ((x - hidden.0).powi(2) + (y - hidden.1).powi(2)).sqrt() / gsd < 1.0
                && (n as f64) > 0.65 * expected_area
        })
        .unwrap_or(false);
    assert!(
        !ok,
        "without occlusion handling the hidden marker should be damaged"
    );

    // Relief displacement: rectified on a flat plane instead of the DEM, the hilltop marker moves.
    let flat = Dem::from_fn(E0 - 200.0, N0 + 200.0, 2.0, 200, 200, |_, _| 100.0).unwrap();
    let flat_out = dir.path().join("flat.tif");
    write_orthophoto(
        &flat_out,
        &block,
        &flat,
        PhotoImages::Decoded(&images),
        &crs,
        &OrthoOptions {
            occlusion: false,
            ..opts.clone()
        },
    )
    .unwrap();
    let (x, y, _) = find_marker(&Dataset::open(&flat_out).unwrap(), MARKERS[0], 12.0).unwrap();
    let shift = ((x - MARKERS[0].0).powi(2) + (y - MARKERS[0].1).powi(2)).sqrt() / gsd;
    assert!(
        shift > 3.0,
        "flat-plane rectification should displace the hilltop marker (shift {shift} px)"
    );

    // GeoTIFF metadata.
    let gt = ds.geo_transform().unwrap();
    assert_eq!(gt, report.geotransform);
    assert_eq!((gt[1], gt[5]), (gsd, -gsd));
    assert_eq!(ds.raster_count(), 4);
    // The alpha band masks; no band has a nodata value (a GeoTIFF's applies to all,
    // the alpha band's 0 included).
    for b in 1..=4 {
        assert_eq!(ds.rasterband(b).unwrap().no_data_value(), None, "band {b}");
    }
    assert_eq!(
        ds.rasterband(4).unwrap().color_interpretation(),
        gdal::raster::ColorInterpretation::AlphaBand
    );
    assert!(ds.rasterband(1).unwrap().overview_count().unwrap() >= 2);
    assert_eq!(ds.spatial_ref().unwrap().auth_code().unwrap(), 32650);
}

#[test]
fn cloud_optimised_output_and_bad_input() {
    let (block, dem, images) = scene();
    let crs = Crs::from_epsg(32650).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cog.tif");
    let opts = OrthoOptions {
        gsd: Some(0.4),
        extent: Some((E0 - 100.0, N0 - 100.0, E0 + 100.0, N0 + 100.0)),
        cog: true,
        ..Default::default()
    };
    write_orthophoto(
        &out,
        &block,
        &dem,
        PhotoImages::Decoded(&images),
        &crs,
        &opts,
    )
    .unwrap();
    let ds = Dataset::open(&out).unwrap();
    let layout = ds.metadata_item("LAYOUT", "IMAGE_STRUCTURE");
    assert_eq!(layout.as_deref(), Some("COG"));
    assert!(ds.rasterband(1).unwrap().overview_count().unwrap() >= 1);
    // Only the output remains: no scratch or temporary files.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    let mut wrong = images.clone();
    wrong.insert(1, RgbImage::new(10, 10, vec![0; 300]).unwrap());
    let e = write_orthophoto(
        &dir.path().join("bad.tif"),
        &block,
        &dem,
        PhotoImages::Decoded(&wrong),
        &crs,
        &opts,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("bad.tif") && e.contains("photo 1") && e.contains("10×10"),
        "{e}"
    );
    assert!(!dir.path().join("bad.tif").exists());
}

/// Band values of a GeoTIFF, all bands.
fn pixels(path: &std::path::Path) -> Vec<Vec<u8>> {
    let ds = Dataset::open(path).unwrap();
    let (w, h) = ds.raster_size();
    (1..=ds.raster_count())
        .map(|b| {
            let band = ds.rasterband(b).unwrap();
            band.read_as::<u8>((0, 0), (w, h), (w, h), None)
                .unwrap()
                .into_shape_and_vec()
                .1
        })
        .collect()
}

#[test]
fn photos_decoded_on_demand_through_a_small_cache_give_the_same_orthophoto() {
    // 25 photos in 5 strips 150 m above the ground (100–125 m): each sees about 60 m, a
    // tile of 32 m a few photos.
    let mut centres = Vec::new();
    for i in 0..5 {
        for j in 0..5 {
            let w = [0.01 * (i as f64 - 2.0), -0.008 * (j as f64 - 2.0), 0.02];
            centres.push((-80.0 + 40.0 * j as f64, -80.0 + 40.0 * i as f64, 260.0, w));
        }
    }
    let (mut block, dem, images) = rendered_block(&centres, 200, 520.0);
    let dir = tempfile::tempdir().unwrap();
    let mut files = BTreeMap::new();
    for (id, img) in &images {
        let path = dir.path().join(format!("p{id}.png"));
        image::RgbImage::from_raw(img.width, img.height, img.data.clone())
            .unwrap()
            .save(&path)
            .unwrap();
        files.insert(*id, path);
    }
    // A photo that is not oriented is neither decoded nor used.
    block.photos.get_mut(&13).unwrap().status = cloudcontrol::block::PhotoStatus::Approximate;
    let crs = Crs::from_epsg(32650).unwrap();
    let one = 200 * 200 * 3;
    let opts = OrthoOptions {
        gsd: Some(0.5),
        extent: Some((E0 - 110.0, N0 - 110.0, E0 + 110.0, N0 + 110.0)),
        tile: 64,
        image_cache_bytes: 4 * one,
        overviews: vec![],
        ..Default::default()
    };
    let a = dir.path().join("decoded.tif");
    let ra =
        write_orthophoto(&a, &block, &dem, PhotoImages::Decoded(&images), &crs, &opts).unwrap();
    assert_eq!(ra.per_photo.len(), 24, "{:?}", ra.per_photo.keys());
    assert!(!ra.per_photo.contains_key(&13));
    assert!(ra.filled > 400 * 400, "{} cells filled", ra.filled);
    // Decoded images held by the caller are not the cache's.
    assert_eq!((ra.image_loads, ra.peak_image_bytes), (0, 0));
    // Cache bounds from 2 photos to all of them: the same orthophoto; at most the bound plus
    // the photos one tile takes cells from alive at once (a 32 m tile within a grid of 40 m
    // Voronoi cells: at most 4); along the Hilbert curve a photo is decoded again only when
    // the curve comes back to its cells after the cache has dropped it (measured 80, 56, 32
    // and 24 loads).
    for (photos, max_loads) in [(2, 90), (4, 64), (8, 36), (24, 24)] {
        let b = dir.path().join(format!("files{photos}.tif"));
        let opts = OrthoOptions {
            image_cache_bytes: photos * one,
            ..opts.clone()
        };
        let rb =
            write_orthophoto(&b, &block, &dem, PhotoImages::Files(&files), &crs, &opts).unwrap();
        eprintln!(
            "cache of {photos} photos: {} loads of 24 photos, peak {} photo images",
            rb.image_loads,
            rb.peak_image_bytes / one
        );
        assert!(pixels(&a) == pixels(&b), "the cache changed the orthophoto");
        assert_eq!(ra.per_photo, rb.per_photo);
        assert!(
            rb.peak_image_bytes <= (photos.max(4)) * one,
            "peak {}",
            rb.peak_image_bytes
        );
        assert!(
            rb.image_loads >= 24 && rb.image_loads <= max_loads,
            "{} loads",
            rb.image_loads
        );
    }
}
