//! GeoTIFF rasters through GDAL: DEMs (float32 with nodata) with CRS and geotransform.
//! Outputs are tiled, written to a temporary file and renamed, so a crash never leaves a
//! half-written GeoTIFF behind.

use super::crs::Crs;
use super::gdal::{self, DataType, Dataset, Driver};
use super::{image_open, write_atomically, FormatError, Result};
use crate::geometry::{Dem, GeoTransform};
use std::path::Path;

/// No-data value written for DEM holes (NaN inside [`Dem`]).
pub const DEM_NODATA: f32 = -9999.0;

/// Options of GeoTIFF outputs.
#[derive(Debug, Clone)]
pub struct GeoTiffOptions {
    /// Internal tile size (pixels); GDAL's default strips are slow for windowed reads.
    pub tile: usize,
    pub compress: &'static str,
    /// Overview factors to build (e.g. [2, 4, 8]); empty for none.
    pub overviews: Vec<i32>,
}

impl Default for GeoTiffOptions {
    fn default() -> Self {
        Self {
            tile: 256,
            compress: "DEFLATE",
            overviews: Vec::new(),
        }
    }
}

fn creation_options(opts: &GeoTiffOptions, width: usize, height: usize) -> Vec<String> {
    let mut list = vec![
        format!("COMPRESS={}", opts.compress),
        "BIGTIFF=IF_SAFER".to_string(),
    ];
    // Tiles larger than the raster are legal but wasteful; GDAL needs multiples of 16.
    if width >= opts.tile && height >= opts.tile && opts.tile % 16 == 0 {
        list.push("TILED=YES".into());
        list.push(format!("BLOCKXSIZE={}", opts.tile));
        list.push(format!("BLOCKYSIZE={}", opts.tile));
    }
    list
}

/// Writes a DEM as a float32 Cloud-Optimised GeoTIFF (GDAL's COG driver: tiled,
/// DEFLATE with the floating-point predictor, overviews by nodata-aware averaging where
/// the raster is larger than a tile, the IFDs before the data) with CRS, geotransform and
/// nodata; `opts.overviews` when given are the overview levels. Built in memory first:
/// the COG driver writes by copying a whole dataset.
pub fn write_dem(path: &Path, dem: &Dem, crs: &Crs, opts: &GeoTiffOptions) -> Result<()> {
    write_atomically(path, |tmp| {
        let err = |e| FormatError::gdal(path, e);
        let mem = Driver::by_name("MEM").map_err(err)?;
        let mut ds = mem
            .create::<f32>(Path::new(""), (dem.width, dem.height), 1, &[] as &[&str])
            .map_err(err)?;
        ds.set_geo_transform(&dem.transform.0).map_err(err)?;
        ds.set_spatial_ref(crs.spatial_ref()).map_err(err)?;
        {
            let mut band = ds.rasterband(1).map_err(err)?;
            band.set_no_data_value(DEM_NODATA as f64).map_err(err)?;
            let data: Vec<f32> = dem
                .data
                .iter()
                .map(|&v| if v.is_finite() { v } else { DEM_NODATA })
                .collect();
            band.write((0, 0), (dem.width, dem.height), &data)
                .map_err(err)?;
        }
        // Overview levels asked for are built here and kept; else the driver's own (halving
        // until the raster fits a tile).
        let overviews = if opts.overviews.is_empty() {
            "OVERVIEWS=AUTO"
        } else {
            ds.build_overviews("AVERAGE", &opts.overviews)
                .map_err(err)?;
            "OVERVIEWS=FORCE_USE_EXISTING"
        };
        let cog = Driver::by_name("COG").map_err(err)?;
        let co = [
            format!("COMPRESS={}", opts.compress),
            "PREDICTOR=YES".into(),
            format!("BLOCKSIZE={}", opts.tile),
            "RESAMPLING=AVERAGE".into(),
            overviews.into(),
            "BIGTIFF=IF_SAFER".into(),
        ];
        ds.create_copy(&cog, tmp, &co).map_err(err)?;
        Ok(())
    })
}

/// Writes an 8-bit single-band image (row-major `data`) as a GeoTIFF with CRS and
/// geotransform: a greyscale orthophoto.
pub fn write_grey(
    path: &Path,
    (width, height): (usize, usize),
    data: Vec<u8>,
    transform: &GeoTransform,
    crs: &Crs,
    opts: &GeoTiffOptions,
) -> Result<()> {
    if data.len() != width * height {
        return Err(FormatError::invalid(
            path,
            format!("{} pixels for a {width}×{height} image", data.len()),
        ));
    }
    write_atomically(path, |tmp| {
        let driver = Driver::by_name("GTiff").map_err(|e| FormatError::gdal(path, e))?;
        let co = creation_options(opts, width, height);
        let mut ds = driver
            .create::<u8>(tmp, (width, height), 1, &co)
            .map_err(|e| FormatError::gdal(path, e))?;
        ds.set_geo_transform(&transform.0)
            .map_err(|e| FormatError::gdal(path, e))?;
        ds.set_spatial_ref(crs.spatial_ref())
            .map_err(|e| FormatError::gdal(path, e))?;
        {
            let mut band = ds.rasterband(1).map_err(|e| FormatError::gdal(path, e))?;
            band.write((0, 0), (width, height), &data)
                .map_err(|e| FormatError::gdal(path, e))?;
        }
        ds.flush_cache().map_err(|e| FormatError::gdal(path, e))?;
        drop(ds);
        Ok(())
    })
}

/// Reprojects the raster at `path` (in `source`, which the file may lack: a world file
/// gives none) into `target`, north-up with square `pixel` cells (target units) over the
/// source's whole extent, written as a GeoTIFF at `out`: GDAL's warper (bilinear), with
/// the bands' type and no-data value kept and cells outside the source left no-data
/// (0 for bands without one).
pub fn warp_to(path: &Path, source: &Crs, target: &Crs, pixel: f64, out: &Path) -> Result<()> {
    use super::crs::Transformer;
    let src = image_open::open_raster(path)?;
    let (w, h) = src.raster_size();
    image_open::check_pixels(path, w as u64, h as u64)?;
    let gt = src
        .geo_transform()
        .map_err(|e| FormatError::gdal(path, e))?;
    let bands = src.raster_count();
    let band_type = src
        .rasterband(1)
        .map_err(|e| FormatError::gdal(path, e))?
        .band_type();
    let nodata = src.rasterband(1).ok().and_then(|b| b.no_data_value());
    // An in-memory copy carries the CRS the file may not state.
    let mem = Driver::by_name("MEM").map_err(|e| FormatError::gdal(path, e))?;
    let mut copy = src
        .create_copy(&mem, Path::new(""), &[] as &[&str])
        .map_err(|e| FormatError::gdal(path, e))?;
    drop(src);
    copy.set_spatial_ref(source.spatial_ref())
        .map_err(|e| FormatError::gdal(path, e))?;
    // The target extent: the source's border, sampled densely (projections bend it).
    let t = Transformer::new(source, target)?;
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for k in 0..=64 {
        let f = k as f64 / 64.0;
        for (c, r) in [
            (f * w as f64, 0.0),
            (f * w as f64, h as f64),
            (0.0, f * h as f64),
            (w as f64, f * h as f64),
        ] {
            let p = t.transform_point([
                gt[0] + c * gt[1] + r * gt[2],
                gt[3] + c * gt[4] + r * gt[5],
                0.0,
            ])?;
            (x0, y0, x1, y1) = (x0.min(p[0]), y0.min(p[1]), x1.max(p[0]), y1.max(p[1]));
        }
    }
    if !(pixel > 0.0 && x0 < x1 && y0 < y1) {
        return Err(FormatError::invalid(
            path,
            "its extent does not map into the target CRS",
        ));
    }
    let (tw, th) = (
        ((x1 - x0) / pixel).ceil() as usize,
        ((y1 - y0) / pixel).ceil() as usize,
    );
    image_open::check_pixels(path, tw as u64, th as u64)?;
    write_atomically(out, |tmp| {
        let driver = Driver::by_name("GTiff").map_err(|e| FormatError::gdal(path, e))?;
        let co = creation_options(&GeoTiffOptions::default(), tw, th);
        let mut dst = match band_type {
            DataType::UInt8 => driver.create::<u8>(tmp, (tw, th), bands, &co),
            DataType::UInt16 => driver.create::<u16>(tmp, (tw, th), bands, &co),
            _ => driver.create::<f32>(tmp, (tw, th), bands, &co),
        }
        .map_err(|e| FormatError::gdal(path, e))?;
        dst.set_geo_transform(&[x0, pixel, 0.0, y1, 0.0, -pixel])
            .map_err(|e| FormatError::gdal(path, e))?;
        dst.set_spatial_ref(target.spatial_ref())
            .map_err(|e| FormatError::gdal(path, e))?;
        for b in 1..=bands {
            let mut band = dst.rasterband(b).map_err(|e| FormatError::gdal(path, e))?;
            band.set_no_data_value(nodata.unwrap_or(0.0))
                .map_err(|e| FormatError::gdal(path, e))?;
            band.fill(nodata.unwrap_or(0.0))
                .map_err(|e| FormatError::gdal(path, e))?;
        }
        gdal::reproject(&copy, &mut dst).map_err(|e| FormatError::gdal(path, e))?;
        dst.flush_cache().map_err(|e| FormatError::gdal(path, e))?;
        Ok(())
    })
}

/// Width, height and geotransform of a DEM raster from its header, without reading the
/// heights (the size query of `ccp_dem_read`).
pub fn dem_size(path: &Path) -> Result<(usize, usize, [f64; 6])> {
    let ds = open_dem(path)?;
    let (w, h) = ds.raster_size();
    let gt = ds.geo_transform().map_err(|e| FormatError::gdal(path, e))?;
    Ok((w, h, gt))
}

/// Opens a DEM through [`image_open::open_raster`] and checks its size against
/// [`image_open::MAX_IMAGE_PIXELS`] before any height is read.
fn open_dem(path: &Path) -> Result<Dataset> {
    if !path.exists() {
        return Err(FormatError::invalid(path, "file does not exist"));
    }
    let ds = image_open::open_raster(path)?;
    let (w, h) = ds.raster_size();
    image_open::check_pixels(path, w as u64, h as u64)?;
    Ok(ds)
}

/// Reads a single-band DEM GeoTIFF (any numeric type) with its CRS; nodata becomes NaN.
pub fn read_dem(path: &Path) -> Result<(Dem, Option<Crs>)> {
    let ds = open_dem(path)?;
    let gt = ds.geo_transform().map_err(|e| FormatError::gdal(path, e))?;
    let band = ds.rasterband(1).map_err(|e| FormatError::gdal(path, e))?;
    let (w, h) = ds.raster_size();
    let nodata = band.no_data_value();
    let mut data = Vec::new();
    image_open::read_band_strips(path, &ds, &[1], (0, 0, w, h), |s| {
        data.extend_from_slice(&s[0])
    })?;
    if let Some(nd) = nodata {
        let nd = nd as f32;
        for v in data.iter_mut().filter(|v| **v == nd) {
            *v = f32::NAN;
        }
    }
    let crs = match ds.spatial_ref().map(|srs| srs.to_wkt()) {
        Some(Ok(wkt)) if !wkt.is_empty() => Some(Crs::parse(&wkt)?),
        _ => None,
    };
    let dem = Dem::new(w, h, GeoTransform(gt), data)
        .map_err(|e| FormatError::invalid(path, e.to_string()))?;
    Ok((dem, crs))
}
