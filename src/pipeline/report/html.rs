//! The self-contained HTML page: the run (version, project hash, date, options), its
//! warnings, accuracy through time (table and plot), the LiDAR's check and its strips'
//! offsets, the map, and per epoch its warnings, checkpoints, rejected checkpoint
//! measurements, film scans, plots and tie statistics. Every section has an `id`
//! (`run-info`, `warnings`, `accuracy-by-date`, `lidar-check`, `lidar-strips`, `map`, and
//! `<section>-<epoch>` per epoch) so that a
//! reader or a test can find it.

use super::model::{EpochReport, Report, Warning};
use super::plots;

pub(crate) fn esc(s: &str) -> String {
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

fn fmt_signed(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:+.digits$}")
    } else {
        "–".into()
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    fmt(v.unwrap_or(f64::NAN), digits)
}

/// An epoch name as part of an element id: letters, digits, `-` and `_` kept, the rest `_`.
pub fn epoch_id(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// A figure: an SVG plot under its title.
fn figure(id: &str, title: &str, svg: &str) -> String {
    format!(
        "<figure class=\"plot\" id=\"{id}\"><figcaption>{}</figcaption>{svg}</figure>",
        esc(title)
    )
}

fn warning_items(ws: &[Warning]) -> String {
    ws.iter()
        .map(|w| {
            format!(
                "<li><span class=\"kind\">{}</span> {}</li>",
                esc(&kind_label(w)),
                esc(&w.message)
            )
        })
        .collect()
}

fn kind_label(w: &Warning) -> String {
    serde_json::to_value(w.kind)
        .ok()
        .and_then(|v| v.as_str().map(|s| s.replace('_', " ")))
        .unwrap_or_default()
}

/// Version, project hash, date, and the options and thresholds of the run.
fn run_info_html(report: &Report) -> String {
    let Some(r) = &report.run else {
        return String::new();
    };
    let mut h = String::from("<section id=\"run-info\"><h2>Run</h2><table class=\"kv\">");
    let row = |k: &str, v: &str| format!("<tr><th>{k}</th><td>{v}</td></tr>");
    h.push_str(&row("cloudcontrol", &esc(&r.cloudcontrol_version)));
    h.push_str(&row(
        "project file SHA-256",
        &format!(
            "<code>{}</code>",
            esc(r.project_sha256.as_deref().unwrap_or("–"))
        ),
    ));
    h.push_str(&row("report made (UTC)", &esc(&r.date_utc)));
    let o = &r.options;
    h.push_str(&row("thresholds", &esc(&key_values(&o.thresholds))));
    h.push_str(&row("outputs", &esc(&key_values(&o.outputs))));
    h.push_str(&row(
        "control σ",
        &format!(
            "LiDAR datum {} m; orthophoto {}; DEM {} m",
            fmt(o.lidar_datum_sigma_m, 3),
            o.orthophoto_sigma_m
                .map_or("one orthophoto pixel".into(), |s| format!(
                    "{} m",
                    fmt(s, 3)
                )),
            fmt(o.dem_sigma_m, 2)
        ),
    ));
    h.push_str(&row(
        "checkpoints",
        &format!(
            "measurements tested with σ = {} px; CRS {}",
            fmt(o.checkpoint_measurement_sigma_px, 1),
            esc(o.checkpoints_crs.as_deref().unwrap_or("the project's"))
        ),
    ));
    for e in &o.epochs {
        let sc = match &e.self_calibration {
            Some(v) if v.is_empty() => "none".to_string(),
            Some(v) => v.join(", "),
            None => "default".to_string(),
        };
        let scan = e
            .scan_pixel_um
            .map_or(String::new(), |p| format!("; scan pixel {} µm", fmt(p, 3)));
        h.push_str(&row(
            &format!("epoch {}", esc(&e.name)),
            &format!("date {}; self-calibration {}{scan}", esc(&e.date), esc(&sc)),
        ));
    }
    let d = &o.default_self_calibration;
    h.push_str(&row(
        "default self-calibration",
        &esc(&format!(
            "reference: {}; archive frame camera: {}; archive film camera: {}",
            list_or_none(&d.reference),
            list_or_none(&d.archive_frame),
            list_or_none(&d.archive_film)
        )),
    ));
    h.push_str("</table></section>");
    h
}

fn list_or_none(v: &[String]) -> String {
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

/// An option block in one line: `key = value, …` (JSON values).
fn key_values(v: &impl serde::Serialize) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::Object(m)) => m
            .iter()
            .map(|(k, v)| format!("{k} = {v}"))
            .collect::<Vec<_>>()
            .join(", "),
        Ok(v) => v.to_string(),
        Err(_) => String::new(),
    }
}

/// The run's warnings and each epoch's, in one list at the top.
fn warnings_html(report: &Report) -> String {
    let n = report.warnings.len()
        + report
            .epochs
            .iter()
            .map(|e| e.warnings.len())
            .sum::<usize>();
    let mut h = format!("<section id=\"warnings\"><h2>Warnings ({n})</h2>");
    if n == 0 {
        h.push_str("<p>None.</p></section>");
        return h;
    }
    h.push_str("<ul>");
    h.push_str(&warning_items(&report.warnings));
    h.push_str("</ul>");
    for e in report.epochs.iter().filter(|e| !e.warnings.is_empty()) {
        h.push_str(&format!(
            "<h3>Epoch {}</h3><ul>{}</ul>",
            esc(&e.name),
            warning_items(&e.warnings)
        ));
    }
    h.push_str("</section>");
    h
}

/// The LiDAR strips' offsets the cleaning removed: the model, its σ0 and one row per strip.
fn lidar_strips_html(report: &Report) -> String {
    let Some(s) = &report.lidar_strips else {
        return String::new();
    };
    let model = match s.model {
        crate::lidar::clean::OffsetModel::Vertical => "a height offset per strip",
        _ => "a 3-D shift per strip",
    };
    let datum = match s.reference {
        Some(r) => format!("strip {r} held"),
        None => "zero mean over the strips".into(),
    };
    let mut h = format!(
        "<section id=\"lidar-strips\"><h2>LiDAR strips</h2>\
         <p>Offsets between overlapping strips from point-to-plane distances, removed before \
         the LiDAR serves as control: {model} ({datum}), σ0 {} m{}.</p>\
         <table><tr><th>strip</th><th>points</th><th>dx (m)</th><th>dy (m)</th><th>dz (m)</th>\
         <th>σ x, y, z (m)</th></tr>",
        fmt(s.sigma0_m, 3),
        s.vertical_because
            .as_ref()
            .map_or(String::new(), |w| format!(
                "; in height alone because {}",
                esc(w)
            )),
    );
    for st in &s.strips {
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}, {}, {}</td></tr>",
            st.source_id,
            st.points,
            fmt_signed(st.offset_m[0], 3),
            fmt_signed(st.offset_m[1], 3),
            fmt_signed(st.offset_m[2], 3),
            fmt(st.sigma_m[0], 4),
            fmt(st.sigma_m[1], 4),
            fmt(st.sigma_m[2], 4),
        ));
    }
    h.push_str("</table></section>");
    h
}

/// The LiDAR against the surveyed checkpoints: statistics and one row per checkpoint.
fn lidar_html(report: &Report) -> String {
    let Some(l) = &report.lidar_checkpoints else {
        return String::new();
    };
    let mut h = format!(
        "<section id=\"lidar-check\"><h2>LiDAR against the checkpoints</h2>\
         <p>Height of the LiDAR ground at each surveyed checkpoint: a plane through the \
         {} nearest ground points within {} m (at least {}); dz = LiDAR − checkpoint.</p>\
         <table><tr><th>checkpoints</th><th>skipped</th><th>mean dz (m)</th><th>σ (m)</th>\
         <th>RMSE (m)</th><th>max |dz| (m)</th><th>3σ outliers</th><th>RMSE without outliers (m)</th></tr>\
         <tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
        l.k,
        fmt(l.radius_m, 1),
        l.min_points,
        l.count,
        l.skipped,
        fmt_signed(l.mean_m, 3),
        fmt(l.std_m, 3),
        fmt(l.rmse_m, 3),
        fmt(l.max_abs_m, 3),
        if l.outliers.is_empty() {
            "0".to_string()
        } else {
            esc(&l.outliers.join(", "))
        },
        fmt(l.rmse_without_outliers_m, 3),
    );
    h.push_str(
        "<table id=\"lidar-check-rows\"><tr><th>id</th><th>E (m)</th><th>N (m)</th><th>Z (m)</th>\
         <th>LiDAR Z (m)</th><th>dz (m)</th><th>ground points</th><th>plane RMS (m)</th><th></th></tr>",
    );
    for r in &l.rows {
        let note = match (&r.skipped, r.outlier) {
            (Some(s), _) => format!("skipped: {}", esc(s)),
            (None, true) => "outlier".into(),
            _ => String::new(),
        };
        let class = if r.outlier || r.skipped.is_some() {
            " class=\"bad\""
        } else {
            ""
        };
        h.push_str(&format!(
            "<tr{class}><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{note}</td></tr>",
            esc(&r.id),
            fmt(r.x, 3),
            fmt(r.y, 3),
            fmt(r.z, 3),
            opt(r.lidar_z, 3),
            r.dz_m.map_or("–".into(), |d| fmt_signed(d, 3)),
            r.neighbours,
            opt(r.plane_rms_m, 3),
        ));
    }
    h.push_str("</table></section>");
    h
}

/// The accuracy table, one row per epoch.
/// Each epoch's own surface against the control's and the next younger epoch's: the
/// Nuth & Kääb shift in ground pixels (a check of the orientation) and dh on stable
/// terrain. Empty when no epoch has a comparison.
fn surface_change_table(report: &Report) -> String {
    if report.epochs.iter().all(|e| e.surface_change.is_empty()) {
        return String::new();
    }
    let mut h = String::from(
        "<section id=\"surface-change\"><h2>Surfaces through time</h2>\
         <p>Each epoch's own surface (dense matching) against the control's surface and the \
         next younger epoch's: the Nuth &amp; Kääb shift that would move it onto the other \
         (in the epoch's ground pixels; not applied), the shift and tilt fitted together \
         (what the flag judges: a tilted surface reads as a Nuth &amp; Kääb shift over gentle \
         terrain; ± block-jackknife standard errors) and the height difference on stable \
         terrain (change-&lt;epoch&gt;/).</p>\
         <table id=\"surface-change-table\"><tr><th>epoch</th><th>date</th><th>against</th>\
         <th>shift E (GSD)</th><th>N (GSD)</th><th>up (GSD)</th><th>plan (GSD)</th>\
         <th>plan with tilt (GSD)</th><th>up with tilt (GSD)</th><th>tilt E, N (m/km)</th>\
         <th>stable cells</th><th>median dh (m)</th><th>NMAD (m)</th>\
         <th>changed areas (m²)</th><th>flag</th></tr>",
    );
    for e in &report.epochs {
        for c in &e.surface_change {
            let bad = if c.flag.is_some() {
                " class=\"bad\""
            } else {
                ""
            };
            h.push_str(&format!(
                "<tr{bad}><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{} ± {}</td>{}<td>{}</td><td>{}</td><td>{}</td><td>{} ({})</td><td>{}</td></tr>",
                esc(&e.name),
                esc(&e.date),
                esc(&c.against),
                fmt(c.shift_gsd[0], 2),
                fmt(c.shift_gsd[1], 2),
                fmt(c.shift_gsd[2], 2),
                fmt(c.shift_plan_gsd, 2),
                fmt(c.shift_plan_sigma_gsd, 2),
                match &c.with_tilt {
                    Some(w) => format!(
                        "<td>{} ± {}</td><td>{} ± {}</td><td>{}, {}</td>",
                        fmt(w.shift_plan_gsd, 2),
                        fmt(w.shift_plan_sigma_gsd, 2),
                        fmt(w.shift_gsd[2], 2),
                        fmt(w.shift_up_sigma_gsd, 2),
                        fmt(w.tilt_m_per_km[0], 2),
                        fmt(w.tilt_m_per_km[1], 2)
                    ),
                    None => "<td>–</td><td>–</td><td>–</td>".to_string(),
                },
                c.stable_cells,
                fmt(c.median_m, 3),
                fmt(c.nmad_m, 3),
                c.changed_areas,
                fmt(c.changed_area_m2, 0),
                esc(c.flag.as_deref().unwrap_or(""))
            ));
        }
    }
    h.push_str("</table>");
    h.push_str(&dh_maps(report));
    h.push_str("</section>");
    h
}

/// The epochs' dh maps side by side, oldest last as in the table: each epoch against the
/// control's surface over its hillshade, with the colour range under it.
fn dh_maps(report: &Report) -> String {
    use base64::Engine;
    let maps: Vec<String> = report
        .epochs
        .iter()
        .filter_map(|e| {
            let c = e.surface_change.first().filter(|c| !c.map_png.is_empty())?;
            Some(format!(
                "<figure class=\"dh-map\"><img alt=\"dh of {name} against {against}\" \
                 src=\"data:image/png;base64,{png}\"/><figcaption>{name} ({date}) − {against}: \
                 <span class=\"dh-lower\">red</span> lower, <span class=\"dh-higher\">blue</span> \
                 higher, full colour at ±{range} m from the median {median} m</figcaption></figure>",
                name = esc(&e.name),
                date = esc(&e.date),
                against = esc(&c.against),
                png = base64::engine::general_purpose::STANDARD.encode(&c.map_png),
                range = fmt(c.map_range_m, 1),
                median = fmt(c.median_m, 2),
            ))
        })
        .collect();
    if maps.is_empty() {
        return String::new();
    }
    format!(
        "<h3>Height change maps</h3><div id=\"dh-maps\" class=\"dh-maps\">{}</div>",
        maps.concat()
    )
}

fn accuracy_table(report: &Report) -> String {
    let mut h = String::from(
        "<table id=\"accuracy-table\"><tr><th>epoch</th><th>date</th><th>GSD (m)</th><th>photos oriented</th>\
         <th>checkpoints</th><th>check RMSE plan (m)</th><th>height (m)</th><th>plan (GSD)</th>\
         <th>height (GSD)</th><th>max (m)</th><th>σ0</th><th>image RMSE (px)</th><th>time (s)</th>\
         <th>controlled by</th></tr>",
    );
    for e in &report.epochs {
        let not = if e.checkpoints_not_evaluated > 0 {
            format!(" (+{} not evaluated)", e.checkpoints_not_evaluated)
        } else {
            String::new()
        };
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}/{}{}</td><td>{}{not}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
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
            e.checkpoints.len(),
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
    h.push_str("</table>");
    h
}

/// An epoch's checkpoints: one row each, errors in metres and in ground pixels, and the
/// photos it was intersected from; then the measurements the evaluation rejected.
fn checkpoints_html(e: &EpochReport) -> String {
    let id = epoch_id(&e.name);
    let mut h = format!("<section id=\"checkpoints-{id}\"><h3>Checkpoints</h3>");
    if e.checkpoints.is_empty() && e.checkpoint_rejections.is_empty() {
        h.push_str("<p>No checkpoint was evaluated in this epoch.</p></section>");
        return h;
    }
    h.push_str(&format!(
        "<p>{} evaluated{}; error = intersected − surveyed; GSD {} m.</p>",
        e.checkpoints.len(),
        if e.checkpoints_not_evaluated > 0 {
            format!(
                ", {} not evaluated (their rays disagree)",
                e.checkpoints_not_evaluated
            )
        } else {
            String::new()
        },
        fmt(e.gsd_m, 3)
    ));
    // A row whose error is beyond three times the epoch's RMSE stands out.
    let plan_lim = 3.0 * e.check_rmse_plan_m;
    let h_lim = 3.0 * e.check_rmse_height_m;
    h.push_str(
        "<table class=\"checkpoints\"><tr><th>id</th><th>dx (m)</th><th>dy (m)</th><th>dz (m)</th>\
         <th>plan (m)</th><th>dx (GSD)</th><th>dy (GSD)</th><th>dz (GSD)</th><th>photos</th></tr>",
    );
    for c in &e.checkpoints {
        let plan = c.dx.hypot(c.dy);
        let class = if plan > plan_lim || c.dz.abs() > h_lim {
            " class=\"bad\""
        } else {
            ""
        };
        h.push_str(&format!(
            "<tr{class}><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&c.id),
            fmt_signed(c.dx, 3),
            fmt_signed(c.dy, 3),
            fmt_signed(c.dz, 3),
            fmt(plan, 3),
            fmt_signed(c.dx / e.gsd_m, 2),
            fmt_signed(c.dy / e.gsd_m, 2),
            fmt_signed(c.dz / e.gsd_m, 2),
            c.rays
        ));
    }
    h.push_str(&format!(
        "<tr class=\"sum\"><th>RMSE</th><td colspan=\"3\"></td><td>{}</td><td colspan=\"2\">{} (plan)</td><td>{}</td><td></td></tr></table>",
        fmt(e.check_rmse_plan_m, 3),
        fmt(e.check_rmse_plan_m / e.gsd_m, 2),
        fmt(e.check_rmse_height_m / e.gsd_m, 2),
    ));
    if !e.checkpoint_rejections.is_empty() {
        h.push_str(&format!(
            "<div id=\"checkpoint-rejections-{id}\"><h4>Checkpoint measurements rejected ({})</h4>\
             <table class=\"rejections\"><tr><th>id</th><th>photo</th><th>line</th><th>pixel (col, row)</th>\
             <th>residual (px)</th><th class=\"text\">reason</th></tr>",
            e.checkpoint_rejections.len()
        ));
        for r in &e.checkpoint_rejections {
            h.push_str(&format!(
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}, {}</td><td>{}</td><td class=\"text\">{}</td></tr>",
                esc(&r.id),
                esc(&r.photo),
                r.line,
                fmt(r.pixel[0], 1),
                fmt(r.pixel[1], 1),
                opt(r.residual_px, 1),
                esc(&r.reason)
            ));
        }
        h.push_str("</table></div>");
    }
    h.push_str("</section>");
    h
}

/// Where a scan's pixel size came from, in a word; the whole text as its tooltip.
fn pixel_source(s: &str) -> String {
    let short = if s.starts_with("estimated") {
        "estimated from the marks"
    } else {
        s
    };
    format!("<span title=\"{}\">{}</span>", esc(s), esc(short))
}

/// A film epoch's scans: marks, residuals, the orientation found and its margin.
fn scans_html(e: &EpochReport) -> String {
    if e.scans.is_empty() {
        return String::new();
    }
    let mut h = format!(
        "<section id=\"scans-{}\"><h3>Film interior orientation per scan</h3>\
         <table class=\"scans\"><tr><th>scan</th><th>marks used</th><th>RMSE (µm)</th><th>RMSE (px)</th>\
         <th>max residual (µm)</th><th>scan orientation</th><th class=\"text\">decided by</th><th>margin</th>\
         <th>pixel (µm)</th><th>marks measure (µm)</th><th class=\"text\">pixel size</th></tr>",
        epoch_id(&e.name)
    );
    for s in &e.scans {
        if let Some(f) = &s.failed {
            h.push_str(&format!(
                "<tr class=\"bad\"><td>{}</td><td colspan=\"10\" class=\"text\">no interior orientation: {}</td></tr>",
                esc(&s.photo),
                esc(f)
            ));
            continue;
        }
        let orientation = s.orientation.map_or("–".into(), |o| o.to_string());
        let margin = if s.orientation_margin >= 1000.0 {
            "no rival".to_string()
        } else {
            fmt(s.orientation_margin, 2)
        };
        let class = if s.orientation_ambiguous || s.orientation_margin < 1.0 {
            " class=\"bad\""
        } else {
            ""
        };
        h.push_str(&format!(
            "<tr{class}><td>{}</td><td>{}/{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"text\">{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"text\">{}</td></tr>",
            esc(&s.photo),
            s.marks_used,
            s.marks_total,
            fmt(s.rmse_um, 1),
            fmt(s.rmse_px, 2),
            fmt(s.max_residual_um, 1),
            esc(&orientation),
            esc(&s.orientation_source),
            margin,
            fmt(s.pixel_um, 2),
            fmt(s.measured_pixel_um, 2),
            pixel_source(&s.pixel_source),
        ));
    }
    h.push_str("</table></section>");
    h
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
    h.push_str("<h3>Photos and standard positions</h3><table><tr><th>photo</th><th>tie obs.</th><th>control obs.</th>");
    for pos in ["TL", "TC", "TR", "ML", "MC", "MR", "BL", "BC", "BR"] {
        h.push_str(&format!("<th>{pos}</th>"));
    }
    h.push_str("<th class=\"text\">not oriented because</th></tr>");
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
        h.push_str(&format!(
            "<td class=\"text\">{}</td></tr>",
            esc(p.reason.as_deref().unwrap_or(""))
        ));
    }
    h.push_str("</table>");
    h
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px;color:#222;max-width:1400px}\
table{border-collapse:collapse;margin:6px 0 14px}\
td,th{border:1px solid #bbb;padding:3px 8px;text-align:right;font-size:14px}th{background:#eee}\
td.text,th.text{text-align:left}table.kv th{text-align:left}table.kv td{text-align:left}\
tr.bad td{background:#fbe3e3}tr.sum td,tr.sum th{border-top:2px solid #888}\
.plots{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}\
figure.plot{display:inline-block;border:1px solid #ddd;margin:0 0 12px;padding:4px}\
figcaption{font-weight:bold;font-size:14px;padding:2px 4px 4px}\
#warnings li{margin:2px 0}.kind{display:inline-block;background:#f6d889;border-radius:3px;padding:0 5px;font-size:12px}\
code{font-size:13px}\
.dh-maps{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}\
figure.dh-map{margin:0;max-width:440px}figure.dh-map img{width:100%;border:1px solid #ddd}\
figure.dh-map figcaption{font-weight:normal}.dh-lower{color:#c22}.dh-higher{color:#26c}";

/// The self-contained HTML page.
pub fn render_html(report: &Report) -> Result<String, String> {
    let mut html = String::new();
    html.push_str("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">");
    html.push_str(&format!(
        "<title>cloudcontrol report — {}</title><style>{STYLE}</style></head><body>",
        esc(&report.project)
    ));
    html.push_str(&format!(
        "<h1>cloudcontrol accuracy report — {}</h1><p>CRS {} · {} epochs</p>",
        esc(&report.project),
        esc(&report.crs),
        report.epochs.len()
    ));
    html.push_str(&run_info_html(report));
    html.push_str(&warnings_html(report));
    html.push_str("<section id=\"accuracy\"><h2>Accuracy through time</h2>");
    html.push_str(&accuracy_table(report));
    if report
        .epochs
        .iter()
        .any(|e| e.check_rmse_plan_m.is_finite() || e.check_rmse_height_m.is_finite())
    {
        html.push_str(&format!(
            "<figure class=\"plot\" id=\"accuracy-by-date\"><figcaption>Checkpoint RMSE \
             against the epoch date, in metres (left) and ground pixels (right): \
             <span style=\"color:#00f\">● plan</span> \
             <span style=\"color:#f00\">● height</span></figcaption>{}</figure>",
            plots::accuracy_by_date_svg(report)?
        ));
    }
    html.push_str("</section>");
    html.push_str(&surface_change_table(report));
    html.push_str(&lidar_html(report));
    html.push_str(&lidar_strips_html(report));
    html.push_str("<h2>Control and checkpoints</h2>");
    html.push_str(&figure(
        "map",
        "Checkpoints (triangles) and photo centres of each epoch (filled: oriented)",
        &plots::map_svg(report, None)?,
    ));
    for e in &report.epochs {
        let id = epoch_id(&e.name);
        html.push_str(&format!(
            "<section class=\"epoch\" id=\"epoch-{id}\"><h2>Epoch {} ({})</h2>",
            esc(&e.name),
            esc(&e.date)
        ));
        if !e.warnings.is_empty() {
            html.push_str(&format!(
                "<div id=\"warnings-{id}\"><h3>Warnings</h3><ul>{}</ul></div>",
                warning_items(&e.warnings)
            ));
        }
        html.push_str(&checkpoints_html(e));
        html.push_str(&scans_html(e));
        html.push_str("<div class=\"plots\">");
        if !e.checkpoints.is_empty() {
            html.push_str(&figure(
                &format!("checkpoint-map-{id}"),
                &format!("{}: checkpoint errors on the map", e.name),
                &plots::map_svg(report, Some(e))?,
            ));
            html.push_str(&format!(
                "<figure class=\"plot\" id=\"histogram-{id}\"><figcaption>{}: checkpoint \
                 errors: <span style=\"color:#00f\">■ plan</span> \
                 <span style=\"color:#f00\">■ height</span></figcaption>{}</figure>",
                esc(&e.name),
                plots::histogram_svg(e)?
            ));
        }
        if !e.photos.is_empty() {
            html.push_str(&figure(
                &format!("residuals-{id}"),
                &format!("{}: mean image residual per photo", e.name),
                &plots::residuals_svg(e)?,
            ));
        }
        // The reference epoch is tied by image matching, not by control patches.
        if e.photos.iter().any(|p| p.patches_predicted > 0) {
            html.push_str(&figure(
                &format!("matching-{id}"),
                &format!("{}: matched / predicted control patches per photo", e.name),
                &plots::matching_svg(e)?,
            ));
        }
        if !e.icp.is_empty() {
            html.push_str(&figure(
                &format!("icp-{id}"),
                &format!("{}: ICP convergence", e.name),
                &plots::icp_svg(e)?,
            ));
        }
        html.push_str("</div>");
        html.push_str(&ties_html(e));
        html.push_str("</section>");
    }
    html.push_str("</body></html>\n");
    Ok(html)
}
