//! The report's plots, SVG drawn with plotters: the control/check map over the orthophoto,
//! checkpoint error histograms, mean image residual vectors, matching success per photo,
//! ICP convergence, and accuracy against the epoch date. Maps are drawn at one scale in
//! both axes, their arrows with a stated exaggeration and a scale arrow. Titles are the
//! page's (`html`), not the plots'.

use super::model::{decimal_year, EpochReport, Report};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

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

/// The largest of 1, 2, 5 × 10^k not above `x` (> 0).
pub(crate) fn nice_floor(x: f64) -> f64 {
    if !(x > 0.0 && x.is_finite()) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|v| *v <= x * (1.0 + 1e-12))
        .unwrap_or(p)
}

/// A number as a short label: no trailing zeros (0.05, 2, 1500).
pub(crate) fn short(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

const EPOCH_COLORS: [RGBColor; 6] = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];

/// Colour of the `k`-th epoch on the map.
pub(crate) fn epoch_color(k: usize) -> RGBColor {
    EPOCH_COLORS[k % EPOCH_COLORS.len()]
}

/// Widens `x` or `y` about its centre so that one metre is as many pixels in both axes of
/// a `w` × `h` pixel plotting area.
fn isotropic(x: (f64, f64), y: (f64, f64), w: f64, h: f64) -> ((f64, f64), (f64, f64)) {
    let (sx, sy) = ((x.1 - x.0) / w, (y.1 - y.0) / h);
    let s = sx.max(sy);
    let grow = |r: (f64, f64), px: f64| {
        let (c, half) = ((r.0 + r.1) / 2.0, s * px / 2.0);
        (c - half, c + half)
    };
    (grow(x, w), grow(y, h))
}

type MapChart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
type Root<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// An arrow from `a` to `b` in pixels: the shaft and two wings at the tip.
fn arrow_px(root: &Root, a: (i32, i32), b: (i32, i32), style: ShapeStyle) -> Result<(), String> {
    let (dx, dy) = ((b.0 - a.0) as f64, (b.1 - a.1) as f64);
    let len = dx.hypot(dy);
    root.draw(&PathElement::new(vec![a, b], style))
        .map_err(plot_err)?;
    if len >= 1.0 {
        let wing = (0.3 * len).clamp(3.0, 9.0);
        for ang in [2.7f64, -2.7] {
            let (c, s) = (ang.cos(), ang.sin());
            let w = (
                b.0 + (wing * (c * dx - s * dy) / len).round() as i32,
                b.1 + (wing * (s * dx + c * dy) / len).round() as i32,
            );
            root.draw(&PathElement::new(vec![b, w], style))
                .map_err(plot_err)?;
        }
    }
    Ok(())
}

/// An arrow from `a` to `b` in world coordinates, drawn in pixels.
fn arrow(
    root: &Root,
    chart: &MapChart,
    a: (f64, f64),
    b: (f64, f64),
    style: ShapeStyle,
) -> Result<(), String> {
    arrow_px(
        root,
        chart.backend_coord(&a),
        chart.backend_coord(&b),
        style,
    )
}

/// Pixel sizes of the map plots: plot, margin, label areas, legend strip on the right.
const MAP_W: u32 = 760;
const MAP_H: u32 = 640;
const MARGIN: u32 = 12;
const X_AREA: u32 = 45;
const Y_AREA: u32 = 90;
const LEGEND_W: u32 = 220;

/// Tick labels of map axes: whole metres.
fn metres(v: &f64) -> String {
    format!("{v:.0}")
}

/// A row of a map's legend: its symbol and text.
enum Key {
    /// A marker: `true` a triangle, else a circle; its style and radius.
    Marker(bool, ShapeStyle, i32),
    /// An arrow `.0` pixels long.
    Arrow(i32, RGBColor),
    /// Text only.
    Note,
}

/// The legend in the strip right of the plot: one row of 22 px per key, from `top`.
fn legend(root: &Root, left: i32, top: i32, rows: &[(Key, String)]) -> Result<(), String> {
    let font = ("sans-serif", 13).into_font().color(&BLACK);
    for (i, (key, text)) in rows.iter().enumerate() {
        let y = top + 22 * i as i32;
        let tx = match key {
            Key::Marker(triangle, style, r) => {
                if *triangle {
                    root.draw(&TriangleMarker::new((left + 8, y), *r, *style))
                } else {
                    root.draw(&Circle::new((left + 8, y), *r, *style))
                }
                .map_err(plot_err)?;
                left + 8 + (*r).max(8) + 8
            }
            Key::Arrow(len, col) => {
                arrow_px(root, (left, y), (left + len, y), col.stroke_width(2))?;
                left + (*len).max(18) + 8
            }
            Key::Note => left,
        };
        root.draw(&Text::new(
            text.clone(),
            (tx, y),
            font.clone().pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(plot_err)?;
    }
    Ok(())
}

/// A chart of world coordinates in metres over the plotting area of `root` left of the
/// legend strip, its mesh and axes drawn.
fn map_chart<'a, 'b>(
    root: &'a Root<'b>,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> Result<MapChart<'a, 'b>, String> {
    let mut chart = ChartBuilder::on(root)
        .margin(MARGIN)
        .margin_right(MARGIN + LEGEND_W)
        .x_label_area_size(X_AREA)
        .y_label_area_size(Y_AREA)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("E (m)")
        .y_desc("N (m)")
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&metres)
        .y_label_formatter(&metres)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(plot_err)?;
    Ok(chart)
}

/// The plotting area (pixels) of a map `w` × `h` wide and high, legend strip included.
fn plot_area(w: u32, h: u32) -> (f64, f64) {
    (
        (w - 2 * MARGIN - Y_AREA - LEGEND_W) as f64,
        (h - 2 * MARGIN - X_AREA) as f64,
    )
}

/// Id of the orthophoto `<image>` in the first map; the epochs' maps `<use>` it (one
/// copy of the PNG in the page).
const ORTHO_ID: &str = "ortho-preview";

/// The world extent every map shows: every photo centre and checkpoint with a margin,
/// and the orthophoto; at one scale in both axes.
fn map_extent(report: &Report) -> ((f64, f64), (f64, f64)) {
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
    let (mut x, mut y) = (finite_range(xs), finite_range(ys));
    let pad = 0.06 * (x.1 - x.0).max(y.1 - y.0);
    (x, y) = ((x.0 - pad, x.1 + pad), (y.0 - pad, y.1 + pad));
    let data = report.epochs.iter().any(|e| {
        !e.checkpoints.is_empty() || e.photos.iter().any(|p| p.x.is_finite() && p.y.is_finite())
    });
    if let Some(o) = &report.ortho {
        if !data {
            (x, y) = ((o.extent[0], o.extent[2]), (o.extent[1], o.extent[3]));
        }
        x = (x.0.min(o.extent[0]), x.1.max(o.extent[2]));
        y = (y.0.min(o.extent[1]), y.1.max(o.extent[3]));
    }
    let (pw, ph) = plot_area(MAP_W + LEGEND_W, MAP_H);
    isotropic(x, y, pw, ph)
}

/// The map: photo centres (filled when oriented) over the orthophoto. `epoch`: that
/// epoch's photos, and its checkpoints' plan errors as arrows and height errors as
/// circles; `None`: every epoch's photos in its colour and the checkpoints (black).
pub fn map_svg(report: &Report, epoch: Option<&EpochReport>) -> Result<String, String> {
    let (xr, yr) = map_extent(report);
    let grey = RGBColor(110, 110, 110);
    let mut image = None;
    let mut s = svg(MAP_W + LEGEND_W, MAP_H, |root| {
        let mut chart = map_chart(root, xr, yr)?;
        if let Some(o) = &report.ortho {
            let a = chart.backend_coord(&(o.extent[0], o.extent[3]));
            let b = chart.backend_coord(&(o.extent[2], o.extent[1]));
            image = Some((a, b));
        }
        let left = (MAP_W - MARGIN + 14) as i32;
        let top = (MARGIN + 12) as i32;
        let photos = |chart: &mut MapChart, e: &EpochReport, col: RGBColor| {
            chart
                .draw_series(e.photos.iter().map(|p| {
                    let style = if p.oriented {
                        col.filled()
                    } else {
                        col.stroke_width(1)
                    };
                    Circle::new((p.x, p.y), 3, style)
                }))
                .map_err(plot_err)
                .map(|_| ())
        };
        let Some(e) = epoch else {
            let mut keys = Vec::new();
            for (n, e) in report.epochs.iter().enumerate() {
                photos(&mut chart, e, epoch_color(n))?;
                keys.push((
                    Key::Marker(false, epoch_color(n).filled(), 3),
                    format!("{} photos", e.name),
                ));
            }
            let mut seen = std::collections::BTreeSet::new();
            chart
                .draw_series(
                    report
                        .epochs
                        .iter()
                        .flat_map(|e| &e.checkpoints)
                        .filter(|c| seen.insert(c.id.as_str()))
                        .map(|c| TriangleMarker::new((c.x, c.y), 6, BLACK.filled())),
                )
                .map_err(plot_err)?;
            keys.push((Key::Marker(true, BLACK.filled(), 6), "checkpoints".into()));
            keys.push((
                Key::Marker(false, grey.stroke_width(1), 3),
                "photo not oriented".into(),
            ));
            return legend(root, left, top, &keys);
        };
        photos(&mut chart, e, grey)?;
        // Height errors: a circle of 3 px plus up to 15 px for the largest, red above
        // the survey, blue below.
        let max_dz = e.checkpoints.iter().map(|c| c.dz.abs()).fold(0.0, f64::max);
        let radius = |dz: f64| {
            (3.0 + 15.0 * if max_dz > 0.0 { dz.abs() / max_dz } else { 0.0 }).round() as i32
        };
        chart
            .draw_series(e.checkpoints.iter().filter(|c| c.dz.is_finite()).map(|c| {
                let col = if c.dz >= 0.0 { RED } else { BLUE };
                Circle::new((c.x, c.y), radius(c.dz), col.mix(0.35).filled())
            }))
            .map_err(plot_err)?;
        chart
            .draw_series(
                e.checkpoints
                    .iter()
                    .map(|c| TriangleMarker::new((c.x, c.y), 5, BLACK.filled())),
            )
            .map_err(plot_err)?;
        let mut keys = vec![
            (
                Key::Marker(true, BLACK.filled(), 5),
                "checkpoint".to_string(),
            ),
            (
                Key::Marker(false, grey.filled(), 3),
                "photo centre".to_string(),
            ),
            (
                Key::Marker(false, grey.stroke_width(1), 3),
                "photo not oriented".into(),
            ),
        ];
        let max = e
            .checkpoints
            .iter()
            .map(|c| c.dx.hypot(c.dy))
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        if max > 0.0 {
            // The largest plan error drawn a tenth of the map across.
            let k = 0.1 * (xr.1 - xr.0) / max;
            for c in &e.checkpoints {
                arrow(
                    root,
                    &chart,
                    (c.x, c.y),
                    (c.x + c.dx * k, c.y + c.dy * k),
                    BLACK.stroke_width(2),
                )?;
            }
            let v = nice_floor(max);
            let px = plot_area(MAP_W + LEGEND_W, MAP_H).0 / (xr.1 - xr.0) * v * k;
            keys.push((
                Key::Note,
                "plan error (arrows ×".to_string() + &short(k.round()) + ")",
            ));
            keys.push((
                Key::Arrow(px.round() as i32, BLACK),
                format!("{} m", short(v)),
            ));
        }
        if max_dz > 0.0 {
            keys.push((Key::Note, "height error (circles):".into()));
            let v = nice_floor(max_dz);
            keys.push((
                Key::Marker(false, RED.mix(0.35).filled(), radius(v)),
                format!("+{} m (above the survey)", short(v)),
            ));
            keys.push((
                Key::Marker(false, BLUE.mix(0.35).filled(), radius(v / 2.0)),
                format!("−{} m (below)", short(v / 2.0)),
            ));
        }
        legend(root, left, top, &keys)
    })?;
    // The orthophoto under everything but the white background: drawn in the first map,
    // used again by the others.
    if let (Some(o), Some(((ax, ay), (bx, by)))) = (&report.ortho, image) {
        use base64::Engine;
        let img = match epoch {
            None => format!(
                "<image id=\"{ORTHO_ID}\" x=\"{ax}\" y=\"{ay}\" width=\"{}\" height=\"{}\" \
                 preserveAspectRatio=\"none\" opacity=\"0.6\" href=\"data:image/png;base64,{}\"/>\n",
                bx - ax,
                by - ay,
                base64::engine::general_purpose::STANDARD.encode(&o.png)
            ),
            Some(_) => format!("<use href=\"#{ORTHO_ID}\"/>\n"),
        };
        if let Some(i) = s
            .find("<rect")
            .and_then(|i| s[i..].find("/>").map(|j| i + j + 2))
        {
            let at = s[i..].find('\n').map_or(i, |j| i + j + 1);
            s.insert_str(at, &img);
        }
    }
    Ok(s)
}

/// Histogram of checkpoint errors (plan and height) for one epoch.
pub fn histogram_svg(e: &EpochReport) -> Result<String, String> {
    let plan: Vec<f64> = e.checkpoints.iter().map(|c| c.dx.hypot(c.dy)).collect();
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
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(45)
            .build_cartesian_2d(0.0..max * 1.0001, 0usize..top + 1)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("|error| (m)")
            .y_desc("checkpoints")
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
            .draw()
            .map_err(plot_err)?;
        // Plan in blue, height in red (the page's caption says so).
        for (h, col, off) in [(&hp, BLUE, 0.0), (&hh, RED, 0.5)] {
            chart
                .draw_series(h.iter().enumerate().map(|(i, &n)| {
                    let x = i as f64 * w + off * w;
                    Rectangle::new([(x, 0), (x + 0.5 * w, n)], col.mix(0.7).filled())
                }))
                .map_err(plot_err)?;
        }
        Ok(())
    })
}

/// Mean image residual vectors per photo, drawn at the photo centres with a stated
/// factor and a scale arrow (image y is down: a positive row residual points south).
pub fn residuals_svg(e: &EpochReport) -> Result<String, String> {
    let (w, h) = (480 + LEGEND_W, 440u32);
    let (pw, ph) = plot_area(w, h);
    let x = finite_range(e.photos.iter().map(|p| p.x));
    let y = finite_range(e.photos.iter().map(|p| p.y));
    // Room for the arrows around the photos.
    let pad = 0.1 * (x.1 - x.0).max(y.1 - y.0);
    let (xr, yr) = isotropic((x.0 - pad, x.1 + pad), (y.0 - pad, y.1 + pad), pw, ph);
    let max = e
        .photos
        .iter()
        .filter(|p| p.oriented)
        .map(|p| p.mean_residual_px[0].hypot(p.mean_residual_px[1]))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    svg(w, h, |root| {
        let chart = map_chart(root, xr, yr)?;
        let mut keys = vec![
            (
                Key::Marker(false, BLACK.filled(), 3),
                "photo centre".to_string(),
            ),
            (
                Key::Marker(false, BLACK.stroke_width(1), 3),
                "photo not oriented".into(),
            ),
        ];
        if max > 0.0 {
            // The largest vector drawn 15 % of the map across.
            let k = 0.15 * (xr.1 - xr.0) / max;
            for p in e.photos.iter().filter(|p| p.oriented) {
                let [dx, dy] = p.mean_residual_px;
                if dx.is_finite() && dy.is_finite() {
                    arrow(
                        root,
                        &chart,
                        (p.x, p.y),
                        (p.x + k * dx, p.y - k * dy),
                        RED.stroke_width(2),
                    )?;
                }
            }
            let v = nice_floor(max);
            let px = pw / (xr.1 - xr.0) * v * k;
            keys.push((Key::Note, "mean image residual".into()));
            keys.push((
                Key::Note,
                format!("(arrows: 1 px = {} m)", short(k.round())),
            ));
            keys.push((
                Key::Arrow(px.round() as i32, RED),
                format!("{} px", short(v)),
            ));
        }
        for p in &e.photos {
            let style = if p.oriented {
                BLACK.filled()
            } else {
                BLACK.stroke_width(1)
            };
            root.draw(&Circle::new(chart.backend_coord(&(p.x, p.y)), 3, style))
                .map_err(plot_err)?;
        }
        legend(
            root,
            (w - LEGEND_W - MARGIN + 14) as i32,
            (MARGIN + 12) as i32,
            &keys,
        )
    })
}

/// Matched / predicted control patches per photo, one bar per photo named on its axis.
pub fn matching_svg(e: &EpochReport) -> Result<String, String> {
    let n = e.photos.len().max(1);
    let row = if n > 60 { 9 } else { 18 };
    let h = (70 + row * n) as u32;
    let longest = e
        .photos
        .iter()
        .map(|p| p.name.chars().count())
        .max()
        .unwrap_or(4);
    let label_area = (longest * 8 + 16).clamp(60, 260) as u32;
    // Every photo named up to 60, then every k-th.
    let every = n.div_ceil(60);
    let names: Vec<&str> = e.photos.iter().map(|p| p.name.as_str()).collect();
    svg(560, h, |root| {
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .margin_right(24)
            .x_label_area_size(40)
            .y_label_area_size(label_area)
            .build_cartesian_2d(0.0..1.0, (0..n).into_segmented())
            .map_err(plot_err)?;
        let label = |v: &SegmentValue<usize>| match v {
            // Photos from the top: the first photo is the top bar.
            SegmentValue::CenterOf(i) if *i < n && (n - 1 - i) % every == 0 => {
                names.get(n - 1 - i).unwrap_or(&"").to_string()
            }
            _ => String::new(),
        };
        chart
            .configure_mesh()
            .x_desc("matched / predicted control patches")
            .y_labels(n)
            .y_label_formatter(&label)
            .x_label_formatter(&|v| format!("{:.0} %", v * 100.0))
            .label_style(("sans-serif", if n > 60 { 9 } else { 12 }))
            .axis_desc_style(("sans-serif", 14))
            .disable_y_mesh()
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
                let y = n - 1 - i;
                Rectangle::new(
                    [
                        (0.0, SegmentValue::Exact(y)),
                        (r.min(1.0), SegmentValue::Exact(y + 1)),
                    ],
                    col.mix(0.7).filled(),
                )
            }))
            .map_err(plot_err)?;
        // A white line between bars.
        chart
            .draw_series((1..n).map(|y| {
                PathElement::new(
                    vec![(0.0, SegmentValue::Exact(y)), (1.0, SegmentValue::Exact(y))],
                    WHITE.stroke_width(2),
                )
            }))
            .map_err(plot_err)?;
        Ok(())
    })
}

/// ICP RMSE per iteration.
pub fn icp_svg(e: &EpochReport) -> Result<String, String> {
    let n = e.icp.len().max(2);
    let (_, hi) = finite_range(e.icp.iter().map(|i| i.rmse_m));
    svg(480, 300, |root| {
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(0usize..n, 0.0..hi.max(1e-3))
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("RMSE (m)")
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
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

/// Checkpoint RMSE in plan and height against the epoch date: in metres (left) and in
/// ground pixels (right). Epochs without a date or checkpoints are left out.
pub fn accuracy_by_date_svg(report: &Report) -> Result<String, String> {
    let mut pts: Vec<(f64, &EpochReport)> = report
        .epochs
        .iter()
        .filter_map(|e| Some((decimal_year(&e.date)?, e)))
        .filter(|(_, e)| e.check_rmse_plan_m.is_finite() || e.check_rmse_height_m.is_finite())
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (t0, t1) = finite_range(pts.iter().map(|p| p.0));
    // Room for the epochs' names at both ends.
    let pad = (0.08 * (t1 - t0)).max(2.0);
    let (t0, t1) = ((t0 - pad).floor(), (t1 + pad).ceil());
    svg(1000, 360, |root| {
        let panels = root.split_evenly((1, 2));
        for (panel, per_gsd) in panels.iter().zip([false, true]) {
            let v = |e: &EpochReport, m: f64| if per_gsd { m / e.gsd_m } else { m };
            let top = pts
                .iter()
                .flat_map(|(_, e)| [v(e, e.check_rmse_plan_m), v(e, e.check_rmse_height_m)])
                .filter(|x| x.is_finite())
                .fold(0.0, f64::max);
            let top = if top > 0.0 { top * 1.25 } else { 1.0 };
            let mut chart = ChartBuilder::on(panel)
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(t0..t1, 0.0..top)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("epoch date (year)")
                .y_desc(if per_gsd {
                    "checkpoint RMSE (GSD)"
                } else {
                    "checkpoint RMSE (m)"
                })
                .x_labels(8)
                .x_label_formatter(&|y| format!("{y:.0}"))
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .draw()
                .map_err(plot_err)?;
            // Plan in blue, height in red (the page's caption says so).
            for (col, height) in [(BLUE, false), (RED, true)] {
                let series: Vec<(f64, f64)> = pts
                    .iter()
                    .map(|(t, e)| {
                        let m = if height {
                            e.check_rmse_height_m
                        } else {
                            e.check_rmse_plan_m
                        };
                        (*t, v(e, m))
                    })
                    .filter(|p| p.1.is_finite())
                    .collect();
                chart
                    .draw_series(LineSeries::new(series.clone(), col.stroke_width(2)))
                    .map_err(plot_err)?;
                chart
                    .draw_series(series.iter().map(|p| Circle::new(*p, 4, col.filled())))
                    .map_err(plot_err)?;
            }
            // Each epoch named above its points.
            chart
                .draw_series(pts.iter().map(|(t, e)| {
                    let y = v(e, e.check_rmse_plan_m)
                        .max(v(e, e.check_rmse_height_m))
                        .max(0.0);
                    Text::new(
                        e.name.clone(),
                        (*t, y + 0.04 * top),
                        ("sans-serif", 12)
                            .into_font()
                            .color(&BLACK)
                            .pos(Pos::new(HPos::Center, VPos::Bottom)),
                    )
                }))
                .map_err(plot_err)?;
        }
        Ok(())
    })
}
