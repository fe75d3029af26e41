//! Small crafted files whose counts or sizes claim far more than they hold: each is refused
//! with a typed error naming the file and the limit, before anything is allocated from
//! the claim, through the library and through the CLI. Every file is written here, byte
//! by byte, from the format documents (formats/colmap, formats/lidar, ...).

use crate::common;
use common::{cli_fails, last_error, says};
use std::path::Path;

// ---------------------------------------------------------------------------------------
// COLMAP frames
// ---------------------------------------------------------------------------------------

/// An empty COLMAP 4 model (no camera, image, point or rig) whose `frames.bin` holds one
/// frame claiming 2³² − 1 data ids (formats/colmap/README.md, `frames.bin`).
fn colmap_frames_bin(dir: &Path) -> std::path::PathBuf {
    for f in ["cameras.bin", "images.bin", "points3D.bin", "rigs.bin"] {
        std::fs::write(dir.join(f), 0u64.to_le_bytes()).unwrap();
    }
    let mut b = Vec::new();
    b.extend(1u64.to_le_bytes()); // frames
    b.extend(1u32.to_le_bytes()); // frame id
    b.extend(1u32.to_le_bytes()); // rig id
    for v in [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] {
        b.extend(v.to_le_bytes());
    }
    b.extend(u32::MAX.to_le_bytes()); // data ids
    b.extend(0i32.to_le_bytes());
    b.extend(1u32.to_le_bytes());
    b.extend(1u64.to_le_bytes());
    let f = dir.join("frames.bin");
    std::fs::write(&f, b).unwrap();
    f
}

fn colmap_frames_txt(dir: &Path) -> std::path::PathBuf {
    for f in ["cameras.txt", "images.txt", "points3D.txt", "rigs.txt"] {
        std::fs::write(dir.join(f), "# empty\n").unwrap();
    }
    let f = dir.join("frames.txt");
    std::fs::write(&f, "# frames\n1 1 1 0 0 0 0 0 0 4294967295 CAMERA 1 1\n").unwrap();
    f
}

#[test]
fn colmap_frame_data_id_count_beyond_the_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let bin = tmp.path().join("bin");
    let txt = tmp.path().join("txt");
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::create_dir_all(&txt).unwrap();
    let fb = colmap_frames_bin(&bin);
    let ft = colmap_frames_txt(&txt);
    let len = std::fs::metadata(&fb).unwrap().len();

    let e = cloudcontrol::formats::colmap::read(&bin)
        .unwrap_err()
        .to_string();
    says(
        &e,
        &fb,
        &[
            "data id count",
            "4294967295",
            &format!("file of {len} bytes"),
        ],
    );
    let e = cloudcontrol::formats::colmap::read(&txt)
        .unwrap_err()
        .to_string();
    says(
        &e,
        &ft,
        &["line 2", "NUM_DATA_IDS 4294967295", "holds 3 more"],
    );

    for (dir, f) in [(&bin, &fb), (&txt, &ft)] {
        let out = tmp.path().join("out.xml");
        let err = cli_fails(&["convert", dir.to_str().unwrap(), out.to_str().unwrap()]);
        says(&err, f, &["4294967295"]);
    }
}

// ---------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------

#[test]
fn ply_vertex_count_beyond_the_file_is_refused() {
    use cloudcontrol::lidar::points_io::read_xyz;
    use cloudcontrol::lidar::LidarError;
    let tmp = tempfile::tempdir().unwrap();
    // 99 999 999 999 vertices (≈ 1.2 TB of float x y z) and 2⁶¹ (the byte count
    // overflows 64 bits), in both encodings, each followed by one real vertex.
    for (k, count) in ["99999999999", "2305843009213693952"].iter().enumerate() {
        for format in ["binary_little_endian", "ascii"] {
            let f = tmp.path().join(format!("v{k}_{format}.ply"));
            let mut b = format!(
                "ply\nformat {format} 1.0\nelement vertex {count}\nproperty float x\n\
                 property float y\nproperty float z\nend_header\n"
            )
            .into_bytes();
            if format == "ascii" {
                b.extend(b"1 2 3\n");
            } else {
                for v in [1.0f32, 2.0, 3.0] {
                    b.extend(v.to_le_bytes());
                }
            }
            std::fs::write(&f, b).unwrap();
            let e = read_xyz(&f).unwrap_err();
            assert!(matches!(e, LidarError::TooLarge { .. }), "{e}");
            // Binary: 12 bytes a vertex; ascii: at least "0 0 0\n", 6 bytes. Either way the
            // bytes after the header hold one vertex.
            let per = if format == "ascii" {
                "at 6 bytes"
            } else {
                "at 12 bytes"
            };
            says(
                &e.to_string(),
                &f,
                &["PLY element vertex count", count, "exceeds 1,", per],
            );
            let err = cli_fails(&[
                "icp",
                "--source",
                f.to_str().unwrap(),
                "--target",
                tmp.path().to_str().unwrap(),
            ]);
            says(&err, &f, &[count]);
        }
    }
    // The same file with its true count reads back.
    let f = tmp.path().join("one.ply");
    std::fs::write(
        &f,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         property float z\nend_header\n1 2 3\n",
    )
    .unwrap();
    assert_eq!(read_xyz(&f).unwrap(), vec![[1.0, 2.0, 3.0]]);
}

// ---------------------------------------------------------------------------------------
// LAS / LAZ
// ---------------------------------------------------------------------------------------

use crate::lidar_synth;

/// A LAS 1.2 (227-byte header) or 1.4 (375-byte header) file by hand (ASPRS LAS 1.4 R15
/// §2.4): point format 0 (20-byte records), `count` declared, the given VLRs (user id,
/// record id, length field, data), `points` zero records, then the given EVLRs (1.4).
struct HandLas {
    minor: u8,
    count: u64,
    vlrs: Vec<(&'static str, u16, u16, Vec<u8>)>,
    points: usize,
    evlrs: Vec<(u64, Vec<u8>)>,
}

impl HandLas {
    fn bytes(&self) -> Vec<u8> {
        let hs: usize = if self.minor >= 4 { 375 } else { 227 };
        let mut h = vec![0u8; hs];
        h[0..4].copy_from_slice(b"LASF");
        h[24] = 1;
        h[25] = self.minor;
        h[94..96].copy_from_slice(&(hs as u16).to_le_bytes());
        let vlr_bytes: usize = self.vlrs.iter().map(|v| 54 + v.3.len()).sum();
        let start = hs + vlr_bytes;
        h[96..100].copy_from_slice(&(start as u32).to_le_bytes());
        h[100..104].copy_from_slice(&(self.vlrs.len() as u32).to_le_bytes());
        h[104] = 0;
        h[105..107].copy_from_slice(&20u16.to_le_bytes());
        let legacy = if self.minor >= 4 {
            0
        } else {
            self.count as u32
        };
        h[107..111].copy_from_slice(&legacy.to_le_bytes());
        for k in 0..3 {
            h[131 + 8 * k..139 + 8 * k].copy_from_slice(&0.01f64.to_le_bytes());
        }
        if self.minor >= 4 {
            let evlr_at = (start + 20 * self.points) as u64;
            if !self.evlrs.is_empty() {
                h[235..243].copy_from_slice(&evlr_at.to_le_bytes());
                h[243..247].copy_from_slice(&(self.evlrs.len() as u32).to_le_bytes());
            }
            h[247..255].copy_from_slice(&self.count.to_le_bytes());
        }
        for (user, id, len, data) in &self.vlrs {
            let mut v = vec![0u8; 54];
            v[2..2 + user.len()].copy_from_slice(user.as_bytes());
            v[18..20].copy_from_slice(&id.to_le_bytes());
            v[20..22].copy_from_slice(&len.to_le_bytes());
            h.extend(v);
            h.extend(data);
        }
        h.extend(vec![0u8; 20 * self.points]);
        for (len, data) in &self.evlrs {
            let mut v = vec![0u8; 60];
            v[2..7].copy_from_slice(b"crash");
            v[20..28].copy_from_slice(&len.to_le_bytes());
            h.extend(v);
            h.extend(data);
        }
        h
    }
}

fn las_refused(f: &Path, words: &[&str]) {
    use cloudcontrol::lidar::points_io::read_xyz;
    use cloudcontrol::lidar::LasStream;
    let e = LasStream::open(f).err().expect("refused").to_string();
    says(&e, f, words);
    let e = read_xyz(f).unwrap_err().to_string();
    says(&e, f, words);
    let out = f.with_extension("rewritten.las");
    let e = cloudcontrol::lidar::las::rewrite_las(f, &out, |_, p| Some(p))
        .unwrap_err()
        .to_string();
    says(&e, f, words);
    let err = cli_fails(&["lidar", "info", f.to_str().unwrap()]);
    says(&err, f, words);
    let err = cli_fails(&[
        "icp",
        "--source",
        f.to_str().unwrap(),
        "--target",
        f.to_str().unwrap(),
    ]);
    says(&err, f, words);
}

#[test]
fn las_counts_and_lengths_beyond_the_file_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let write = |name: &str, las: HandLas| {
        let f = tmp.path().join(name);
        std::fs::write(&f, las.bytes()).unwrap();
        f
    };
    // The well-formed file reads (an independent check of the hand-written layout).
    let f = write(
        "good.las",
        HandLas {
            minor: 4,
            count: 2,
            vlrs: vec![("cloudcontrol", 1, 3, vec![1, 2, 3])],
            points: 2,
            evlrs: vec![(4, vec![0; 4])],
        },
    );
    let s = cloudcontrol::lidar::LasStream::open(&f).unwrap();
    assert_eq!(
        (s.info().point_count, s.info().version.as_str()),
        (2, "1.4")
    );

    // 2³² − 1 points of 20 bytes in a 267-byte file.
    let f = write(
        "count.las",
        HandLas {
            minor: 2,
            count: u32::MAX as u64,
            vlrs: vec![],
            points: 2,
            evlrs: vec![],
        },
    );
    las_refused(&f, &["declares 4294967295 points", "holds only 2"]);
    // LAS 1.4's 64-bit count: 2⁶³ (its byte count overflows 64 bits).
    let f = write(
        "count64.las",
        HandLas {
            minor: 4,
            count: 1 << 63,
            vlrs: vec![],
            points: 2,
            evlrs: vec![],
        },
    );
    // Refused before the file size is asked: no 64-bit offset reaches its records.
    las_refused(
        &f,
        &[
            "point count 9223372036854775808 exceeds",
            "a 64-bit file offset can address",
        ],
    );
    // 2³² − 1 VLRs (54 bytes each at least).
    let mut las = HandLas {
        minor: 2,
        count: 0,
        vlrs: vec![],
        points: 0,
        evlrs: vec![],
    };
    let mut b = las.bytes();
    b[100..104].copy_from_slice(&u32::MAX.to_le_bytes());
    b.extend(vec![0u8; 200]);
    let f = tmp.path().join("vlr_count.las");
    std::fs::write(&f, &b).unwrap();
    las_refused(
        &f,
        &[
            "VLR count 4294967295 exceeds 3",
            "200 bytes after the header",
        ],
    );
    // A VLR whose length field says 65 535 bytes where 3 follow.
    las.vlrs = vec![("cloudcontrol", 1, u16::MAX, vec![1, 2, 3])];
    let f = write("vlr_len.las", las);
    las_refused(&f, &["VLR 0 length 65535 exceeds 3"]);
    // LAS 1.4 with an extended VLR of 2⁴⁰ bytes.
    let f = write(
        "evlr.las",
        HandLas {
            minor: 4,
            count: 1,
            vlrs: vec![],
            points: 1,
            evlrs: vec![(1 << 40, vec![0; 8])],
        },
    );
    las_refused(&f, &["EVLR 0 length 1099511627776 exceeds 8"]);
    // 2³² − 1 EVLRs (60 bytes each at least).
    let mut b = std::fs::read(&f).unwrap();
    b[243..247].copy_from_slice(&u32::MAX.to_le_bytes());
    let f = tmp.path().join("evlr_count.las");
    std::fs::write(&f, &b).unwrap();
    las_refused(&f, &["EVLR count 4294967295 exceeds 1"]);
}

/// A small real LAZ (three points written by the `las` crate, 50 000-point chunks).
fn small_laz(path: &Path) -> Vec<u8> {
    use lidar_synth::{write_las, CrsVlr, P};
    let pts: Vec<P> = (0..3)
        .map(|i| P {
            x: 500_000.0 + i as f64,
            y: 4_400_000.0,
            z: 10.0,
            class: 2,
            source: 1,
            gps: 0.0,
        })
        .collect();
    write_las(path, &pts, 2, CrsVlr::None, true);
    std::fs::read(path).unwrap()
}

#[test]
fn laz_counts_beyond_the_chunk_table_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good.laz");
    let b = small_laz(&good);
    assert_eq!(
        cloudcontrol::lidar::las::read_points(&good, None, None)
            .unwrap()
            .len(),
        3
    );
    // The header claims 2³² − 1 points; the one chunk holds at most 50 000.
    let mut c = b.clone();
    c[107..111].copy_from_slice(&u32::MAX.to_le_bytes());
    let f = tmp.path().join("count.laz");
    std::fs::write(&f, &c).unwrap();
    las_refused(
        &f,
        &["point count 4294967295 exceeds 50000", "1 LAZ chunks"],
    );

    // The chunk table claims 2³² − 1 chunks (laszip: the table's offset is the first 8
    // bytes of the point data; the table starts with version and count, u32 each).
    let start = u32::from_le_bytes(b[96..100].try_into().unwrap()) as usize;
    let table = i64::from_le_bytes(b[start..start + 8].try_into().unwrap()) as usize;
    let mut c = b.clone();
    c[table + 4..table + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let f = tmp.path().join("chunks.laz");
    std::fs::write(&f, &c).unwrap();
    las_refused(
        &f,
        &[
            "LAZ chunk table entry count 4294967295",
            "bytes of compressed point data",
        ],
    );
}

/// The real LAS/LAZ samples (PDAL's test data) still read whole, each with the count its
/// header declares.
#[test]
fn real_las_samples_still_read() {
    let dir = Path::new("/work/shared/data/las_format_samples");
    if !dir.is_dir() {
        return;
    }
    for name in [
        "1.2-with-color.las",
        "extrabytes.las",
        "lone-star.copc.laz",
        "mvk-thin.las",
        "simple.las",
        "simple.laz",
        "test1_4.las",
        "warsaw_small.las",
    ] {
        let f = dir.join(name);
        let s = cloudcontrol::lidar::LasStream::open(&f).unwrap();
        let n = s.info().point_count;
        let pts = cloudcontrol::lidar::las::read_points(&f, None, None).unwrap();
        assert_eq!(pts.len() as u64, n, "{name}");
    }
    // warsaw_small.las: its WKT VLR holds `''`, which means no CRS, not a bad one.
    let f = dir.join("warsaw_small.las");
    let s = cloudcontrol::lidar::LasStream::open(&f).unwrap();
    assert!(s.info().crs_wkt.is_none());
    assert_eq!(s.info().point_count, 3000);
}

// ---------------------------------------------------------------------------------------
// Images and rasters
// ---------------------------------------------------------------------------------------

/// CRC-32 of PNG chunks (ISO 3309, reflected polynomial 0xEDB88320).
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG of `width`×`height` pixels (bit depth, colour type) holding only its signature,
/// IHDR, an empty IDAT and IEND: 57 bytes whatever size it claims.
fn png_header(width: u32, height: u32, depth: u8, colour: u8) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let mut body = kind.to_vec();
        body.extend(data);
        c.extend(&body);
        c.extend(crc32(&body).to_be_bytes());
        c
    };
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([depth, colour, 0, 0, 0]);
    let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
    b.extend(chunk(b"IHDR", &ihdr));
    b.extend(chunk(b"IDAT", &[]));
    b.extend(chunk(b"IEND", &[]));
    b
}

const CAMERA: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/formats/cameras/wild_rc10.json"
);

#[test]
fn images_beyond_the_size_limits_are_refused_before_decoding() {
    use cloudcontrol::formats::image_open::{MAX_DECODED_BYTES, MAX_IMAGE_PIXELS};
    use cloudcontrol::matching::GreyImage;
    let tmp = tempfile::tempdir().unwrap();
    // 100 000 × 100 000 grey pixels (10¹⁰ > 2³⁰) in 57 bytes.
    let big = tmp.path().join("big.png");
    std::fs::write(&big, png_header(100_000, 100_000, 8, 0)).unwrap();
    // 30 000 × 30 000 RGBA 16-bit: 9·10⁸ pixels (within the pixel limit) but 7.2 GB decoded.
    let bomb = tmp.path().join("bomb.png");
    std::fs::write(&bomb, png_header(30_000, 30_000, 16, 6)).unwrap();
    let pixels = MAX_IMAGE_PIXELS.to_string();
    let bytes = MAX_DECODED_BYTES.to_string();
    for (f, words) in [
        (&big, vec!["100000×100000", "10000000000", pixels.as_str()]),
        (&bomb, vec!["30000×30000", "7200000000", bytes.as_str()]),
    ] {
        let e = GreyImage::load(f).unwrap_err().to_string();
        says(&e, f, &words);
        let e = cloudcontrol::formats::ortho::RgbImage::load(f)
            .err()
            .unwrap()
            .to_string();
        says(&e, f, &words);
        let err = cli_fails(&["io", "--camera", CAMERA, f.to_str().unwrap()]);
        says(&err, f, &words);
        let err = cli_fails(&["match", f.to_str().unwrap(), f.to_str().unwrap()]);
        says(&err, f, &words);
    }
    // From memory (a package member) the same limits hold.
    let e = cloudcontrol::formats::image_open::decode_image_bytes(
        Path::new("chip.png"),
        &png_header(30_000, 30_000, 16, 6),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("chip.png") && e.contains(&bytes), "{e}");
    // The same header with a size that fits reads (an empty IDAT: a decode error, not a
    // size error).
    let small = tmp.path().join("small.png");
    std::fs::write(&small, png_header(4, 4, 8, 0)).unwrap();
    let e = GreyImage::load(&small).unwrap_err().to_string();
    assert!(!e.contains("exceeds"), "{e}");
}

#[test]
fn dem_size_query_reads_the_header_only() {
    use cloudcontrol::ffi::*;
    use std::ptr::{null, null_mut};
    let tmp = tempfile::tempdir().unwrap();
    let big = tmp.path().join("dem.png");
    std::fs::write(&big, png_header(100_000, 100_000, 8, 0)).unwrap();
    let p = std::ffi::CString::new(big.to_str().unwrap()).unwrap();
    let (mut w, mut h, mut gt) = (0usize, 0usize, [0f64; 6]);
    let st = unsafe { ccp_dem_read(p.as_ptr(), &mut w, &mut h, gt.as_mut_ptr(), null_mut(), 0) };
    assert_eq!(st, CcpStatus::Format);
    let e = last_error();
    says(&e, &big, &["100000×100000", "1073741824"]);
    let _ = null::<u8>();

    // A DEM that fits: the size query fills the size without reading the heights.
    let dem = tmp.path().join("dem.tif");
    let d = cloudcontrol::geometry::Dem::from_fn(500_000.0, 4_400_000.0, 2.0, 30, 20, |_, _| 1.0)
        .unwrap();
    let crs = cloudcontrol::formats::crs::Crs::from_epsg(32650).unwrap();
    cloudcontrol::formats::raster::write_dem(&dem, &d, &crs, &Default::default()).unwrap();
    let p = std::ffi::CString::new(dem.to_str().unwrap()).unwrap();
    let st = unsafe { ccp_dem_read(p.as_ptr(), &mut w, &mut h, gt.as_mut_ptr(), null_mut(), 0) };
    assert_eq!((st, w, h), (CcpStatus::BufferTooSmall, 30, 20));
    assert_eq!(gt, d.transform.0);
}

#[test]
fn a_png_that_is_vrt_xml_is_not_opened_by_gdal() {
    use cloudcontrol::matching::GreyImage;
    let tmp = tempfile::tempdir().unwrap();
    // A real raster the VRT would read, and the VRT itself named .png.
    let target = tmp.path().join("secret.tif");
    let d = cloudcontrol::geometry::Dem::from_fn(0.0, 10.0, 1.0, 10, 10, |_, _| 7.0).unwrap();
    let crs = cloudcontrol::formats::crs::Crs::from_epsg(32650).unwrap();
    cloudcontrol::formats::raster::write_dem(&target, &d, &crs, &Default::default()).unwrap();
    let vrt = format!(
        "<VRTDataset rasterXSize=\"10\" rasterYSize=\"10\"><VRTRasterBand dataType=\"Float32\" \
         band=\"1\"><SimpleSource><SourceFilename relativeToVRT=\"0\">{}</SourceFilename>\
         <SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>",
        target.display()
    );
    let f = tmp.path().join("photo.png");
    std::fs::write(&f, vrt).unwrap();
    // GDAL itself would read it (the test is meaningful).
    assert!(gdal::Dataset::open(&f).is_ok());
    let e = GreyImage::load(&f).unwrap_err().to_string();
    says(&e, &f, &["GTiff, PNG, JPEG"]);
    let e = cloudcontrol::formats::raster::read_dem(&f)
        .err()
        .unwrap()
        .to_string();
    says(&e, &f, &["GTiff, PNG, JPEG"]);
    // GDAL's network file system is refused before GDAL sees the name.
    let url = Path::new("/vsicurl/http://127.0.0.1:9/dem.tif");
    let e = cloudcontrol::formats::raster::read_dem(url)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("not a local file") || e.contains("does not exist"),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------
// Parameters with physical meaning
// ---------------------------------------------------------------------------------------

#[test]
fn fiducial_mark_larger_than_a_tenth_of_the_film_is_refused() {
    use cloudcontrol::matching::fiducial::CameraDefinition;
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(CAMERA).unwrap();
    let mut cam: serde_json::Value = serde_json::from_str(&text).unwrap();
    cam["fiducials"][0]["shape"]["size_mm"] = 1000.0.into();
    let f = tmp.path().join("cam.json");
    std::fs::write(&f, cam.to_string()).unwrap();
    let e = CameraDefinition::load(&f).unwrap_err().to_string();
    says(&e, &f, &["size_mm 1000", "at most 23 mm"]);
    // The scan is never read: the camera is refused first.
    let err = cli_fails(&["io", "--camera", f.to_str().unwrap(), "no-such-scan.tif"]);
    says(&err, &f, &["size_mm 1000"]);
    // A film format of a kilometre is no film.
    cam["fiducials"][0]["shape"]["size_mm"] = 1.0.into();
    cam["format_mm"] = serde_json::json!([1e6, 1e6]);
    std::fs::write(&f, cam.to_string()).unwrap();
    let e = CameraDefinition::load(&f).unwrap_err().to_string();
    says(&e, &f, &["format_mm", "at most 500 mm"]);
}

#[test]
fn scan_pixel_size_outside_film_scanning_is_refused_at_every_entry() {
    use cloudcontrol::ffi::*;
    let tmp = tempfile::tempdir().unwrap();
    let scan = tmp.path().join("scan.png");
    std::fs::write(&scan, png_header(4, 4, 8, 0)).unwrap();
    let err = cli_fails(&[
        "io",
        "--camera",
        CAMERA,
        scan.to_str().unwrap(),
        "--pixel-um",
        "0.000001",
    ]);
    assert!(
        err.contains("--pixel-um") && err.contains("3–200 µm"),
        "{err}"
    );

    let cam = std::ffi::CString::new(std::fs::read_to_string(CAMERA).unwrap()).unwrap();
    let img = vec![0f32; 64 * 64];
    let mut needed = 0usize;
    let st = unsafe {
        ccp_fiducial_io(
            cam.as_ptr(),
            img.as_ptr(),
            64,
            64,
            1e-9,
            0,
            -1,
            std::ptr::null_mut(),
            0,
            &mut needed,
        )
    };
    assert_eq!(st, CcpStatus::InvalidArgument);
    let e = last_error();
    assert!(e.contains("pixel_mm") && e.contains("3–200 µm"), "{e}");
}

#[test]
fn orthophoto_gsd_far_below_the_extent_is_refused() {
    use cloudcontrol::block::{Block, BlockCamera, Photo};
    use cloudcontrol::formats::ortho::{
        write_orthophoto, OrthoOptions, PhotoImages, RgbImage, MAX_ORTHO_PIXELS,
    };
    use cloudcontrol::geometry::{Camera, Dem, FrameCamera, Pose};
    use nalgebra::{Matrix3, Vector3};
    let tmp = tempfile::tempdir().unwrap();
    let (e0, n0) = (500_000.0, 4_400_000.0);
    let dem = Dem::from_fn(e0, n0 + 400.0, 2.0, 200, 200, |_, _| 0.0).unwrap();
    let mut block = Block::new();
    block.crs = Some("EPSG:32650".into());
    block.origin = [e0 + 200.0, n0 + 200.0, 0.0];
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "cam".into(),
            model: Camera::Frame(FrameCamera::pinhole(8, 8, 8.0)),
            free_params: vec![],
            calibration_group: None,
        },
    );
    let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let pose = Pose::new(nadir, Vector3::new(0.0, 0.0, 400.0));
    block
        .photos
        .insert(1, Photo::new(1, "p1.png", 1, pose).oriented());
    let images = [(1, RgbImage::new(8, 8, vec![128; 192]).unwrap())].into();
    let crs = cloudcontrol::formats::crs::Crs::from_epsg(32650).unwrap();
    let out = tmp.path().join("ortho.tif");
    let opts = OrthoOptions {
        gsd: Some(0.0005),
        ..Default::default()
    };
    let e = write_orthophoto(
        &out,
        &block,
        &dem,
        PhotoImages::Decoded(&images),
        &crs,
        &opts,
    )
    .unwrap_err()
    .to_string();
    says(&e, &out, &["gsd 0.0005", &MAX_ORTHO_PIXELS.to_string()]);
    assert!(!out.exists());

    // The same through the CLI: a COLMAP model, the DEM GeoTIFF and the photo.
    let model = tmp.path().join("model");
    std::fs::create_dir_all(&model).unwrap();
    cloudcontrol::formats::colmap::write(&model, &block, &Default::default()).unwrap();
    image::RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128]))
        .save(model.join("p1.png"))
        .unwrap();
    let dem_f = tmp.path().join("dem.tif");
    cloudcontrol::formats::raster::write_dem(&dem_f, &dem, &crs, &Default::default()).unwrap();
    let err = cli_fails(&[
        "ortho",
        "--block",
        model.to_str().unwrap(),
        "--dem",
        dem_f.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--gsd",
        "0.0005",
    ]);
    says(&err, &out, &["gsd 0.0005", &MAX_ORTHO_PIXELS.to_string()]);
}
