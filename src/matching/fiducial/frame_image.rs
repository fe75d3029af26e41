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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Brown, Camera, InteriorTransformKind};
    use nalgebra::{Matrix2, Vector2, Vector3};

    /// A camera-frame point's scan pixel (film camera) moved into the frame, and its pixel
    /// through the frame camera.
    fn frame_pixel_of(
        frame: &FiducialFrame,
        film: &FilmCamera,
        xc: &Vector3<f64>,
    ) -> ([f64; 2], [f64; 2]) {
        let scan = Camera::Film(film.clone()).project(xc).unwrap();
        let via_scan = frame.scan_to_frame(&film.interior, [scan.x, scan.y]);
        let direct = Camera::Frame(frame.frame_camera(film)).project(xc).unwrap();
        (via_scan, [direct.x, direct.y])
    }

    /// A scan interior orientation of a `w`×`h` scan: pixel → mm = R(rot) · M ·
    /// [[s, shear·s], [0, −1.003·s]] · (col, row) + t, M mirroring x when asked (a scan
    /// read from the emulsion side), with the scan centre at `centre_mm`.
    fn affine(
        (w, h): (f64, f64),
        s: f64,
        rot_deg: f64,
        shear: f64,
        centre_mm: [f64; 2],
        mirror: bool,
    ) -> InteriorOrientation {
        let (sn, cs) = rot_deg.to_radians().sin_cos();
        let m = if mirror { -1.0 } else { 1.0 };
        let a = Matrix2::new(cs, -sn, sn, cs)
            * Matrix2::new(m, 0.0, 0.0, 1.0)
            * Matrix2::new(s, shear * s, 0.0, -s * 1.003);
        let t = Vector2::from(centre_mm) - a * Vector2::new(w / 2.0, h / 2.0);
        InteriorOrientation::affine(&a, &t).unwrap()
    }

    /// Marks as Gaussian blobs (σ in mm) at known fiducial coordinates on a grey
    /// background, rendered into a scan through its interior orientation.
    fn render_scan(w: usize, h: usize, io: &InteriorOrientation, marks: &[[f64; 2]]) -> GreyImage {
        let sigma = 0.25;
        GreyImage::from_fn(w, h, |x, y| {
            let mm = io.pixel_to_mm(Vector2::new(x, y));
            40.0 + marks
                .iter()
                .map(|m| {
                    let d2 = (mm.x - m[0]).powi(2) + (mm.y - m[1]).powi(2);
                    180.0 * (-d2 / (2.0 * sigma * sigma)).exp()
                })
                .sum::<f64>()
        })
    }

    /// Background-subtracted centroid of the grey values within `r` px of `p`.
    fn centroid(img: &GreyImage, p: [f64; 2], r: f64) -> [f64; 2] {
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        let (c0, r0) = ((p[0] - r).floor() as usize, (p[1] - r).floor() as usize);
        for row in r0..=(p[1] + r).ceil() as usize {
            for col in c0..=(p[0] + r).ceil() as usize {
                let (x, y) = (col as f64 + 0.5, row as f64 + 0.5);
                if (x - p[0]).hypot(y - p[1]) > r {
                    continue;
                }
                let v = (img.at(col, row) as f64 - 40.0).max(0.0);
                sx += v * x;
                sy += v * y;
                s += v;
            }
        }
        [sx / s, sy / s]
    }

    #[test]
    fn a_mark_lands_at_its_predicted_frame_pixel_under_rotation_shear_and_offset() {
        // A 0.1 mm scan of a 40 × 30 mm format, turned 23° with 0.4 % shear and 0.3 %
        // scale difference, the frame centre off the scan centre, upright and mirrored;
        // resampled at 0.08 mm (finer than the scan).
        let marks = [[0.0, 0.0], [-14.3, 9.7], [15.1, -11.2], [6.55, 12.05]];
        for mirror in [false, true] {
            let io = affine((600.0, 560.0), 0.1, 23.0, 0.004, [1.3, -0.9], mirror);
            let scan = render_scan(600, 560, &io, &marks);
            let frame = FiducialFrame::new([40.0, 30.0], 0.08).unwrap();
            assert_eq!((frame.width, frame.height), (500, 375));
            let (img, masked) = resample_scan(&scan, &io, &frame).unwrap();
            assert_eq!(masked, 0, "the scan covers the format");
            for m in marks {
                let want = frame.mm_to_pixel(m);
                let got = centroid(&img, want, 12.0);
                let err = (got[0] - want[0]).hypot(got[1] - want[1]);
                assert!(
                    err < 0.05,
                    "mirror {mirror}: mark at {m:?} mm: {got:?} vs predicted {want:?} ({err:.4} px)"
                );
            }
        }
    }

    #[test]
    fn what_the_scan_does_not_cover_is_masked() {
        // The scan's pixel centres span x_mm −10.025 + 0.05 … and y_mm ±9.95; the
        // 30 × 19 mm format sticks out by about 5 mm left and right. Samples exist inside
        // the pixel-centre hull: frame columns c with 0.5 ≤ c + 0.5 − 49.75 ≤ 199.5, i.e.
        // 50..=248; the other 101 columns of all 190 rows are masked.
        let io = InteriorOrientation::new(
            InteriorTransformKind::Affine,
            Matrix3::new(0.1, 0.0, -10.025, 0.0, -0.1, 10.0, 0.0, 0.0, 1.0),
        )
        .unwrap();
        let scan = GreyImage::filled(200, 200, 100.0);
        let frame = FiducialFrame::new([30.0, 19.0], 0.1).unwrap();
        assert_eq!((frame.width, frame.height), (300, 190));
        let (img, masked) = resample_scan(&scan, &io, &frame).unwrap();
        assert_eq!(masked, 101 * 190);
        for r in [0, 95, 189] {
            assert_eq!(img.at(49, r), MASKED as f32);
            assert_eq!(img.at(249, r), MASKED as f32);
            assert!((img.at(50, r) - 100.0).abs() < 1e-4);
            assert!((img.at(248, r) - 100.0).abs() < 1e-4);
        }
    }

    #[test]
    fn the_frame_camera_projects_where_the_film_camera_does_moved_into_the_frame() {
        let io = affine((11000.0, 11000.0), 0.021, -91.0, 0.002, [0.4, -0.7], false);
        let film = FilmCamera {
            width: 11000,
            height: 11000,
            focal_mm: 152.865,
            principal_point_mm: [-0.03, 0.012],
            distortion: Brown {
                k1: -0.02,
                k2: 0.004,
                k3: -0.0007,
                p1: 2e-5,
                p2: -1e-5,
            },
            interior: io,
        };
        let frame = FiducialFrame::new([230.0, 230.0], 0.025).unwrap();
        assert_eq!((frame.width, frame.height), (9200, 9200));
        let cam = frame.frame_camera(&film);
        assert_eq!(cam.fx, 152.865 / 0.025);
        assert_eq!(cam.cx, 4600.0 - 0.03 / 0.025);
        assert_eq!(cam.cy, 4600.0 - 0.012 / 0.025);
        let mut worst: f64 = 0.0;
        for i in 0..50 {
            let t = i as f64;
            let xc = Vector3::new(
                700.0 * (t * 0.37).sin(),
                650.0 * (t * 0.91).cos(),
                1500.0 + 20.0 * t,
            );
            let (a, b) = frame_pixel_of(&frame, &film, &xc);
            worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
        }
        assert!(worst < 1e-7, "frame camera vs film camera: {worst} px");
    }

    #[test]
    fn implausible_frames_are_refused() {
        assert!(FiducialFrame::new([230.0, 230.0], 0.0).is_err());
        assert!(FiducialFrame::new([230.0, 230.0], 0.5).is_err()); // 500 µm
        assert!(FiducialFrame::new([f64::NAN, 230.0], 0.02).is_err());
        assert!(FiducialFrame::new([-1.0, 230.0], 0.02).is_err());
        // A unit mistake (format in µm) would make 10¹⁰ pixels: refused before anything.
        let e = FiducialFrame::new([230_000.0, 230_000.0], 0.02).unwrap_err();
        assert!(e.to_string().contains("exceeds"), "{e}");
    }
}
