//! The accuracy report: JSON for machines and a self-contained HTML page with the plots a
//! photogrammetrist looks at (control/check map over the orthophoto, residual vectors per
//! photo, checkpoint error histograms, ICP convergence, matching success per photo, the
//! time series of accuracy). Plots are SVG drawn with plotters and inlined, so the page
//! needs no network and no companion files.

use super::tie_statistics::{PhotoTies, TieStatistics};
use crate::adjust::VarianceComponent;
use crate::formats::{write_bytes_atomically, FormatError};
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Reads a number that JSON may hold as `null` (serde_json writes NaN so): absent
/// statistics (no checkpoints, no adjustment) stay NaN through a round trip.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// One checkpoint's error: adjusted minus surveyed (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointError {
    pub id: String,
    pub x: f64,
    pub y: f64,
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    /// The photos it was intersected from (its measurements kept).
    #[serde(default)]
    pub rays: usize,
}

/// Per-photo summary of the adjustment and of the patch matching.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoSummary {
    pub name: String,
    /// Projection centre, world XY.
    #[serde(deserialize_with = "nan_if_null")]
    pub x: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub y: f64,
    pub oriented: bool,
    /// Mean image residual vector (px) and RMS (px).
    pub mean_residual_px: [f64; 2],
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_px: f64,
    /// Control patches predicted in the photo and matched (accepted).
    pub patches_predicted: usize,
    pub patches_matched: usize,
    /// The photo's tie points and control in the adjusted block.
    #[serde(default)]
    pub ties: PhotoTies,
}

/// Statistics of one ICP iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcpIteration {
    pub iteration: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_m: f64,
    pub inliers: usize,
}

/// Results of one epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochReport {
    pub name: String,
    pub date: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub gsd_m: f64,
    pub photos_total: usize,
    pub photos_oriented: usize,
    /// Of the oriented photos, those oriented through tie points with the epoch's other
    /// photos only (no control patch of their own).
    #[serde(default)]
    pub photos_through_ties: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_rmse_plan_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_rmse_height_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub check_max_m: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma0: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_px: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub time_s: f64,
    #[serde(default)]
    pub checkpoints: Vec<CheckpointError>,
    /// Checkpoints whose rays could not be made to agree (not in the RMSE).
    #[serde(default)]
    pub checkpoints_not_evaluated: usize,
    /// Checkpoint measurements left out of the evaluation, and why.
    #[serde(default)]
    pub checkpoint_rejections: Vec<crate::control::checkpoints::RejectedMeasurement>,
    #[serde(default)]
    pub photos: Vec<PhotoSummary>,
    #[serde(default)]
    pub icp: Vec<IcpIteration>,
    /// What controlled the epoch (LiDAR, an existing block, the DCP packages used).
    #[serde(default)]
    pub control: Vec<String>,
    /// Tie points and control of the adjusted block.
    #[serde(default)]
    pub ties: TieStatistics,
    /// σ0 per observation group of the epoch's adjustment.
    #[serde(default)]
    pub variance_components: Vec<VarianceComponent>,
}

impl EpochReport {
    /// Checkpoint RMSE in plan and height, and the largest 3-D error, from the rows.
    pub fn set_check_statistics(&mut self) {
        let n = self.checkpoints.len();
        if n == 0 {
            (
                self.check_rmse_plan_m,
                self.check_rmse_height_m,
                self.check_max_m,
            ) = (f64::NAN, f64::NAN, f64::NAN);
            return;
        }
        let plan = self
            .checkpoints
            .iter()
            .map(|c| c.dx * c.dx + c.dy * c.dy)
            .sum::<f64>()
            / n as f64;
        let h = self.checkpoints.iter().map(|c| c.dz * c.dz).sum::<f64>() / n as f64;
        self.check_rmse_plan_m = plan.sqrt();
        self.check_rmse_height_m = h.sqrt();
        self.check_max_m = self
            .checkpoints
            .iter()
            .map(|c| (c.dx * c.dx + c.dy * c.dy + c.dz * c.dz).sqrt())
            .fold(0.0, f64::max);
    }
}

/// Orthophoto preview for the map: a PNG and its world extent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrthoPreview {
    /// PNG bytes (not serialised to JSON).
    #[serde(skip)]
    pub png: Vec<u8>,
    /// World extent (x_min, y_min, x_max, y_max).
    pub extent: [f64; 4],
}

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub project: String,
    pub crs: String,
    pub epochs: Vec<EpochReport>,
    #[serde(skip)]
    pub ortho: Option<OrthoPreview>,
}

fn plot_err<E: std::fmt::Debug>(e: E) -> String {
    format!("plot: {e:?}")
}

fn svg<F>(w: u32, h: u32, draw: F) -> Result<String, String>
where
    F: FnOnce(&DrawingArea<SVGBackend, Shift>) -> Result<(), String>,
{
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        draw(&root)?;
        root.present().map_err(plot_err)?;
    }
    Ok(s)
}

fn finite_range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-9 {
        return (lo - 0.5, hi + 0.5);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

const EPOCH_COLORS: [RGBColor; 6] = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];

/// Map of checkpoints (plan error vectors, exaggerated) and photo centres over the orthophoto.
fn map_svg(report: &Report) -> Result<String, String> {
    let xs = report.epochs.iter().flat_map(|e| {
        e.checkpoints
            .iter()
            .map(|c| c.x)
            .chain(e.photos.iter().map(|p| p.x))
    });
    let ys = report.epochs.iter().flat_map(|e| {
        e.checkpoints
            .iter()
            .map(|c| c.y)
            .chain(e.photos.iter().map(|p| p.y))
    });
    let (mut x0, mut x1) = finite_range(xs);
    let (mut y0, mut y1) = finite_range(ys);
    if let Some(o) = &report.ortho {
        (x0, y0, x1, y1) = (o.extent[0], o.extent[1], o.extent[2], o.extent[3]);
    }
    let max_err = report
        .epochs
        .iter()
        .flat_map(|e| {
            e.checkpoints
                .iter()
                .map(|c| (c.dx * c.dx + c.dy * c.dy).sqrt())
        })
        .fold(0.0, f64::max);
    let exaggeration = if max_err > 0.0 {
        0.08 * (x1 - x0).max(y1 - y0) / max_err
    } else {
        1.0
    };
    svg(760, 640, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("Checkpoints (plan error ×{exaggeration:.0}) and photo centres"),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("E (m)")
            .y_desc("N (m)")
            .draw()
            .map_err(plot_err)?;
        for (k, e) in report.epochs.iter().enumerate() {
            let col = EPOCH_COLORS[k % EPOCH_COLORS.len()];
            chart
                .draw_series(e.photos.iter().map(|p| {
                    let style = if p.oriented {
                        col.filled()
                    } else {
                        col.stroke_width(1)
                    };
                    Circle::new((p.x, p.y), 3, style)
                }))
                .map_err(plot_err)?
                .label(format!("{} photos", e.name))
                .legend(move |(x, y)| Circle::new((x, y), 3, col.filled()));
            chart
                .draw_series(e.checkpoints.iter().map(|c| {
                    PathElement::new(
                        vec![
                            (c.x, c.y),
                            (c.x + c.dx * exaggeration, c.y + c.dy * exaggeration),
                        ],
                        col.stroke_width(2),
                    )
                }))
                .map_err(plot_err)?;
            chart
                .draw_series(
                    e.checkpoints
                        .iter()
                        .map(|c| TriangleMarker::new((c.x, c.y), 5, col.filled())),
                )
                .map_err(plot_err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(plot_err)?;
        Ok(())
    })
}

/// Histogram of checkpoint errors (plan and height) for one epoch.
fn histogram_svg(e: &EpochReport) -> Result<String, String> {
    let plan: Vec<f64> = e
        .checkpoints
        .iter()
        .map(|c| (c.dx * c.dx + c.dy * c.dy).sqrt())
        .collect();
    let height: Vec<f64> = e.checkpoints.iter().map(|c| c.dz.abs()).collect();
    let max = plan
        .iter()
        .chain(&height)
        .cloned()
        .fold(0.0, f64::max)
        .max(1e-3);
    let bins = 12usize;
    let w = max / bins as f64 * 1.0001;
    let count = |v: &[f64]| {
        let mut h = vec![0usize; bins];
        for x in v {
            h[((x / w) as usize).min(bins - 1)] += 1;
        }
        h
    };
    let (hp, hh) = (count(&plan), count(&height));
    let top = hp.iter().chain(&hh).cloned().max().unwrap_or(1).max(1);
    svg(480, 300, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(format!("{}: checkpoint errors", e.name), ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(35)
            .build_cartesian_2d(0.0..max * 1.0001, 0usize..top + 1)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("|error| (m)")
            .y_desc("count")
            .draw()
            .map_err(plot_err)?;
        for (h, col, label, off) in [(&hp, BLUE, "plan", 0.0), (&hh, RED, "height", 0.5)] {
            chart
                .draw_series(h.iter().enumerate().map(|(i, &n)| {
                    let x = i as f64 * w + off * w;
                    Rectangle::new([(x, 0), (x + 0.5 * w, n)], col.mix(0.7).filled())
                }))
                .map_err(plot_err)?
                .label(label)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 10, y + 5)], col.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(plot_err)?;
        Ok(())
    })
}

/// Mean image residual vectors per photo, drawn at the photo centres.
fn residuals_svg(e: &EpochReport) -> Result<String, String> {
    let (x0, x1) = finite_range(e.photos.iter().map(|p| p.x));
    let (y0, y1) = finite_range(e.photos.iter().map(|p| p.y));
    let max = e
        .photos
        .iter()
        .map(|p| p.mean_residual_px[0].hypot(p.mean_residual_px[1]))
        .fold(0.0, f64::max);
    let k = if max > 0.0 {
        0.1 * (x1 - x0).max(y1 - y0) / max
    } else {
        1.0
    };
    svg(480, 380, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "{}: mean image residual per photo (1 px = {k:.1} m)",
                    e.name
                ),
                ("sans-serif", 15),
            )
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(plot_err)?;
        chart.configure_mesh().draw().map_err(plot_err)?;
        chart
            .draw_series(e.photos.iter().map(|p| {
                // Image y is down: a positive row residual points south on the map.
                PathElement::new(
                    vec![
                        (p.x, p.y),
                        (
                            p.x + k * p.mean_residual_px[0],
                            p.y - k * p.mean_residual_px[1],
                        ),
                    ],
                    RED.stroke_width(2),
                )
            }))
            .map_err(plot_err)?;
        chart
            .draw_series(
                e.photos
                    .iter()
                    .map(|p| Circle::new((p.x, p.y), 2, BLACK.filled())),
            )
            .map_err(plot_err)?;
        Ok(())
    })
}

/// Matching success ratio per photo.
fn matching_svg(e: &EpochReport) -> Result<String, String> {
    let n = e.photos.len().max(1);
    svg(480, 300, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("{}: matched / predicted patches per photo", e.name),
                ("sans-serif", 15),
            )
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(0usize..n, 0.0..1.05)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("photo")
            .y_desc("success ratio")
            .draw()
            .map_err(plot_err)?;
        chart
            .draw_series(e.photos.iter().enumerate().map(|(i, p)| {
                let r = if p.patches_predicted > 0 {
                    p.patches_matched as f64 / p.patches_predicted as f64
                } else {
                    0.0
                };
                let col = if p.oriented { GREEN } else { RED };
                Rectangle::new([(i, 0.0), (i + 1, r)], col.mix(0.7).filled())
            }))
            .map_err(plot_err)?;
        Ok(())
    })
}

/// ICP RMSE per iteration.
fn icp_svg(e: &EpochReport) -> Result<String, String> {
    let n = e.icp.len().max(2);
    let (_, hi) = finite_range(e.icp.iter().map(|i| i.rmse_m));
    svg(480, 300, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(format!("{}: ICP convergence", e.name), ("sans-serif", 15))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(0usize..n, 0.0..hi.max(1e-3))
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("RMSE (m)")
            .draw()
            .map_err(plot_err)?;
        chart
            .draw_series(LineSeries::new(
                e.icp.iter().map(|i| (i.iteration, i.rmse_m)),
                BLUE.stroke_width(2),
            ))
            .map_err(plot_err)?;
        chart
            .draw_series(
                e.icp
                    .iter()
                    .map(|i| Circle::new((i.iteration, i.rmse_m), 3, BLUE.filled())),
            )
            .map_err(plot_err)?;
        Ok(())
    })
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

/// An epoch's tie points, control and observation groups, and each photo's coverage of
/// the standard positions (a required position short of points in red, one outside every
/// overlap in grey).
fn ties_html(e: &EpochReport) -> String {
    let t = &e.ties;
    let mult = t
        .multiplicity
        .iter()
        .map(|(k, n)| format!("{n}×{k}"))
        .collect::<Vec<_>>()
        .join(", ");
    let mean = if t.points > 0 {
        t.observations as f64 / t.points as f64
    } else {
        f64::NAN
    };
    let mut h = format!(
        "<h3>Tie points and control</h3><table><tr><th>tie points</th><th>observations</th>\
         <th>mean photos per point</th><th>points × photos</th><th>control points</th>\
         <th>control observations</th><th>photos through tie points only</th>\
         <th>photos short of {} points at a standard position</th></tr>\
         <tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
        t.min_per_position,
        t.points,
        t.observations,
        fmt(mean, 2),
        esc(&mult),
        t.control_points,
        t.control_observations,
        e.photos_through_ties,
        t.photos_short
    );
    if !e.variance_components.is_empty() {
        h.push_str("<h3>Observation groups</h3><table><tr><th>group</th><th>observations</th><th>redundancy</th><th>σ0 (a-priori σ = 1)</th></tr>");
        for v in &e.variance_components {
            h.push_str(&format!(
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&v.group),
                v.observations,
                fmt(v.redundancy, 1),
                v.sigma0.map_or("–".into(), |s| fmt(s, 2))
            ));
        }
        h.push_str("</table>");
    }
    h.push_str("<h3>Standard positions per photo</h3><table><tr><th>photo</th><th>tie obs.</th><th>control obs.</th>");
    for pos in ["TL", "TC", "TR", "ML", "MC", "MR", "BL", "BC", "BR"] {
        h.push_str(&format!("<th>{pos}</th>"));
    }
    h.push_str("</tr>");
    for p in &e.photos {
        let name = if p.oriented {
            esc(&p.name)
        } else {
            format!("{} (not oriented)", esc(&p.name))
        };
        h.push_str(&format!(
            "<tr><td>{name}</td><td>{}</td><td>{}</td>",
            p.ties.tie_observations, p.ties.control_observations
        ));
        for k in 0..9 {
            let style = if !p.ties.required[k] {
                " style=\"color:#999\""
            } else if p.ties.positions[k] < e.ties.min_per_position {
                " style=\"background:#f4b6b6\""
            } else {
                ""
            };
            h.push_str(&format!("<td{style}>{}</td>", p.ties.positions[k]));
        }
        h.push_str("</tr>");
    }
    h.push_str("</table>");
    h
}

/// The self-contained HTML page.
pub fn render_html(report: &Report) -> Result<String, String> {
    let mut html = String::new();
    html.push_str("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">");
    html.push_str(&format!(
        "<title>cloudcontrol report — {}</title>",
        esc(&report.project)
    ));
    html.push_str(
        "<style>body{font-family:sans-serif;margin:24px;color:#222}table{border-collapse:collapse}\
         td,th{border:1px solid #bbb;padding:4px 8px;text-align:right}th{background:#eee}\
         .plots{display:flex;flex-wrap:wrap;gap:12px}.plot{border:1px solid #ddd}\
         .map{position:relative;display:inline-block}.map img{position:absolute;left:80px;top:45px;width:670px;height:560px;opacity:.55}</style>",
    );
    html.push_str("</head><body>");
    html.push_str(&format!(
        "<h1>cloudcontrol accuracy report — {}</h1><p>CRS {} · {} epochs</p>",
        esc(&report.project),
        esc(&report.crs),
        report.epochs.len()
    ));
    html.push_str("<h2>Accuracy through time</h2><table><tr><th>epoch</th><th>date</th><th>GSD (m)</th><th>photos oriented</th><th>check RMSE plan (m)</th><th>height (m)</th><th>plan (px)</th><th>height (px)</th><th>max (m)</th><th>σ0</th><th>image RMSE (px)</th><th>time (s)</th><th>controlled by</th></tr>");
    for e in &report.epochs {
        html.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}/{}{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&e.name),
            esc(&e.date),
            fmt(e.gsd_m, 2),
            e.photos_oriented,
            e.photos_total,
            if e.photos_through_ties > 0 {
                format!(" ({} through tie points)", e.photos_through_ties)
            } else {
                String::new()
            },
            fmt(e.check_rmse_plan_m, 3),
            fmt(e.check_rmse_height_m, 3),
            fmt(e.check_rmse_plan_m / e.gsd_m, 2),
            fmt(e.check_rmse_height_m / e.gsd_m, 2),
            fmt(e.check_max_m, 3),
            fmt(e.sigma0, 2),
            fmt(e.rmse_px, 2),
            fmt(e.time_s, 1),
            esc(&e.control.join("; "))
        ));
    }
    html.push_str("</table>");
    html.push_str("<h2>Control and checkpoints</h2><div class=\"map\">");
    if let Some(o) = &report.ortho {
        use base64::Engine;
        html.push_str(&format!(
            "<img alt=\"orthophoto\" src=\"data:image/png;base64,{}\">",
            base64::engine::general_purpose::STANDARD.encode(&o.png)
        ));
    }
    html.push_str(&format!(
        "<div class=\"plot\" id=\"map\">{}</div></div>",
        map_svg(report)?
    ));
    for e in &report.epochs {
        html.push_str(&format!(
            "<h2>Epoch {}</h2><div class=\"plots\">",
            esc(&e.name)
        ));
        html.push_str(&format!("<div class=\"plot\">{}</div>", histogram_svg(e)?));
        if !e.photos.is_empty() {
            html.push_str(&format!("<div class=\"plot\">{}</div>", residuals_svg(e)?));
        }
        // The reference epoch is tied by image matching, not by control patches.
        if e.photos.iter().any(|p| p.patches_predicted > 0) {
            html.push_str(&format!("<div class=\"plot\">{}</div>", matching_svg(e)?));
        }
        if !e.icp.is_empty() {
            html.push_str(&format!("<div class=\"plot\">{}</div>", icp_svg(e)?));
        }
        html.push_str("</div>");
        html.push_str(&ties_html(e));
    }
    html.push_str("</body></html>\n");
    Ok(html)
}

/// Writes `report.json` and `report.html` into `dir`, atomically.
pub fn write(report: &Report, dir: &Path) -> Result<(), FormatError> {
    let json = serde_json::to_vec_pretty(report)
        .map_err(|e| FormatError::invalid(dir.join("report.json"), e.to_string()))?;
    write_bytes_atomically(&dir.join("report.json"), &json)?;
    let html = render_html(report).map_err(|e| FormatError::invalid(dir.join("report.html"), e))?;
    write_bytes_atomically(&dir.join("report.html"), html.as_bytes())
}
