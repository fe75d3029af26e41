//! A scan's pixels taken by windows, for work that needs a few parts of a large scan (the
//! fiducial marks of a film scan: eight windows of a few millimetres in a 10⁸-pixel
//! scan). The scan is admitted from its header exactly as [`GreyImage::load`] admits it
//! (pixel cap, decoded bytes, photo memory budget, with the same messages), then read:
//!
//! * an uncompressed TIFF (what film scanners write) straight from the file by windows
//!   ([`crate::formats::tiff_window`]);
//! * another TIFF of more than [`SMALL_PIXELS`] (compressed, planar, float, …) by windows
//!   through GDAL, which decodes only the strips or tiles a window touches;
//! * anything else (PNG, JPEG, a small TIFF, what GDAL cannot open) whole with
//!   [`GreyImage::load`], as before: those files are small, or cannot be read by windows
//!   without decoding them from their start.
//!
//! A window has the grey values [`GreyImage::load`] gives there; through GDAL, those of
//! its whole read (the same for 8/16-bit grey and RGB).

use super::ncc::Window;
use super::{GreyImage, MatchingError, Result};
use crate::formats::gdal::Dataset;
use crate::formats::image_open;
use crate::formats::tiff_window::TiffWindows;
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// Pixels up to which a scan that is not read straight from its file is decoded whole
/// rather than read through GDAL (16 M): loading GDAL takes 60–100 ms on the 2-core
/// machines, as long as decoding about that many pixels whole.
pub const SMALL_PIXELS: u64 = 1 << 24;

enum Source<'a> {
    /// In memory: the caller's, or a small file decoded whole.
    Image(Cow<'a, GreyImage>),
    Tiff(TiffWindows),
    Gdal {
        ds: Dataset,
        bands: Vec<usize>,
    },
}

/// A scan read by windows (module documentation).
pub struct ScanWindows<'a> {
    /// The file, None for a scan held by the caller.
    path: Option<PathBuf>,
    width: usize,
    height: usize,
    source: Source<'a>,
    pixels_read: u64,
}

impl<'a> ScanWindows<'a> {
    /// A scan the caller holds.
    pub fn held(img: &'a GreyImage) -> Self {
        Self {
            path: None,
            width: img.width,
            height: img.height,
            source: Source::Image(Cow::Borrowed(img)),
            pixels_read: 0,
        }
    }

    /// Opens a scan file; the errors of [`GreyImage::load`] for what it refuses.
    pub fn open(path: &Path) -> Result<ScanWindows<'static>> {
        let err = |m: String| MatchingError::Read {
            path: path.to_path_buf(),
            message: m,
        };
        image_open::photo_memory_for(path).map_err(|e| err(e.detail()))?;
        let whole = || -> Result<ScanWindows<'static>> {
            let img = GreyImage::load(path)?;
            Ok(ScanWindows {
                path: Some(path.to_path_buf()),
                width: img.width,
                height: img.height,
                source: Source::Image(Cow::Owned(img)),
                pixels_read: 0,
            })
        };
        let header = match image_open::grey_header(path) {
            Ok(h) => h,
            Err(e @ crate::formats::FormatError::TooLarge { .. }) => return Err(err(e.detail())),
            // What the `image` crate cannot read: GDAL, as the whole load tries it.
            Err(_) => return whole(),
        };
        if header.format != Some(image::ImageFormat::Tiff) {
            return whole();
        }
        let source = match TiffWindows::open(path).map_err(|e| err(e.detail()))? {
            Some(t) => Source::Tiff(t),
            None if u64::from(header.width) * u64::from(header.height) <= SMALL_PIXELS => {
                return whole()
            }
            None => match image_open::open_raster(path) {
                Ok(ds) => {
                    let bands = if ds.raster_count() >= 3 {
                        vec![1, 2, 3]
                    } else {
                        vec![1]
                    };
                    Source::Gdal { ds, bands }
                }
                Err(_) => return whole(),
            },
        };
        let (width, height) = match &source {
            Source::Tiff(t) => t.size(),
            Source::Gdal { ds, .. } => ds.raster_size(),
            Source::Image(i) => (i.width, i.height),
        };
        if (width, height) != (header.width as usize, header.height as usize) {
            return Err(err(format!(
                "its header says {}×{} pixels, the raster {width}×{height}",
                header.width, header.height
            )));
        }
        Ok(ScanWindows {
            path: Some(path.to_path_buf()),
            width,
            height,
            source,
            pixels_read: 0,
        })
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The whole scan when it is held in memory (the caller's, or a small file).
    pub fn image(&self) -> Option<&GreyImage> {
        match &self.source {
            Source::Image(i) => Some(i),
            _ => None,
        }
    }

    /// Pixels read by [`ScanWindows::read`] so far.
    pub fn pixels_read(&self) -> u64 {
        self.pixels_read
    }

    /// The grey values of `win` (inside the scan), within the photo memory budget.
    pub fn read(&mut self, win: Window) -> Result<GreyImage> {
        let Window {
            col,
            row,
            width: w,
            height: h,
        } = win;
        if w == 0 || h == 0 || col + w > self.width || row + h > self.height {
            return Err(super::invalid(
                "scan window",
                format!(
                    "{w}×{h} at ({col}, {row}) is outside the {}×{} scan",
                    self.width, self.height
                ),
            ));
        }
        self.pixels_read += (w * h) as u64;
        match &mut self.source {
            Source::Image(img) => img.crop(col, row, w, h),
            Source::Tiff(t) => {
                let path = self.path.as_deref().unwrap_or(Path::new("scan"));
                window_from(path, w, h, |data| t.read((col, row, w, h), data))
            }
            Source::Gdal { ds, bands } => {
                let path = self.path.as_deref().unwrap_or(Path::new("scan"));
                window_from(path, w, h, |data| {
                    image_open::read_band_strips(path, ds, bands, (col, row, w, h), |s| match s {
                        [r, g, b] => data.extend(
                            r.iter()
                                .zip(g)
                                .zip(b)
                                .map(|((r, g), b)| image_open::luma(*r, *g, *b)),
                        ),
                        [grey] => data.extend_from_slice(grey),
                        _ => {}
                    })
                })
            }
        }
    }
}

/// A `w`×`h` window of the scan file `path` whose values `fill` appends, within the photo
/// memory budget; errors name the file.
fn window_from(
    path: &Path,
    w: usize,
    h: usize,
    fill: impl FnOnce(&mut Vec<f32>) -> crate::formats::Result<()>,
) -> Result<GreyImage> {
    let err = |m: String| MatchingError::Read {
        path: path.to_path_buf(),
        message: m,
    };
    image_open::check_photo_memory(
        path,
        w as u64,
        h as u64,
        image_open::MATCHING_BYTES_PER_PIXEL,
        "a window of the scan",
    )
    .map_err(|e| err(e.detail()))?;
    let mut data = Vec::new();
    data.try_reserve_exact(w * h)
        .map_err(|e| err(format!("cannot allocate a window of {w}×{h} pixels: {e}")))?;
    fill(&mut data).map_err(|e| err(e.detail()))?;
    GreyImage::new(w, h, data).map_err(|e| err(e.to_string()))
}
