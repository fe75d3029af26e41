//! Opening images and rasters named by data files (photos, scans, DEMs): the size is read
//! from the header and checked against [`MAX_IMAGE_PIXELS`] before anything is decoded,
//! the decoder's allocations are capped by [`MAX_DECODED_BYTES`], and GDAL opens only the
//! raster drivers we mean ([`RASTER_DRIVERS`]) on local paths — never VRT (which reads
//! other files) nor `/vsicurl/` and URLs (which fetch from the network).

use super::gdal::Dataset;
use super::{FormatError, Result};
use std::path::Path;

/// Largest image or raster window read whole: 2³⁰ pixels (a 230 mm film frame scanned
/// at 7 µm is 1.08·10⁹; 4 GiB as the f32 grey the matchers work on). Larger scans are
/// read by windows.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 30;

/// Largest decoded image the `image` decoders may allocate (4 GiB): a small, highly
/// compressed file cannot expand beyond this, whatever its header says.
pub const MAX_DECODED_BYTES: u64 = 4 << 30;

/// GDAL drivers allowed to open a raster named by a data file.
pub const RASTER_DRIVERS: &[&str] = &["GTiff", "PNG", "JPEG"];

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
    if !path.is_file() {
        return Err(FormatError::invalid(path, "is not a file"));
    }
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

fn reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    image::ImageReader::open(path)
        .map_err(|e| FormatError::io(path, e))?
        .with_guessed_format()
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
/// [`MAX_IMAGE_PIXELS`] and its decoded size against [`MAX_DECODED_BYTES`], which also caps
/// the decoder's allocations.
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

fn decode<R: std::io::BufRead + std::io::Seek>(
    path: &Path,
    mut r: image::ImageReader<R>,
) -> Result<image::DynamicImage> {
    use image::ImageDecoder;
    let bad =
        |e: image::ImageError| FormatError::invalid(path, format!("cannot decode the image: {e}"));
    // Our cap replaces the reader's default (512 MiB) for the header's own allocations
    // (PNG text and ICC chunks, TIFF tags) and the decoded image.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODED_BYTES);
    r.limits(limits);
    let decoder = r.into_decoder().map_err(bad)?;
    let (w, h) = decoder.dimensions();
    check_pixels(path, w.into(), h.into())?;
    let bytes = decoder.total_bytes();
    if bytes > MAX_DECODED_BYTES {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!(
                "image of {w}×{h} pixels ({:?}) decoded, in bytes",
                decoder.color_type()
            ),
            claimed: bytes,
            limit: MAX_DECODED_BYTES,
            basis: "the bytes an image may decode to".into(),
        });
    }
    image::DynamicImage::from_decoder(decoder).map_err(bad)
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
    let handles = bands
        .iter()
        .map(|&b| ds.rasterband(b).map_err(|e| FormatError::gdal(path, e)))
        .collect::<Result<Vec<_>>>()?;
    let mut row = r;
    while row < r + h {
        let rows = STRIP_ROWS.min(r + h - row);
        let parts = handles
            .iter()
            .map(|band| {
                band.read::<f32>((c, row), (w, rows), (w, rows))
                    .map_err(|e| FormatError::gdal(path, e))
            })
            .collect::<Result<Vec<_>>>()?;
        strip(&parts);
        row += rows;
    }
    Ok(())
}
