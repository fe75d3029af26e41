//! Fiducial-frame images of film scans, as hipp and MicMac's ReSampFid make them: each
//! scan is resampled through its fiducial interior orientation into an image whose pixels
//! are the fiducial coordinate system at one chosen pixel size, cropped to the calibrated
//! film format, with what the scan does not cover masked. Its camera is then a plain frame
//! camera, which COLMAP, BlocksExchange and the orthophoto take exactly.
//!
//! The frame (formats/workflow/README.md, "Resampled film scans"): an image of
//! `W = round(format_x / p)` × `H = round(format_y / p)` pixels whose centre `(W/2, H/2)`
//! is the fiducial origin (the format centre), x right and y down:
//! `x_mm = (u − W/2)·p`, `y_mm = (H/2 − v)·p`. The principal point is not moved to the
//! image centre but carried as `cx = W/2 + x0/p`, `cy = H/2 − y0/p`: the mapping pixel ↔
//! mm is then a pure scale with no rounding of the principal point to the pixel grid, the
//! crop is the calibrated format to the nearest pixel and centred as the format is (about
//! the fiducial centre, not the principal point), every scan of one camera gets the same
//! frame camera (one photogroup), and a later self-calibration of the principal point
//! changes `cx, cy` without making the pixels wrong.

use super::super::resample::{sample, Interpolation, PatchWarp};
use super::super::{invalid, GreyImage, MatchingError, Result};
use super::camera::check_scan_pixel_um;
use crate::formats::image_open::check_pixels;
use crate::geometry::{FilmCamera, FrameCamera, InteriorOrientation};
use nalgebra::Matrix3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Grey value of masked pixels (outside the scan) in a written frame image; the pixels
/// the scan covers are lifted to at least 1, so 0 means masked and nothing else.
pub const MASKED: u16 = 0;

/// The pixel grid of a fiducial-frame image (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FiducialFrame {
    pub width: u32,
    pub height: u32,
    /// Pixel size (mm), square.
    pub pixel_mm: f64,
}

impl FiducialFrame {
    /// The frame of a film format (mm) at `pixel_mm`: the format rounded to whole pixels.
    pub fn new(format_mm: [f64; 2], pixel_mm: f64) -> Result<Self> {
        let what = "fiducial frame";
        check_scan_pixel_um(pixel_mm * 1000.0).map_err(|m| invalid(what, m))?;
        let [fw, fh] = format_mm;
        if !(fw.is_finite() && fh.is_finite() && fw > 0.0 && fh > 0.0) {
            return Err(invalid(
                what,
                format!("film format [{fw}, {fh}] mm is not a positive size"),
            ));
        }
        let (w, h) = ((fw / pixel_mm).round(), (fh / pixel_mm).round());
        check_pixels(Path::new(what), w as u64, h as u64).map_err(|e| invalid(what, e.detail()))?;
        if w < 1.0 || h < 1.0 {
            return Err(invalid(
                what,
                format!("film format [{fw}, {fh}] mm is less than a {pixel_mm} mm pixel"),
            ));
        }
        Ok(Self {
            width: w as u32,
            height: h as u32,
            pixel_mm,
        })
    }

    /// Homogeneous frame pixel → fiducial mm.
    fn pixel_to_mm_matrix(&self) -> Matrix3<f64> {
        let p = self.pixel_mm;
        Matrix3::new(
            p,
            0.0,
            -p * self.width as f64 / 2.0,
            0.0,
            -p,
            p * self.height as f64 / 2.0,
            0.0,
            0.0,
            1.0,
        )
    }

    /// Fiducial coordinates (mm) of a frame pixel position.
    pub fn pixel_to_mm(&self, px: [f64; 2]) -> [f64; 2] {
        let p = self.pixel_mm;
        [
            (px[0] - self.width as f64 / 2.0) * p,
            (self.height as f64 / 2.0 - px[1]) * p,
        ]
    }

    /// Frame pixel position of fiducial coordinates (mm).
    pub fn mm_to_pixel(&self, mm: [f64; 2]) -> [f64; 2] {
        let p = self.pixel_mm;
        [
            self.width as f64 / 2.0 + mm[0] / p,
            self.height as f64 / 2.0 - mm[1] / p,
        ]
    }

    /// Frame pixel position of a scan pixel position, through the scan's interior
    /// orientation (how observations in a scan move into its frame image).
    pub fn scan_to_frame(&self, interior: &InteriorOrientation, scan_px: [f64; 2]) -> [f64; 2] {
        let mm = interior.pixel_to_mm(nalgebra::Vector2::new(scan_px[0], scan_px[1]));
        self.mm_to_pixel([mm.x, mm.y])
    }

    /// The frame pixel → scan pixel transform (an affine for an affine interior
    /// orientation), for resampling.
    fn frame_to_scan(&self, interior: &InteriorOrientation) -> Result<PatchWarp> {
        let inv = interior.pixel_to_mm.try_inverse().ok_or_else(|| {
            invalid(
                "fiducial frame",
                "the scan's interior orientation is singular",
            )
        })?;
        let h = inv * self.pixel_to_mm_matrix();
        let h = h / h[(2, 2)];
        Ok(if h[(2, 0)] == 0.0 && h[(2, 1)] == 0.0 {
            PatchWarp::Affine([
                h[(0, 0)],
                h[(0, 1)],
                h[(0, 2)],
                h[(1, 0)],
                h[(1, 1)],
                h[(1, 2)],
            ])
        } else {
            PatchWarp::Homography(h)
        })
    }

    /// The frame camera of the frame image of a scan taken with `film`: the calibrated
    /// focal length and principal point in pixels of this frame, and the calibrated Brown
    /// distortion unchanged — both cameras use the same normalised image coordinates
    /// (`(x_mm − x0)/f`, `−(y_mm − y0)/f`), so the coefficients carry over as they are.
    pub fn frame_camera(&self, film: &FilmCamera) -> FrameCamera {
        let p = self.pixel_mm;
        let [x0, y0] = film.principal_point_mm;
        FrameCamera {
            width: self.width,
            height: self.height,
            fx: film.focal_mm / p,
            fy: film.focal_mm / p,
            cx: self.width as f64 / 2.0 + x0 / p,
            cy: self.height as f64 / 2.0 - y0 / p,
            distortion: film.distortion,
        }
    }

    /// Sensor size as BlocksExchange means it: the frame's larger side (mm).
    pub fn sensor_size_mm(&self) -> f64 {
        self.width.max(self.height) as f64 * self.pixel_mm
    }
}

/// The default pixel size of an epoch's frame images: the mean over its scans of each
/// scan's mean pixel size from its interior orientation (what the scans resolve). One
/// size for the epoch gives every scan of a camera the same frame camera; the scans'
/// sizes differ by the scanner's scale errors (parts per thousand) only.
pub fn mean_scan_pixel_mm<'a>(
    interiors: impl IntoIterator<Item = &'a InteriorOrientation>,
) -> Option<f64> {
    let (sum, n) = interiors.into_iter().fold((0.0, 0usize), |(s, n), io| {
        (s + io.mean_pixel_size_mm(), n + 1)
    });
    (n > 0).then(|| sum / n as f64)
}

/// Resamples the frame image into `out` (row-major, `frame.width` × `frame.height`),
/// each pixel made by `value` from the bicubic sample at its centre (None: outside the
/// scan); rows in parallel. Returns the number of masked pixels.
fn resample_into<T: Send>(
    scan: &GreyImage,
    warp: &PatchWarp,
    frame: &FiducialFrame,
    out: &mut [T],
    value: impl Fn(Option<f64>) -> T + Sync,
) -> usize {
    let w = frame.width as usize;
    out.par_chunks_mut(w)
        .enumerate()
        .map(|(r, row)| {
            let mut masked = 0;
            for (c, px) in row.iter_mut().enumerate() {
                let (x, y) = warp.apply(c as f64 + 0.5, r as f64 + 0.5);
                let v = sample(scan, x, y, Interpolation::Bicubic);
                masked += usize::from(v.is_none());
                *px = value(v);
            }
            masked
        })
        .sum()
}

/// The frame image of a scan in memory (grey values as sampled, masked pixels 0) and the
/// number of masked pixels.
pub fn resample_scan(
    scan: &GreyImage,
    interior: &InteriorOrientation,
    frame: &FiducialFrame,
) -> Result<(GreyImage, usize)> {
    let warp = frame.frame_to_scan(interior)?;
    let (w, h) = (frame.width as usize, frame.height as usize);
    let mut data = vec![0f32; w * h];
    let masked = resample_into(scan, &warp, frame, &mut data, |v| {
        v.map_or(MASKED as f32, |v| v as f32)
    });
    Ok((
        GreyImage {
            width: w,
            height: h,
            data,
        },
        masked,
    ))
}

/// What [`write_frame_image`] made of one scan.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameImageReport {
    pub scan: PathBuf,
    pub image: PathBuf,
    pub frame: FiducialFrame,
    /// Pixels outside the scan, written as [`MASKED`].
    pub masked_pixels: usize,
    /// 8, or 16 when the scan holds grey values above 255.
    pub bits: u8,
    /// Wall time of reading, resampling and writing (s); not serialised, so that the
    /// products of equal inputs are equal bytes.
    #[serde(skip)]
    pub seconds: f64,
}

/// Reads the scan `scan_path` (through `formats::image_open`'s size limits), resamples it
/// into `frame` through its interior orientation and writes the frame image to `out`
/// (TIFF or PNG by the extension, grey, 8-bit or 16-bit as the scan; masked pixels
/// [`MASKED`], covered ones at least 1), atomically. Holds one scan and one frame image.
pub fn write_frame_image(
    scan_path: &Path,
    interior: &InteriorOrientation,
    frame: &FiducialFrame,
    out: &Path,
) -> Result<FrameImageReport> {
    let t = std::time::Instant::now();
    let scan = GreyImage::load(scan_path)?;
    let warp = frame.frame_to_scan(interior)?;
    let (w, h) = (frame.width, frame.height);
    let n = w as usize * h as usize;
    let sixteen = scan.data.iter().any(|&v| v > 255.0);
    let write_err = |e: crate::formats::FormatError| MatchingError::Read {
        path: out.to_path_buf(),
        message: format!("cannot write the frame image: {}", e.detail()),
    };
    let fmt = image::ImageFormat::from_path(out).map_err(|e| MatchingError::Read {
        path: out.to_path_buf(),
        message: format!("no image format for this file name: {e}"),
    })?;
    let masked = if sixteen {
        let mut buf = vec![0u16; n];
        let masked = resample_into(&scan, &warp, frame, &mut buf, |v| {
            v.map_or(MASKED, |v| v.round().clamp(1.0, 65535.0) as u16)
        });
        drop(scan);
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, buf)
            .expect("buffer of the frame's size");
        crate::formats::write_atomically(out, |tmp| {
            img.save_with_format(tmp, fmt)
                .map_err(|e| crate::formats::FormatError::invalid(out, e.to_string()))
        })
        .map_err(write_err)?;
        masked
    } else {
        let mut buf = vec![0u8; n];
        let masked = resample_into(&scan, &warp, frame, &mut buf, |v| {
            v.map_or(MASKED as u8, |v| v.round().clamp(1.0, 255.0) as u8)
        });
        drop(scan);
        let img = image::GrayImage::from_raw(w, h, buf).expect("buffer of the frame's size");
        crate::formats::write_atomically(out, |tmp| {
            img.save_with_format(tmp, fmt)
                .map_err(|e| crate::formats::FormatError::invalid(out, e.to_string()))
        })
        .map_err(write_err)?;
        masked
    };
    Ok(FrameImageReport {
        scan: scan_path.to_path_buf(),
        image: out.to_path_buf(),
        frame: *frame,
        masked_pixels: masked,
        bits: if sixteen { 16 } else { 8 },
        seconds: t.elapsed().as_secs_f64(),
    })
}
