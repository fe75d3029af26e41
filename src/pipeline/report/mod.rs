//! The accuracy report: JSON for machines and a self-contained HTML page for the operator.
//! It gives the run (version, project hash, options, date), its warnings, accuracy through
//! time (table and plot against the epoch date), the LiDAR's check against the surveyed
//! checkpoints, the control/check map over the orthophoto, and per epoch its checkpoints
//! one by one with the measurements rejected, its film scans' interior orientation, its
//! plots (checkpoint errors, residual vectors, matching per photo, ICP) and tie
//! statistics. Plots are SVG drawn with plotters and inlined, so the page needs no network
//! and no companion files.
//!
//! [`model`] is what `report.json` holds, [`gather`] takes it from where the run decided
//! it, [`plots`] and [`html`] draw the page.

pub mod gather;
pub mod html;
pub mod model;
pub mod plots;

pub use html::render_html;
pub use model::*;

use crate::formats::{write_bytes_atomically, FormatError};
use std::path::Path;

/// Writes `report.json` and `report.html` into `dir`, atomically.
pub fn write(report: &Report, dir: &Path) -> Result<(), FormatError> {
    let json = serde_json::to_vec_pretty(report)
        .map_err(|e| FormatError::invalid(dir.join("report.json"), e.to_string()))?;
    write_bytes_atomically(&dir.join("report.json"), &json)?;
    let html = render_html(report).map_err(|e| FormatError::invalid(dir.join("report.html"), e))?;
    write_bytes_atomically(&dir.join("report.html"), html.as_bytes())
}
