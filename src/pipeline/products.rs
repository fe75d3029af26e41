//! The products of an oriented epoch (`outputs-<epoch>/`): COLMAP model, BlocksExchange
//! XML, orthophoto and the LiDAR ground DEM as GeoTIFFs, and the report's preview.

use super::epoch_files::{load_block, write_json};
use super::project::Project;
use super::stages::WorkError;
use crate::formats::crs::Crs;
use crate::formats::{self, FormatError};
use crate::lidar::GroundSurface;
use std::collections::BTreeMap;
use std::path::Path;

/// COLMAP model, BlocksExchange XML, orthophoto and DEM of the oriented epoch in `edir`,
/// written into `dir`; `surface` is the LiDAR ground (block-local with `origin`).
pub fn write_products(
    project: &Project,
    surface: &GroundSurface,
    origin: [f64; 3],
    edir: &Path,
    dir: &Path,
) -> Result<(), WorkError> {
    let block = load_block(edir)?;
    let o = &project.outputs;
    // Products hold the oriented photos, named by their image file as COLMAP and
    // ContextCapture expect.
    let mut named = block.oriented_only();
    for p in named.photos.values_mut() {
        if let Some(f) = p.image.as_ref().and_then(|i| i.file_name()) {
            p.name = f.to_string_lossy().into_owned();
        }
    }
    // A film camera whose scan affine is not a pure scale has no exact COLMAP or
    // BlocksExchange camera: such products are skipped with the reason recorded (the
    // orthophoto and the block JSON hold the epoch in full).
    let mut skipped: BTreeMap<&str, String> = BTreeMap::new();
    // Reasons name files relative to the stage folder (its temporary name is per process).
    let reason =
        |e: &dyn std::fmt::Display| e.to_string().replace(&format!("{}/", dir.display()), "");
    if o.colmap {
        if let Err(e) = formats::colmap::write(
            &dir.join("colmap"),
            &named,
            &formats::colmap::WriteOptions::default(),
        ) {
            let _ = std::fs::remove_dir_all(dir.join("colmap"));
            tracing::warn!("COLMAP model not written: {e}");
            skipped.insert("colmap", reason(&e));
        }
    }
    if o.blocks_exchange {
        let base = named
            .photos
            .values()
            .find_map(|p| p.image.as_ref()?.parent())
            .map(|p| p.display().to_string());
        if let Err(e) = formats::blocks_exchange::write(
            &dir.join("blocks_exchange.xml"),
            &named,
            &formats::blocks_exchange::WriteOptions {
                base_image_path: base,
                block_name: Some(project.name.clone()),
                pixel_mm: BTreeMap::new(),
            },
        ) {
            tracing::warn!("BlocksExchange XML not written: {e}");
            skipped.insert("blocks_exchange", reason(&e));
        }
    }
    write_json(&dir.join("skipped.json"), &skipped)?;
    if o.orthophoto || o.dem {
        let crs = Crs::parse(&project.crs)?;
        // Back to world coordinates: shifting by the negated origin.
        let dem = surface
            .ground
            .shifted([-origin[0], -origin[1], -origin[2]])
            .map_err(FormatError::Geometry)?;
        if o.dem {
            formats::raster::write_dem(
                &dir.join("dem.tif"),
                &dem,
                &crs,
                &formats::raster::GeoTiffOptions::default(),
            )?;
        }
        if o.orthophoto {
            let mut rgb = BTreeMap::new();
            for (id, p) in &named.photos {
                if let Some(path) = &p.image {
                    rgb.insert(*id, formats::ortho::RgbImage::load(path)?);
                }
            }
            let gsd = formats::ortho::default_gsd(&named, &dem).map(|g| g * o.ortho_gsd_factor);
            let rep = formats::ortho::write_orthophoto(
                &dir.join("orthophoto.tif"),
                &named,
                &dem,
                &rgb,
                &crs,
                &formats::ortho::OrthoOptions {
                    gsd,
                    ..Default::default()
                },
            )?;
            write_json(&dir.join("orthophoto.json"), &rep)?;
            let (png, extent) = formats::ortho::preview(&dir.join("orthophoto.tif"), 800)?;
            std::fs::write(dir.join("preview.png"), png)
                .map_err(|e| FormatError::io(dir.join("preview.png"), e))?;
            write_json(&dir.join("preview.json"), &extent)?;
        }
    }
    Ok(())
}
