//! Hostile inputs, second round (issue 51), items 2–4: memory budgets. Each crafted input is
//! written here by hand from formats/ — camera definitions (formats/cameras/README.md),
//! PNG, TIFF and JPEG headers and compressed streams — never by `synth`, and run in a child
//! process under a 2 GiB RLIMIT_AS (tests/common: [`cli_confined`], [`run_confined`]; the C
//! ABI through a Python ctypes script on `libcloudcontrol.so`): each must be refused with a
//! non-zero exit or a documented status, a message naming the input (the file, and the
//! key that named it) and the limit, within 1 GiB of resident memory and 5 s.
//!
//! 2. A template mark whose `pixel_mm` makes it larger than a mark (a 14 KB PNG at 0.9 mm a
//!    pixel drew an 8 GB template), or larger than the scan's pixel allows.
//! 3. A camera with 10⁴ (CLI) or 3·10⁴ (`ccp_fiducial_io`) fiducials: refused at parse time.
//! 4. Decompression bombs within the old pixel cap: a 260 KB PNG of 16384², a 780 KB RGB
//!    PNG, an LZW TIFF, a JPEG claiming 30000², through `match`, `io` and `ccp_orient_photo`;
//!    a caller's buffer claiming 16384² through `ccp_match_template`; and the budget itself
//!    (configurable, and a whole admitted photo searched within it).

use crate::common::{cli_confined, exe, run_confined, Confined};
use std::path::{Path, PathBuf};
use std::process::Command;

// ---------------------------------------------------------------------------------------
// Hand-written files.

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

/// A PNG of `width`×`height` pixels (bit depth, colour type) with `idat` as its one IDAT.
fn png(width: u32, height: u32, depth: u8, colour: u8, idat: &[u8]) -> Vec<u8> {
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
    b.extend(chunk(b"IDAT", idat));
    b.extend(chunk(b"IEND", &[]));
    b
}

/// Bits written least significant first (deflate, RFC 1951).
struct LsbBits {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl LsbBits {
    fn new() -> Self {
        Self {
            out: Vec::new(),
            acc: 0,
            n: 0,
        }
    }
    fn put(&mut self, value: u32, bits: u32) {
        self.acc |= u64::from(value) << self.n;
        self.n += bits;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }
    /// A Huffman code of `len` bits, its most significant bit first.
    fn code(&mut self, code: u32, len: u32) {
        let r = (0..len).fold(0, |r, i| r | ((code >> i) & 1) << (len - 1 - i));
        self.put(r, len);
    }
    fn finish(mut self) -> Vec<u8> {
        if self.n > 0 {
            self.out.push(self.acc as u8);
        }
        self.out
    }
}

/// A zlib stream of `n` zero bytes in one dynamic-Huffman deflate block whose only codes
/// are the literal 0 (2 bits), end of block (2 bits), length 258 (1 bit) and distance 1
/// (1 bit): 258 bytes in every 2 bits, about 1/1000 of the data.
fn zlib_zeros(n: u64) -> Vec<u8> {
    let mut b = LsbBits::new();
    b.put(1, 1); // last block
    b.put(2, 2); // dynamic Huffman
    b.put(29, 5); // 286 literal/length codes
    b.put(1, 5); // 2 distance codes
    b.put(14, 4); // 18 code length codes
    for s in [16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1] {
        b.put(
            match s {
                18 => 1,
                1 | 2 => 2,
                _ => 0,
            },
            3,
        );
    }
    // Code length codes: 18 → 0, 1 → 10, 2 → 11.
    let cl = |b: &mut LsbBits, sym: u32| match sym {
        18 => b.code(0, 1),
        1 => b.code(2, 2),
        _ => b.code(3, 2),
    };
    cl(&mut b, 2); // literal 0: 2 bits
    cl(&mut b, 18);
    b.put(138 - 11, 7);
    cl(&mut b, 18);
    b.put(117 - 11, 7); // literals 1–255: none
    cl(&mut b, 2); // end of block: 2 bits
    cl(&mut b, 18);
    b.put(28 - 11, 7); // lengths 257–284: none
    cl(&mut b, 1); // length 258 (285): 1 bit
    cl(&mut b, 1);
    cl(&mut b, 1); // distances 1 and 2: 1 bit
                   // Literal/length codes: 285 → 0, literal 0 → 10, end → 11; distance 1 → 0.
    b.code(2, 2);
    let mut left = n - 1;
    while left >= 258 {
        b.code(0, 1);
        b.code(0, 1);
        left -= 258;
    }
    for _ in 0..left {
        b.code(2, 2);
    }
    b.code(3, 2);
    let mut z = vec![0x78, 0x01];
    z.extend(b.finish());
    // Adler-32 of zeros: a = 1, b = n (mod 65521).
    z.extend((((n % 65521) as u32) << 16 | 1).to_be_bytes());
    z
}

/// A PNG of zeros: `width`×`height`, 8-bit grey (`colour` 0) or RGB (2).
fn png_bomb(width: u32, height: u32, colour: u8) -> Vec<u8> {
    let channels = if colour == 2 { 3 } else { 1 };
    let raw = u64::from(height) * (1 + u64::from(width) * channels);
    png(width, height, 8, colour, &zlib_zeros(raw))
}

/// Bits written most significant first (TIFF LZW).
struct MsbBits {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl MsbBits {
    fn put(&mut self, v: u32, bits: u32) {
        self.acc = (self.acc << bits) | u64::from(v);
        self.n += bits;
        while self.n >= 8 {
            self.n -= 8;
            self.out.push((self.acc >> self.n) as u8);
        }
        self.acc &= (1 << self.n) - 1;
    }
}

/// `n` zero bytes compressed as TIFF LZW (TIFF 6.0 §13, as libtiff writes it): a run of
/// zeros is sent as codes for runs of 1, 2, 3, … bytes, the table cleared when full.
fn lzw_zeros(n: u64) -> Vec<u8> {
    let mut w = MsbBits {
        out: Vec::new(),
        acc: 0,
        n: 0,
    };
    let (clear, eoi) = (256, 257);
    let mut width = 9;
    w.put(clear, width);
    let (mut next, mut run, mut left) = (258u32, 1u64, n);
    while left > 0 {
        let len = run.min(left);
        w.put(if len == 1 { 0 } else { 256 + len as u32 }, width);
        left -= len;
        // The table gains the string sent and one more zero.
        next += 1;
        run = len + 1;
        if next == 4094 {
            w.put(clear, width);
            width = 9;
            next = 258;
            run = 1;
        } else if next > (1 << width) - 1 {
            width += 1;
        }
    }
    w.put(eoi, width);
    if w.n > 0 {
        let last = (w.acc << (8 - w.n)) as u8;
        w.out.push(last);
    }
    w.out
}

/// A little-endian TIFF of `width`×`height` 8-bit grey zeros in one LZW strip.
fn tiff_bomb(width: u32, height: u32) -> Vec<u8> {
    let data = lzw_zeros(u64::from(width) * u64::from(height));
    let entries: [(u16, u16, u32); 9] = [
        (256, 4, width),             // ImageWidth
        (257, 4, height),            // ImageLength
        (258, 3, 8),                 // BitsPerSample
        (259, 3, 5),                 // Compression: LZW
        (262, 3, 1),                 // PhotometricInterpretation: BlackIsZero
        (273, 4, 8),                 // StripOffsets: the data follows the header
        (277, 3, 1),                 // SamplesPerPixel
        (278, 4, height),            // RowsPerStrip
        (279, 4, data.len() as u32), // StripByteCounts
    ];
    let ifd = 8 + data.len() as u32;
    let mut b = b"II*\0".to_vec();
    b.extend(ifd.to_le_bytes());
    b.extend(&data);
    b.extend((entries.len() as u16).to_le_bytes());
    for (tag, kind, value) in entries {
        b.extend(tag.to_le_bytes());
        b.extend(kind.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        if kind == 3 {
            b.extend((value as u16).to_le_bytes());
            b.extend([0, 0]);
        } else {
            b.extend(value.to_le_bytes());
        }
    }
    b.extend(0u32.to_le_bytes());
    b
}

/// A baseline grey JPEG of 64×64 pixels whose frame header (SOF0) claims
/// `width`×`height`.
fn jpeg_claiming(width: u16, height: u16) -> Vec<u8> {
    let img =
        image::GrayImage::from_fn(64, 64, |x, y| image::Luma([((x * 7 + y * 3) % 256) as u8]));
    let mut b = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut b), image::ImageFormat::Jpeg)
        .unwrap();
    let sof = b.windows(2).position(|w| w == [0xFF, 0xC0]).expect("SOF0");
    b[sof + 5..sof + 7].copy_from_slice(&height.to_be_bytes());
    b[sof + 7..sof + 9].copy_from_slice(&width.to_be_bytes());
    b
}

/// A textured 8-bit grey PNG (deterministic), for templates and small scans.
fn textured_png(path: &Path, w: u32, h: u32, seed: u32) {
    image::GrayImage::from_fn(w, h, |x, y| {
        let v = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503) ^ seed)
            .wrapping_mul(2_246_822_519);
        image::Luma([(v >> 24) as u8])
    })
    .save(path)
    .unwrap();
}

/// A film camera definition (formats/cameras/README.md) with four marks of `shape`.
fn camera_json(shape: &str) -> String {
    let fids = [
        ("1", -110.0, 0.0),
        ("2", 110.0, 0.0),
        ("3", 0.0, 110.0),
        ("4", 0.0, -110.0),
    ]
    .iter()
    .map(|(id, x, y)| format!(r#"{{"id": "{id}", "x_mm": {x}, "y_mm": {y}, "shape": {shape}}}"#))
    .collect::<Vec<_>>()
    .join(", ");
    format!(
        r#"{{"name": "hand-written test camera", "source": "issue 51", "focal_mm": 152.0,
            "principal_point_mm": [0, 0], "format_mm": [230, 230], "fiducials": [{fids}]}}"#
    )
}

/// A camera definition listing `n` cross marks on a circle (formats/cameras/README.md).
fn many_fiducials(n: usize) -> String {
    let fids = (0..n)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / n as f64;
            format!(
                r#"{{"id": "{k}", "x_mm": {:.4}, "y_mm": {:.4}, "shape": {{"type": "cross", "size_mm": 1.2, "line_mm": 0.12}}}}"#,
                110.0 * a.cos(),
                110.0 * a.sin()
            )
        })
        .collect::<Vec<_>>()
        .join(",\n");
    format!(
        r#"{{"name": "many marks", "source": "issue 51", "focal_mm": 152.0,
            "principal_point_mm": [0, 0], "format_mm": [230, 230], "fiducials": [{fids}]}}"#
    )
}

// ---------------------------------------------------------------------------------------
// The C ABI through Python.

/// The Python that runs the C ABI scripts: the project's venv, else `python3` (only
/// ctypes is used).
fn python() -> PathBuf {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if venv.exists() {
        venv
    } else {
        PathBuf::from("python3")
    }
}

/// The shared library of this build: beside the test binary (`target/release/deps`, where
/// the test build leaves it), else beside the CLI.
fn library() -> PathBuf {
    let deps = std::env::current_exe()
        .unwrap()
        .with_file_name("libcloudcontrol.so");
    if deps.exists() {
        deps
    } else {
        Path::new(exe()).with_file_name("libcloudcontrol.so")
    }
}

/// Common part of the scripts: the library, and `fail(status)` printing the status and the
/// last error and exiting with 3 when the call did not return OK.
const PRELUDE: &str = r#"
import ctypes, os, sys
lib = ctypes.CDLL(os.environ["CLOUDCONTROL_LIB"])
lib.ccp_last_error.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
lib.ccp_last_error.restype = ctypes.c_size_t
def done(status):
    buf = ctypes.create_string_buffer(8192)
    lib.ccp_last_error(buf, len(buf))
    print(f"status={status} error={buf.value.decode()}")
    sys.exit(0 if status == 0 else 3)
"#;

/// Runs `body` (after [`PRELUDE`]) with `args` under the acceptance's limits.
fn c_abi(dir: &Path, body: &str, args: &[&str]) -> Confined {
    let script = dir.join("case.py");
    std::fs::write(&script, format!("{PRELUDE}\n{body}")).unwrap();
    run_confined(
        Command::new(python())
            .arg(&script)
            .args(args)
            .env("CLOUDCONTROL_LIB", library()),
        2 << 30,
        30.0,
    )
}

/// `ccp_orient_photo` of `image` with `camera` from the sample DCP package
/// (formats/dcp/sample.dcp) over a flat DEM written here; the call's status and message.
fn orient_photo(dir: &Path, camera: &Path, image: &Path) -> Confined {
    let dem = dir.join("dem.tif");
    let d = cloudcontrol::geometry::Dem::from_fn(499_800.0, 4_400_200.0, 2.0, 200, 200, |_, _| 0.0)
        .unwrap();
    let crs = cloudcontrol::formats::crs::Crs::from_epsg(4547).unwrap();
    cloudcontrol::formats::raster::write_dem(&dem, &d, &crs, &Default::default()).unwrap();
    let dcp = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/dcp/sample.dcp");
    let body = r#"
dcp = ctypes.c_void_p()
st = lib.ccp_dcp_open(sys.argv[1].encode(), ctypes.byref(dcp))
if st != 0:
    done(st)
dcps = (ctypes.c_void_p * 1)(dcp)
approx = (ctypes.c_double * 6)(500000.0, 4400000.0, 200.0, 0.0, 0.0, 0.0)
sigma = (ctypes.c_double * 2)(5.0, 2.0)
out = ctypes.c_void_p()
lib.ccp_orient_photo.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_double,
    ctypes.c_char_p, ctypes.c_char_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
done(lib.ccp_orient_photo(dcps, 1, sys.argv[2].encode(), 0.0, sys.argv[3].encode(),
    sys.argv[4].encode(), approx, sigma, ctypes.byref(out)))
"#;
    c_abi(
        dir,
        body,
        &[
            dcp.to_str().unwrap(),
            camera.to_str().unwrap(),
            image.to_str().unwrap(),
            dem.to_str().unwrap(),
        ],
    )
}

/// Asserts the C call's status (printed by [`PRELUDE`]'s `done`).
fn status(c: &Confined, expected: i32) {
    assert!(
        c.stdout.contains(&format!("status={expected} ")),
        "expected status {expected}: {}{}",
        c.stdout,
        c.stderr
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

// ---------------------------------------------------------------------------------------
// Item 2: template marks bounded by the film format and the scan's pixel.

#[test]
fn a_template_mark_larger_than_a_mark_is_refused_by_its_camera_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::create_dir(dir.join("marks")).unwrap();
    // A 400×400 crop, 14 KB of PNG: at pixel_mm 0.9 a 360 mm mark on 230 mm film.
    let mark = image::GrayImage::from_fn(400, 400, |x, y| {
        image::Luma([if (x / 20 + y / 20) % 2 == 0 { 30 } else { 220 }])
    });
    mark.save(dir.join("marks/mark.png")).unwrap();
    let camera = dir.join("camera.json");
    std::fs::write(
        &camera,
        camera_json(r#"{"type": "template", "file": "marks/mark.png", "pixel_mm": 0.9}"#),
    )
    .unwrap();
    let scan = dir.join("scan.png");
    textured_png(&scan, 600, 600, 1);
    let c = cli_confined(&["io", "--camera", s(&camera), s(&scan)]);
    c.refused_cleanly(5.0, &[s(&camera), "fiducial 1", "pixel_mm 0.9", "23 mm"]);
    // Through the C ABI: ccp_orient_photo reads the camera file the same way.
    let c = orient_photo(dir, &camera, &scan);
    c.refused_cleanly(5.0, &[s(&camera), "fiducial 1", "pixel_mm 0.9", "23 mm"]);
    status(&c, 5); // CCP_STATUS_FORMAT: the camera file is wrong
}

#[test]
fn a_template_too_large_for_the_scan_pixel_is_refused_before_it_is_drawn() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::create_dir(dir.join("marks")).unwrap();
    // A 200×200 crop at 0.1 mm reaches 14 mm: a mark on the film, but 8 300² pixels drawn
    // at a 3 µm scan pixel.
    textured_png(&dir.join("marks/mark.png"), 200, 200, 2);
    let camera = dir.join("camera.json");
    std::fs::write(
        &camera,
        camera_json(r#"{"type": "template", "file": "marks/mark.png", "pixel_mm": 0.1}"#),
    )
    .unwrap();
    let scan = dir.join("scan.png");
    textured_png(&scan, 800, 800, 3);
    let c = cli_confined(&["io", "--camera", s(&camera), s(&scan), "--pixel-um", "3"]);
    c.refused_cleanly(
        5.0,
        &[s(&scan), "fiducial 1", "MAX_TEMPLATE_PIXELS", "4194304"],
    );
}

// ---------------------------------------------------------------------------------------
// Item 3: fiducial counts bounded at parse time.

#[test]
fn a_camera_with_ten_thousand_fiducials_is_refused_at_parse_time() {
    let tmp = tempfile::tempdir().unwrap();
    let camera = tmp.path().join("camera.json");
    let json = many_fiducials(10_000);
    assert!(json.len() > 1_000_000, "{} bytes", json.len());
    std::fs::write(&camera, &json).unwrap();
    let scan = tmp.path().join("scan.png");
    textured_png(&scan, 600, 600, 4);
    let c = cli_confined(&["io", "--camera", s(&camera), s(&scan)]);
    c.refused_cleanly(5.0, &[s(&camera), "fiducials", "10000", "at most 16"]);
}

#[test]
fn thirty_thousand_fiducials_through_the_c_abi_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let camera = tmp.path().join("camera.json");
    std::fs::write(&camera, many_fiducials(30_000)).unwrap();
    let body = r#"
text = open(sys.argv[1], "rb").read()
w = h = 512
scan = (ctypes.c_float * (w * h))()
needed = ctypes.c_size_t()
lib.ccp_fiducial_io.argtypes = [ctypes.c_char_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32,
    ctypes.c_double, ctypes.c_int32, ctypes.c_int32, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_void_p]
done(lib.ccp_fiducial_io(text, scan, w, h, 0.0, 0, -1, None, 0, ctypes.byref(needed)))
"#;
    let c = c_abi(tmp.path(), body, &[s(&camera)]);
    c.refused_cleanly(5.0, &["camera_json", "fiducials", "30000", "at most 16"]);
    status(&c, 2); // CCP_STATUS_INVALID_ARGUMENT
}

// ---------------------------------------------------------------------------------------
// Item 4: decompression bombs against the photo memory budget.

#[test]
fn the_bombs_compress_as_claimed() {
    // The PNG of the issue: 16384² grey in ~260 KB, and a 16384² RGB one under 1 MB.
    let grey = png_bomb(16_384, 16_384, 0);
    assert!((250_000..270_000).contains(&grey.len()), "{}", grey.len());
    assert!(png_bomb(16_384, 16_384, 2).len() < 1_000_000);
    assert!(tiff_bomb(16_384, 16_384).len() < 300_000);
    // Small ones decode to what they claim (the bombs are valid files, not just headers).
    let img = cloudcontrol::formats::image_open::decode_image_bytes(
        Path::new("small.png"),
        &png_bomb(700, 300, 2),
    )
    .unwrap();
    assert_eq!((img.width(), img.height()), (700, 300));
    assert!(img.to_rgb8().pixels().all(|p| p.0 == [0, 0, 0]));
    let img = cloudcontrol::formats::image_open::decode_image_bytes(
        Path::new("small.tif"),
        &tiff_bomb(3000, 3000),
    )
    .unwrap();
    // 9 MB: the LZW table is cleared once on the way.
    assert_eq!((img.width(), img.height()), (3000, 3000));
    assert!(img.to_luma8().pixels().all(|p| p.0 == [0]));
}

#[test]
fn decompression_bombs_are_refused_from_their_headers() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let camera = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/cameras/wild_rc10.json");
    let template = dir.join("template.png");
    textured_png(&template, 31, 31, 5);
    let cases: [(&str, Vec<u8>, &str); 4] = [
        (
            "grey.png",
            png_bomb(16_384, 16_384, 0),
            "16384×16384 pixels (L8)",
        ),
        (
            "rgb.png",
            png_bomb(16_384, 16_384, 2),
            "16384×16384 pixels (Rgb8)",
        ),
        (
            "lzw.tif",
            tiff_bomb(16_384, 16_384),
            "16384×16384 pixels (L8)",
        ),
        (
            "claim.jpg",
            jpeg_claiming(30_000, 30_000),
            "30000×30000 pixels (L8)",
        ),
    ];
    for (name, bytes, what) in cases {
        let f = dir.join(name);
        std::fs::write(&f, bytes).unwrap();
        // The JPEG is refused before the budget is asked: 1 135 bytes cannot hold the coded
        // data of 14 million 8×8 blocks (a bit each at least).
        let words: Vec<&str> = if name.ends_with(".jpg") {
            vec![
                s(&f),
                "JPEG of 30000×30000 pixels",
                "a decompression bomb, or a truncated file",
            ]
        } else {
            vec![
                s(&f),
                what,
                "photo memory budget",
                "1073741824",
                "CLOUDCONTROL_PHOTO_MEMORY",
            ]
        };
        eprintln!("{name}: match");
        cli_confined(&["match", s(&f), s(&template)]).refused_cleanly(5.0, &words);
        eprintln!("{name}: io");
        cli_confined(&["io", "--camera", s(&camera), s(&f)]).refused_cleanly(5.0, &words);
    }
    // Through the C ABI: a frame photo that is a bomb is not oriented, the reason naming it.
    let bomb = dir.join("grey.png");
    let frame = dir.join("frame.json");
    std::fs::write(
        &frame,
        r#"{"kind": "frame", "width": 16384, "height": 16384, "fx": 16000, "fy": 16000,
            "cx": 8192, "cy": 8192}"#,
    )
    .unwrap();
    let c = orient_photo(dir, &frame, &bomb);
    c.refused_cleanly(5.0, &[s(&bomb), "photo memory budget", "1073741824"]);
    status(&c, 9); // CCP_STATUS_NOT_ORIENTED
}

#[test]
fn a_buffer_claiming_a_huge_image_is_refused_before_it_is_read() {
    let tmp = tempfile::tempdir().unwrap();
    // A 64-value buffer claiming 16384² (and 30000² for the scan of ccp_fiducial_io): the
    // budget refuses the claim before a value is read or copied.
    let body = r#"
buf = (ctypes.c_float * 64)()
out = ctypes.create_string_buffer(4096)
if sys.argv[1] == "match":
    lib.ccp_match_template.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32,
        ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p, ctypes.c_double,
        ctypes.c_double, ctypes.c_void_p]
    done(lib.ccp_match_template(buf, 16384, 16384, buf, 8, 8, None, 0.7, 1.0, out))
needed = ctypes.c_size_t()
cam = open(sys.argv[2], "rb").read()
lib.ccp_fiducial_io.argtypes = [ctypes.c_char_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32,
    ctypes.c_double, ctypes.c_int32, ctypes.c_int32, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_void_p]
done(lib.ccp_fiducial_io(cam, buf, 30000, 30000, 0.0, 0, -1, None, 0, ctypes.byref(needed)))
"#;
    let camera = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/cameras/wild_rc10.json");
    let c = c_abi(tmp.path(), body, &["match", s(&camera)]);
    c.refused_cleanly(5.0, &["image", "16384×16384", "photo memory budget"]);
    status(&c, 2);
    let c = c_abi(tmp.path(), body, &["io", s(&camera)]);
    c.refused_cleanly(5.0, &["scan", "30000×30000", "photo memory budget"]);
    status(&c, 2);
}

#[test]
fn the_photo_memory_budget_is_configurable() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let photo = dir.join("photo.png");
    // 4000² grey (16 M pixels, 85 MB to match): over a 64 MiB budget, within the default.
    std::fs::write(&photo, png_bomb(4000, 4000, 0)).unwrap();
    let template = dir.join("template.png");
    textured_png(&template, 31, 31, 6);
    let run = |budget: Option<&str>| {
        let mut cmd = Command::new(exe());
        cmd.args(["match", s(&photo), s(&template)]);
        match budget {
            Some(b) => cmd.env("CLOUDCONTROL_PHOTO_MEMORY", b),
            None => cmd.env_remove("CLOUDCONTROL_PHOTO_MEMORY"),
        };
        run_confined(&cmd, 2 << 30, 30.0)
    };
    run(Some("64M")).refused_cleanly(5.0, &[s(&photo), "photo memory budget", "67108864"]);
    run(Some("lots")).refused_cleanly(5.0, &[s(&photo), "CLOUDCONTROL_PHOTO_MEMORY=\"lots\""]);
    run(Some("1M")).refused_cleanly(5.0, &[s(&photo), "below the smallest"]);
    // Within the default the constant photo is read and searched: no texture, so no
    // match (exit 2), and no error.
    let c = run(None);
    // The exit status of a search without an accepted position (README.md, "Exit statuses").
    assert!(matches!(c.code, Some(2 | 4)), "{c:?}");
    assert!(c.stdout.contains("\"accepted\": false"), "{}", c.stdout);
}

#[test]
fn a_whole_admitted_photo_is_searched_within_the_budget() {
    // 12000² grey, 144 M pixels: 768 MB to match by the budget's count (within 1 GiB). The
    // template is searched over the whole photo at full resolution (11 px: no coarser
    // level), whose correlation buffers took 32 bytes a pixel at once and now go by bands.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let photo = dir.join("photo.png");
    std::fs::write(&photo, png_bomb(12_000, 12_000, 0)).unwrap();
    let template = dir.join("template.png");
    textured_png(&template, 11, 11, 7);
    let c = cli_confined(&["match", s(&photo), s(&template)]);
    assert!(matches!(c.code, Some(2 | 4)), "{c:?}");
    assert!(c.stdout.contains("\"accepted\": false"), "{}", c.stdout);
    assert!(c.peak_rss <= 1 << 30, "peak RSS {} MiB", c.peak_rss >> 20);
    eprintln!(
        "match over 12000² at full resolution: peak RSS {} MiB, {:.1} s",
        c.peak_rss >> 20,
        c.seconds
    );
}

#[test]
fn a_banded_search_finds_the_peak_of_the_whole_surface() {
    use cloudcontrol::matching::ncc::{ncc_search, ncc_surface_with, CorrelationMethod, Window};
    use cloudcontrol::matching::GreyImage;
    // 2400² (over NCC_SCRATCH_BYTES at once: 36 bytes a window pixel) with the template cut
    // from it at a known place and a second, weaker copy elsewhere.
    let noise = |x: f64, y: f64| {
        let h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        (h.wrapping_mul(0xBF58_476D_1CE4_E5B9) >> 40) as f64 / (1u64 << 24) as f64
    };
    let img = GreyImage::from_fn(2400, 2400, |x, y| {
        255.0 * (noise(x, y) + noise(x + 1.0, y) + noise(x, y + 1.0) + noise(x + 1.0, y + 1.0))
            / 4.0
    });
    let tpl = img.crop(1500, 700, 25, 25).unwrap();
    let whole = Window::whole(&img);
    let banded = ncc_search(&img, &tpl, whole, false).unwrap();
    let s = ncc_surface_with(&img, &tpl, whole, CorrelationMethod::Direct).unwrap();
    // The exclusion ncc_search takes: a quarter of the template, at least 2.
    let at_once = s.peak(25, 25, 6, false);
    assert!(
        (banded.x - 1512.5).abs() < 0.01 && (banded.y - 712.5).abs() < 0.01,
        "{banded:?}"
    );
    assert!((banded.x - at_once.x).abs() < 1e-3 && (banded.y - at_once.y).abs() < 1e-3);
    assert!((banded.ncc - at_once.ncc).abs() < 1e-4);
    assert!(
        (banded.second - at_once.second).abs() < 1e-3,
        "{banded:?} {at_once:?}"
    );
}
