//! Two surface models compared: B − A on A's grid (B sampled bilinearly where the grids
//! differ, said in the report), A's terrain, the stable terrain, B's Nuth & Kääb shift
//! and its shift and tilt fitted together there, and the statistics of dh before and after
//! the shift. The shift is a check of B's orientation: applied to the written dh only when
//! asked (`apply_shift`). The one call `cloudcontrol change` makes.

use super::areas::{areas_geojson, changed_areas, AreaOptions, ChangedArea};
use super::nuth_kaab::{dh_moved, nuth_kaab_from, NuthKaab, NuthKaabOptions};
use super::render::{dh_map_png, map_range};
pub use super::shift_tilt::Tilt;
use super::shift_tilt::{shift_and_tilt, ShiftTilt};
use super::stable::{stable_terrain, StableOptions, StableStep};
use super::stats::{dh_statistics, DhStatistics};
use super::terrain::{slope_aspect, Terrain};
use super::{invalid, ChangeError, Result};
use crate::formats::crs::Crs;
use crate::formats::raster::{read_dem, write_dem, GeoTiffOptions};
use crate::formats::{write_bytes_atomically, FormatError};
use crate::geometry::Dem;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// DEM of difference, B − A (m).
pub const DH_FILE: &str = "dh.tif";
/// Stable terrain: 1 stable, 0 not, nodata without dh.
pub const STABLE_FILE: &str = "stable.tif";
/// The report.
pub const CHANGE_REPORT_FILE: &str = "change.json";
/// The changed areas as GeoJSON polygons.
pub const CHANGED_AREAS_FILE: &str = "changed_areas.geojson";
/// dh in colour over the reference's hillshade ([`super::render`]), for the report.
pub const DH_MAP_FILE: &str = "dh.png";
/// Longest side of [`DH_MAP_FILE`] (px).
const DH_MAP_SIDE: usize = 800;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ChangeOptions {
    pub stable: StableOptions,
    pub nuth_kaab: NuthKaabOptions,
    pub areas: AreaOptions,
    /// Write dh of B moved by its shift (the co-registered difference).
    pub apply_shift: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ChangeReport {
    /// A's grid: upper-left corner, cell (m), columns, rows.
    pub x_min: f64,
    pub y_max: f64,
    pub cell_m: f64,
    pub width: usize,
    pub height: usize,
    /// Whether B was sampled onto A's grid (bilinear) rather than sharing it.
    pub resampled: bool,
    pub stable_steps: Vec<StableStep>,
    pub stable_cells: usize,
    pub nuth_kaab: NuthKaab,
    /// The shift and tilt fitted together (null where the stable cells do not determine
    /// them): what to judge B's orientation by when Nuth & Kääb's shift is a tilt.
    pub shift_and_tilt: Option<ShiftTilt>,
    /// Whether `dh.tif` is of B moved by the shift.
    pub shift_applied: bool,
    /// dh on stable terrain as written, and after the shift.
    pub statistics: DhStatistics,
    pub statistics_after_shift: DhStatistics,
    /// The changed areas of the written dh ([`CHANGED_AREAS_FILE`]): how many, their area
    /// and net volume.
    pub changed_areas: usize,
    pub changed_area_m2: f64,
    pub changed_volume_m3: f64,
    /// dh − median of full colour in [`DH_MAP_FILE`] (m): red that much lower, blue that
    /// much higher ([`super::render::map_range`]).
    #[serde(default)]
    pub map_range_m: f64,
}

/// What [`compare_dems`] computes: the report, dh (as written) and the stable mask.
pub struct Comparison {
    pub report: ChangeReport,
    pub dh: Vec<f64>,
    pub stable: Vec<bool>,
    pub areas: Vec<ChangedArea>,
    /// A's slope and aspect (the hillshade of the dh map).
    pub terrain: Terrain,
}

/// What is known of the two surface models cell by cell besides their heights.
#[derive(Debug, Clone, Copy, Default)]
pub struct CellKnowledge<'a> {
    /// Cells of A's grid known not to be stable (A's buildings and trees).
    pub exclude: Option<&'a [bool]>,
    /// 1σ of A's heights (m) per cell of A's grid, e.g. the spread a fused DSM wrote.
    pub sigma_a: Option<&'a Dem>,
    /// 1σ of B's heights (m) on B's grid.
    pub sigma_b: Option<&'a Dem>,
}

impl CellKnowledge<'_> {
    /// sqrt(σa² + σb²) at each cell of A's grid, B's σ taken where dh took B's height
    /// (moved by `t`); None when neither is known.
    fn sigma_on(&self, a: &Dem, t: [f64; 2]) -> Option<Vec<f64>> {
        if self.sigma_a.is_none() && self.sigma_b.is_none() {
            return None;
        }
        let at = |d: Option<&Dem>, x: f64, y: f64| {
            d.and_then(|d| d.height_at(x, y)).filter(|v| v.is_finite())
        };
        Some(
            (0..a.data.len())
                .map(|i| {
                    let (c, r) = ((i % a.width) as f64 + 0.5, (i / a.width) as f64 + 0.5);
                    let (x, y) = a.transform.pixel_to_world(c, r);
                    let sa = at(self.sigma_a, x, y).unwrap_or(0.0);
                    let sb = at(self.sigma_b, x - t[0], y - t[1]).unwrap_or(0.0);
                    sa.hypot(sb)
                })
                .collect(),
        )
    }
}

/// B compared with the reference A (both world coordinates, the same CRS), with what is
/// `known` of their cells.
pub fn compare_dems(
    a: &Dem,
    b: &Dem,
    known: &CellKnowledge,
    options: &ChangeOptions,
) -> Result<Comparison> {
    if !(a.transform.is_north_up() && b.transform.is_north_up()) {
        return Err(invalid("surface models", "not north-up grids"));
    }
    let terrain = slope_aspect(a);
    let raw = dh_moved(a, b, [0.0, 0.0]);
    if raw.iter().all(|v| !v.is_finite()) {
        return Err(ChangeError::TooLittle(
            "the two surface models share no cell with a height".into(),
        ));
    }
    let stable = stable_terrain(&raw, &terrain, known.exclude, &options.stable);
    let (nk, moved) = nuth_kaab_from(
        a,
        b,
        &terrain,
        &stable.mask,
        &options.nuth_kaab,
        raw.clone(),
    )?;
    let joint = shift_and_tilt(
        a,
        &terrain,
        &stable.mask,
        &moved,
        [nk.shift_m[0], nk.shift_m[1]],
    );
    let shifted: Vec<f64> = moved.into_iter().map(|v| v + nk.shift_m[2]).collect();
    let statistics_after_shift = dh_statistics(&shifted, &stable.mask, &terrain);
    let (dh, statistics) = if options.apply_shift {
        (shifted, statistics_after_shift.clone())
    } else {
        let s = dh_statistics(&raw, &stable.mask, &terrain);
        (raw, s)
    };
    let moved_by = if options.apply_shift {
        [nk.shift_m[0], nk.shift_m[1]]
    } else {
        [0.0; 2]
    };
    let areas = changed_areas(
        &dh,
        a,
        (statistics.median_m, statistics.nmad_m),
        known.sigma_on(a, moved_by).as_deref(),
        &options.areas,
    )?;
    let same_grid = a.transform == b.transform && (a.width, a.height) == (b.width, b.height);
    let (x_min, y_max) = (a.transform.0[0], a.transform.0[3]);
    Ok(Comparison {
        report: ChangeReport {
            x_min,
            y_max,
            cell_m: a.transform.0[1],
            width: a.width,
            height: a.height,
            resampled: !same_grid,
            stable_cells: stable.cells(),
            stable_steps: stable.steps,
            nuth_kaab: nk,
            shift_and_tilt: joint,
            shift_applied: options.apply_shift,
            statistics_after_shift,
            changed_areas: areas.len(),
            changed_area_m2: areas.iter().map(|a| a.area_m2).sum(),
            changed_volume_m3: areas.iter().map(|a| a.volume_m3).sum(),
            map_range_m: map_range(&dh, statistics.median_m),
            statistics,
        },
        dh,
        stable: stable.mask,
        areas,
        terrain,
    })
}

/// Compares the rasters `b` and the reference `a` (GeoTIFF or any DEM GDAL reads, the
/// same CRS) and writes `dh.tif`, `stable.tif`, `changed_areas.geojson` and `change.json`
/// into `out_dir` (made if missing). `sigmas` are optional rasters of each model's 1σ per
/// cell (cloudcontrol's `dsm_spread.tif`), in the model's CRS: the changed areas' level
/// of detection.
pub fn write_change(
    a: &Path,
    b: &Path,
    sigmas: [Option<&Path>; 2],
    out_dir: &Path,
    options: &ChangeOptions,
) -> Result<ChangeReport> {
    let (dem_a, crs_a) = read_dem(a)?;
    let (dem_b, crs_b) = read_dem(b)?;
    let mut sigma = [None, None];
    for (k, (path, model_crs)) in sigmas.iter().zip([&crs_a, &crs_b]).enumerate() {
        let Some(path) = path else { continue };
        let (dem, crs) = read_dem(path)?;
        if let (Some(e), Some(m)) = (
            crs.as_ref().and_then(Crs::epsg),
            model_crs.as_ref().and_then(Crs::epsg),
        ) {
            if e != m {
                return Err(invalid(
                    &path.display().to_string(),
                    format!("is in EPSG:{e} but its surface model in EPSG:{m}"),
                ));
            }
        }
        if let Some(v) = dem.data.iter().find(|v| v.is_finite() && **v < 0.0) {
            return Err(invalid(
                &path.display().to_string(),
                format!("holds {v}: a standard deviation is not negative"),
            ));
        }
        sigma[k] = Some(dem);
    }
    let crs = match (crs_a, crs_b) {
        (Some(x), Some(y)) => {
            if let (Some(ex), Some(ey)) = (x.epsg(), y.epsg()) {
                if ex != ey {
                    return Err(invalid(
                        &b.display().to_string(),
                        format!(
                            "is in EPSG:{ey} but {} in EPSG:{ex}; reproject it",
                            a.display()
                        ),
                    ));
                }
            }
            x
        }
        (Some(x), None) | (None, Some(x)) => x,
        (None, None) => {
            return Err(invalid(
                &a.display().to_string(),
                "neither surface model has a CRS (heights need a projected one in metres)",
            ))
        }
    };
    if crs.is_geographic() {
        return Err(invalid(
            &a.display().to_string(),
            "is in a geographic CRS: slopes and shifts need a projected CRS in metres",
        ));
    }
    let known = CellKnowledge {
        exclude: None,
        sigma_a: sigma[0].as_ref(),
        sigma_b: sigma[1].as_ref(),
    };
    let cmp = compare_dems(&dem_a, &dem_b, &known, options)?;
    std::fs::create_dir_all(out_dir).map_err(|e| FormatError::io(out_dir, e))?;
    write_rasters(out_dir, &dem_a, &cmp, &crs)?;
    let json = serde_json::to_vec_pretty(&cmp.report).expect("the change report serialises");
    write_bytes_atomically(&out_dir.join(CHANGE_REPORT_FILE), &json)?;
    Ok(cmp.report)
}

/// Writes [`DH_FILE`], [`STABLE_FILE`], [`DH_MAP_FILE`] and [`CHANGED_AREAS_FILE`] of
/// `cmp` into `dir`, on the grid of its reference `grid`, in `crs`.
pub fn write_rasters(dir: &Path, grid: &Dem, cmp: &Comparison, crs: &Crs) -> Result<()> {
    let on_grid = |data: Vec<f32>| Dem::new(grid.width, grid.height, grid.transform, data);
    let dh = on_grid(cmp.dh.iter().map(|&v| v as f32).collect())?;
    let stable = on_grid(
        cmp.dh
            .iter()
            .zip(&cmp.stable)
            .map(|(v, &m)| match (v.is_finite(), m) {
                (false, _) => f32::NAN,
                (true, true) => 1.0,
                (true, false) => 0.0,
            })
            .collect(),
    )?;
    let opts = GeoTiffOptions::default();
    write_dem(&dir.join(DH_FILE), &dh, crs, &opts)?;
    write_dem(&dir.join(STABLE_FILE), &stable, crs, &opts)?;
    let r = &cmp.report;
    let png = dh_map_png(
        grid,
        &cmp.terrain,
        &cmp.dh,
        (r.statistics.median_m, r.map_range_m),
        DH_MAP_SIDE,
    )?;
    write_bytes_atomically(&dir.join(DH_MAP_FILE), &png)?;
    let name = crs.epsg().map(|e| format!("urn:ogc:def:crs:EPSG::{e}"));
    let json = serde_json::to_vec_pretty(&areas_geojson(&cmp.areas, name.as_deref()))
        .expect("GeoJSON serialises");
    write_bytes_atomically(&dir.join(CHANGED_AREAS_FILE), &json)?;
    Ok(())
}
