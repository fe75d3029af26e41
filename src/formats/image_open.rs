//! Opening images and rasters named by data files (photos, scans, DEMs): the size is read
//! from the header and checked against [`MAX_IMAGE_PIXELS`] and the photo memory budget
//! ([`photo_memory`]) before anything is decoded, the decoder's allocations are capped by
//! the budget (and never beyond [`MAX_DECODED_BYTES`]), and GDAL opens only the raster
//! drivers we mean ([`RASTER_DRIVERS`]) on local paths — never VRT (which reads other
//! files) nor `/vsicurl/` and URLs (which fetch from the network).
//!
//! ## The photo memory budget
//!
//! A photo being matched (a film scan in its fiducial interior orientation, an archive
//! photo searched for control patches, the image of `cloudcontrol match`) is held as one
//! f32 grey copy and the coarser levels of its pyramid: [`MATCHING_BYTES_PER_PIXEL`]
//! (16/3) bytes a pixel. Its decoder may need more while it runs (its own buffer, a JPEG's
//! coefficients, colour channels): [`grey_decode_cost`] counts both, and a photo whose
//! cost exceeds the budget is refused from its header, naming the file, its size and the
//! budget. The default, [`DEFAULT_PHOTO_MEMORY`] (1 GiB), admits an 8-bit grey scan of
//! 201 million pixels (a 230 mm frame scanned at 16.2 µm, 14 190² pixels; a 21 µm scan is
//! 11 000², 121 million pixels, 645 MiB); set [`PHOTO_MEMORY_ENV`]
//! (`CLOUDCONTROL_PHOTO_MEMORY=2G`) or call [`set_photo_memory`] for finer scans. Each
//! photo worked on at once (one per thread) takes its own budget.

use super::gdal::Dataset;
use super::{FormatError, Result};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::RwLock;

/// Largest image or raster window read whole, whatever the memory budget: 2³⁰ pixels (a
/// 230 mm film frame scanned at 7 µm is 1.08·10⁹). Photos are further bounded by the
/// photo memory budget ([`photo_memory`]); larger scans are read by windows.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 30;

/// Largest decoded image the `image` decoders may allocate, whatever the memory budget
/// (4 GiB): a small, highly compressed file cannot expand beyond this, whatever its header
/// says. The photo memory budget ([`photo_memory`]) caps them further.
pub const MAX_DECODED_BYTES: u64 = 4 << 30;

/// Default photo memory budget (bytes): 1 GiB per photo being worked on (module
/// documentation).
pub const DEFAULT_PHOTO_MEMORY: u64 = 1 << 30;

/// Smallest photo memory budget accepted (bytes): 64 MiB.
pub const MIN_PHOTO_MEMORY: u64 = 64 << 20;

/// The environment variable that sets the photo memory budget: bytes, or a number with a
/// binary suffix `K`, `M`, `G` (`CLOUDCONTROL_PHOTO_MEMORY=2G`).
pub const PHOTO_MEMORY_ENV: &str = "CLOUDCONTROL_PHOTO_MEMORY";

/// Bytes a photo's pixel takes while it is matched: its f32 grey value (4) and the coarser
/// levels of its factor-2 pyramid (4/3).
pub const MATCHING_BYTES_PER_PIXEL: f64 = 16.0 / 3.0;

/// GDAL drivers allowed to open a raster named by a data file.
pub const RASTER_DRIVERS: &[&str] = &["GTiff", "PNG", "JPEG"];

static PHOTO_MEMORY: RwLock<Option<u64>> = RwLock::new(None);

/// Sets the photo memory budget for this process (bytes, at least [`MIN_PHOTO_MEMORY`]),
/// over [`PHOTO_MEMORY_ENV`]; `None` returns to the environment's or the default.
pub fn set_photo_memory(bytes: Option<u64>) -> std::result::Result<(), String> {
    if let Some(b) = bytes {
        check_budget(b)?;
    }
    *PHOTO_MEMORY.write().unwrap_or_else(|e| e.into_inner()) = bytes;
    Ok(())
}

fn check_budget(b: u64) -> std::result::Result<u64, String> {
    if b < MIN_PHOTO_MEMORY {
        return Err(format!(
            "a photo memory budget of {b} bytes is below the smallest, {MIN_PHOTO_MEMORY}"
        ));
    }
    Ok(b)
}

/// Parses a size: bytes, or a number with a binary suffix `K`, `M`, `G`, `T`.
fn parse_size(text: &str) -> Option<u64> {
    let t = text.trim();
    let (num, shift) = match t.as_bytes().last()?.to_ascii_uppercase() {
        b'K' => (&t[..t.len() - 1], 10),
        b'M' => (&t[..t.len() - 1], 20),
        b'G' => (&t[..t.len() - 1], 30),
        b'T' => (&t[..t.len() - 1], 40),
        _ => (t, 0),
    };
    num.trim().parse::<u64>().ok()?.checked_mul(1 << shift)
}

/// The photo memory budget (bytes): [`set_photo_memory`]'s, else [`PHOTO_MEMORY_ENV`]'s,
/// else [`DEFAULT_PHOTO_MEMORY`]. A malformed variable is an error saying so.
pub fn photo_memory() -> std::result::Result<u64, String> {
    if let Some(b) = *PHOTO_MEMORY.read().unwrap_or_else(|e| e.into_inner()) {
        return Ok(b);
    }
    match std::env::var(PHOTO_MEMORY_ENV) {
        Err(std::env::VarError::NotPresent) => Ok(DEFAULT_PHOTO_MEMORY),
        Err(e) => Err(format!("{PHOTO_MEMORY_ENV}: {e}")),
        Ok(v) => parse_size(&v)
            .ok_or_else(|| {
                format!("{PHOTO_MEMORY_ENV}={v:?} is not a size (bytes, or with K, M, G)")
            })
            .and_then(|b| check_budget(b).map_err(|e| format!("{PHOTO_MEMORY_ENV}={v:?}: {e}"))),
    }
}

/// [`photo_memory`] with its error naming `path` (the photo it was asked for).
pub fn photo_memory_for(path: &Path) -> Result<u64> {
    photo_memory().map_err(|m| FormatError::invalid(path, m))
}

/// Refuses a photo of `width`×`height` pixels whose working copies take more than the photo
/// memory budget: `bytes_per_pixel` while it is decoded or read (at least
/// [`MATCHING_BYTES_PER_PIXEL`], its grey copy and pyramid); `how` says what was counted.
pub fn check_photo_memory(
    path: &Path,
    width: u64,
    height: u64,
    bytes_per_pixel: f64,
    how: &str,
) -> Result<()> {
    let budget = photo_memory_for(path)?;
    let pixels = width.saturating_mul(height);
    let per = bytes_per_pixel.max(MATCHING_BYTES_PER_PIXEL);
    let need = (pixels as f64 * per).ceil() as u64;
    if need > budget {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!("image of {width}×{height} pixels ({how}) held for matching, in bytes"),
            claimed: need,
            limit: budget,
            basis: format!(
                "the photo memory budget ({per:.1} bytes a pixel, so at most {} pixels of \
                 this kind; set {PHOTO_MEMORY_ENV}, e.g. {PHOTO_MEMORY_ENV}=2G, for larger \
                 scans)",
                (budget as f64 / per) as u64
            ),
        });
    }
    Ok(())
}

/// Refuses an image of `width`×`height` pixels beyond [`MAX_IMAGE_PIXELS`].
pub fn check_pixels(path: &Path, width: u64, height: u64) -> Result<()> {
    let pixels = width.saturating_mul(height);
    if pixels > MAX_IMAGE_PIXELS {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!("image of {width}×{height} pixels"),
            claimed: pixels,
            limit: MAX_IMAGE_PIXELS,
            basis: "the pixels an image read whole may have (read larger scans by windows)".into(),
        });
    }
    Ok(())
}

/// Opens a local raster with GDAL, read-only, with only [`RASTER_DRIVERS`]. GDAL's virtual
/// file systems (`/vsicurl/`, `/vsizip/`, …) and URLs are refused before GDAL sees them.
pub fn open_raster(path: &Path) -> Result<Dataset> {
    let s = path.to_string_lossy();
    if s.starts_with("/vsi") || s.contains("://") {
        return Err(FormatError::invalid(
            path,
            "is not a local file (GDAL virtual file systems and URLs are not opened)",
        ));
    }
    // A regular file only (links followed): GDAL opening a FIFO would wait for a writer.
    let (mut file, meta) = super::input::open_file(path, super::input::Links::Follow)?;
    check_png_chunks(path, &mut file, meta.len())?;
    drop(file);
    Dataset::open_raster(path, RASTER_DRIVERS).map_err(|e| {
        FormatError::invalid(
            path,
            format!(
                "not a raster GDAL may open here (allowed drivers: {}): {e}",
                RASTER_DRIVERS.join(", ")
            ),
        )
    })
}

/// The PNG signature.
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];

/// Refuses a PNG (other files pass) with a chunk longer than what the file holds after its
/// header: libpng, under GDAL's PNG driver, allocates a chunk's declared length before
/// reading it, and a 193-byte PNG declaring a 2 GB `tEXt` chunk took a fuzzed reader past
/// 2 GB resident (fuzz/artifacts-fixed/image_decode/png_text_chunk_2_gb). Only chunk
/// headers are read (a seek over each chunk's data), up to `IEND`.
fn check_png_chunks<R: Read + Seek>(path: &Path, r: &mut R, file_len: u64) -> Result<()> {
    let mut head = [0u8; 8];
    if r.read_exact(&mut head).is_err() || head != PNG_SIGNATURE {
        return Ok(());
    }
    let mut at = 8u64;
    while at + 8 <= file_len {
        r.seek(SeekFrom::Start(at))
            .and_then(|_| r.read_exact(&mut head))
            .map_err(|e| FormatError::io(path, e))?;
        let len = u64::from(u32::from_be_bytes([head[0], head[1], head[2], head[3]]));
        let kind = String::from_utf8_lossy(&head[4..8]).into_owned();
        // Length, type, data and CRC.
        let end = at + 12 + len;
        if end > file_len {
            return Err(FormatError::TooLarge {
                path: path.to_path_buf(),
                what: format!("PNG chunk {kind:?} at byte {at}, in bytes with its header and CRC"),
                claimed: 12 + len,
                limit: file_len - at,
                basis: "what the file holds after the chunk's start (a truncated or corrupt PNG)"
                    .into(),
            });
        }
        if &head[4..8] == b"IEND" {
            break;
        }
        at = end;
    }
    Ok(())
}

fn reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    // A regular file only (formats/README.md, "Input files"): not a FIFO, not /dev/zero.
    let file = super::input::open(path)?;
    let mut r = image::ImageReader::new(std::io::BufReader::new(file));
    if let Ok(f) = image::ImageFormat::from_path(path) {
        r.set_format(f);
    }
    r.with_guessed_format()
        .map_err(|e| FormatError::io(path, e))
}

/// Width and height from the image header, without decoding the pixels.
pub fn image_size(path: &Path) -> Result<(u32, u32)> {
    reader(path)?
        .into_dimensions()
        .map_err(|e| FormatError::invalid(path, format!("cannot read the image header: {e}")))
}

/// Width and height from the header of an image held in memory (a package member),
/// without decoding the pixels; `name` labels errors.
pub fn image_size_bytes(name: &Path, bytes: &[u8]) -> Result<(u32, u32)> {
    image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| FormatError::io(name, e))?
        .into_dimensions()
        .map_err(|e| FormatError::invalid(name, format!("cannot read the image header: {e}")))
}

/// Decodes an image with the `image` crate after checking its header size against
/// [`MAX_IMAGE_PIXELS`] and its decoded size against [`MAX_DECODED_BYTES`] and the photo
/// memory budget ([`photo_memory`]), which also caps the decoder's allocations.
pub fn decode_image(path: &Path) -> Result<image::DynamicImage> {
    decode(path, reader(path)?)
}

/// [`decode_image`] of an image held in memory (a package member); `name` labels errors.
pub fn decode_image_bytes(name: &Path, bytes: &[u8]) -> Result<image::DynamicImage> {
    let r = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| FormatError::io(name, e))?;
    decode(name, r)
}

fn bad_image(path: &Path) -> impl Fn(image::ImageError) -> FormatError + '_ {
    move |e| FormatError::invalid(path, format!("cannot decode the image: {e}"))
}

/// The decoder of `r` with its allocations capped by the photo memory budget, once the
/// header's size passed [`MAX_IMAGE_PIXELS`] and [`MAX_DECODED_BYTES`].
fn limited_decoder<'a, R: std::io::BufRead + Seek + 'a>(
    path: &Path,
    mut r: image::ImageReader<R>,
) -> Result<impl image::ImageDecoder + 'a> {
    use image::ImageDecoder;
    let budget = photo_memory_for(path)?;
    let coded_bytes = if r.format() == Some(image::ImageFormat::Jpeg) {
        let mut inner = r.into_inner();
        let here = inner
            .stream_position()
            .map_err(|e| FormatError::io(path, e))?;
        let end = inner
            .seek(SeekFrom::End(0))
            .map_err(|e| FormatError::io(path, e))?;
        inner
            .seek(SeekFrom::Start(here))
            .map_err(|e| FormatError::io(path, e))?;
        r = image::ImageReader::with_format(inner, image::ImageFormat::Jpeg);
        Some(end.saturating_sub(here))
    } else {
        None
    };
    // Our cap replaces the reader's default (512 MiB) for the header's own allocations
    // (PNG text and ICC chunks, TIFF tags) and the decoded image.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODED_BYTES.min(budget));
    r.limits(limits);
    let decoder = r.into_decoder().map_err(bad_image(path))?;
    let (w, h) = decoder.dimensions();
    check_pixels(path, w.into(), h.into())?;
    if let Some(len) = coded_bytes {
        check_jpeg_coded_size(path, w, h, len)?;
    }
    let bytes = decoder.total_bytes();
    for (limit, basis) in [
        (MAX_DECODED_BYTES, "the bytes an image may decode to".to_string()),
        (
            budget,
            format!("the photo memory budget (set {PHOTO_MEMORY_ENV}, e.g. {PHOTO_MEMORY_ENV}=2G, for larger images)"),
        ),
    ] {
        if bytes > limit {
            return Err(FormatError::TooLarge {
                path: path.to_path_buf(),
                what: format!(
                    "image of {w}×{h} pixels ({:?}) decoded, in bytes",
                    decoder.color_type()
                ),
                claimed: bytes,
                limit,
                basis,
            });
        }
    }
    Ok(decoder)
}

/// Refuses a JPEG of `width`×`height` pixels held in `file_bytes` bytes that cannot hold
/// the coded data of that many pixels. Every 8×8 block of a component at full sampling
/// (one always is: the largest sampling factor is some component's) is coded in its first
/// (DC) scan by a Huffman code, at least 1 bit long (lengths are 1–16 bits); a baseline
/// block takes 2 at least (its DC difference and the end of block). A smaller file is a
/// decompression bomb or a truncated file: a 796-byte JPEG claiming 65 313 × 4 128 pixels
/// decoded as zeros into 800 MB in 2.6 s. (Arithmetic-coded JPEG, which could go below a
/// bit a block, is not decoded by the `image` crate.)
fn check_jpeg_coded_size(path: &Path, width: u32, height: u32, file_bytes: u64) -> Result<()> {
    let blocks = u64::from(width.div_ceil(8)) * u64::from(height.div_ceil(8));
    let least = blocks.div_ceil(8);
    if file_bytes < least {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!(
                "JPEG of {width}×{height} pixels ({blocks} blocks of 8×8, a bit each at least) in a file of {file_bytes} bytes: coded bytes needed"
            ),
            claimed: least,
            limit: file_bytes,
            basis: "what the file holds (a decompression bomb, or a truncated file)".into(),
        });
    }
    Ok(())
}

fn decode<R: std::io::BufRead + Seek>(
    path: &Path,
    r: image::ImageReader<R>,
) -> Result<image::DynamicImage> {
    image::DynamicImage::from_decoder(limited_decoder(path, r)?).map_err(bad_image(path))
}

/// A photo decoded into grey f32 values, row-major — what the matchers work on: 8/16-bit
/// grey as it is, colour reduced to luma with the Rec. 601 weights (0.299, 0.587, 0.114)
/// that scanners and film densitometry conventionally use, 32-bit float channels scaled to
/// 0–65535. Refused from the header, before anything is decoded, beyond
/// [`MAX_IMAGE_PIXELS`], [`MAX_DECODED_BYTES`] or the photo memory budget
/// ([`grey_decode_cost`]). 8-bit and 16-bit grey, RGB and RGBA are decoded into the f32
/// buffer itself and widened in place, so their decoded bytes take no memory of their own.
/// Returns width, height and the values.
pub fn decode_grey(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    decode_grey_from(path, reader(path)?)
}

/// [`decode_grey`] of an image held in memory; `name` labels errors.
pub fn decode_grey_bytes(name: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<f32>)> {
    let r = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| FormatError::io(name, e))?;
    decode_grey_from(name, r)
}

/// Colour types decoded into the f32 buffer and widened in place (at most 4 bytes a pixel).
fn widened_in_place(ct: image::ColorType) -> bool {
    use image::ColorType as C;
    matches!(ct, C::L8 | C::La8 | C::Rgb8 | C::Rgba8 | C::L16 | C::La16)
}

/// Bytes a pixel takes while a photo of colour type `ct` is decoded to grey f32 by
/// [`decode_grey`]: the f32 buffer (4), the decoded bytes when they cannot be widened in
/// place, the TIFF decoder's own buffer of the whole image, and a JPEG's coefficients
/// (`jpeg_coefficients`, bytes a pixel, from [`jpeg_coefficient_bytes`]). The photo memory
/// budget counts the larger of this and [`MATCHING_BYTES_PER_PIXEL`].
pub fn grey_decode_cost(
    format: Option<image::ImageFormat>,
    ct: image::ColorType,
    jpeg_coefficients: f64,
) -> f64 {
    let bpp = ct.bytes_per_pixel() as f64;
    let mut per = 4.0;
    if !widened_in_place(ct) {
        per += bpp;
    }
    match format {
        Some(image::ImageFormat::Tiff) => per += bpp,
        Some(image::ImageFormat::Jpeg) => per += jpeg_coefficients,
        _ => {}
    }
    per
}

/// Bytes a pixel a JPEG's decoder holds beside its output, read from the markers up to the
/// first scan: a progressive file, or one whose first scan does not hold every component,
/// keeps every component's DCT coefficients (2 bytes a sample, at most one sample per
/// component a pixel) until its last scan; a baseline interleaved file is decoded one row
/// of blocks at a time (0). Leaves `r` where it found it.
pub fn jpeg_coefficient_bytes<R: Read + Seek>(r: &mut R) -> std::io::Result<f64> {
    let start = r.stream_position()?;
    let found = jpeg_scan_layout(r);
    r.seek(SeekFrom::Start(start))?;
    // A header we cannot follow is the decoder's to refuse; count the worst case meanwhile.
    Ok(match found {
        Ok(Some((progressive, components, first_scan))) => {
            if progressive || first_scan < components {
                2.0 * components as f64
            } else {
                0.0
            }
        }
        Ok(None) | Err(_) => 8.0,
    })
}

/// (progressive, components of the frame, components of its first scan) from a JPEG's
/// markers, `None` when the file ends or is no JPEG before the first scan.
fn jpeg_scan_layout<R: Read + Seek>(r: &mut R) -> std::io::Result<Option<(bool, u8, u8)>> {
    let mut two = [0u8; 2];
    let mut one = [0u8; 1];
    r.read_exact(&mut two)?;
    if two != [0xFF, 0xD8] {
        return Ok(None);
    }
    let mut frame: Option<(bool, u8)> = None;
    // Markers (and stray bytes between them) up to the first scan; real files have tens.
    for _ in 0..65_536 {
        r.read_exact(&mut one)?;
        if one[0] != 0xFF {
            continue;
        }
        let mut m = 0xFF;
        while m == 0xFF {
            r.read_exact(&mut one)?;
            m = one[0];
        }
        match m {
            0x00 | 0x01 | 0xD0..=0xD7 => continue,
            0xD9 => return Ok(None),
            _ => {}
        }
        r.read_exact(&mut two)?;
        let len = i64::from(u16::from_be_bytes(two));
        if len < 2 {
            return Ok(None);
        }
        match m {
            0xC0..=0xCF if !matches!(m, 0xC4 | 0xC8 | 0xCC) => {
                let mut sof = [0u8; 6];
                r.read_exact(&mut sof)?;
                frame = Some((matches!(m, 0xC2 | 0xC6 | 0xCA | 0xCE), sof[5]));
                r.seek(SeekFrom::Current((len - 8).max(0)))?;
            }
            0xDA => {
                r.read_exact(&mut one)?;
                return Ok(frame.map(|(p, n)| (p, n, one[0])));
            }
            _ => {
                r.seek(SeekFrom::Current(len - 2))?;
            }
        }
    }
    Ok(None)
}

/// What [`decode_grey`] checks before it decodes a photo: its size and colour type from the
/// header, admitted by [`MAX_IMAGE_PIXELS`], [`MAX_DECODED_BYTES`] and the photo memory
/// budget ([`grey_decode_cost`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GreyHeader {
    pub width: u32,
    pub height: u32,
    pub color: image::ColorType,
    pub format: Option<image::ImageFormat>,
}

/// The header of a photo as [`decode_grey`] admits it (the same refusals, naming the file),
/// nothing decoded: for a reader that takes the photo by windows instead.
pub fn grey_header(path: &Path) -> Result<GreyHeader> {
    grey_decoder(path, reader(path)?).map(|(_, header)| header)
}

/// The decoder of a photo to grey, once its header passed every limit.
fn grey_decoder<'a, R: std::io::BufRead + Seek + 'a>(
    path: &Path,
    r: image::ImageReader<R>,
) -> Result<(impl image::ImageDecoder + 'a, GreyHeader)> {
    use image::ImageDecoder;
    let format = r.format();
    let (r, jpeg) = if format == Some(image::ImageFormat::Jpeg) {
        let mut inner = r.into_inner();
        let c = jpeg_coefficient_bytes(&mut inner).map_err(|e| FormatError::io(path, e))?;
        (
            image::ImageReader::with_format(inner, image::ImageFormat::Jpeg),
            c,
        )
    } else {
        (r, 0.0)
    };
    let decoder = limited_decoder(path, r)?;
    let ct = decoder.color_type();
    let (w, h) = decoder.dimensions();
    check_photo_memory(
        path,
        w.into(),
        h.into(),
        grey_decode_cost(format, ct, jpeg),
        &format!("{ct:?}"),
    )?;
    let header = GreyHeader {
        width: w,
        height: h,
        color: ct,
        format,
    };
    Ok((decoder, header))
}

/// Grey value of a colour pixel: luma with the Rec. 601 weights (module documentation of
/// [`decode_grey`]), in this order of operations wherever a photo is reduced to grey, so
/// that a photo read whole and by windows has the same values.
#[inline]
pub fn luma(r: f32, g: f32, b: f32) -> f32 {
    0.299 * r + 0.587 * g + 0.114 * b
}

fn decode_grey_from<R: std::io::BufRead + Seek>(
    path: &Path,
    r: image::ImageReader<R>,
) -> Result<(usize, usize, Vec<f32>)> {
    use image::{ColorType as C, ImageDecoder};
    let (decoder, header) = grey_decoder(path, r)?;
    let (ct, w, h) = (header.color, header.width, header.height);
    let n = w as usize * h as usize;
    let alloc = |what: &str, e: std::collections::TryReserveError| {
        FormatError::invalid(
            path,
            format!("cannot allocate the {what} of {w}×{h} pixels: {e}"),
        )
    };
    let mut data: Vec<f32> = Vec::new();
    data.try_reserve_exact(n)
        .map_err(|e| alloc("grey image", e))?;
    data.resize(n, 0.0);
    let bpp = ct.bytes_per_pixel() as usize;
    if widened_in_place(ct) {
        decoder
            .read_image(&mut f32_bytes_mut(&mut data)[..n * bpp])
            .map_err(bad_image(path))?;
        let ne16 = |b: &[u8]| f32::from(u16::from_ne_bytes([b[0], b[1]]));
        let rgb = |b: &[u8]| luma(f32::from(b[0]), f32::from(b[1]), f32::from(b[2]));
        match ct {
            C::L8 => widen::<1>(&mut data, |b| f32::from(b[0])),
            C::La8 => widen::<2>(&mut data, |b| {
                let l = f32::from(b[0]);
                luma(l, l, l)
            }),
            C::Rgb8 => widen::<3>(&mut data, |b| rgb(b)),
            C::Rgba8 => widen::<4>(&mut data, |b| rgb(b)),
            C::L16 => widen::<2>(&mut data, |b| ne16(b)),
            _ => widen::<4>(&mut data, |b| ne16(b)),
        }
    } else {
        let mut buf: Vec<u8> = Vec::new();
        let total = n * bpp;
        buf.try_reserve_exact(total)
            .map_err(|e| alloc("decoded image", e))?;
        buf.resize(total, 0);
        decoder.read_image(&mut buf).map_err(bad_image(path))?;
        let ch = usize::from(ct.channel_count());
        let (f32_ch, u16_ch) = (
            matches!(ct, C::Rgb32F | C::Rgba32F),
            matches!(ct, C::Rgb16 | C::Rgba16),
        );
        if !(f32_ch || u16_ch) {
            return Err(FormatError::invalid(
                path,
                format!("colour type {ct:?} is not one a photo is read in"),
            ));
        }
        for (d, px) in data.iter_mut().zip(buf.chunks_exact(bpp)) {
            let c = |k: usize| {
                let b = &px[k * bpp / ch..(k + 1) * bpp / ch];
                if f32_ch {
                    f32::from_ne_bytes([b[0], b[1], b[2], b[3]])
                } else {
                    f32::from(u16::from_ne_bytes([b[0], b[1]]))
                }
            };
            let l = luma(c(0), c(1), c(2));
            *d = if f32_ch { 65535.0 * l } else { l };
        }
    }
    Ok((w as usize, h as usize, data))
}

/// The bytes of an f32 buffer, for a decoder to write into.
fn f32_bytes_mut(v: &mut [f32]) -> &mut [u8] {
    // SAFETY: the slice covers exactly the memory of `v`, u8 has no alignment requirement,
    // and every byte pattern is a valid f32, so the buffer stays valid whatever is written.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast::<u8>(), std::mem::size_of_val(v)) }
}

/// Widens pixels of `B` ≤ 4 bytes, packed at the start of `data`'s memory, to one f32 each
/// (`f` of the pixel's bytes), in place: from the last pixel to the first, so that a pixel's
/// bytes are read before any f32 is written over them.
fn widen<const B: usize>(data: &mut [f32], f: impl Fn(&[u8; B]) -> f32) {
    const { assert!(B >= 1 && B <= 4) };
    let base = data.as_mut_ptr();
    let bytes = base.cast::<u8>().cast_const();
    for i in (0..data.len()).rev() {
        // SAFETY: pixel i's bytes [B·i, B·i + B) lie inside the buffer (B ≤ 4) and below
        // [4(i + 1), …), the only bytes written so far (B·i + B ≤ 4i + 4), so they are
        // intact; they are copied out before f32 i is written; both stay inside `data`.
        unsafe {
            let px = bytes.add(B * i).cast::<[u8; B]>().read();
            base.add(i).write(f(&px));
        }
    }
}

/// Rows read from GDAL per call: a file whose data ends early fails after one strip, not
/// after a buffer for its whole claimed size was allocated.
const STRIP_ROWS: usize = 256;

/// Reads `bands` (1-based) of the window `(col, row, width, height)` as f32, row strip by
/// row strip, passing each strip (one row-major buffer per band, in the order of `bands`)
/// to `strip`.
pub fn read_band_strips(
    path: &Path,
    ds: &Dataset,
    bands: &[usize],
    (c, r, w, h): (usize, usize, usize, usize),
    mut strip: impl FnMut(&[Vec<f32>]),
) -> Result<()> {
    check_blocks(path, ds, bands)?;
    let mut row = r;
    while row < r + h {
        let rows = STRIP_ROWS.min(r + h - row);
        strip(&read_strip(path, ds, bands, (c, row, w, rows))?);
        row += rows;
    }
    Ok(())
}

/// [`read_band_strips`] dropping GDAL's cached blocks of the dataset after each strip:
/// GDAL keeps the blocks it decoded up to its cache size (5 % of the machine's memory by
/// default), which for a whole scan read by strips would be a second copy of it beside
/// ours. A tiled file whose tiles are taller than a strip decodes a tile row again for its
/// next strip.
pub fn read_band_strips_uncached(
    path: &Path,
    ds: &mut Dataset,
    bands: &[usize],
    (c, r, w, h): (usize, usize, usize, usize),
    mut strip: impl FnMut(&[Vec<f32>]),
) -> Result<()> {
    check_blocks(path, ds, bands)?;
    let mut row = r;
    while row < r + h {
        let rows = STRIP_ROWS.min(r + h - row);
        let parts = read_strip(path, ds, bands, (c, row, w, rows));
        ds.flush_cache().map_err(|e| FormatError::gdal(path, e))?;
        strip(&parts?);
        row += rows;
    }
    Ok(())
}

/// Refuses a raster whose blocks exceed the photo memory budget: GDAL decodes and caches a
/// whole block to read any part of it, and the block of a pixel-interleaved file holds
/// every band of the dataset, read or not. An 847-byte TIFF of 32 × 19 785 pixels claiming
/// 61 955 samples a pixel, one strip of all of them, made GDAL allocate 4.9 GB to read the
/// first rows of its first three bands. Counted as the first band's block times the
/// dataset's bands (the read bands' when fewer would do is not known from here).
fn check_blocks(path: &Path, ds: &Dataset, bands: &[usize]) -> Result<()> {
    let budget = photo_memory_for(path)?;
    let Some(&first) = bands.first() else {
        return Ok(());
    };
    let band = ds
        .rasterband(first)
        .map_err(|e| FormatError::gdal(path, e))?;
    let (bx, by) = band.block_size();
    let all = ds.raster_count().max(bands.len());
    let bytes = (bx as u64)
        .saturating_mul(by as u64)
        .saturating_mul(band.pixel_bytes() as u64)
        .saturating_mul(all as u64);
    if bytes > budget {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!(
                "blocks of {bx}×{by} pixels × {all} band(s), which GDAL decodes whole, in bytes"
            ),
            claimed: bytes,
            limit: budget,
            basis: format!(
                "the photo memory budget (set {PHOTO_MEMORY_ENV}, e.g. {PHOTO_MEMORY_ENV}=2G, or write the raster tiled)"
            ),
        });
    }
    Ok(())
}

fn read_strip(
    path: &Path,
    ds: &Dataset,
    bands: &[usize],
    (c, row, w, rows): (usize, usize, usize, usize),
) -> Result<Vec<Vec<f32>>> {
    bands
        .iter()
        .map(|&b| {
            ds.rasterband(b)
                .map_err(|e| FormatError::gdal(path, e))?
                .read::<f32>((c, row), (w, rows), (w, rows))
                .map_err(|e| FormatError::gdal(path, e))
        })
        .collect()
}
