//! The present scene as an orthophoto with a DEM, the control source of an archive owner
//! without LiDAR or a reference flight: a true orthophoto (the scene seen straight down at
//! every pixel centre, with sensor noise as a digital photo has it) and the surface model
//! it was made on (first-return heights), both GeoTIFFs in the block's CRS.

use super::film;
use super::scene::Scene;
use super::SynthError;
use crate::formats::crs::Crs;
use crate::formats::raster::{self, GeoTiffOptions};
use crate::geometry::{Dem, GeoTransform};
use rayon::prelude::*;
use std::path::Path;

/// Cell of the synthetic DEM (m): a national surface model's.
pub const DEM_CELL_M: f64 = 1.0;

/// Writes `orthophoto.tif` (ground pixel `gsd`) and `dem.tif` of `scene` over `area`
/// (block-local; world = local + `origin`) into `dir`.
pub fn write(
    scene: &Scene,
    area: [f64; 4],
    origin: [f64; 3],
    gsd: f64,
    crs: &Crs,
    seed: u64,
    dir: &Path,
) -> Result<(), SynthError> {
    std::fs::create_dir_all(dir).map_err(|e| crate::formats::FormatError::io(dir, e))?;
    let [x0, y0, x1, y1] = area;
    let (w, h) = (
        ((x1 - x0) / gsd).floor() as usize,
        ((y1 - y0) / gsd).floor() as usize,
    );
    let radiance: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (i, j) = (k % w, k / w);
            let (x, y) = (x0 + (i as f64 + 0.5) * gsd, y1 - (j as f64 + 0.5) * gsd);
            let sp = scene.sample(x, y);
            scene.albedo(x, y, &sp, sp.height, gsd) as f32
        })
        .collect();
    let grey = film::finish_digital(&radiance, w as u32, h as u32, seed, 1.0, 8.0, 1.5);
    let transform = GeoTransform::north_up(x0 + origin[0], y1 + origin[1], gsd);
    raster::write_grey(
        &dir.join("orthophoto.tif"),
        (w, h),
        grey,
        &transform,
        crs,
        &GeoTiffOptions::default(),
    )?;
    write_surface(scene, area, origin, DEM_CELL_M, crs, &dir.join("dem.tif"))
}

/// Writes the surface of `scene` (first-return heights: terrain, roofs, crowns; world
/// heights) over `area` (block-local) in cells of `cell` m, north up, as a float32
/// GeoTIFF at `path`: the orthophoto's DEM, and each epoch's true DSM (the scene as it
/// was then) that the epoch's dense matching is scored against.
pub fn write_surface(
    scene: &Scene,
    area: [f64; 4],
    origin: [f64; 3],
    cell: f64,
    crs: &Crs,
    path: &Path,
) -> Result<(), SynthError> {
    let [x0, y0, x1, y1] = area;
    let (w, h) = (
        ((x1 - x0) / cell).floor() as usize,
        ((y1 - y0) / cell).floor() as usize,
    );
    let transform = GeoTransform::north_up(x0 + origin[0], y1 + origin[1], cell);
    let data: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (x, y) = transform.pixel_to_world((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            (scene.height_at(x - origin[0], y - origin[1]) + origin[2]) as f32
        })
        .collect();
    let dem = Dem::new(w, h, transform, data)?;
    raster::write_dem(path, &dem, crs, &GeoTiffOptions::default())?;
    Ok(())
}
