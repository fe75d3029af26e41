//! The LiDAR as a control surface for photos: a ground DEM (class 2, holes under
//! buildings filled) and a surface model of every non-noise return (classes 2–6), so that
//! bare, stable ground can be told from roofs and canopy where control points are chosen.

use super::LidarError;
use crate::geometry::Dem;
use std::path::{Path, PathBuf};

/// Cell (m) of the ground and surface grids the workflow uses.
pub const LIDAR_CELL_M: f64 = 1.0;

/// Bare ground as seen by LiDAR: where the surface model stands no higher than the
/// ground DEM around a point, the point is on open ground, the place least likely to
/// change between epochs and whose height is the LiDAR ground's.
#[derive(Debug, Clone)]
pub struct GroundSurface {
    /// Ground DEM (block-local), holes filled.
    pub ground: Dem,
    /// Mean height of all non-noise returns per cell (block-local).
    pub surface: Dem,
    /// Largest surface-above-ground difference still taken as bare ground (m).
    pub max_above_ground_m: f64,
    /// Radius (m) around the point that must be bare ground too (the chip's footprint).
    pub radius_m: f64,
}

/// Ground DEM and surface model (block-local, `origin` subtracted) from LAS/LAZ tiles,
/// grid cell `cell` (m). With `lattice_base_m`, both start at the corner of the project
/// lattice of that base around the LiDAR's extent ([`crate::geometry::Lattice::around`]),
/// so every other raster of the project lines up with them; else at the extent's corner
/// snapped to the cell.
pub fn lidar_surfaces(
    tiles: &[PathBuf],
    origin: [f64; 3],
    cell: f64,
    lattice_base_m: Option<f64>,
) -> Result<GroundSurface, LidarError> {
    let mut ground = Vec::new();
    let mut all = Vec::new();
    for t in tiles {
        let b = super::las::read_points(t, None, Some(&[2, 3, 4, 5, 6]))?;
        for (x, c) in b.xyz.iter().zip(&b.class) {
            let l = [x[0] - origin[0], x[1] - origin[1], x[2] - origin[2]];
            if *c == 2 {
                ground.push(l);
            }
            all.push(l);
        }
    }
    let first = tiles
        .first()
        .map(|p| p.to_path_buf())
        .unwrap_or_else(|| Path::new(".").to_path_buf());
    let data = |message: String| LidarError::Data {
        what: first.display().to_string(),
        message,
    };
    if ground.is_empty() {
        return Err(data("no ground (class 2) LiDAR points".into()));
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in &all {
        for a in 0..2 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let bbox = super::Bbox {
        min_x: lo[0],
        min_y: lo[1],
        max_x: hi[0],
        max_y: hi[1],
    };
    let corner = match lattice_base_m {
        Some(base) => {
            let world = [
                lo[0] + origin[0],
                lo[1] + origin[1],
                hi[0] + origin[0],
                hi[1] + origin[1],
            ];
            let l = crate::geometry::Lattice::around(base, world)
                .map_err(|e| LidarError::InvalidOption(e.to_string()))?;
            Some([l.corner[0] - origin[0], l.corner[1] - origin[1]])
        }
        None => None,
    };
    let grid = |pts: &[[f64; 3]], fill: usize| {
        super::grid_dem(
            pts,
            &super::DemOptions {
                cell,
                max_fill_cells: fill,
                bbox: Some(bbox),
                corner,
                ..Default::default()
            },
        )
        .map_err(|e| data(e.to_string()))
    };
    // Buildings leave holes of tens of metres in the ground: fill them generously (the
    // surface model marks them unstable anyway).
    let g = grid(&ground, (60.0 / cell).ceil() as usize)?;
    let s = grid(&all, 2)?;
    Ok(GroundSurface {
        ground: g,
        surface: s,
        max_above_ground_m: MAX_ABOVE_GROUND_M,
        radius_m: BARE_RADIUS_M,
    })
}

/// [`GroundSurface::max_above_ground_m`] of the LiDAR's surfaces.
const MAX_ABOVE_GROUND_M: f64 = 0.3;
/// [`GroundSurface::radius_m`]: the matching chip's footprint on the ground.
const BARE_RADIUS_M: f64 = 2.0;

impl GroundSurface {
    /// A DEM alone as the control surface (no LiDAR): it tells nothing of what stands on
    /// the ground, so every place is taken as bare and planarity alone selects control.
    pub fn from_dem(dem: Dem) -> Self {
        Self {
            ground: dem.clone(),
            surface: dem,
            max_above_ground_m: MAX_ABOVE_GROUND_M,
            radius_m: BARE_RADIUS_M,
        }
    }
}
