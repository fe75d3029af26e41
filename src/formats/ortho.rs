//! True orthophotos of oriented photos on a DEM, written as RGB + alpha GeoTIFF.
//!
//! Per ground cell: height from the DEM (bilinear), so relief displacement is removed;
//! the photos are tried in order of nadir distance (horizontal distance from the cell to
//! the projection centre), which puts the seamlines on the Voronoi edges between nadir
//! points, where relief displacement and view angle are smallest; a photo is used only if
//! the cell is inside its frame and visible — the ray from the cell to the projection
//! centre is marched over the DEM in half-cell steps and must not pass below the surface
//! (occlusion test by ray–DEM intersection). A cell no photo sees is transparent.
//!
//! The raster is computed and written in strips of whole tiles (windowed writing), so
//! only one strip is in memory; cells are independent, so strips are filled in parallel
//! with identical results. Outputs: tiled, DEFLATE, alpha band, nodata on the colour
//! bands, overviews, or a cloud-optimised GeoTIFF; written atomically.

use super::crs::Crs;
use super::{write_atomically, FormatError, Result};
use crate::block::{Block, PhotoId};
use crate::geometry::{Camera, Dem, GeoTransform};
use gdal::raster::{Buffer, ColorInterpretation, RasterCreationOptions};
use gdal::DriverManager;
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

/// An 8-bit RGB photo in memory, row-major; pixel (c, r) has its centre at (c+½, r+½).
#[derive(Debug, Clone)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl RgbImage {
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> std::result::Result<Self, String> {
        if data.len() != width as usize * height as usize * 3 {
            return Err(format!(
                "RGB image {width}×{height} needs {} bytes, got {}",
                width as usize * height as usize * 3,
                data.len()
            ));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Loads any format the `image` crate decodes (TIFF, PNG, JPEG), converted to RGB8.
    pub fn load(path: &Path) -> Result<Self> {
        let img = super::image_open::decode_image(path)?.to_rgb8();
        let (w, h) = img.dimensions();
        Ok(Self {
            width: w,
            height: h,
            data: img.into_raw(),
        })
    }

    /// Bilinear sample at a pixel position (our corner-origin convention).
    pub fn sample(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let (fx, fy) = (x - 0.5, y - 0.5);
        if !(fx >= -0.5 && fy >= -0.5 && x <= self.width as f64 && y <= self.height as f64) {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let fx = fx.clamp(0.0, (w - 1) as f64);
        let fy = fy.clamp(0.0, (h - 1) as f64);
        let (c0, r0) = (fx.floor() as usize, fy.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(w - 1), (r0 + 1).min(h - 1));
        let (u, v) = (fx - c0 as f64, fy - r0 as f64);
        let px = |c: usize, r: usize, k: usize| self.data[(r * w + c) * 3 + k] as f64;
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            *o = (1.0 - v) * ((1.0 - u) * px(c0, r0, k) + u * px(c1, r0, k))
                + v * ((1.0 - u) * px(c0, r1, k) + u * px(c1, r1, k));
        }
        Some(out)
    }
}

/// Largest orthophoto (pixels): 2³² (65 536² px, e.g. 6.5 km square at 10 cm). A gsd far
/// below the photos' ground pixel over a large extent is refused before anything is made.
pub const MAX_ORTHO_PIXELS: u64 = 1 << 32;

/// Options of orthophoto production.
#[derive(Debug, Clone)]
pub struct OrthoOptions {
    /// Ground sampling distance (m); `None`: the median ground pixel size of the photos.
    pub gsd: Option<f64>,
    /// World extent `(x_min, y_min, x_max, y_max)`; `None`: the DEM's extent.
    pub extent: Option<(f64, f64, f64, f64)>,
    /// Internal tile size (pixels, multiple of 16); also the strip height of the writer.
    pub tile: usize,
    /// Overview factors (e.g. [2, 4, 8]); empty for none. A COG always gets overviews.
    pub overviews: Vec<i32>,
    /// Write a cloud-optimised GeoTIFF (GDAL's COG driver).
    pub cog: bool,
    /// Test visibility by marching the ray over the DEM (off: plain rectification).
    pub occlusion: bool,
    /// Tolerance of the occlusion test (m): the ray may dip this far below the DEM.
    pub occlusion_tolerance: f64,
}

impl Default for OrthoOptions {
    fn default() -> Self {
        Self {
            gsd: None,
            extent: None,
            tile: 256,
            overviews: vec![2, 4, 8, 16],
            cog: false,
            occlusion: true,
            occlusion_tolerance: 0.05,
        }
    }
}

/// What was produced.
#[derive(Debug, Clone, serde::Serialize)]
pub struct OrthoReport {
    pub width: usize,
    pub height: usize,
    pub gsd: f64,
    pub geotransform: [f64; 6],
    /// Cells filled from a photo.
    pub filled: usize,
    /// Cells where the nadir-nearest photo containing the cell could not see it.
    pub occluded_fallbacks: usize,
    /// Filled cells per photo.
    pub per_photo: BTreeMap<PhotoId, usize>,
}

/// No-data value of the colour bands; valid pixels are lifted to at least 1.
pub const ORTHO_NODATA: u8 = 0;

/// One rendered cell: colour and the index of the view it came from (None: no photo
/// sees it), and whether a nearer photo was skipped because the cell is hidden in it.
type Cell = (Option<([u8; 3], usize)>, bool);

struct View<'a> {
    id: PhotoId,
    camera: &'a Camera,
    rotation: nalgebra::Matrix3<f64>,
    /// Projection centre in world coordinates.
    center: Vector3<f64>,
    image: &'a RgbImage,
}

/// Median ground pixel size of the photos over the DEM's mean height.
pub fn default_gsd(block: &Block, dem: &Dem) -> Option<f64> {
    let (z0, z1) = dem.z_range();
    let zm = 0.5 * (z0 + z1);
    let mut v: Vec<f64> = block
        .photos
        .values()
        .filter_map(|p| {
            let cam = &block.cameras.get(&p.camera)?.model;
            let h = block.to_world(&p.pose.center).z - zm;
            (h > 0.0).then(|| h / cam.focal_px())
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// True when the segment from ground point `g` towards the camera `c` stays above the DEM.
fn visible(dem: &Dem, g: &Vector3<f64>, c: &Vector3<f64>, tol: f64) -> bool {
    let d = c - g;
    let horizontal = (d.x * d.x + d.y * d.y).sqrt();
    let z_top = dem.z_range().1;
    if horizontal < 1e-9 || d.z <= 0.0 {
        return d.z > 0.0;
    }
    // Only the part of the ray below the highest terrain can be blocked.
    let t_end = ((z_top - g.z) / d.z).clamp(0.0, 1.0);
    let step = 0.5 * dem.cell_size() / horizontal;
    // Start one step away so the cell's own surface does not occlude it.
    let mut t = step;
    while t < t_end {
        let p = g + d * t;
        if let Some(h) = dem.height_at(p.x, p.y) {
            if p.z < h - tol {
                return false;
            }
        }
        t += step;
    }
    true
}

/// Orthorectifies the block's photos onto `dem` (world coordinates in `crs`) and writes an
/// RGB + alpha GeoTIFF. `images` holds the photos' pixels by photo id; photos without an
/// image or without an oriented pose are skipped.
pub fn write_orthophoto(
    path: &Path,
    block: &Block,
    dem: &Dem,
    images: &BTreeMap<PhotoId, RgbImage>,
    crs: &Crs,
    opts: &OrthoOptions,
) -> Result<OrthoReport> {
    let mut views = Vec::new();
    for p in block.photos.values().filter(|p| p.is_oriented()) {
        let Some(image) = images.get(&p.id) else {
            continue;
        };
        let cam = &block
            .cameras
            .get(&p.camera)
            .ok_or_else(|| {
                FormatError::invalid(
                    path,
                    format!("photo {} has unknown camera {}", p.id, p.camera),
                )
            })?
            .model;
        let (w, h) = cam.image_size();
        if (w, h) != (image.width, image.height) {
            return Err(FormatError::invalid(
                path,
                format!(
                    "photo {} ({}): image is {}×{} but its camera is {w}×{h}",
                    p.id, p.name, image.width, image.height
                ),
            ));
        }
        views.push(View {
            id: p.id,
            camera: cam,
            rotation: p.pose.rotation,
            center: block.to_world(&p.pose.center),
            image,
        });
    }
    if views.is_empty() {
        return Err(FormatError::invalid(
            path,
            "no oriented photo with an image to orthorectify",
        ));
    }
    let gsd = match opts.gsd {
        Some(g) => g,
        None => default_gsd(block, dem).ok_or_else(|| {
            FormatError::invalid(path, "cannot derive a ground sampling distance; give one")
        })?,
    };
    if !(gsd.is_finite() && gsd > 0.0) {
        return Err(FormatError::invalid(
            path,
            format!("ground sampling distance {gsd} is not positive"),
        ));
    }
    let (x0, y0, x1, y1) = opts.extent.unwrap_or_else(|| dem.extent());
    // Snap the grid to multiples of the GSD so adjacent products align.
    let (x0, y1) = ((x0 / gsd).floor() * gsd, (y1 / gsd).ceil() * gsd);
    let (w, h) = (((x1 - x0) / gsd).ceil(), ((y1 - y0) / gsd).ceil());
    if w * h > MAX_ORTHO_PIXELS as f64 {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!(
                "orthophoto of {w}×{h} pixels (gsd {gsd} m over {:.1}×{:.1} m)",
                x1 - x0,
                y1 - y0
            ),
            claimed: (w * h).min(u64::MAX as f64) as u64,
            limit: MAX_ORTHO_PIXELS,
            basis: "the pixels an orthophoto may have; raise the gsd or give a smaller extent"
                .into(),
        });
    }
    let (width, height) = (w as usize, h as usize);
    if width == 0 || height == 0 || width > 1 << 20 || height > 1 << 20 {
        return Err(FormatError::invalid(
            path,
            format!("orthophoto of {width}×{height} pixels is empty or implausible (GSD {gsd} m)"),
        ));
    }
    let gt = GeoTransform::north_up(x0, y1, gsd);
    let tile = if opts.tile >= 16 && opts.tile % 16 == 0 {
        opts.tile
    } else {
        256
    };

    let render_cell = |col: usize, row: usize| -> Cell {
        let (x, y) = gt.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
        let Some(z) = dem.height_at(x, y) else {
            return (None, false);
        };
        let g = Vector3::new(x, y, z);
        let mut order: Vec<(f64, usize)> = views
            .iter()
            .enumerate()
            .map(|(i, v)| (((v.center.x - x).powi(2) + (v.center.y - y).powi(2)), i))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut fell_back = false;
        for (_, i) in order {
            let v = &views[i];
            let xc = v.rotation * (g - v.center);
            let Ok(px) = v.camera.project(&xc) else {
                continue;
            };
            let Some(rgb) = inside(v.image, px) else {
                continue;
            };
            if opts.occlusion && !visible(dem, &g, &v.center, opts.occlusion_tolerance) {
                fell_back = true;
                continue;
            }
            let c = rgb.map(|c| (c.round().clamp(0.0, 255.0) as u8).max(ORTHO_NODATA + 1));
            return (Some((c, i)), fell_back);
        }
        (None, fell_back)
    };

    let report = write_atomically(path, |tmp| {
        let err = |e: gdal::errors::GdalError| FormatError::gdal(path, e);
        let driver = DriverManager::get_driver_by_name("GTiff").map_err(err)?;
        // A COG is made by copying a plain tiled GeoTIFF; write that to a scratch file.
        let scratch = tmp.with_extension("scratch.tif");
        let target = if opts.cog { scratch.as_path() } else { tmp };
        let mut co = vec![
            "TILED=YES".to_string(),
            format!("BLOCKXSIZE={tile}"),
            format!("BLOCKYSIZE={tile}"),
            "COMPRESS=DEFLATE".into(),
            "PHOTOMETRIC=RGB".into(),
            "ALPHA=YES".into(),
            "BIGTIFF=IF_SAFER".into(),
        ];
        if opts.cog {
            co.retain(|s| !s.starts_with("COMPRESS"));
        }
        let co = RasterCreationOptions::from_iter(co.iter().map(|s| s.as_str()));
        let result = (|| -> Result<OrthoReport> {
            let mut ds = driver
                .create_with_band_type_with_options::<u8, _>(target, width, height, 4, &co)
                .map_err(err)?;
            ds.set_geo_transform(&gt.0).map_err(err)?;
            ds.set_spatial_ref(crs.spatial_ref()).map_err(err)?;
            for b in 1..=3 {
                ds.rasterband(b)
                    .map_err(err)?
                    .set_no_data_value(Some(ORTHO_NODATA as f64))
                    .map_err(err)?;
            }
            ds.rasterband(4)
                .map_err(err)?
                .set_color_interpretation(ColorInterpretation::AlphaBand)
                .map_err(err)?;
            let mut filled = 0usize;
            let mut occluded = 0usize;
            let mut per_photo: BTreeMap<PhotoId, usize> = BTreeMap::new();
            for r0 in (0..height).step_by(tile) {
                let rows = tile.min(height - r0);
                let cells: Vec<Cell> = (0..rows * width)
                    .into_par_iter()
                    .map(|k| render_cell(k % width, r0 + k / width))
                    .collect();
                let mut bands = vec![vec![0u8; rows * width]; 4];
                for (k, (c, fb)) in cells.iter().enumerate() {
                    occluded += *fb as usize;
                    if let Some((rgb, i)) = c {
                        bands[0][k] = rgb[0];
                        bands[1][k] = rgb[1];
                        bands[2][k] = rgb[2];
                        bands[3][k] = 255;
                        filled += 1;
                        *per_photo.entry(views[*i].id).or_default() += 1;
                    }
                }
                for (b, data) in bands.into_iter().enumerate() {
                    let mut buf = Buffer::new((width, rows), data);
                    ds.rasterband(b + 1)
                        .map_err(err)?
                        .write((0, r0 as isize), (width, rows), &mut buf)
                        .map_err(err)?;
                }
                tracing::debug!(row = r0, of = height, "orthophoto strip written");
            }
            let mut levels = opts.overviews.clone();
            if opts.cog && levels.is_empty() {
                levels = vec![2, 4, 8, 16];
            }
            // Overviews smaller than a tile are useless; keep those that still have detail.
            levels.retain(|&l| l > 1 && width.max(height) / l as usize >= 16);
            if !levels.is_empty() && !opts.cog {
                ds.build_overviews("AVERAGE", &levels, &[]).map_err(err)?;
            }
            if opts.cog {
                let cog = DriverManager::get_driver_by_name("COG").map_err(err)?;
                let cog_co = RasterCreationOptions::from_iter([
                    "COMPRESS=DEFLATE",
                    "RESAMPLING=AVERAGE",
                    "OVERVIEWS=IGNORE_EXISTING",
                    &format!("BLOCKSIZE={tile}"),
                ]);
                ds.flush_cache().map_err(err)?;
                ds.create_copy(&cog, tmp, &cog_co).map_err(err)?;
            } else {
                ds.flush_cache().map_err(err)?;
            }
            Ok(OrthoReport {
                width,
                height,
                gsd,
                geotransform: gt.0,
                filled,
                occluded_fallbacks: occluded,
                per_photo,
            })
        })();
        if opts.cog {
            let _ = std::fs::remove_file(&scratch);
        }
        result
    })?;
    tracing::info!(path = %path.display(), width, height, gsd, filled = report.filled, "wrote orthophoto");
    Ok(report)
}

fn inside(image: &RgbImage, px: Vector2<f64>) -> Option<[f64; 3]> {
    if px.x >= 0.0 && px.y >= 0.0 && px.x <= image.width as f64 && px.y <= image.height as f64 {
        image.sample(px.x, px.y)
    } else {
        None
    }
}

/// A PNG preview of an orthophoto GeoTIFF (RGB + alpha, longest side ≤ `max_side`
/// pixels, read through GDAL's overview-aware downsampling) and its world extent
/// `[x_min, y_min, x_max, y_max]`: the background of the report's control-point map.
pub fn preview(path: &Path, max_side: usize) -> Result<(Vec<u8>, [f64; 4])> {
    use image::ImageEncoder;
    let err = |e: gdal::errors::GdalError| FormatError::gdal(path, e);
    let ds = super::image_open::open_raster(path)?;
    let (w, h) = ds.raster_size();
    let gt = ds.geo_transform().map_err(err)?;
    if w == 0 || h == 0 || gt[2] != 0.0 || gt[4] != 0.0 {
        return Err(FormatError::invalid(
            path,
            "empty or rotated raster; no preview",
        ));
    }
    let f = (w.max(h) as f64 / max_side.max(1) as f64).max(1.0);
    let (pw, ph) = (
        ((w as f64 / f).round() as usize).max(1),
        ((h as f64 / f).round() as usize).max(1),
    );
    let bands = ds.raster_count();
    let mut rgba = vec![255u8; pw * ph * 4];
    for b in 1..=bands.min(4) {
        let band = ds.rasterband(b).map_err(err)?;
        let buf = band
            .read_as::<u8>((0, 0), (w, h), (pw, ph), None)
            .map_err(err)?;
        let (_, data) = buf.into_shape_and_vec();
        // Grey orthophotos fill R, G and B from their one band.
        let targets: &[usize] = if bands == 1 { &[0, 1, 2] } else { &[b - 1] };
        for (i, v) in data.iter().enumerate() {
            for &c in targets {
                rgba[4 * i + c] = *v;
            }
        }
    }
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&rgba, pw as u32, ph as u32, image::ExtendedColorType::Rgba8)
        .map_err(|e| FormatError::invalid(path, format!("preview PNG: {e}")))?;
    let x0 = gt[0];
    let y1 = gt[3];
    let x1 = x0 + gt[1] * w as f64;
    let y0 = y1 + gt[5] * h as f64;
    Ok((png, [x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1)]))
}
