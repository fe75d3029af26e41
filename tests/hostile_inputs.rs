//! Small crafted files whose counts or sizes claim far more than they hold: each is refused
//! with a typed error naming the file and the limit, before anything is allocated from
//! the claim, through the library and through the CLI. Every file is written here, byte
//! by byte, from the format documents (formats/colmap, formats/lidar, ...).

mod common;
use common::cli;
use std::path::Path;

/// Asserts that `message` names `file` and holds each of `words`.
fn says(message: &str, file: &Path, words: &[&str]) {
    assert!(
        message.contains(&file.display().to_string()),
        "names the file {}: {message}",
        file.display()
    );
    for w in words {
        assert!(message.contains(w), "says {w:?}: {message}");
    }
}

/// Runs the CLI, which must fail, and returns its stderr.
fn cli_fails(args: &[&str]) -> String {
    let (ok, out, err) = cli(args);
    assert!(!ok, "succeeded: {out}");
    err
}

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
            // Binary: 12 bytes a vertex; ascii: at least "0 0 0\n", 6 bytes.
            let limit = if format == "ascii" { "exceeds 1," } else { "exceeds 1," };
            says(
                &e.to_string(),
                &f,
                &["PLY element vertex count", count, limit],
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

#[path = "lidar_synth/mod.rs"]
mod lidar_synth;

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
        let legacy = if self.minor >= 4 { 0 } else { self.count as u32 };
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
    assert_eq!((s.info().point_count, s.info().version.as_str()), (2, "1.4"));

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
    las_refused(&f, &["declares 9223372036854775808 points", "holds only 2"]);
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
    las_refused(&f, &["VLR count 4294967295 exceeds 3", "200 bytes after the header"]);
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
    las_refused(&f, &["point count 4294967295 exceeds 50000", "1 LAZ chunks"]);

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
