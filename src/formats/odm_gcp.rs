//! OpenDroneMap's ground control point file, `gcp_list.txt` (formats/control-points/odm.md),
//! read into the same [`SurveyedPoint`]s and [`Measurement`]s as our control point CSVs, so
//! [`super::control_points::add_points`] and `add_measurements` put them into a block.
//!
//! The file is whitespace-separated text, not CSV (no header row, no quoting), so it is split
//! here rather than by [`super::csv`]; its CRS line goes through the one CRS parser
//! ([`Crs::parse`]). Layout (ODM's docs, docs.opendronemap.org/gcp, and its reader,
//! `opendm/gcp.py`):
//!
//! ```text
//! <CRS: +proj=… | EPSG:<code> | WGS84 UTM <zone><N|S>>
//! geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra…]
//! ```
//!
//! Pixels: ODM hands the file to OpenSfM, whose pixel coordinates have their origin at the
//! centre of the top-left pixel (OpenSfM doc/source/geometry.rst, "Pixel Coordinates": "the
//! origin is at the center of the top-left pixel"; `opensfm/io.py::_read_gcp_list_lines`
//! passes `im_x, im_y` to `features.normalized_image_coordinates`, which computes
//! `(x + 0.5 - width / 2) / max(width, height)`, i.e. the image centre is at
//! `width / 2 - 0.5`). Ours have their origin at the top-left corner of that pixel, so
//! our pixel = ODM pixel + [`ODM_PIXEL_OFFSET`] on both axes.

use super::control_points::{Measurement, SurveyedPoint};
use super::crs::Crs;
use super::crs_input::excerpt;
use super::pos::photo_key;
use super::{FormatError, Result};
use crate::block::PointKind;
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

/// Added to an ODM/OpenSfM pixel coordinate (origin at the centre of the top-left pixel)
/// to get ours (origin at its top-left corner).
pub const ODM_PIXEL_OFFSET: f64 = 0.5;

/// Largest file read. A GCP file has one short line per measurement (~100 bytes); 64 MiB
/// is over half a million measurements, far beyond any survey.
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// Coordinates of lines naming the same point may differ by this much, relative to the
/// larger magnitude (at least 1): text written with different rounding, nothing more.
const SAME_COORDINATE: f64 = 1e-9;

/// The a-priori standard deviations the file does not carry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GcpOptions {
    /// Horizontal σ of every GCP (m, or the CRS's unit).
    pub sigma_xy: f64,
    /// Vertical σ of every GCP (m).
    pub sigma_z: f64,
    /// σ of every image measurement (px).
    pub sigma_px: f64,
}

impl Default for GcpOptions {
    fn default() -> Self {
        Self {
            sigma_xy: 0.05,
            sigma_z: 0.05,
            sigma_px: 1.0,
        }
    }
}

/// A GCP file as read.
#[derive(Debug, Clone)]
pub struct GcpFile {
    /// The CRS of the header line; the points' coordinates are in it (a geographic CRS
    /// gives longitude, latitude: GIS order, as ODM).
    pub crs: Crs,
    /// One control point per GCP, in order of first appearance, σ from the options.
    /// Named by the file's `gcp_name`, else `gcp_<line of its first measurement>`.
    pub points: Vec<SurveyedPoint>,
    /// Every line's measurement, in file order, pixels in our convention (ODM + 0.5).
    pub measurements: Vec<Measurement>,
    /// No point has a height other than 0: ODM users write 0 (or `NaN`, read as 0) when
    /// the height is unknown, so the heights are then no control.
    pub heights_all_zero: bool,
    /// Points whose height was written `NaN` (ODM's "no value"); their z is 0.
    pub unknown_heights: Vec<String>,
}

/// Reads an ODM `gcp_list.txt` into control points (in the file's CRS) and image
/// measurements, whose pixels are converted from ODM's convention (origin at the centre
/// of the top-left pixel) to ours (its top-left corner): ours = ODM + 0.5 on both axes.
/// Errors name the file, the line and the problem.
pub fn read_odm_gcp(path: &Path, opts: &GcpOptions) -> Result<GcpFile> {
    let too_large = |claimed: u64| FormatError::TooLarge {
        path: path.to_path_buf(),
        what: "file size".into(),
        claimed,
        limit: MAX_FILE_BYTES,
        basis: "the largest GCP file read (bytes)".into(),
    };
    let file = super::input::open(path)?;
    if let Some(len) = file.metadata().ok().map(|m| m.len()) {
        if len > MAX_FILE_BYTES {
            return Err(too_large(len));
        }
    }
    let mut bytes = Vec::new();
    // `take` bounds what is read even when the size the file system reports is stale.
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| FormatError::io(path, e))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(too_large(bytes.len() as u64));
    }
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        FormatError::at(path, line, None, "not UTF-8 text")
    })?;
    parse_odm_gcp(path, text, opts)
}

/// [`read_odm_gcp`] on text already in memory (`path` names it in errors).
pub fn parse_odm_gcp(path: &Path, text: &str, opts: &GcpOptions) -> Result<GcpFile> {
    for (name, v) in [
        ("sigma_xy", opts.sigma_xy),
        ("sigma_z", opts.sigma_z),
        ("sigma_px", opts.sigma_px),
    ] {
        // An infinite σ_xy or σ_z is an axis without a coordinate (2-D or height-only
        // control); a pixel σ must be finite.
        if !(v > 0.0 && (v.is_finite() || name != "sigma_px")) {
            return Err(FormatError::invalid(
                path,
                format!("GCP option {name} must be positive (finite for sigma_px), found {v}"),
            ));
        }
    }
    if opts.sigma_xy.is_infinite() && opts.sigma_z.is_infinite() {
        return Err(FormatError::invalid(
            path,
            "GCP options sigma_xy and sigma_z are both infinite: the points would control nothing",
        ));
    }
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // ODM and OpenSfM skip blank lines and lines starting with `#`.
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((header_line, header)) = lines.next() else {
        return Err(FormatError::invalid(
            path,
            "empty file: no CRS line (a GCP file starts with its CRS: a PROJ string, \
             EPSG:<code> or WGS84 UTM <zone><N|S>)",
        ));
    };
    let crs = header_crs(header).map_err(|m| FormatError::at(path, header_line, None, m))?;
    let mut g = Grouping::default();
    for (line, l) in lines {
        let row = parse_line(l)
            .map_err(|(column, m)| FormatError::at(path, line, column.map(str::to_string), m))?;
        g.add(line, row)
            .map_err(|m| FormatError::at(path, line, None, m))?;
    }
    if g.points.is_empty() {
        return Err(FormatError::at(
            path,
            header_line,
            None,
            "no GCP line after the CRS line",
        ));
    }
    Ok(g.finish(crs, opts))
}

/// The CRS of the header line, in the three forms ODM reads (`opendm/location.py`
/// `parse_srs_header`): a PROJ string, `EPSG:<code>`, `WGS84 UTM <zone><N|S>`.
fn header_crs(header: &str) -> std::result::Result<Crs, String> {
    // ODM strips single quotes around a PROJ string.
    let h = header.trim_matches('\'').trim();
    let words: Vec<&str> = h.split_whitespace().take(4).collect();
    if words.len() >= 2
        && words[0].eq_ignore_ascii_case("WGS84")
        && words[1].eq_ignore_ascii_case("UTM")
    {
        let code = utm_epsg(&words[2..]).ok_or_else(|| {
            format!(
                "CRS line {:?}: a UTM zone is written `WGS84 UTM <zone 1-60><N|S>`, \
                 e.g. `WGS84 UTM 32N`",
                excerpt(h)
            )
        })?;
        return Crs::from_epsg(code).map_err(|e| format!("CRS line: {}", e.detail()));
    }
    let proj = h.starts_with('+');
    let epsg = h.get(..5).is_some_and(|p| p.eq_ignore_ascii_case("EPSG:"));
    if proj || epsg {
        return Crs::parse(h).map_err(|e| format!("CRS line: {}", e.detail()));
    }
    let first = words.first().copied().unwrap_or_default();
    Err(if first.parse::<f64>().is_ok() {
        format!(
            "no CRS line: the file starts with data ({:?}); a GCP file starts with its CRS: \
             a PROJ string, EPSG:<code> or WGS84 UTM <zone><N|S>",
            excerpt(h)
        )
    } else {
        format!(
            "CRS line {:?} is none of the forms ODM reads: a PROJ string (+proj=…), \
             EPSG:<code> or WGS84 UTM <zone><N|S>",
            excerpt(h)
        )
    })
}

/// EPSG code of WGS 84 / UTM from `["32N"]` (zone 1–60, N or S, either case).
fn utm_epsg(rest: &[&str]) -> Option<u32> {
    let [zone] = rest else { return None };
    let (number, base) = match zone.strip_suffix(['N', 'n']) {
        Some(number) => (number, 32600),
        None => (zone.strip_suffix(['S', 's'])?, 32700),
    };
    let n: u32 = number.parse().ok().filter(|n| (1..=60).contains(n))?;
    Some(base + n)
}

/// One data line.
struct Row<'a> {
    xyz: [f64; 3],
    pixel: [f64; 2],
    image: &'a str,
    name: Option<&'a str>,
}

const COLUMNS: [&str; 6] = ["geo_x", "geo_y", "geo_z", "im_x", "im_y", "image_name"];

/// Splits a line at blanks; a word starting with `#` starts a comment. Columns after the
/// seventh are ODM's extras and read over. Errors carry the column name.
fn parse_line(l: &str) -> std::result::Result<Row<'_>, (Option<&'static str>, String)> {
    let mut words = l.split_whitespace().take_while(|w| !w.starts_with('#'));
    let mut first = [""; 7];
    let mut n = 0;
    for (slot, w) in first.iter_mut().zip(&mut words) {
        *slot = w;
        n += 1;
    }
    if n < 6 {
        let hint = if n == 4 && first[0].parse::<f64>().is_err() {
            "; this looks like a list of GCP coordinates (name x y z) without image \
             measurements, which ODM's GCP interfaces read, not a gcp_list"
        } else {
            ""
        };
        return Err((
            None,
            format!(
                "{n} word{} where a GCP line has at least 6: \
                 geo_x geo_y geo_z im_x im_y image_name [gcp_name]{hint}",
                if n == 1 { "" } else { "s" }
            ),
        ));
    }
    let mut v = [0.0_f64; 5];
    for (i, x) in v.iter_mut().enumerate() {
        let column = COLUMNS[i];
        *x = first[i].parse().map_err(|_| {
            (
                Some(column),
                format!("{:?} is not a number", excerpt(first[i])),
            )
        })?;
        // ODM documents `NaN` as "no value" for the height only.
        if !(x.is_finite() || (i == 2 && x.is_nan())) {
            return Err((
                Some(column),
                format!("{:?} is not a finite number", excerpt(first[i])),
            ));
        }
    }
    Ok(Row {
        xyz: [v[0], v[1], v[2]],
        pixel: [v[3], v[4]],
        image: first[5],
        name: (n == 7).then_some(first[6]),
    })
}

/// A GCP being gathered.
struct Point {
    name: Option<String>,
    xyz: [f64; 3],
    first_line: usize,
}

/// Who sits at one exact position: lines without a name join that point, which is
/// ambiguous once two named points share the position.
struct AtPosition {
    point: usize,
    other: Option<usize>,
    unnamed_line: Option<usize>,
}

#[derive(Default)]
struct Grouping {
    points: Vec<Point>,
    by_name: HashMap<String, usize>,
    by_position: HashMap<[u64; 3], AtPosition>,
    /// (point, photo) → line of its measurement.
    measured: HashMap<(usize, String), usize>,
    /// (point, image name, ODM pixel).
    measurements: Vec<(usize, String, [f64; 2])>,
}

/// Exact-position key (OpenSfM groups unnamed lines by equal coordinates): `-0` is `0`,
/// every `NaN` the same.
fn position_key(xyz: [f64; 3]) -> [u64; 3] {
    xyz.map(|v| {
        if v.is_nan() {
            f64::NAN.to_bits()
        } else {
            (v + 0.0).to_bits()
        }
    })
}

fn same_coordinates(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter().zip(&b).all(|(&a, &b)| {
        if a.is_nan() || b.is_nan() {
            return a.is_nan() && b.is_nan();
        }
        (a - b).abs() <= SAME_COORDINATE * a.abs().max(b.abs()).max(1.0)
    })
}

fn show(xyz: [f64; 3]) -> String {
    format!("({} {} {})", xyz[0], xyz[1], xyz[2])
}

impl Grouping {
    fn add(&mut self, line: usize, row: Row) -> std::result::Result<(), String> {
        let point = match row.name {
            Some(name) => self.named(line, name, row.xyz)?,
            None => self.unnamed(line, row.xyz)?,
        };
        let key = (point, photo_key(row.image).to_string());
        if let Some(&first) = self.measured.get(&key) {
            return Err(format!(
                "{} is measured a second time in image {:?} (first on line {first})",
                self.label(point),
                excerpt(row.image)
            ));
        }
        self.measured.insert(key, line);
        self.measurements
            .push((point, row.image.to_string(), row.pixel));
        Ok(())
    }

    fn label(&self, point: usize) -> String {
        match &self.points[point].name {
            Some(n) => format!("point {:?}", excerpt(n)),
            None => format!(
                "the unnamed point of line {}",
                self.points[point].first_line
            ),
        }
    }

    fn new_point(&mut self, line: usize, name: Option<&str>, xyz: [f64; 3]) -> usize {
        self.points.push(Point {
            name: name.map(str::to_string),
            xyz,
            first_line: line,
        });
        self.points.len() - 1
    }

    fn named(
        &mut self,
        line: usize,
        name: &str,
        xyz: [f64; 3],
    ) -> std::result::Result<usize, String> {
        if let Some(&p) = self.by_name.get(name) {
            let q = &self.points[p];
            if !same_coordinates(q.xyz, xyz) {
                return Err(format!(
                    "point {:?} is at {} here but at {} on line {}",
                    excerpt(name),
                    show(xyz),
                    show(q.xyz),
                    q.first_line
                ));
            }
            return Ok(p);
        }
        let key = position_key(xyz);
        let p = match self.by_position.get(&key).map(|a| a.point) {
            // Unnamed lines at this position came first: they were this point.
            Some(q) if self.points[q].name.is_none() => {
                self.points[q].name = Some(name.to_string());
                q
            }
            Some(q) => {
                let p = self.new_point(line, Some(name), xyz);
                let at = self.by_position.get_mut(&key).expect("found above");
                if let Some(u) = at.unnamed_line {
                    return Err(ambiguous(u, &self.points[q], name));
                }
                at.other.get_or_insert(p);
                p
            }
            None => {
                let p = self.new_point(line, Some(name), xyz);
                self.by_position.insert(
                    key,
                    AtPosition {
                        point: p,
                        other: None,
                        unnamed_line: None,
                    },
                );
                p
            }
        };
        self.by_name.insert(name.to_string(), p);
        Ok(p)
    }

    fn unnamed(&mut self, line: usize, xyz: [f64; 3]) -> std::result::Result<usize, String> {
        let key = position_key(xyz);
        if let Some(at) = self.by_position.get_mut(&key) {
            if let Some(o) = at.other {
                let first = &self.points[at.point];
                let other = self.points[o].name.as_deref().unwrap_or_default();
                return Err(ambiguous(line, first, other));
            }
            at.unnamed_line.get_or_insert(line);
            return Ok(at.point);
        }
        let p = self.new_point(line, None, xyz);
        self.by_position.insert(
            key,
            AtPosition {
                point: p,
                other: None,
                unnamed_line: Some(line),
            },
        );
        Ok(p)
    }

    fn finish(self, crs: Crs, opts: &GcpOptions) -> GcpFile {
        // A generated name must not be one the file gives another point.
        let names: Vec<String> = self
            .points
            .iter()
            .map(|p| match &p.name {
                Some(n) => n.clone(),
                None => {
                    let mut n = format!("gcp_{}", p.first_line);
                    while self.by_name.contains_key(&n) {
                        n.push_str("_unnamed");
                    }
                    n
                }
            })
            .collect();
        let unknown_heights = self
            .points
            .iter()
            .zip(&names)
            .filter(|(p, _)| p.xyz[2].is_nan())
            .map(|(_, n)| n.clone())
            .collect();
        let points: Vec<SurveyedPoint> = self
            .points
            .iter()
            .zip(&names)
            .map(|(p, n)| SurveyedPoint {
                id: n.clone(),
                xyz: [
                    p.xyz[0],
                    p.xyz[1],
                    if p.xyz[2].is_nan() { 0.0 } else { p.xyz[2] },
                ],
                sigma_xy: opts.sigma_xy,
                sigma_z: opts.sigma_z,
                kind: PointKind::Control,
            })
            .collect();
        let measurements = self
            .measurements
            .into_iter()
            .map(|(p, image_name, px)| Measurement {
                id: names[p].clone(),
                image_name,
                pixel: px.map(|v| v + ODM_PIXEL_OFFSET),
                sigma_px: opts.sigma_px,
            })
            .collect();
        GcpFile {
            crs,
            heights_all_zero: points.iter().all(|p| p.xyz[2] == 0.0),
            points,
            measurements,
            unknown_heights,
        }
    }
}

fn ambiguous(unnamed_line: usize, first: &Point, other: &str) -> String {
    format!(
        "the line without a GCP name on line {unnamed_line} is at {}, where points {:?} and \
         {:?} both are; name its point",
        show(first.xyz),
        excerpt(first.name.as_deref().unwrap_or_default()),
        excerpt(other)
    )
}
