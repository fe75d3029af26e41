//! Format detection and conversion between block formats: a COLMAP model folder and a
//! BlocksExchange XML file, chosen by the path (folder or `.xml`) unless told.

use super::{blocks_exchange, colmap, FormatError, Result};
use crate::block::Block;
use crate::formats::crs::Crs;
use crate::geometry::Dem;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockFormat {
    Colmap,
    BlocksExchange,
}

impl BlockFormat {
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "colmap" => Some(Self::Colmap),
            "bx" | "blocks-exchange" | "blocksexchange" | "xml" => Some(Self::BlocksExchange),
            _ => None,
        }
    }

    /// By path: `.xml` is BlocksExchange, a folder or a path without extension COLMAP.
    pub fn detect(path: &Path) -> Result<Self> {
        match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()) {
            Some(e) if e == "xml" => Ok(Self::BlocksExchange),
            Some(e) if e == "xmlz" => Err(FormatError::invalid(
                path,
                "XMLZ (zipped BlocksExchange) is not supported; unzip it to .xml",
            )),
            None => Ok(Self::Colmap),
            _ if path.is_dir() => Ok(Self::Colmap),
            Some(e) => Err(FormatError::invalid(
                path,
                format!("cannot tell the block format from the extension .{e}; use a COLMAP folder or .xml"),
            )),
        }
    }
}

/// Options of [`write_block`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ConvertOptions {
    /// COLMAP: text instead of binary.
    pub text: bool,
    /// COLMAP: the legacy 3-file layout instead of COLMAP 4's 5 files.
    pub legacy: bool,
}

pub fn read_block(path: &Path, format: Option<BlockFormat>) -> Result<Block> {
    if !path.exists() {
        return Err(FormatError::invalid(path, "does not exist"));
    }
    match format.map_or_else(|| BlockFormat::detect(path), Ok)? {
        BlockFormat::Colmap => colmap::read(path),
        BlockFormat::BlocksExchange => blocks_exchange::read(path),
    }
}

pub fn write_block(
    path: &Path,
    block: &Block,
    format: Option<BlockFormat>,
    opts: &ConvertOptions,
) -> Result<()> {
    match format.map_or_else(|| BlockFormat::detect(path), Ok)? {
        BlockFormat::Colmap => colmap::write(
            path,
            block,
            &colmap::WriteOptions {
                encoding: if opts.text {
                    colmap::Encoding::Text
                } else {
                    colmap::Encoding::Binary
                },
                layout: if opts.legacy {
                    colmap::Layout::Legacy
                } else {
                    colmap::Layout::Rigs
                },
            },
        ),
        BlockFormat::BlocksExchange => {
            blocks_exchange::write(path, block, &blocks_exchange::WriteOptions::default())
        }
    }
}

/// Reads `input` and writes `output`, each in the format of its path.
pub fn convert(input: &Path, output: &Path, opts: &ConvertOptions) -> Result<Block> {
    let block = read_block(input, None)?;
    write_block(output, &block, None, opts)?;
    Ok(block)
}

/// Where a block file's photos are when no folder is given: a COLMAP model folder
/// itself, else the folder holding the block file.
pub fn default_images_dir(block_path: &Path) -> std::path::PathBuf {
    if block_path.is_dir() {
        block_path.to_path_buf()
    } else {
        block_path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default()
    }
}

/// The image files of a block's oriented photos in `images_dir` (photo names relative to
/// it); a missing file is reported in the error, naming the first.
pub fn image_files(
    block: &Block,
    images_dir: &Path,
) -> Result<BTreeMap<crate::block::PhotoId, std::path::PathBuf>> {
    let mut out = BTreeMap::new();
    for p in block.photos.values().filter(|p| p.is_oriented()) {
        let path = images_dir.join(p.name.replace('\\', "/"));
        if !path.is_file() {
            return Err(FormatError::invalid(
                &path,
                format!("image of photo {} ({}) is missing", p.id, p.name),
            ));
        }
        out.insert(p.id, path);
    }
    Ok(out)
}

/// Orthophoto of a block file on a DEM GeoTIFF: the one call the CLI and the C ABI make.
pub fn orthophoto_from_files(
    block_path: &Path,
    dem_path: &Path,
    images_dir: &Path,
    out: &Path,
    opts: &super::ortho::OrthoOptions,
) -> Result<super::ortho::OrthoReport> {
    let block = read_block(block_path, None)?;
    let (dem, dem_crs): (Dem, Option<Crs>) = super::raster::read_dem(dem_path)?;
    let crs = match (dem_crs, &block.crs) {
        (Some(c), _) => c,
        (None, Some(b)) => Crs::parse(b)?,
        (None, None) => {
            return Err(FormatError::invalid(
                dem_path,
                "neither the DEM nor the block has a CRS; the orthophoto needs one",
            ))
        }
    };
    if let Some(b) = &block.crs {
        let b = Crs::parse(b)?;
        if let (Some(x), Some(y)) = (b.epsg(), crs.epsg()) {
            if x != y {
                return Err(FormatError::invalid(
                    dem_path,
                    format!("DEM is in EPSG:{y} but the block in EPSG:{x}; reproject the DEM"),
                ));
            }
        }
    }
    let files = image_files(&block, images_dir)?;
    super::ortho::write_orthophoto(
        out,
        &block,
        &dem,
        super::ortho::PhotoImages::Files(&files),
        &crs,
        opts,
    )
}
