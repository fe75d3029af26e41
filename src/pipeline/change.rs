//! The change stage of an epoch (`change-<epoch>/`): the epoch's own surface
//! (`surface-<epoch>/dsm.tif`) against the control's surface model (the LiDAR's, today) and
//! against the next younger epoch's surface ([`crate::change`]). The Nuth & Kääb shift is
//! reported in the epoch's ground pixels as a check of its orientation and flagged beyond
//! [`ShiftLimits`]; it is not applied (`dh.tif` is of the surface as measured).
//!
//! Stable terrain starts from the LiDAR's bare ground: a cell whose surface stands more than
//! the control's bare-ground tolerance above its ground (a building, a tree) is left out
//! before the slope and NMAD steps; what changed on bare ground leaves at the NMAD step.
//! Changed areas are called against each cell's level of detection: a surface's spread
//! (`dsm_spread.tif`, the pairs' disagreement) raises it where the surface is unsure.

use super::epoch_files::write_json;
use super::stages::WorkError;
use crate::change::compare::{
    compare_dems, write_rasters, CellKnowledge, ChangeOptions, ChangeReport, CHANGE_REPORT_FILE,
};
use crate::change::ChangeError;
use crate::dense::products::{DsmReport, DSM_FILE, DSM_REPORT_FILE, DSM_SPREAD_FILE};
use crate::formats::crs::Crs;
use crate::formats::raster::read_dem;
use crate::lidar::GroundSurface;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Written instead of the comparison when the epoch has no surface (its reason inside).
pub(crate) const SKIPPED_FILE: &str = "skipped.json";

/// The largest Nuth & Kääb shift an oriented epoch may show against the control without
/// being flagged, in its ground pixels: the orientation is to make it zero.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ShiftLimits {
    pub plan_gsd: f64,
    pub height_gsd: f64,
}

impl Default for ShiftLimits {
    fn default() -> Self {
        Self {
            plan_gsd: 0.3,
            height_gsd: 0.2,
        }
    }
}

/// One comparison of the epoch's surface, with the shift in its ground pixels.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpochComparison {
    /// What the epoch was compared with: `lidar_surface`, `control_dem`, or an epoch's name.
    pub against: String,
    /// The epoch's ground pixel (m).
    pub ground_pixel_m: f64,
    /// Nuth & Kääb shift (east, north, up) in ground pixels, its plan length, and the
    /// standard error of that length.
    pub shift_gsd: [f64; 3],
    pub shift_plan_gsd: f64,
    pub shift_plan_sigma_gsd: f64,
    /// Why the shift is beyond [`ShiftLimits`] (or not determined), when it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flag: Option<String>,
    pub change: ChangeReport,
}

/// `change.json` of the stage.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpochChange {
    pub epoch: String,
    pub limits: ShiftLimits,
    /// Against the control's surface (files `dh.tif`, `stable.tif`).
    pub control: EpochComparison,
    /// Against the next younger epoch's surface (files in `vs_<epoch>/`), when it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub younger: Option<EpochComparison>,
}

/// Compares the surface of epoch `epoch` in `surface_dir` with the control's surface model
/// `ground` (block-local; `origin` the block's) and with `younger` (the next younger
/// epoch's name and surface folder), writing into `dir`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_epoch_change(
    epoch: &str,
    surface_dir: &Path,
    younger: Option<(&str, &Path)>,
    (ground, against): (&GroundSurface, &str),
    origin: [f64; 3],
    crs: &Crs,
    options: &ChangeOptions,
    dir: &Path,
) -> Result<(), WorkError> {
    let dsm_path = surface_dir.join(DSM_FILE);
    if !dsm_path.is_file() {
        write_json(
            &dir.join(SKIPPED_FILE),
            &serde_json::json!({ "reason": "the epoch has no surface of its own" }),
        )?;
        return Ok(());
    }
    let gsd = DsmReport::read(&surface_dir.join(DSM_REPORT_FILE))?.ground_pixel_m;
    let (dsm, _) = read_dem(&dsm_path)?;
    let spread = read_spread(surface_dir)?;
    let back = [-origin[0], -origin[1], -origin[2]];
    let surface = ground.surface.shifted(back).map_err(ChangeError::from)?;
    let bare = ground.ground.shifted(back).map_err(ChangeError::from)?;
    let not_ground: Vec<bool> = surface
        .data
        .iter()
        .zip(&bare.data)
        .map(|(s, g)| {
            !(s.is_finite() && g.is_finite()) || f64::from(s - g) > ground.max_above_ground_m
        })
        .collect();
    let limits = ShiftLimits::default();
    let known = CellKnowledge {
        exclude: Some(&not_ground),
        sigma_a: None,
        sigma_b: spread.as_ref(),
    };
    let cmp = compare_dems(&surface, &dsm, &known, options)?;
    write_rasters(dir, &surface, &cmp, crs)?;
    let control = comparison(against, gsd, &limits, cmp.report);
    let younger = match younger {
        Some((name, ydir)) if ydir.join(DSM_FILE).is_file() => {
            let (reference, _) = read_dem(&ydir.join(DSM_FILE))?;
            let reference_spread = read_spread(ydir)?;
            let known = CellKnowledge {
                exclude: None,
                sigma_a: reference_spread.as_ref(),
                sigma_b: spread.as_ref(),
            };
            let cmp = compare_dems(&reference, &dsm, &known, options)?;
            let vs = younger_dir(dir, name);
            std::fs::create_dir_all(&vs).map_err(|e| crate::formats::FormatError::io(&vs, e))?;
            write_rasters(&vs, &reference, &cmp, crs)?;
            Some(comparison(name, gsd, &limits, cmp.report))
        }
        _ => None,
    };
    if let Some(flag) = &control.flag {
        tracing::warn!(epoch, %flag, "surface shifted against the control");
    }
    write_json(
        &dir.join(CHANGE_REPORT_FILE),
        &EpochChange {
            epoch: epoch.to_string(),
            limits,
            control,
            younger,
        },
    )?;
    Ok(())
}

/// The folder of the comparison with the next younger epoch `name` in the change stage's
/// folder `dir`.
pub(crate) fn younger_dir(dir: &Path, name: &str) -> std::path::PathBuf {
    dir.join(format!("vs_{name}"))
}

/// The spread raster of a surface folder, when the fusion wrote one.
fn read_spread(surface_dir: &Path) -> Result<Option<crate::geometry::Dem>, WorkError> {
    let path = surface_dir.join(DSM_SPREAD_FILE);
    Ok(if path.is_file() {
        Some(read_dem(&path)?.0)
    } else {
        None
    })
}

fn comparison(
    against: &str,
    gsd: f64,
    limits: &ShiftLimits,
    change: ChangeReport,
) -> EpochComparison {
    let s = change.nuth_kaab.shift_m;
    let shift_gsd = [s[0] / gsd, s[1] / gsd, s[2] / gsd];
    let plan = shift_gsd[0].hypot(shift_gsd[1]);
    // The standard error of the plan length, along the shift's direction.
    let [se, sn] = change.nuth_kaab.sigma_m.map(|v| v / gsd);
    let sigma = if plan > 0.0 {
        ((shift_gsd[0] * se).powi(2) + (shift_gsd[1] * sn).powi(2)).sqrt() / plan
    } else {
        se.hypot(sn)
    };
    let beyond_plan = plan > limits.plan_gsd;
    let flag = if let Some(note) = &change.nuth_kaab.note {
        Some(note.clone())
    } else if beyond_plan || shift_gsd[2].abs() > limits.height_gsd {
        // Beyond the limits, and said whether the data determine it (twice its σ).
        let determined = if beyond_plan && plan <= 2.0 * sigma {
            " — within twice its standard error: not determined by this terrain"
        } else {
            ""
        };
        Some(format!(
            "shift {plan:.2} ± {sigma:.2} GSD in plan, {:+.2} GSD in height against {against} (limits {} and {}){determined}",
            shift_gsd[2], limits.plan_gsd, limits.height_gsd
        ))
    } else {
        None
    };
    EpochComparison {
        against: against.to_string(),
        ground_pixel_m: gsd,
        shift_gsd,
        shift_plan_gsd: plan,
        shift_plan_sigma_gsd: sigma,
        flag,
        change,
    }
}
