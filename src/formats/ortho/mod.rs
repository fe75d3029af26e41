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
//! The raster is computed and written tile by tile (windowed writing), so only one tile is
//! in memory; a tile is rendered from the photos whose ground footprint meets it, decoded
//! on demand through a cache bounded in bytes, with tiles visited along a Hilbert curve
//! ([`tiles`]), so memory does not grow with the number of photos. Cells are independent,
//! so a tile is filled in parallel with identical results. Outputs: tiled, DEFLATE, alpha
//! band, nodata on the colour bands, overviews, or a cloud-optimised GeoTIFF; written
//! atomically.

mod images;
#[doc(hidden)]
pub mod tiles;

pub use images::{PhotoImages, RgbImage};

use super::crs::Crs;
use super::{write_atomically, FormatError, Result};
use crate::block::{Block, PhotoId};
use crate::formats::gdal::{Driver, GdalError};
use crate::geometry::{Camera, Dem, GeoTransform};
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Largest orthophoto (pixels): 2³² (65 536² px, e.g. 6.5 km square at 10 cm). A gsd far
/// below the photos' ground pixel over a large extent is refused before anything is made.
pub const MAX_ORTHO_PIXELS: u64 = 1 << 32;

pub use crate::cache::DEFAULT_IMAGE_CACHE_BYTES;

/// Options of orthophoto production.
#[derive(Debug, Clone)]
pub struct OrthoOptions {
    /// Ground sampling distance (m); `None`: the median ground pixel size of the photos.
    pub gsd: Option<f64>,
    /// World extent `(x_min, y_min, x_max, y_max)`; `None`: the DEM's extent.
    pub extent: Option<(f64, f64, f64, f64)>,
    /// A project's raster lattice: the GSD becomes its nearest lattice cell and the grid
    /// starts at its corner, so the orthophoto lines up with the project's other rasters.
    /// `None`: the grid is snapped to multiples of the GSD.
    pub lattice: Option<crate::geometry::Lattice>,
    /// Internal tile size (pixels, multiple of 16); also the unit the writer renders.
    pub tile: usize,
    /// Bytes of decoded photo images kept between tiles (a tile's own photos are held
    /// even beyond it).
    pub image_cache_bytes: u64,
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
            lattice: None,
            tile: 256,
            image_cache_bytes: DEFAULT_IMAGE_CACHE_BYTES,
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
    /// Photo images decoded (a photo evicted from the cache and needed again counts again).
    pub image_loads: usize,
    /// Most bytes of decoded image files alive at once.
    pub peak_image_bytes: u64,
}

/// Colour of cells no photo sees (alpha 0 there); valid pixels are lifted to at least 1,
/// so a reader that ignores the alpha band can still take 0 as empty.
pub const ORTHO_NODATA: u8 = 0;

/// One rendered cell: colour and the index of the view it came from (None: no photo
/// sees it), and whether a nearer photo was skipped because the cell is hidden in it.
type Cell = (Option<([u8; 3], usize)>, bool);

/// A cell's view (index) and pixel in it, before any image is decoded; and the fallback flag.
type Choice = (Option<(usize, Vector2<f64>)>, bool);

struct View<'a> {
    id: PhotoId,
    camera: &'a Camera,
    rotation: nalgebra::Matrix3<f64>,
    /// Projection centre in world coordinates.
    center: Vector3<f64>,
    /// Ground box the photo can see ([`tiles::footprint`]); `None`: anywhere.
    footprint: Option<[f64; 4]>,
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

/// The grid of an orthophoto and the views it is rendered from: everything a tile needs
/// but the photos' pixels. Made the same way wherever it is made (a Dask worker renders
/// tiles of the grid the run writes).
pub struct OrthoGrid<'a> {
    views: Vec<View<'a>>,
    dem: &'a Dem,
    gt: GeoTransform,
    pub width: usize,
    pub height: usize,
    pub gsd: f64,
    /// Tile size (pixels): the unit rendered and written.
    pub tile: usize,
    occlusion: bool,
    occlusion_tolerance: f64,
}

/// One rendered tile: its (column, row) among the tiles, its pixels band-sequential (red,
/// green, blue, alpha; each `rows × cols`, row-major) and what it counted.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct RenderedTile {
    pub tile: [usize; 2],
    #[serde(with = "serde_bytes")]
    pub bands: Vec<u8>,
    pub filled: usize,
    pub occluded: usize,
    pub per_photo: BTreeMap<PhotoId, usize>,
}

impl<'a> OrthoGrid<'a> {
    /// The grid of the orthophoto `path` of the block's oriented photos on `dem` (world
    /// coordinates); `images` gives the photos' image sizes (checked against their
    /// cameras). Photos without an image are left out.
    pub fn new(
        path: &Path,
        block: &'a Block,
        dem: &'a Dem,
        images: &PhotoImages,
        opts: &OrthoOptions,
    ) -> Result<Self> {
        let mut views = Vec::new();
        for p in block.photos.values().filter(|p| p.is_oriented()) {
            let Some((iw, ih)) = images.size(p.id)? else {
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
            if (w, h) != (iw, ih) {
                return Err(FormatError::invalid(
                    path,
                    format!(
                        "photo {} ({}): image is {iw}×{ih} but its camera is {w}×{h}",
                        p.id, p.name
                    ),
                ));
            }
            let center = block.to_world(&p.pose.center);
            views.push(View {
                id: p.id,
                camera: cam,
                rotation: p.pose.rotation,
                center,
                footprint: tiles::footprint(cam, &p.pose.rotation, &center, dem.z_range()),
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
        let (gsd, x0, y1) = match &opts.lattice {
            Some(l) => {
                let g = l
                    .grid(l.cell_for(gsd), [x0, y0, x1, y1])
                    .map_err(FormatError::Geometry)?;
                (g.cell, g.x_min, g.y_max)
            }
            // Snap the grid to multiples of the GSD so adjacent products align.
            None => (gsd, (x0 / gsd).floor() * gsd, (y1 / gsd).ceil() * gsd),
        };
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
                format!(
                    "orthophoto of {width}×{height} pixels is empty or implausible (GSD {gsd} m)"
                ),
            ));
        }
        let tile = if opts.tile >= 16 && opts.tile % 16 == 0 {
            opts.tile
        } else {
            256
        };
        Ok(Self {
            views,
            dem,
            gt: GeoTransform::north_up(x0, y1, gsd),
            width,
            height,
            gsd,
            tile,
            occlusion: opts.occlusion,
            occlusion_tolerance: opts.occlusion_tolerance,
        })
    }

    /// The tiles in the order they are rendered and written: along a Hilbert curve, so
    /// consecutive tiles share their photos ([`tiles`]).
    pub fn tiles(&self) -> Vec<[usize; 2]> {
        let (nx, ny) = (
            self.width.div_ceil(self.tile),
            self.height.div_ceil(self.tile),
        );
        tiles::hilbert_order(nx, ny)
            .into_iter()
            .map(|(x, y)| [x, y])
            .collect()
    }

    /// Pixel window `(c0, r0, cols, rows)` of tile `t`.
    fn window(&self, t: [usize; 2]) -> (usize, usize, usize, usize) {
        let (c0, r0) = (t[0] * self.tile, t[1] * self.tile);
        (
            c0,
            r0,
            self.tile.min(self.width - c0),
            self.tile.min(self.height - r0),
        )
    }

    /// The view a cell is taken from, by geometry alone (so only the photos a tile uses
    /// are decoded): the nadir-nearest of `cand` (views whose footprint meets the tile)
    /// that has the cell in its frame and sees it, and the pixel there.
    fn choose_view(&self, col: usize, row: usize, cand: &[usize]) -> Choice {
        let (x, y) = self.gt.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
        let Some(z) = self.dem.height_at(x, y) else {
            return (None, false);
        };
        let g = Vector3::new(x, y, z);
        let mut order: Vec<(f64, usize)> = cand
            .iter()
            .map(|&i| {
                let c = &self.views[i].center;
                ((c.x - x).powi(2) + (c.y - y).powi(2), i)
            })
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut fell_back = false;
        for (_, i) in order {
            let v = &self.views[i];
            let xc = v.rotation * (g - v.center);
            let Ok(px) = v.camera.project(&xc) else {
                continue;
            };
            if !in_frame(v.camera, px) {
                continue;
            }
            if self.occlusion && !visible(self.dem, &g, &v.center, self.occlusion_tolerance) {
                fell_back = true;
                continue;
            }
            return (Some((i, px)), fell_back);
        }
        (None, fell_back)
    }
}

/// Renders tiles of a grid, decoding the photos through one cache bounded in bytes.
pub struct TileRenderer<'a> {
    grid: &'a OrthoGrid<'a>,
    cache: images::ImageCache<'a>,
}

impl<'a> TileRenderer<'a> {
    /// `out` is the product being made (named in errors).
    pub fn new(
        grid: &'a OrthoGrid<'a>,
        images: PhotoImages<'a>,
        cache_bytes: u64,
        out: &'a Path,
    ) -> Self {
        Self {
            grid,
            cache: images::ImageCache::new(images, cache_bytes, out),
        }
    }

    /// Photo images decoded so far (again after eviction counts again).
    pub fn image_loads(&self) -> usize {
        self.cache.loads()
    }

    /// Most bytes of decoded images alive at once so far.
    pub fn peak_image_bytes(&self) -> u64 {
        self.cache.peak_bytes
    }

    /// Renders tile `t`. Cells are independent, so they are filled in parallel with
    /// identical results.
    pub fn render(&mut self, t: [usize; 2]) -> Result<RenderedTile> {
        let g = self.grid;
        let (c0, r0, cols, rows) = g.window(t);
        let (xa, yb) = g.gt.pixel_to_world(c0 as f64, r0 as f64);
        let (xb, ya) = g.gt.pixel_to_world((c0 + cols) as f64, (r0 + rows) as f64);
        let bbox = [xa.min(xb), ya.min(yb), xa.max(xb), ya.max(yb)];
        let cand: Vec<usize> = (0..g.views.len())
            .filter(|&i| {
                g.views[i]
                    .footprint
                    .is_none_or(|f| tiles::overlaps(&f, &bbox))
            })
            .collect();
        let chosen: Vec<Choice> = (0..rows * cols)
            .into_par_iter()
            .map(|k| g.choose_view(c0 + k % cols, r0 + k / cols, &cand))
            .collect();
        let used: Vec<usize> = chosen
            .iter()
            .filter_map(|c| Some(c.0?.0))
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        let ids: Vec<PhotoId> = used.iter().map(|&i| g.views[i].id).collect();
        let held = self.cache.get_all(&ids)?;
        let cells: Vec<Cell> = chosen
            .into_par_iter()
            .map(|(c, fb)| {
                let rgb = c.and_then(|(i, px)| {
                    let k = used.binary_search(&i).ok()?;
                    let rgb = held[k].sample(px.x, px.y)?;
                    Some((
                        rgb.map(|c| (c.round().clamp(0.0, 255.0) as u8).max(ORTHO_NODATA + 1)),
                        i,
                    ))
                });
                (rgb, fb)
            })
            .collect();
        drop(held);
        let n = rows * cols;
        let mut out = RenderedTile {
            tile: t,
            bands: vec![0u8; 4 * n],
            filled: 0,
            occluded: 0,
            per_photo: BTreeMap::new(),
        };
        for (k, (c, fb)) in cells.iter().enumerate() {
            out.occluded += *fb as usize;
            if let Some((rgb, i)) = c {
                out.bands[k] = rgb[0];
                out.bands[n + k] = rgb[1];
                out.bands[2 * n + k] = rgb[2];
                out.bands[3 * n + k] = 255;
                out.filled += 1;
                *out.per_photo.entry(g.views[*i].id).or_default() += 1;
            }
        }
        Ok(out)
    }
}

/// Orthorectifies the block's photos onto `dem` (world coordinates in `crs`) and writes an
/// RGB + alpha GeoTIFF. `images` gives the photos' pixels by photo id; photos without an
/// image or without an oriented pose are skipped.
pub fn write_orthophoto(
    path: &Path,
    block: &Block,
    dem: &Dem,
    images: PhotoImages,
    crs: &Crs,
    opts: &OrthoOptions,
) -> Result<OrthoReport> {
    let grid = OrthoGrid::new(path, block, dem, &images, opts)?;
    let mut renderer = TileRenderer::new(&grid, images, opts.image_cache_bytes, path);
    let order = grid.tiles();
    let mut report = write_tiles(path, &grid, crs, opts, |k| renderer.render(order[k]))?;
    report.image_loads = renderer.image_loads();
    report.peak_image_bytes = renderer.peak_image_bytes();
    Ok(report)
}

/// Writes the orthophoto of `grid` as an RGB + alpha GeoTIFF (atomically) from its tiles,
/// `tile(k)` giving the k-th of [`OrthoGrid::tiles`]: rendered here or elsewhere, only
/// one is held at a time. The report's image counts are the renderer's (zero here).
/// The temporary files a killed writer of `path` left beside it are removed first
/// ([`super::remove_dead_temporaries`]).
pub fn write_tiles(
    path: &Path,
    grid: &OrthoGrid,
    crs: &Crs,
    opts: &OrthoOptions,
    mut tile: impl FnMut(usize) -> Result<RenderedTile>,
) -> Result<OrthoReport> {
    let (width, height, gsd, gt) = (grid.width, grid.height, grid.gsd, grid.gt);
    let order = grid.tiles();
    // What a killed writer of this orthophoto left (its temporary GeoTIFF, the COG's
    // scratch file, GDAL's files beside them) goes now; a live writer's stays.
    if let Err(e) = super::remove_dead_temporaries(path) {
        tracing::warn!(path = %path.display(), "temporary files of a killed writer not removed: {e}");
    }
    let report = write_atomically(path, |tmp| {
        let err = |e: GdalError| FormatError::gdal(path, e);
        let driver = Driver::by_name("GTiff").map_err(err)?;
        // A COG is made by copying a plain tiled GeoTIFF; write that to a scratch file.
        let scratch = tmp.with_extension("scratch.tif");
        let target = if opts.cog { scratch.as_path() } else { tmp };
        let block_size = grid.tile;
        let mut co = vec![
            "TILED=YES".to_string(),
            format!("BLOCKXSIZE={block_size}"),
            format!("BLOCKYSIZE={block_size}"),
            "COMPRESS=DEFLATE".into(),
            "PHOTOMETRIC=RGB".into(),
            "ALPHA=YES".into(),
            "BIGTIFF=IF_SAFER".into(),
        ];
        if opts.cog {
            co.retain(|s| !s.starts_with("COMPRESS"));
        }
        let result = (|| -> Result<OrthoReport> {
            let mut ds = driver
                .create::<u8>(target, (width, height), 4, &co)
                .map_err(err)?;
            ds.set_geo_transform(&gt.0).map_err(err)?;
            ds.set_spatial_ref(crs.spatial_ref()).map_err(err)?;
            // The alpha band is the mask. No nodata value: a GeoTIFF holds one for all
            // bands, so it would mark the alpha band's 0 (transparent) as missing too, and
            // readers that honour both (QGIS, rasterio's masks) would disagree.
            ds.rasterband(4).map_err(err)?.set_alpha().map_err(err)?;
            let mut filled = 0usize;
            let mut occluded = 0usize;
            let mut per_photo: BTreeMap<PhotoId, usize> = BTreeMap::new();
            for (k, &t) in order.iter().enumerate() {
                let r = tile(k)?;
                let (c0, r0, cols, rows) = grid.window(t);
                let n = rows * cols;
                if r.tile != t || r.bands.len() != 4 * n {
                    return Err(FormatError::invalid(
                        path,
                        format!(
                            "tile {k}: got tile {:?} of {} bytes, expected {t:?} of {}",
                            r.tile,
                            r.bands.len(),
                            4 * n
                        ),
                    ));
                }
                filled += r.filled;
                occluded += r.occluded;
                for (id, c) in &r.per_photo {
                    *per_photo.entry(*id).or_default() += c;
                }
                for (b, data) in r.bands.chunks_exact(n).enumerate() {
                    ds.rasterband(b + 1)
                        .map_err(err)?
                        .write((c0, r0), (cols, rows), data)
                        .map_err(err)?;
                }
                tracing::debug!(tile = k + 1, of = order.len(), "orthophoto tile written");
            }
            let mut levels = opts.overviews.clone();
            if opts.cog && levels.is_empty() {
                levels = vec![2, 4, 8, 16];
            }
            // Overviews smaller than a tile are useless; keep those that still have detail.
            levels.retain(|&l| l > 1 && width.max(height) / l as usize >= 16);
            if !levels.is_empty() && !opts.cog {
                ds.build_overviews("AVERAGE", &levels).map_err(err)?;
            }
            if opts.cog {
                let cog = Driver::by_name("COG").map_err(err)?;
                let cog_co = [
                    "COMPRESS=DEFLATE".to_string(),
                    "RESAMPLING=AVERAGE".into(),
                    "OVERVIEWS=IGNORE_EXISTING".into(),
                    format!("BLOCKSIZE={block_size}"),
                ];
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
                image_loads: 0,
                peak_image_bytes: 0,
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

/// Whether a pixel position lies in the camera's frame (where [`RgbImage::sample`] has a value).
fn in_frame(camera: &Camera, px: Vector2<f64>) -> bool {
    let (w, h) = camera.image_size();
    px.x >= 0.0 && px.y >= 0.0 && px.x <= w as f64 && px.y <= h as f64
}

/// A PNG preview of an orthophoto GeoTIFF (RGB + alpha, longest side ≤ `max_side`
/// pixels, read through GDAL's overview-aware downsampling) and its world extent
/// `[x_min, y_min, x_max, y_max]`: the background of the report's control-point map.
pub fn preview(path: &Path, max_side: usize) -> Result<(Vec<u8>, [f64; 4])> {
    use image::ImageEncoder;
    let err = |e: GdalError| FormatError::gdal(path, e);
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
        let data = band.read::<u8>((0, 0), (w, h), (pw, ph)).map_err(err)?;
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
