//! Greyscale f32 images: the one pixel type every matcher works on, loaded from 8/16-bit
//! grey or RGB files with `image`, or as a window of a large scan with GDAL.

use super::{invalid, MatchingError, Result};
use std::path::Path;

/// Row-major greyscale image. Grey values keep the file's range (0–255 for 8-bit,
/// 0–65535 for 16-bit) because NCC and LSM are invariant to a linear radiometric change.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl GreyImage {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(invalid("image", format!("size {width}×{height} is empty")));
        }
        if data.len() != width * height {
            return Err(invalid(
                "image",
                format!(
                    "{width}×{height} pixels need {} values, got {}",
                    width * height,
                    data.len()
                ),
            ));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(invalid("image", format!("pixel {i} is not finite")));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Samples `f(x, y)` at the pixel centres (x + 0.5, y + 0.5).
    pub fn from_fn(width: usize, height: usize, f: impl Fn(f64, f64) -> f64) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for r in 0..height {
            for c in 0..width {
                data.push(f(c as f64 + 0.5, r as f64 + 0.5) as f32);
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    #[inline]
    pub fn at(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    #[inline]
    pub fn row(&self, row: usize) -> &[f32] {
        &self.data[row * self.width..(row + 1) * self.width]
    }

    /// Copy of a rectangle given by its top-left pixel and size (must lie inside).
    pub fn crop(&self, col: usize, row: usize, w: usize, h: usize) -> Result<GreyImage> {
        if w == 0 || h == 0 || col + w > self.width || row + h > self.height {
            return Err(invalid(
                "crop",
                format!(
                    "window {w}×{h} at ({col}, {row}) is outside the {}×{} image",
                    self.width, self.height
                ),
            ));
        }
        let mut data = Vec::with_capacity(w * h);
        for r in row..row + h {
            data.extend_from_slice(&self.data[r * self.width + col..r * self.width + col + w]);
        }
        Ok(GreyImage {
            width: w,
            height: h,
            data,
        })
    }

    /// Standard deviation of the grey values (texture check before correlation).
    pub fn std_dev(&self) -> f64 {
        let n = self.data.len() as f64;
        let mean = self.data.iter().map(|&v| v as f64).sum::<f64>() / n;
        (self
            .data
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    }

    /// Loads a whole image file (8/16-bit grey or RGB(A); colour is reduced to luma
    /// with the Rec. 601 weights that scanners and film densitometry conventionally use)
    /// within the photo memory budget (`formats::image_open`: the grey copy and its
    /// pyramid, and what the decoder needs, are counted from the header before anything is
    /// decoded; [`crate::formats::image_open::PHOTO_MEMORY_ENV`] sets it).
    pub fn load(path: &Path) -> Result<GreyImage> {
        let err = |m: String| MatchingError::Read {
            path: path.to_path_buf(),
            message: m,
        };
        use crate::formats::{image_open, FormatError};
        // A malformed budget is the error, not a reason to try GDAL.
        image_open::photo_memory_for(path).map_err(|e| err(e.detail()))?;
        let (w, h, data) = match image_open::decode_grey(path) {
            Ok(i) => i,
            // Refused for its size: GDAL must not read it either.
            Err(e @ FormatError::TooLarge { .. }) => return Err(err(e.detail())),
            // Large or exotic TIFF scans (tiled, BigTIFF, JPEG-in-TIFF) go through GDAL.
            Err(e) => {
                return Self::load_window(path, None).map_err(|g| match g {
                    MatchingError::Read { message, .. } => {
                        err(format!("{}; GDAL: {message}", e.detail()))
                    }
                    g => g,
                })
            }
        };
        GreyImage::new(w, h, data).map_err(|e| err(e.to_string()))
    }

    /// Reads a window (col, row, width, height) of a raster with GDAL without loading the
    /// whole file — scans are often 10⁸ pixels. `None` reads everything. Multi-band
    /// rasters are reduced to luma from their first three bands. The window is held within
    /// the photo memory budget (as [`GreyImage::load`]), read by strips with GDAL's block
    /// cache dropped after each.
    pub fn load_window(
        path: &Path,
        window: Option<(usize, usize, usize, usize)>,
    ) -> Result<GreyImage> {
        let err = |m: String| MatchingError::Read {
            path: path.to_path_buf(),
            message: m,
        };
        use crate::formats::image_open;
        let mut ds = image_open::open_raster(path).map_err(|e| err(e.detail()))?;
        let (rw, rh) = ds.raster_size();
        let (c, r, w, h) = window.unwrap_or((0, 0, rw, rh));
        if w == 0 || h == 0 || c + w > rw || r + h > rh {
            return Err(err(format!(
                "window {w}×{h} at ({c}, {r}) is outside the {rw}×{rh} raster"
            )));
        }
        image_open::check_pixels(path, w as u64, h as u64).map_err(|e| err(e.detail()))?;
        let bands: &[usize] = if ds.raster_count() >= 3 {
            &[1, 2, 3]
        } else {
            &[1]
        };
        image_open::check_photo_memory(
            path,
            w as u64,
            h as u64,
            image_open::MATCHING_BYTES_PER_PIXEL,
            &format!("{} band(s) read by GDAL", bands.len()),
        )
        .map_err(|e| err(e.detail()))?;
        let mut data = Vec::new();
        data.try_reserve_exact(w * h).map_err(|e| {
            err(format!(
                "cannot allocate the grey image of {w}×{h} pixels: {e}"
            ))
        })?;
        // Luma from the first three bands, strip by strip.
        image_open::read_band_strips_uncached(path, &mut ds, bands, (c, r, w, h), |s| match s {
            [rr, gg, bb] => data.extend(
                rr.iter()
                    .zip(gg)
                    .zip(bb)
                    .map(|((r, g), b)| image_open::luma(*r, *g, *b)),
            ),
            [grey] => data.extend_from_slice(grey),
            _ => {}
        })
        .map_err(|e| err(e.detail()))?;
        GreyImage::new(w, h, data).map_err(|e| err(e.to_string()))
    }

    /// Writes an 8-bit (values clamped to 0–255) or 16-bit PNG/TIFF, atomically.
    pub fn save(&self, path: &Path, sixteen_bit: bool) -> Result<()> {
        let err = |m: String| MatchingError::Read {
            path: path.to_path_buf(),
            message: m,
        };
        crate::formats::write_atomically(path, |tmp| {
            let fmt = image::ImageFormat::from_path(path)
                .map_err(|e| crate::formats::FormatError::invalid(path, e.to_string()))?;
            let res = if sixteen_bit {
                let buf: Vec<u16> = self
                    .data
                    .iter()
                    .map(|&v| v.round().clamp(0.0, 65535.0) as u16)
                    .collect();
                image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
                    self.width as u32,
                    self.height as u32,
                    buf,
                )
                .expect("size matches")
                .save_with_format(tmp, fmt)
            } else {
                let buf: Vec<u8> = self
                    .data
                    .iter()
                    .map(|&v| v.round().clamp(0.0, 255.0) as u8)
                    .collect();
                image::GrayImage::from_raw(self.width as u32, self.height as u32, buf)
                    .expect("size matches")
                    .save_with_format(tmp, fmt)
            };
            res.map_err(|e| crate::formats::FormatError::invalid(path, e.to_string()))
        })
        .map_err(|e| err(e.to_string()))
    }
}

/// A photo's pixels for matching: held by the caller, or a file decoded when a stage needs
/// it, so a block's stages do not have to hold every photo at once.
#[derive(Debug, Clone, Copy)]
pub enum Pixels<'a> {
    Held(&'a GreyImage),
    File(&'a Path),
}

impl Pixels<'_> {
    /// The image: borrowed, or decoded from its file.
    pub fn get(&self) -> Result<std::borrow::Cow<'_, GreyImage>> {
        Ok(match self {
            Pixels::Held(i) => std::borrow::Cow::Borrowed(*i),
            Pixels::File(p) => std::borrow::Cow::Owned(GreyImage::load(p)?),
        })
    }
}
