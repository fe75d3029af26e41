//! Control and check points as CSV (formats/control-points/README.md), read with the
//! project's one CSV reader ([`super::csv`]).
//!
//! Points: header `id,x,y,z[,sigma_xy,sigma_z][,kind]` (σ default [`DEFAULT_SIGMA_M`]), kind `control` (default) or `check`,
//! coordinates in any CRS PROJ knows (x = easting or longitude, y = northing or latitude:
//! GIS order), σ in metres. They are converted to the block's CRS, which must be projected:
//! bundle adjustment needs metric, conformal coordinates, so a geographic block CRS is
//! refused with the UTM zone of the points as a suggestion. Surveyed checkpoints of a
//! project are such a file.
//!
//! Measurements: header `id,image_name,x,y[,sigma_px]`, pixels with the origin at the
//! top-left corner of the top-left pixel (its centre is (0.5, 0.5)).
//!
//! Checkpoint measurements: header `epoch,photo,id,col,row`, the same pixel convention,
//! one file for every epoch of a project.

use super::crs::{Crs, Transformer};
use super::csv::{read_records, Extra, Layout};
use super::pos::photo_key;
use super::{write_bytes_atomically, FormatError, Result};
use crate::block::{Block, ObjectPoint, Observation, PointId, PointKind};
use nalgebra::Vector3;
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// One surveyed point as read from the CSV (coordinates still in the file's CRS).
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyedPoint {
    pub id: String,
    pub xyz: [f64; 3],
    pub sigma_xy: f64,
    pub sigma_z: f64,
    pub kind: PointKind,
}

/// One image measurement of a named point.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    pub id: String,
    pub image_name: String,
    pub pixel: [f64; 2],
    pub sigma_px: f64,
}

/// One checkpoint measured in one photo of an epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointMeasurement {
    /// 1-based line of the file, to name the row when its photo or point is unknown.
    pub line: usize,
    /// The photo as written: its image file name or stem (match with [`photo_key`]).
    pub photo: String,
    pub id: String,
    /// Column, row (px, top-left corner origin).
    pub pixel: [f64; 2],
}

fn require_text(path: &Path, line: usize, column: &str, v: &str) -> Result<()> {
    if v.is_empty() {
        return Err(FormatError::at(path, line, Some(column.into()), "empty"));
    }
    Ok(())
}

/// A σ must be positive; `inf` is allowed (an axis without a coordinate: 2-D control or a
/// height-only point), NaN is not.
fn require_positive(path: &Path, line: usize, column: &str, v: f64) -> Result<f64> {
    if v.is_nan() || v <= 0.0 {
        return Err(FormatError::at(
            path,
            line,
            Some(column.into()),
            format!("σ must be positive (or inf for an unknown axis), found {v}"),
        ));
    }
    Ok(v)
}

#[derive(Deserialize)]
struct PointRow {
    id: String,
    x: f64,
    y: f64,
    z: f64,
    sigma_xy: Option<Sigma>,
    sigma_z: Option<Sigma>,
    kind: Option<String>,
}

/// A σ cell: a number, or `inf` for an axis without a coordinate (2-D or height-only
/// control) — the one column where the CSV reader's refusal of non-finite numbers is
/// lifted. Its sign is checked with the row, naming line and column.
#[derive(Clone, Copy)]
struct Sigma(f64);

impl<'de> Deserialize<'de> for Sigma {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        match text.trim().to_ascii_lowercase().as_str() {
            "inf" | "+inf" | "infinity" => Ok(Sigma(f64::INFINITY)),
            t => t
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .map(Sigma)
                .ok_or_else(|| {
                    serde::de::Error::custom(format!(
                        "{text:?} is not a σ (a positive number, or inf for an unknown axis)"
                    ))
                }),
        }
    }
}

/// σ of a surveyed coordinate when the file has no σ column (m): a GNSS-surveyed target.
pub const DEFAULT_SIGMA_M: f64 = 0.05;

/// Reads a control/check point CSV.
pub fn read_points(path: &Path) -> Result<Vec<SurveyedPoint>> {
    let table = read_records::<PointRow>(
        path,
        &Layout {
            required: &["id", "x", "y", "z"],
            optional: &["sigma_xy", "sigma_z", "kind"],
            extra: Extra::Refuse,
        },
    )?;
    // One σ column without the other is a file written for another layout.
    for (have, missing) in [("sigma_xy", "sigma_z"), ("sigma_z", "sigma_xy")] {
        if table.has(have) && !table.has(missing) {
            return Err(FormatError::at(
                path,
                table.header_line,
                None,
                format!("no column {missing:?} (given with {have:?})"),
            ));
        }
    }
    let mut seen = HashMap::new();
    let mut out = Vec::with_capacity(table.rows.len());
    for (line, r) in table.rows {
        require_text(path, line, "id", &r.id)?;
        if let Some(prev) = seen.insert(r.id.clone(), line) {
            return Err(FormatError::at(
                path,
                line,
                Some("id".into()),
                format!("point {} already defined on line {prev}", r.id),
            ));
        }
        let kind = match r.kind.map(|k| k.to_ascii_lowercase()).as_deref() {
            None | Some("control") => PointKind::Control,
            Some("check") => PointKind::Check,
            Some(k) => {
                return Err(FormatError::at(
                    path,
                    line,
                    Some("kind".into()),
                    format!("point {}: {k:?} is neither control nor check", r.id),
                ))
            }
        };
        if r.sigma_xy
            .zip(r.sigma_z)
            .is_some_and(|(a, b)| a.0.is_infinite() && b.0.is_infinite())
        {
            return Err(FormatError::at(
                path,
                line,
                Some("sigma_z".into()),
                format!(
                    "point {}: σ_xy and σ_z both inf, it would control nothing",
                    r.id
                ),
            ));
        }
        out.push(SurveyedPoint {
            sigma_xy: require_positive(
                path,
                line,
                "sigma_xy",
                r.sigma_xy.map_or(DEFAULT_SIGMA_M, |s| s.0),
            )?,
            sigma_z: require_positive(
                path,
                line,
                "sigma_z",
                r.sigma_z.map_or(DEFAULT_SIGMA_M, |s| s.0),
            )?,
            id: r.id,
            xyz: [r.x, r.y, r.z],
            kind,
        });
    }
    Ok(out)
}

#[derive(Deserialize)]
struct MeasurementRow {
    id: String,
    image_name: String,
    x: f64,
    y: f64,
    sigma_px: Option<f64>,
}

/// Reads an image measurement CSV.
pub fn read_measurements(path: &Path) -> Result<Vec<Measurement>> {
    let table = read_records::<MeasurementRow>(
        path,
        &Layout {
            required: &["id", "image_name", "x", "y"],
            optional: &["sigma_px"],
            extra: Extra::Refuse,
        },
    )?;
    table
        .rows
        .into_iter()
        .map(|(line, r)| {
            require_text(path, line, "id", &r.id)?;
            require_text(path, line, "image_name", &r.image_name)?;
            Ok(Measurement {
                sigma_px: require_positive(path, line, "sigma_px", r.sigma_px.unwrap_or(1.0))?,
                id: r.id,
                image_name: r.image_name,
                pixel: [r.x, r.y],
            })
        })
        .collect()
}

#[derive(Deserialize)]
struct CheckpointRow {
    epoch: String,
    photo: String,
    id: String,
    col: f64,
    row: f64,
}

/// Reads the checkpoint measurements of `epoch` from an `epoch,photo,id,col,row` file
/// (every row is checked, whatever its epoch). The photos are checked against the epoch
/// where the block is known (`control::checkpoints::evaluate_checkpoints`).
pub fn read_checkpoint_measurements(
    path: &Path,
    epoch: &str,
) -> Result<Vec<CheckpointMeasurement>> {
    Ok(read_all_checkpoint_measurements(path)?
        .into_iter()
        .filter(|(e, _)| e == epoch)
        .map(|(_, m)| m)
        .collect())
}

/// Every checkpoint measurement of an `epoch,photo,id,col,row` file with its epoch, in
/// file order: the check before a run reads the file once for all epochs.
pub fn read_all_checkpoint_measurements(
    path: &Path,
) -> Result<Vec<(String, CheckpointMeasurement)>> {
    let table = read_records::<CheckpointRow>(
        path,
        &Layout {
            required: &["epoch", "photo", "id", "col", "row"],
            optional: &[],
            extra: Extra::Refuse,
        },
    )?;
    let mut seen: BTreeMap<(String, String, String), usize> = BTreeMap::new();
    let mut out = Vec::new();
    for (line, r) in table.rows {
        for (column, v) in [("epoch", &r.epoch), ("photo", &r.photo), ("id", &r.id)] {
            require_text(path, line, column, v)?;
        }
        let key = (
            r.epoch.clone(),
            photo_key(&r.photo).to_string(),
            r.id.clone(),
        );
        if let Some(first) = seen.insert(key, line) {
            return Err(FormatError::at(
                path,
                line,
                None,
                format!(
                    "checkpoint {} in photo {} of epoch {} is already measured on line {first}",
                    r.id, r.photo, r.epoch
                ),
            ));
        }
        out.push((
            r.epoch,
            CheckpointMeasurement {
                line,
                photo: r.photo,
                id: r.id,
                pixel: [r.col, r.row],
            },
        ));
    }
    Ok(out)
}

/// Converts surveyed points from `source` to the block's CRS and adds them to the block
/// (a point whose name already exists is updated). Returns their ids in input order.
pub fn add_points(
    block: &mut Block,
    points: &[SurveyedPoint],
    source: &Crs,
) -> Result<Vec<PointId>> {
    let target_def = block.crs.clone().ok_or_else(|| FormatError::Crs {
        crs: "(none)".into(),
        message: "the block has no CRS to convert control points to; set a projected CRS first"
            .into(),
    })?;
    let target = Crs::parse(&target_def)?;
    // A hint for the message: the points' position in WGS 84 longitude/latitude.
    let lon_lat = points.first().and_then(|p| {
        let wgs84 = Crs::from_epsg(4326).ok()?;
        let t = Transformer::new(source, &wgs84).ok()?;
        t.transform_point(p.xyz).ok().map(|q| (q[0], q[1]))
    });
    target.require_projected(lon_lat)?;
    let t = Transformer::new(source, &target)?;
    let (mut x, mut y, mut z): (Vec<f64>, Vec<f64>, Vec<f64>) = (
        points.iter().map(|p| p.xyz[0]).collect(),
        points.iter().map(|p| p.xyz[1]).collect(),
        points.iter().map(|p| p.xyz[2]).collect(),
    );
    t.transform(&mut x, &mut y, &mut z)?;
    let by_name: HashMap<String, PointId> = block
        .points
        .values()
        .filter(|p| !p.name.is_empty())
        .map(|p| (p.name.clone(), p.id))
        .collect();
    let mut ids = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        let local = block.to_local(&Vector3::new(x[i], y[i], z[i]));
        let sigma = Some([p.sigma_xy, p.sigma_xy, p.sigma_z]);
        let id = match by_name.get(&p.id) {
            Some(&id) => {
                let q = block.points.get_mut(&id).expect("id from the block");
                q.position = local;
                q.kind = p.kind;
                q.sigma = sigma;
                id
            }
            None => {
                let id = block.next_point_id();
                block.points.insert(
                    id,
                    ObjectPoint {
                        id,
                        name: p.id.clone(),
                        kind: p.kind,
                        position: local,
                        sigma,
                        color: [0; 3],
                        observations: Vec::new(),
                    },
                );
                id
            }
        };
        ids.push(id);
    }
    Ok(ids)
}

/// Attaches image measurements to the block's named points; names the unknown point or
/// image when one is missing. `path` names the measurement file in errors.
pub fn add_measurements(
    block: &mut Block,
    measurements: &[Measurement],
    path: &Path,
) -> Result<()> {
    let photos: HashMap<&str, u32> = block
        .photos
        .values()
        .map(|p| (p.name.as_str(), p.id))
        .collect();
    // An image file name or stem designates the same photo (formats/pos/, photo names).
    let by_key: HashMap<&str, u32> = block
        .photos
        .values()
        .map(|p| (photo_key(&p.name), p.id))
        .collect();
    let points: HashMap<String, PointId> = block
        .points
        .values()
        .filter(|p| !p.name.is_empty())
        .map(|p| (p.name.clone(), p.id))
        .collect();
    let mut add = Vec::with_capacity(measurements.len());
    for m in measurements {
        let photo = *photos
            .get(m.image_name.as_str())
            .or_else(|| by_key.get(photo_key(&m.image_name)))
            .ok_or_else(|| {
                FormatError::invalid(
                    path,
                    format!(
                        "point {}: image {:?} is not in the block",
                        m.id, m.image_name
                    ),
                )
            })?;
        let point = *points.get(&m.id).ok_or_else(|| {
            FormatError::invalid(path, format!("point {} is not in the block", m.id))
        })?;
        add.push((point, photo, m));
    }
    for (point, photo, m) in add {
        let p = block.points.get_mut(&point).expect("checked");
        p.observations.retain(|o| o.photo != photo);
        p.observations.push(Observation {
            photo,
            pixel: m.pixel,
            sigma_px: m.sigma_px,
            provenance: "measurement csv".into(),
        });
    }
    Ok(())
}

/// Writes the block's control and check points (world coordinates in the block CRS).
pub fn write_points(path: &Path, block: &Block) -> Result<()> {
    let mut s = String::from("id,x,y,z,sigma_xy,sigma_z,kind\n");
    for p in block.points.values().filter(|p| p.kind != PointKind::Tie) {
        if p.name.contains(',') || p.name.contains('"') {
            return Err(FormatError::invalid(
                path,
                format!("point {} name {:?} contains a comma or quote", p.id, p.name),
            ));
        }
        let w = block.to_world(&p.position);
        let sg = p.sigma.unwrap_or([0.01; 3]);
        let kind = if p.kind == PointKind::Check {
            "check"
        } else {
            "control"
        };
        let name = if p.name.is_empty() {
            p.id.to_string()
        } else {
            p.name.clone()
        };
        s.push_str(&format!(
            "{name},{},{},{},{},{},{kind}\n",
            w.x, w.y, w.z, sg[0], sg[2]
        ));
    }
    write_bytes_atomically(path, s.as_bytes())
}
