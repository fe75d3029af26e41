//! The ground every epoch stage predicts over, exports DCPs on and rectifies onto: the
//! cleaned LiDAR's (ground and surface models, planes for the reference), or the DEM of
//! the control sources where there is no LiDAR. The run and each per-photo task of a
//! distributed run build it the same way from the `sources` stage.

use super::project::Project;
use super::stages::WorkError;
use crate::control::reference;
use crate::formats::crs::Crs;
use crate::geometry::lattice::{lattice_cell, Lattice};
use crate::lidar::{self, GroundSurface, PlaneIndex, PlaneOptions};
use std::cell::OnceCell;
use std::path::PathBuf;
use std::sync::Arc;

/// Classes whose LiDAR points give planes for the reference adjustment: ground and
/// buildings (stable, planar, present in the reference photos).
const PLANE_CLASSES: [u8; 2] = [2, 6];

/// The control ground of a run, built once when first needed (a rerun that skips every
/// epoch stage never reads it).
pub(crate) struct ControlGround<'a> {
    project: &'a Project,
    /// Cleaned LiDAR tiles (None: no LiDAR, the project's DEM).
    tiles_dir: Option<PathBuf>,
    pub(crate) origin: [f64; 3],
    surface: OnceCell<Arc<GroundSurface>>,
    planes: OnceCell<PlaneIndex>,
}

impl<'a> ControlGround<'a> {
    /// The ground of the `sources` stage's folder: its cleaned LiDAR tiles when the
    /// project has LiDAR, else the project's DEM.
    pub(crate) fn new(project: &'a Project, sources: &std::path::Path, origin: [f64; 3]) -> Self {
        Self {
            project,
            tiles_dir: (!project.control.lidar.is_empty()).then(|| sources.join("lidar")),
            origin,
            surface: OnceCell::new(),
            planes: OnceCell::new(),
        }
    }

    pub(crate) fn surface(&self) -> Result<&GroundSurface, WorkError> {
        Ok(self.surface_arc()?)
    }

    /// The surface, shareable with the per-photo work of an epoch.
    pub(crate) fn surface_arc(&self) -> Result<&Arc<GroundSurface>, WorkError> {
        if let Some(s) = self.surface.get() {
            return Ok(s);
        }
        let s = match &self.tiles_dir {
            Some(dir) => {
                let tiles = lidar::catalogue::expand_inputs(std::slice::from_ref(dir))?;
                let base = self.project.outputs.grid_base_m;
                lidar::lidar_surfaces(
                    &tiles,
                    self.origin,
                    lattice_cell(base, lidar::LIDAR_CELL_M),
                    Some(base),
                )?
            }
            None => {
                let dem = control_dem(self.project)?
                    .shifted(self.origin)
                    .map_err(crate::formats::FormatError::Geometry)?;
                GroundSurface::from_dem(dem)
            }
        };
        Ok(self.surface.get_or_init(|| Arc::new(s)))
    }

    pub(crate) fn planes(&self) -> Result<&PlaneIndex, WorkError> {
        if let Some(p) = self.planes.get() {
            return Ok(p);
        }
        let Some(dir) = &self.tiles_dir else {
            return Err(WorkError::Inconsistent(
                "LiDAR planes are needed (reference epoch) but control.lidar is empty".into(),
            ));
        };
        let tiles = lidar::catalogue::expand_inputs(std::slice::from_ref(dir))?;
        let p = reference::lidar_plane_index(
            &tiles,
            self.origin,
            &PLANE_CLASSES,
            PlaneOptions::default(),
        )?;
        Ok(self.planes.get_or_init(|| p))
    }

    /// The project's raster lattice: the LiDAR surfaces' corner (they are gridded on it),
    /// or around the extent of the control DEM.
    pub(crate) fn lattice(&self) -> Result<Lattice, WorkError> {
        let base = self.project.outputs.grid_base_m;
        let ground = &self.surface()?.ground;
        let (x0, y0, x1, y1) = ground.extent();
        let o = self.origin;
        let world = [x0 + o[0], y0 + o[1], x1 + o[0], y1 + o[1]];
        // The LiDAR's surfaces were gridded from the lattice's corner, so snapping their
        // extent gives that corner back.
        Ok(Lattice::around(base, world).map_err(crate::formats::FormatError::Geometry)?)
    }

    /// File name of the DEM product: whose surface it is.
    pub(crate) fn dem_file(&self) -> &'static str {
        if self.tiles_dir.is_some() {
            super::products::LIDAR_DEM
        } else {
            super::products::CONTROL_DEM
        }
    }
}

/// The project's DEM (`control.dem`) in the project CRS, metres (world coordinates).
pub(crate) fn control_dem(project: &Project) -> Result<crate::geometry::Dem, WorkError> {
    let path = project
        .control
        .dem
        .as_deref()
        .ok_or_else(|| WorkError::Inconsistent("no LiDAR and no control.dem".into()))?;
    let crs = Crs::parse(&project.crs)?;
    Ok(crate::control::ortho_source::dem_in_metres(
        path,
        project.control.dem_crs.as_deref(),
        &crs,
    )?)
}
