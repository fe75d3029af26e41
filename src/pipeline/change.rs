//! The change stage of an epoch (`change-<epoch>/`): the epoch's own surface
//! (`surface-<epoch>/dsm.tif`) against the control's surface model (the LiDAR's, today) and
//! against the next younger epoch's surface ([`crate::change`]). The Nuth & Kääb shift is
//! reported in the epoch's ground pixels as a check of its orientation, beside the shift
//! and tilt fitted together ([`crate::change::shift_tilt`]), which is what is flagged beyond
//! [`ShiftLimits`]: a tilted surface reads as a Nuth & Kääb shift over gentle terrain, and
//! the orientation is what both are checking. Neither is applied (`dh.tif` is of the
//! surface as measured).
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
    /// The shift fitted together with a tilt, in ground pixels (null where the stable
    /// terrain does not determine it).
    pub with_tilt: Option<ShiftWithTilt>,
    /// Why the shift is beyond [`ShiftLimits`] (or not determined), when it is: the shift
    /// fitted with the tilt where there is one, else Nuth & Kääb's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flag: Option<String>,
    pub change: ChangeReport,
}

/// [`crate::change::ShiftTilt`] in the epoch's ground pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShiftWithTilt {
    /// East, north, up (GSD), the up part at the compared extent's centre.
    pub shift_gsd: [f64; 3],
    pub shift_plan_gsd: f64,
    /// Standard errors (block jackknife) of the plan length and of the up part (GSD).
    pub shift_plan_sigma_gsd: f64,
    pub shift_up_sigma_gsd: f64,
    /// dh gradient east and north (m per km) and the height it makes at the extent's edge
    /// (GSD).
    pub tilt_m_per_km: [f64; 2],
    pub tilt_over_extent_gsd: f64,
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
    let nk = &change.nuth_kaab;
    let (shift_gsd, plan, sigma) = in_gsd(nk.shift_m, nk.sigma_m, gsd);
    let with_tilt = change.shift_and_tilt.as_ref().map(|j| {
        let (shift_gsd, plan, sigma) = in_gsd(j.shift_m, [j.sigma_m[0], j.sigma_m[1]], gsd);
        ShiftWithTilt {
            shift_gsd,
            shift_plan_gsd: plan,
            shift_plan_sigma_gsd: sigma,
            shift_up_sigma_gsd: j.sigma_m[2] / gsd,
            tilt_m_per_km: [j.tilt.east_m_per_km, j.tilt.north_m_per_km],
            tilt_over_extent_gsd: j.tilt.max_over_extent_m / gsd,
        }
    });
    // What is judged: the shift with its tilt where the terrain gave one.
    let (judged, judged_plan, judged_sigma, fitted) = match &with_tilt {
        Some(w) => (
            w.shift_gsd,
            w.shift_plan_gsd,
            w.shift_plan_sigma_gsd,
            format!(
                " with a tilt of {:+.2}, {:+.2} m/km fitted with it (Nuth & Kääb alone: {plan:.2} GSD)",
                w.tilt_m_per_km[0], w.tilt_m_per_km[1]
            ),
        ),
        None => (shift_gsd, plan, sigma, String::new()),
    };
    let beyond_plan = judged_plan > limits.plan_gsd;
    let flag = if let Some(note) = &nk.note {
        Some(note.clone())
    } else if beyond_plan || judged[2].abs() > limits.height_gsd {
        // Beyond the limits, and said whether the data determine it (twice its σ).
        let determined = if beyond_plan && judged_plan <= 2.0 * judged_sigma {
            " — within twice its standard error: not determined by this terrain"
        } else {
            ""
        };
        Some(format!(
            "shift {judged_plan:.2} ± {judged_sigma:.2} GSD in plan, {:+.2} GSD in height{fitted} against {against} (limits {} and {}){determined}",
            judged[2], limits.plan_gsd, limits.height_gsd
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
        with_tilt,
        flag,
        change,
    }
}

/// A shift (m) and the standard errors of its plan part (m) in ground pixels: the shift,
/// its plan length, and the standard error of that length along the shift's direction.
fn in_gsd(shift_m: [f64; 3], sigma_m: [f64; 2], gsd: f64) -> ([f64; 3], f64, f64) {
    let shift = shift_m.map(|v| v / gsd);
    let plan = shift[0].hypot(shift[1]);
    let [se, sn] = sigma_m.map(|v| v / gsd);
    let sigma = if plan > 0.0 {
        ((shift[0] * se).powi(2) + (shift[1] * sn).powi(2)).sqrt() / plan
    } else {
        se.hypot(sn)
    };
    (shift, plan, sigma)
}
