//! An epoch's surface as files: `dsm.tif` (median height per cell), `dsm_count.tif`
//! (points per cell), `dsm_spread.tif` (their NMAD), all float32 GeoTIFFs with nodata
//! where the photos gave nothing, and `dsm.json` (grid, ground pixel, pairs). The one
//! call the CLI (`cloudcontrol dsm`) and the pipeline's surface stage make.

use super::epoch::{epoch_dsm, tie_point_plane, DsmOptions, EpochDsm, PairReport};
use super::fusion::DsmGrid;
use super::{invalid, DenseError, Result};
use crate::block::Block;
use crate::formats::convert::{image_files, read_block};
use crate::formats::crs::Crs;
use crate::formats::raster::{read_dem, write_dem, GeoTiffOptions};
use crate::formats::{write_bytes_atomically, FormatError};
use crate::geometry::Dem;
use crate::matching::oriented::Surface;
use crate::matching::GreyImage;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The surface model.
pub const DSM_FILE: &str = "dsm.tif";
/// Points fused per cell.
pub const DSM_COUNT_FILE: &str = "dsm_count.tif";
/// 1.4826 × the median absolute deviation of a cell's points (NaN below two).
pub const DSM_SPREAD_FILE: &str = "dsm_spread.tif";
/// What the surface was made from.
pub const DSM_REPORT_FILE: &str = "dsm.json";
/// The surface as points (LAZ, optional): a point a cell with a height.
pub const DSM_POINTS_FILE: &str = "dsm_points.laz";

/// `dsm.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DsmReport {
    /// World coordinates of the grid's upper-left corner, cell (m), columns, rows.
    pub x_min: f64,
    pub y_max: f64,
    pub cell_m: f64,
    pub width: usize,
    pub height: usize,
    /// The photos' median ground pixel (m).
    pub ground_pixel_m: f64,
    /// Cells with a height, of all.
    pub cells_with_height: usize,
    pub cells: usize,
    /// What bounded the search: `dem` (a surface ± margin) or `tie_points` (a plane at
    /// their median height ± their relief and the margin).
    pub prior: String,
    pub prior_margin_m: f64,
    pub pairs: Vec<PairReport>,
    pub seconds: f64,
    /// Points written to [`DSM_POINTS_FILE`], when it was asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<u64>,
}

impl DsmReport {
    /// `dsm.json` of a surface folder.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
        serde_json::from_slice(&text)
            .map_err(|e| DenseError::Format(FormatError::invalid(path, e.to_string())))
    }

    /// The photos of each pair the surface was made from (left, right).
    pub fn pair_ids(&self) -> Vec<(crate::block::PhotoId, crate::block::PhotoId)> {
        self.pairs
            .iter()
            .map(|p| (p.pair.left, p.pair.right))
            .collect()
    }
}

/// Writes `result` into `dir` (which exists) in `crs`, with [`DSM_POINTS_FILE`] when
/// `points`; returns its report.
pub fn write_dsm(
    dir: &Path,
    result: &EpochDsm,
    crs: &Crs,
    prior: &str,
    options: &DsmOptions,
    seconds: f64,
    points: bool,
) -> Result<DsmReport> {
    let opts = GeoTiffOptions::default();
    let s = &result.surface;
    write_dem(&dir.join(DSM_FILE), &s.dsm, crs, &opts)?;
    write_dem(&dir.join(DSM_COUNT_FILE), &s.count, crs, &opts)?;
    write_dem(&dir.join(DSM_SPREAD_FILE), &s.spread, crs, &opts)?;
    let g: &DsmGrid = &result.grid;
    let report = DsmReport {
        x_min: g.x_min,
        y_max: g.y_max,
        cell_m: g.cell,
        width: g.width,
        height: g.height,
        ground_pixel_m: result.ground_pixel,
        cells_with_height: s.dsm.data.iter().filter(|v| v.is_finite()).count(),
        cells: s.dsm.data.len(),
        prior: prior.to_string(),
        prior_margin_m: options.prior_margin_m,
        pairs: result.pairs.clone(),
        seconds,
        points: if points {
            Some(write_dsm_points(
                &dir.join(DSM_POINTS_FILE),
                &s.dsm,
                &s.count,
                crs,
            )?)
        } else {
            None
        },
    };
    let json = serde_json::to_vec_pretty(&report).expect("the DSM report serialises");
    let path = dir.join(DSM_REPORT_FILE);
    write_bytes_atomically(&path, &json)?;
    Ok(report)
}

/// Writes the surface `dsm` as points at `path` (LAZ): one at the centre of each cell
/// with a height, its intensity the number of points fused there (`count`, at most
/// 65 535), in `crs`. For the point-cloud tools (CloudCompare, PDAL) that take no raster.
fn write_dsm_points(path: &Path, dsm: &Dem, count: &Dem, crs: &Crs) -> Result<u64> {
    let wkt = crs.to_wkt()?;
    let t = &dsm.transform;
    let (x0, y1) = (t.0[0], t.0[3]);
    let header = crate::lidar::las_write::new_header([x0.floor(), y1.floor(), 0.0], true, &wkt)
        .map_err(|e| FormatError::invalid(path, e))?;
    let points = dsm.data.iter().enumerate().filter_map(|(i, &z)| {
        if !z.is_finite() {
            return None;
        }
        let (c, r) = ((i % dsm.width) as f64 + 0.5, (i / dsm.width) as f64 + 0.5);
        let (x, y) = t.pixel_to_world(c, r);
        Some(Ok(las::Point {
            x,
            y,
            z: f64::from(z),
            intensity: count.data[i].clamp(0.0, 65_535.0) as u16,
            return_number: 1,
            number_of_returns: 1,
            // Format 6 has a time: none here (a surface, not a flight).
            gps_time: Some(0.0),
            ..Default::default()
        }))
    });
    Ok(crate::lidar::las_write::write_points(path, header, points)?)
}

/// The surface of a block file (COLMAP model folder or BlocksExchange XML) whose photos are
/// in `images_dir`, searched around `prior_dem` (a GeoTIFF in the block's CRS; without
/// it, around a plane at the block's tie points), written into `out_dir` (made if
/// missing), with [`DSM_POINTS_FILE`] when `points`.
pub fn dsm_from_files(
    block_path: &Path,
    images_dir: &Path,
    prior_dem: Option<&Path>,
    (out_dir, points): (&Path, bool),
    options: &DsmOptions,
    progress: impl FnMut(usize, usize, &PairReport),
) -> Result<DsmReport> {
    let t0 = std::time::Instant::now();
    let block = read_block(block_path, None)?;
    let files = image_files(&block, images_dir)?;
    let dem = prior_dem.map(read_dem).transpose()?;
    let crs = block_crs(&block, block_path, dem.as_ref().and_then(|d| d.1.clone()))?;
    let origin = Vector3::from(block.origin);
    let (prior, name) = match &dem {
        Some((d, _)) => (
            Surface::Dem {
                dem: d,
                origin,
                sigma_m: 0.0,
            },
            "dem",
        ),
        None => (
            tie_point_plane(&block).ok_or_else(|| {
                invalid(
                    &block_path.display().to_string(),
                    "the block has no tie points to bound the search: give a prior DEM",
                )
            })?,
            "tie_points",
        ),
    };
    let image = |p: &crate::block::Photo| {
        let path = files
            .get(&p.id)
            .ok_or_else(|| format!("photo {} has no image file", p.name))?;
        GreyImage::load(path).map_err(|e| e.to_string())
    };
    let result = epoch_dsm(&block, &image, &prior, None, options, progress)?;
    std::fs::create_dir_all(out_dir).map_err(|e| FormatError::io(out_dir, e))?;
    write_dsm(
        out_dir,
        &result,
        &crs,
        name,
        options,
        t0.elapsed().as_secs_f64(),
        points,
    )
}

/// The CRS of the products: the prior DEM's, else the block's; they must agree.
fn block_crs(block: &Block, block_path: &Path, dem_crs: Option<Crs>) -> Result<Crs> {
    let from_block = block.crs.as_deref().map(Crs::parse).transpose()?;
    match (dem_crs, from_block) {
        (Some(d), Some(b)) => {
            if let (Some(x), Some(y)) = (b.epsg(), d.epsg()) {
                if x != y {
                    return Err(invalid(
                        "prior DEM",
                        format!("is in EPSG:{y} but the block in EPSG:{x}; reproject the DEM"),
                    ));
                }
            }
            Ok(d)
        }
        (Some(c), None) | (None, Some(c)) => Ok(c),
        (None, None) => Err(DenseError::InvalidInput {
            what: block_path.display().to_string(),
            message: "neither the block nor a prior DEM has a CRS; the DSM needs one".into(),
        }),
    }
}
