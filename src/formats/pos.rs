//! Approximate exterior orientation files of an epoch (specified in `formats/pos/`), read
//! with the project's one CSV reader ([`super::csv`]):
//!
//! * POS CSV: `name,x,y,z,omega,phi,kappa[,sigma_xyz,sigma_angle]` — projection centre in
//!   world coordinates (m) and photogrammetric omega/phi/kappa in degrees (our camera
//!   frame, see the design overview), with optional 1σ of the centre (m) and of each angle
//!   (degrees);
//! * strips CSV: `strip,photo,x,y,z[,flight_axis]` — every photo of every strip in flight
//!   order, with the projection centre given for the first and last photo of each strip and
//!   left empty for the photos in between (archives without POS, seed 000), and the image
//!   axis that points forward along the flight.
//!
//! Photos are named by image file name or stem; [`photo_key`] matches the two.

use super::csv::{read_records, Extra, Layout};
use super::{FormatError, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Which image axis points forward along the flight (pixel axes: x = column to the
/// right, y = row downwards). Serde and the strips CSV use `+x`, `-x`, `+y`, `-y`, with
/// the aliases `image_x` (= `+x`) and `image_up` (= `-y`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum FlightAxis {
    /// Image x (the fiducial x axis) forward: the classic film-camera convention.
    #[default]
    #[serde(rename = "+x", alias = "image_x")]
    PlusX,
    #[serde(rename = "-x")]
    MinusX,
    /// Image down (towards the last row) forward.
    #[serde(rename = "+y")]
    PlusY,
    /// Image up (towards row 0) forward: common for digital frame cameras.
    #[serde(rename = "-y", alias = "image_up")]
    MinusY,
}

/// A strip given by its end points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StripEnds {
    pub name: String,
    /// Photo names in flight order (first to last), as written in the file.
    pub photos: Vec<String>,
    /// Projection centres of the first and last photo (block-local).
    pub first: [f64; 3],
    pub last: [f64; 3],
    #[serde(default)]
    pub flight_axis: FlightAxis,
}

/// One line of a POS file.
#[derive(Debug, Clone, PartialEq)]
pub struct PosRecord {
    /// The photo as written in the file: its image file name, or its stem.
    pub name: String,
    /// World coordinates of the projection centre.
    pub center: [f64; 3],
    /// Omega, phi, kappa (radians).
    pub opk: [f64; 3],
    pub sigma_xyz: Option<f64>,
    /// 1σ of each angle (radians).
    pub sigma_angle: Option<f64>,
}

/// Image file extensions a photo may have (as the photo folders are read).
pub const IMAGE_EXTENSIONS: [&str; 5] = ["png", "tif", "tiff", "jpg", "jpeg"];

/// The key a photo is matched by: its file name without folders and without an image
/// extension (`IMAGE_EXTENSIONS`, any case), so that `scans/f1_001.tif`, `f1_001.tif`
/// and `f1_001` designate the same photo. Other dots are kept (`p.2012.05` stays).
pub fn photo_key(name: &str) -> &str {
    let file = name.rsplit(['/', '\\']).next().unwrap_or(name);
    match file.rsplit_once('.') {
        Some((stem, ext))
            if !stem.is_empty() && IMAGE_EXTENSIONS.iter().any(|e| e.eq_ignore_ascii_case(ext)) =>
        {
            stem
        }
        _ => file,
    }
}

/// A POS row; the sigma columns come as a pair.
#[derive(Deserialize)]
struct PosRow {
    name: String,
    x: f64,
    y: f64,
    z: f64,
    omega: f64,
    phi: f64,
    kappa: f64,
    sigma_xyz: Option<f64>,
    sigma_angle: Option<f64>,
}

/// Reads a POS file (formats/pos/README.md); angles come back in radians.
pub fn read_pos(path: &Path) -> Result<Vec<PosRecord>> {
    let table = read_records::<PosRow>(
        path,
        &Layout {
            required: &["name", "x", "y", "z", "omega", "phi", "kappa"],
            optional: &["sigma_xyz", "sigma_angle"],
            extra: Extra::Refuse,
        },
    )?;
    let with_sigma = table.has("sigma_xyz");
    if with_sigma != table.has("sigma_angle") {
        return Err(FormatError::at(
            path,
            table.header_line,
            None,
            "sigma_xyz and sigma_angle come together (both columns or none)",
        ));
    }
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = Vec::with_capacity(table.rows.len());
    for (line, r) in table.rows {
        if r.name.is_empty() {
            return Err(FormatError::at(path, line, Some("name".into()), "empty"));
        }
        if let Some(first) = seen.insert(photo_key(&r.name).to_string(), line) {
            return Err(FormatError::at(
                path,
                line,
                Some("name".into()),
                format!("photo {:?} is already listed on line {first}", r.name),
            ));
        }
        let sigma = |column: &str, v: Option<f64>| -> Result<Option<f64>> {
            match (with_sigma, v) {
                (false, _) => Ok(None),
                (true, Some(v)) if v > 0.0 => Ok(Some(v)),
                (true, Some(v)) => Err(FormatError::at(
                    path,
                    line,
                    Some(column.into()),
                    format!("σ must be positive, found {v}"),
                )),
                (true, None) => Err(FormatError::at(
                    path,
                    line,
                    Some(column.into()),
                    "empty, a positive σ is needed",
                )),
            }
        };
        out.push(PosRecord {
            sigma_xyz: sigma("sigma_xyz", r.sigma_xyz)?,
            sigma_angle: sigma("sigma_angle", r.sigma_angle)?.map(f64::to_radians),
            name: r.name,
            center: [r.x, r.y, r.z],
            opk: [
                r.omega.to_radians(),
                r.phi.to_radians(),
                r.kappa.to_radians(),
            ],
        });
    }
    if out.is_empty() {
        return Err(FormatError::invalid(path, "no photo listed"));
    }
    Ok(out)
}

/// Writes a POS file (angles in degrees), atomically.
pub fn write_pos(path: &Path, records: &[PosRecord]) -> Result<()> {
    let with_sigma = records
        .iter()
        .all(|r| r.sigma_xyz.is_some() && r.sigma_angle.is_some());
    let mut s = String::from("name,x,y,z,omega,phi,kappa");
    if with_sigma {
        s.push_str(",sigma_xyz,sigma_angle");
    }
    s.push('\n');
    for r in records {
        s.push_str(&format!(
            "{},{:.4},{:.4},{:.4},{:.8},{:.8},{:.8}",
            r.name,
            r.center[0],
            r.center[1],
            r.center[2],
            r.opk[0].to_degrees(),
            r.opk[1].to_degrees(),
            r.opk[2].to_degrees()
        ));
        if with_sigma {
            s.push_str(&format!(
                ",{},{}",
                r.sigma_xyz.unwrap_or(0.0),
                r.sigma_angle.unwrap_or(0.0).to_degrees()
            ));
        }
        s.push('\n');
    }
    super::write_bytes_atomically(path, s.as_bytes())
}

/// Writes a strips file: every photo of every strip in flight order, the centre on the
/// first and last photo only, and the strip's flight axis on every row.
pub fn write_strips(path: &Path, strips: &[StripEnds]) -> Result<()> {
    let mut s = String::from("strip,photo,x,y,z,flight_axis\n");
    for st in strips {
        let n = st.photos.len();
        for (k, photo) in st.photos.iter().enumerate() {
            let centre = match k {
                0 => Some(st.first),
                _ if k + 1 == n => Some(st.last),
                _ => None,
            };
            let xyz = centre.map_or(",,".to_string(), |c| {
                format!("{:.3},{:.3},{:.3}", c[0], c[1], c[2])
            });
            s.push_str(&format!(
                "{},{photo},{xyz},{}\n",
                st.name,
                st.flight_axis.label()
            ));
        }
    }
    super::write_bytes_atomically(path, s.as_bytes())
}

/// A strips row: the centre only on the strip's first and last photo.
#[derive(Deserialize)]
struct StripRow {
    strip: String,
    photo: String,
    x: Option<f64>,
    y: Option<f64>,
    z: Option<f64>,
    flight_axis: Option<FlightAxis>,
}

/// One strip as it is read: (photo, centre if given, line) in file order, and its flight
/// axis with the line that first gave it.
struct StripRows {
    name: String,
    photos: Vec<(String, Option<[f64; 3]>, usize)>,
    axis: Option<(FlightAxis, usize)>,
}

/// Reads a strips file (formats/pos/README.md) into strips with world end points; the
/// flight axis is the file's `flight_axis` column, `+x` when absent.
pub fn read_strips(path: &Path) -> Result<Vec<StripEnds>> {
    let table = read_records::<StripRow>(
        path,
        &Layout {
            required: &["strip", "photo", "x", "y", "z"],
            optional: &["flight_axis"],
            extra: Extra::Refuse,
        },
    )?;
    let mut strips: Vec<StripRows> = Vec::new();
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (line, r) in table.rows {
        for (column, v) in [("strip", &r.strip), ("photo", &r.photo)] {
            if v.is_empty() {
                return Err(FormatError::at(path, line, Some(column.into()), "empty"));
            }
        }
        if let Some(first) = seen.insert(photo_key(&r.photo).to_string(), line) {
            return Err(FormatError::at(
                path,
                line,
                Some("photo".into()),
                format!("photo {:?} is already listed on line {first}", r.photo),
            ));
        }
        let centre = match (r.x, r.y, r.z) {
            (Some(x), Some(y), Some(z)) => Some([x, y, z]),
            (None, None, None) => None,
            _ => {
                return Err(FormatError::at(
                    path,
                    line,
                    None,
                    "x, y and z are given together or left empty together",
                ))
            }
        };
        let k = match strips.iter().position(|s| s.name == r.strip) {
            Some(k) => k,
            None => {
                strips.push(StripRows {
                    name: r.strip.clone(),
                    photos: Vec::new(),
                    axis: None,
                });
                strips.len() - 1
            }
        };
        let s = &mut strips[k];
        match (r.flight_axis, s.axis) {
            (Some(a), Some((b, first))) if a != b => {
                return Err(FormatError::at(
                    path,
                    line,
                    Some("flight_axis".into()),
                    format!(
                        "strip {}: flight axis {} differs from {} given on line {first}",
                        s.name,
                        a.label(),
                        b.label()
                    ),
                ))
            }
            (Some(a), None) => s.axis = Some((a, line)),
            _ => {}
        }
        s.photos.push((r.photo, centre, line));
    }
    if strips.is_empty() {
        return Err(FormatError::invalid(path, "no strip listed"));
    }
    strips
        .into_iter()
        .map(|s| {
            let n = s.photos.len();
            if n < 2 {
                return Err(FormatError::at(
                    path,
                    s.photos[0].2,
                    None,
                    format!("strip {}: needs at least two photos", s.name),
                ));
            }
            let end = |k: usize| {
                s.photos[k].1.ok_or_else(|| {
                    FormatError::at(
                        path,
                        s.photos[k].2,
                        None,
                        format!(
                            "strip {}: the {} photo needs its centre",
                            s.name,
                            if k == 0 { "first" } else { "last" }
                        ),
                    )
                })
            };
            Ok(StripEnds {
                first: end(0)?,
                last: end(n - 1)?,
                photos: s.photos.into_iter().map(|p| p.0).collect(),
                name: s.name,
                flight_axis: s.axis.map(|a| a.0).unwrap_or_default(),
            })
        })
        .collect()
}

impl FlightAxis {
    /// The axis as written in the strips CSV (`+x`, `-x`, `+y`, `-y`).
    pub fn label(self) -> &'static str {
        match self {
            FlightAxis::PlusX => "+x",
            FlightAxis::MinusX => "-x",
            FlightAxis::PlusY => "+y",
            FlightAxis::MinusY => "-y",
        }
    }
}
