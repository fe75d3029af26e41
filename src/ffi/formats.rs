//! C ABI of the format adapters: block conversion (COLMAP ↔ BlocksExchange), orthophoto
//! production and DEM GeoTIFF I/O. Paths are NUL-terminated UTF-8.

use super::{finite, guard, input, output, CcpStatus, FfiError, FfiResult};
use crate::formats::convert::{convert, orthophoto_from_files, ConvertOptions};
use crate::formats::crs::Crs;
use crate::formats::ortho::OrthoOptions;
use crate::formats::raster::{dem_size, read_dem, write_dem, GeoTiffOptions};
use crate::geometry::{Dem, GeoTransform};
use std::ffi::{c_char, CStr};
use std::path::PathBuf;

/// Borrows a NUL-terminated UTF-8 string argument, naming it when null or not UTF-8.
unsafe fn c_str<'a>(p: *const c_char, name: &str) -> FfiResult<&'a str> {
    if p.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            format!("{name} is a null pointer"),
        ));
    }
    CStr::from_ptr(p)
        .to_str()
        .map_err(|_| FfiError::invalid(format!("{name} is not valid UTF-8")))
}

unsafe fn c_path(p: *const c_char, name: &str) -> FfiResult<PathBuf> {
    let s = c_str(p, name)?;
    if s.is_empty() {
        return Err(FfiError::invalid(format!("{name} is empty")));
    }
    Ok(PathBuf::from(s))
}

/// Converts a block: `input` and `output` are a COLMAP model folder or a BlocksExchange
/// `.xml` (by extension). COLMAP output is binary unless `text` ≠ 0, in COLMAP 4's 5-file
/// layout unless `legacy` ≠ 0.
///
/// # Safety
/// Pointer arguments must be null or valid for the lengths given; strings NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn ccp_convert(
    input: *const c_char,
    output: *const c_char,
    text: i32,
    legacy: i32,
) -> CcpStatus {
    guard(|| {
        let (i, o) = (c_path(input, "input")?, c_path(output, "output")?);
        convert(
            &i,
            &o,
            &ConvertOptions {
                text: text != 0,
                legacy: legacy != 0,
            },
        )?;
        Ok(())
    })
}

/// Writes a true orthophoto of the block's oriented photos on a DEM GeoTIFF.
/// `images_dir` is the folder the photo names are relative to; `gsd` ≤ 0 picks the photos'
/// median ground pixel; `cog` ≠ 0 writes a cloud-optimised GeoTIFF. On success
/// `width_out`/`height_out` (either may be null) receive the raster size.
///
/// # Safety
/// Pointer arguments must be null or valid for the lengths given; strings NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn ccp_orthophoto(
    block: *const c_char,
    dem: *const c_char,
    images_dir: *const c_char,
    out: *const c_char,
    gsd: f64,
    cog: i32,
    width_out: *mut usize,
    height_out: *mut usize,
) -> CcpStatus {
    guard(|| {
        finite(&[gsd], "gsd")?;
        let opts = OrthoOptions {
            gsd: (gsd > 0.0).then_some(gsd),
            cog: cog != 0,
            ..Default::default()
        };
        let r = orthophoto_from_files(
            &c_path(block, "block")?,
            &c_path(dem, "dem")?,
            &c_path(images_dir, "images_dir")?,
            &c_path(out, "out")?,
            &opts,
        )?;
        if let Some(w) = width_out.as_mut() {
            *w = r.width;
        }
        if let Some(h) = height_out.as_mut() {
            *h = r.height;
        }
        Ok(())
    })
}

/// Writes a DEM GeoTIFF (float32, tiled, nodata for NaN) from `width × height` row-major
/// heights, a north-up GDAL geotransform `geotransform[6]` and a CRS (`EPSG:n` or WKT).
///
/// # Safety
/// Pointer arguments must be null or valid for the lengths given; strings NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn ccp_dem_write(
    path: *const c_char,
    width: usize,
    height: usize,
    geotransform: *const f64,
    heights: *const f32,
    heights_len: usize,
    crs: *const c_char,
) -> CcpStatus {
    guard(|| {
        let p = c_path(path, "path")?;
        let gt = input(geotransform, 6, "geotransform", false)?;
        finite(gt, "geotransform")?;
        let n = width
            .checked_mul(height)
            .ok_or_else(|| FfiError::invalid("width × height overflows"))?;
        if heights_len != n {
            return Err(FfiError::invalid(format!(
                "heights holds {heights_len} values but width × height = {n}"
            )));
        }
        let data = input(heights, heights_len, "heights", false)?;
        let crs = Crs::parse(c_str(crs, "crs")?)?;
        let dem = Dem::new(
            width,
            height,
            GeoTransform([gt[0], gt[1], gt[2], gt[3], gt[4], gt[5]]),
            data.to_vec(),
        )?;
        write_dem(&p, &dem, &crs, &GeoTiffOptions::default())?;
        Ok(())
    })
}

/// Reads a DEM GeoTIFF into a caller buffer (NaN for nodata). `width_out`, `height_out`
/// and `geotransform_out[6]` are always filled; when `heights` is null or
/// `heights_len < width·height` the call returns CCP_STATUS_BUFFER_TOO_SMALL, so call it
/// once with `heights = NULL` to learn the size.
///
/// # Safety
/// Pointer arguments must be null or valid for the lengths given; strings NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn ccp_dem_read(
    path: *const c_char,
    width_out: *mut usize,
    height_out: *mut usize,
    geotransform_out: *mut f64,
    heights: *mut f32,
    heights_len: usize,
) -> CcpStatus {
    guard(|| {
        let p = c_path(path, "path")?;
        let w = output(width_out, 1, 1, "width_out")?;
        let h = output(height_out, 1, 1, "height_out")?;
        let gt = output(geotransform_out, 6, 6, "geotransform_out")?;
        // The size query reads the header only; the heights are read once they fit.
        let (width, height, transform) = dem_size(&p)?;
        w[0] = width;
        h[0] = height;
        gt.copy_from_slice(&transform);
        if heights.is_null() || heights_len < width * height {
            return Err(FfiError::new(
                CcpStatus::BufferTooSmall,
                format!(
                    "heights holds {heights_len} values but the DEM has {} ({width}×{height})",
                    width * height,
                ),
            ));
        }
        let (dem, _) = read_dem(&p)?;
        let out = output(heights, heights_len, dem.data.len(), "heights")?;
        out.copy_from_slice(&dem.data);
        Ok(())
    })
}

/// Reads a block (COLMAP folder or BlocksExchange `.xml`) and reports its size in
/// `counts_out[4]`: cameras, photos, points, observations.
///
/// # Safety
/// Pointer arguments must be null or valid for the lengths given; strings NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn ccp_block_summary(path: *const c_char, counts_out: *mut u64) -> CcpStatus {
    guard(|| {
        let p = c_path(path, "path")?;
        let out = output(counts_out, 4, 4, "counts_out")?;
        let b = crate::formats::convert::read_block(&p, None)?;
        out.copy_from_slice(&[
            b.cameras.len() as u64,
            b.photos.len() as u64,
            b.points.len() as u64,
            b.num_observations() as u64,
        ]);
        Ok(())
    })
}
