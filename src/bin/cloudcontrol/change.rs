//! `cloudcontrol change`: elevation change between two surface models.

use cloudcontrol::change::{write_change, ChangeOptions};
use std::path::PathBuf;
use std::process::ExitCode;

/// Elevation change B − A of two surface models (GeoTIFF DEMs or DSMs, the same projected
/// CRS): dh.tif on A's grid, stable.tif (the stable terrain it is judged on), change.json
/// (B's Nuth & Kääb shift against A, its shift and tilt fitted together, the statistics of
/// dh there, by slope).
///
/// Stable terrain: both have a height, slope ≤ --max-slope, then |dh − median| ≤ k·NMAD
/// repeated. The shift is reported; dh.tif is of B as given unless --apply-shift.
/// Changed areas (changed_areas.geojson): |dh − median| beyond max(1 m, 3·NMAD), raised
/// cell by cell by --sigma-a/--sigma-b, over at least 25 m².
///
/// Example: cloudcontrol change dem.tif dsm/dsm.tif --out change/
#[derive(clap::Args)]
pub struct Args {
    /// Reference surface model A (its grid is dh's).
    a: PathBuf,
    /// Surface model B, compared with A.
    b: PathBuf,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Steepest slope of stable terrain (degrees).
    #[arg(long, default_value_t = ChangeOptions::default().stable.max_slope_deg)]
    max_slope: f64,
    /// Stable terrain keeps |dh − median| ≤ K × NMAD.
    #[arg(long, default_value_t = ChangeOptions::default().stable.k_nmad)]
    k_nmad: f64,
    /// Write dh of B moved by its Nuth & Kääb shift.
    #[arg(long)]
    apply_shift: bool,
    /// A raster of A's 1σ per cell (m), e.g. a cloudcontrol surface's dsm_spread.tif:
    /// changed areas must exceed 3·sqrt(NMAD² + σA² + σB²) there.
    #[arg(long, value_name = "TIF")]
    sigma_a: Option<PathBuf>,
    /// A raster of B's 1σ per cell (m), as --sigma-a.
    #[arg(long, value_name = "TIF")]
    sigma_b: Option<PathBuf>,
}

pub fn run(a: Args, json: bool, quiet: bool) -> ExitCode {
    if !(a.max_slope.is_finite() && a.max_slope > 0.0 && a.max_slope <= 90.0) {
        return crate::console::fail(
            "change",
            format!("--max-slope {}: needs 0 < slope ≤ 90 degrees", a.max_slope),
            crate::EXIT_USAGE,
        );
    }
    if !(a.k_nmad.is_finite() && a.k_nmad > 0.0) {
        return crate::console::fail(
            "change",
            format!("--k-nmad {}: needs a positive factor", a.k_nmad),
            crate::EXIT_USAGE,
        );
    }
    let mut options = ChangeOptions {
        apply_shift: a.apply_shift,
        ..ChangeOptions::default()
    };
    options.stable.max_slope_deg = a.max_slope;
    options.stable.k_nmad = a.k_nmad;
    let sigmas = [a.sigma_a.as_deref(), a.sigma_b.as_deref()];
    match write_change(&a.a, &a.b, sigmas, &a.out, &options) {
        Ok(r) => {
            crate::console::report(json, quiet, &r, || {
                let s = &r.statistics;
                let nk = &r.nuth_kaab;
                format!(
                    "{}: dh median {:.3} m, NMAD {:.3} m on {} stable cells; shift of B \
                     (east, north, up) {:.3}, {:.3}, {:.3} m ({:.2}, {:.2} cells){}{}",
                    a.out.join("dh.tif").display(),
                    s.median_m,
                    s.nmad_m,
                    r.stable_cells,
                    nk.shift_m[0],
                    nk.shift_m[1],
                    nk.shift_m[2],
                    nk.shift_px[0],
                    nk.shift_px[1],
                    if r.shift_applied { ", applied" } else { "" },
                    nk.note
                        .as_ref()
                        .map(|n| format!(" ({n})"))
                        .unwrap_or_default()
                )
            });
            ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail("change", e, crate::EXIT_FAILED),
    }
}
