//! Inputs the fuzz targets (fuzz/) found, replayed through the library: each must end in a
//! typed error naming its input, never a panic, abort or leak.

use cloudcontrol::formats::crs::Crs;
use cloudcontrol::formats::FormatError;
use cloudcontrol::lidar::{LasStream, PointBatch};
use std::path::Path;

fn reproducer(target: &str, name: &str) -> Vec<u8> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/artifacts-fixed")
        .join(target)
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// simple.laz with one byte of its arithmetic-coded points changed: the laz crate's
/// decoder meets a symbol beyond 16 bits (a `debug_assert!` in laz 0.12 decoders.rs, a
/// panic only where debug assertions are on, as in the fuzz build). The header and chunk
/// table are intact, so the file opens; reading its points must end in an error naming it.
#[test]
fn laz_with_corrupt_point_data_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corrupt.laz");
    std::fs::write(&path, reproducer("las", "laz_debug_assert_sym_short")).unwrap();
    let mut s = LasStream::open(&path).expect("header and chunk table are intact");
    assert_eq!(s.info().point_count, 1065, "simple.laz's count");
    let mut batch = PointBatch::default();
    let mut read = 0;
    let err = loop {
        match s.read_batch(1 << 16, &mut batch) {
            Ok(0) => panic!("all {read} points read from corrupt point data"),
            Ok(n) => read += n,
            Err(e) => break e.to_string(),
        }
    };
    assert!(
        err.contains(&path.display().to_string()),
        "names the file: {err}"
    );
}

/// A LAZ whose LASzip VLR describes point records of another size than the header's
/// record length: laz 0.12's parallel decompressor asserts (also in release builds) that
/// the buffer las sizes from the header is a whole number of the VLR's records. Opening
/// it is an error naming the file and both sizes.
#[test]
fn laz_whose_items_disagree_with_the_record_length_is_an_error() {
    // The second file's item sizes add up beyond u16 (laz's own sum overflows).
    for name in ["laz_items_size_mismatch", "laz_items_size_u16_overflow"] {
        las_open_fails_naming(name, "point record length");
    }
}

/// Opens the `las` reproducer `name` and expects an error naming the file and `what`.
fn las_open_fails_naming(name: &str, what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(format!("{name}.laz"));
    std::fs::write(&path, reproducer("las", name)).unwrap();
    let err = match LasStream::open(&path) {
        Ok(_) => panic!("{name}: opened"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains(&path.display().to_string()) && err.contains(what),
        "{name}: names the file and {what}: {err}"
    );
}

/// A LAZ whose header size field is 0: the `las` crate reads its VLRs after the whole
/// LAS 1.2 header (227 bytes), where this file's LASzip VLR and a chunk table claiming
/// two billion chunks lie, while the guard looked at byte 0, found no LASzip VLR and let
/// the crate allocate 32 GB. The header size is now refused, naming the file.
#[test]
fn las_whose_header_size_is_below_its_version_is_an_error() {
    las_open_fails_naming("las_header_size_zero", "header size 0 bytes");
}

/// A LAS 1.4 LAZ without a chunk table whose 64-bit point count (0xe147ae0000000000
/// 61-byte records) overflows the end-of-points offset the `las` crate computes (a panic
/// in `las::raw::Header::offset_to_end_of_points` where overflow checks are on, as in the
/// fuzz build; a wrapped offset otherwise). The guard refuses the count on open, naming
/// the file.
#[test]
fn las_whose_point_count_overflows_a_file_offset_is_an_error() {
    las_open_fails_naming("laz_point_count_overflow", "point count");
}

/// LAZ files whose LASzip VLR declares 60 000 extra bytes a point (the sample's 27-byte
/// item resized, in a LASzip 2 and a LASzip 3 file of 3.5 and 8 KB): laz's decompressor
/// keeps arithmetic models for every extra byte in each chunk it decompresses, one per
/// thread, and reading them took 200 and 640 MB a thread. The `las` fuzz target met such
/// files as an RSS of 2 GB (an out-of-memory stop). The guard refuses them on open,
/// naming the file and the limit.
#[test]
fn laz_with_a_huge_extra_bytes_item_is_an_error() {
    for name in ["laz_extra_bytes_60000_v2", "laz_extra_bytes_60000_v3"] {
        las_open_fails_naming(name, "LAZ extra bytes per point 60000 exceeds 1024");
    }
}

/// A 2.8 KB LASzip 3 file (point format 6) whose first chunk's header claims a layer of
/// 4.18 GB: laz sizes a buffer from each layer's byte count before reading it, so reading
/// the points took 4.1 GB and 10 s (`lidar catalogue`, release build; the `las` fuzz
/// target stopped at the malloc limit). The guard checks every chunk's layer byte counts
/// against the chunk's bytes and refuses the file on open, naming it.
#[test]
fn laz_whose_chunk_claims_a_layer_beyond_the_chunk_is_an_error() {
    las_open_fails_naming("laz_layer_size_4gb", "LAZ chunk 0 layer bytes");
}

/// A LAZ whose compressed GPS times make laz 0.12's predictor overflow an i64 (an
/// overflow-checked add in src/las/gps.rs; the fuzz build panics there). The library
/// ships without overflow checks: reading every point ends in wrong GPS times or in an
/// error naming the file, never a panic.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "laz's arithmetic is overflow-checked in debug builds"
)]
fn laz_whose_gps_times_overflow_reads_without_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gps.laz");
    std::fs::write(&path, reproducer("las", "laz_gps_overflow_debug_only")).unwrap();
    let result = std::panic::catch_unwind(|| -> Result<usize, String> {
        let mut s = LasStream::open(&path).map_err(|e| e.to_string())?;
        let mut batch = PointBatch::default();
        let mut read = 0;
        loop {
            match s.read_batch(1 << 16, &mut batch) {
                Ok(0) => return Ok(read),
                Ok(n) => read += n,
                Err(e) => return Err(e.to_string()),
            }
        }
    });
    match result {
        Err(_) => panic!("reading panicked"),
        Ok(Ok(_)) => {}
        Ok(Err(e)) => assert!(
            e.contains(&path.display().to_string()),
            "names the file: {e}"
        ),
    }
}

/// A project's `crs = "EPSG:7963"` (no such CRS in PROJ's database) leaked the GDAL
/// spatial reference the import failed on (gdal 0.19 `SpatialRef::from_definition`), as
/// did a refused PROJ string; LeakSanitizer found it. The error names the definition.
#[test]
fn unknown_crs_is_a_typed_error_naming_it() {
    for def in ["EPSG:7963", "+proj=nosuchprojection +ellps=GRS80"] {
        match Crs::parse(def) {
            Err(FormatError::Crs { crs, message }) => {
                assert_eq!(crs, def);
                assert!(message.contains("not a CRS GDAL/PROJ knows"), "{message}");
            }
            other => panic!("{def}: {other:?}"),
        }
    }
    // The same importers still take good definitions.
    assert_eq!(Crs::parse("EPSG:4547").unwrap().label(), "EPSG:4547");
    let utm = Crs::parse("+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs").unwrap();
    assert!(utm.is_projected());
    let wkt = utm.to_wkt().unwrap();
    assert!(wkt.contains("\"central_meridian\",-117]"), "{wkt}");
}

/// LAZ files whose GPS time data switches sequence without end (point format 6, LAS 1.4;
/// point format 3, LAS 1.2): laz 0.12.2 called itself per switch and overflowed the stack,
/// aborting the process (`lidar catalogue`, or a host through the C ABI). The vendored laz
/// (vendor/README.md) reads them in a bounded loop: an error naming the file, no abort.
#[test]
fn laz_gps_time_switching_without_end_is_an_error() {
    for (name, count, says) in [
        (
            "laz_gps_sequence_switches_point6",
            40,
            "switches of sequence",
        ),
        (
            "laz_gps_sequence_switches_point3",
            1065,
            "switches of sequence",
        ),
        // A mutation of the first: the arithmetic decoder's state beyond its model indexed
        // past the decoder table (a bounds-check panic, release builds too).
        (
            "laz_decoder_table_index_out_of_bounds",
            40,
            "beyond its model",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(format!("{name}.laz"));
        std::fs::write(&path, reproducer("las", name)).unwrap();
        let mut s = LasStream::open(&path).expect("header and chunk table are intact");
        assert_eq!(s.info().point_count, count, "{name}");
        let mut batch = PointBatch::default();
        let err = loop {
            match s.read_batch(1 << 16, &mut batch) {
                Ok(0) => panic!("{name}: every point read"),
                Ok(_) => {}
                Err(e) => break e.to_string(),
            }
        };
        assert!(
            err.contains(&path.display().to_string()) && err.contains(says),
            "{name}: {err}"
        );
    }
}

/// A 796-byte baseline JPEG whose frame claims 65 313 × 4 128 pixels: decoded as a valid
/// image of zeros (800 MB, 2.6 s; a timeout under the fuzzer's sanitizer). Its 4.2 million
/// 8×8 blocks need 527 KB of coded data at least: refused from the header, as a chip and
/// as a photo, naming the bound.
#[test]
fn jpeg_too_small_for_its_claimed_size_is_refused() {
    let bytes = reproducer("image_decode", "jpeg_65313x4128_in_796_bytes");
    let t = std::time::Instant::now();
    let chip = cloudcontrol::formats::image_open::decode_image_bytes(Path::new("chip.jpg"), &bytes)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("photo.jpg");
    std::fs::write(&path, &bytes).unwrap();
    let photo = cloudcontrol::matching::GreyImage::load(&path)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    for (e, name) in [(&chip, "chip.jpg"), (&photo, "photo.jpg")] {
        assert!(
            e.contains(name) && e.contains("JPEG of 65313×4128 pixels") && e.contains("796 bytes"),
            "{e}"
        );
    }
    assert!(t.elapsed().as_secs_f64() < 1.0, "{:?}", t.elapsed());
}

/// An 847-byte TIFF of 32 × 19 785 pixels claiming 61 955 samples a pixel, pixel
/// interleaved in one strip: the `image` crate refuses it and GDAL, the photo reader's
/// fallback, allocated 4.9 GB for the strip to read the first rows of three bands. Refused
/// from its block size and band count against the photo memory budget.
#[test]
fn tiff_whose_block_exceeds_the_photo_budget_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("photo.tif");
    std::fs::write(
        &path,
        reproducer("image_decode", "tiff_one_strip_4_9_gb_block"),
    )
    .unwrap();
    let e = cloudcontrol::matching::GreyImage::load(&path)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("photo.tif")
            && e.contains("GDAL decodes whole")
            && e.contains("photo memory budget"),
        "{e}"
    );
}

/// A 193-byte PNG declaring a `tEXt` chunk of 2 GB: libpng (GDAL's PNG driver) allocated
/// the declared length, 2.1 GB resident under the fuzzer. Refused from the chunk headers
/// before GDAL opens it, naming the chunk; the orthophoto and DEM readers share the check.
#[test]
fn png_chunk_longer_than_the_file_is_refused_before_gdal() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("photo.png");
    std::fs::write(&path, reproducer("image_decode", "png_text_chunk_2_gb")).unwrap();
    let e = cloudcontrol::matching::GreyImage::load(&path)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("photo.png") && e.contains("PNG chunk \"tEXt\"") && e.contains("truncated"),
        "{e}"
    );
    let e = cloudcontrol::formats::image_open::open_raster(&path)
        .map(|_| ())
        .unwrap_err();
    assert!(
        matches!(e, cloudcontrol::formats::FormatError::TooLarge { claimed, .. } if claimed == 12 + 0x7ff0_0000),
        "{e}"
    );
}
