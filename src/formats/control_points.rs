//! Control and check points as CSV (formats/control-points/README.md).
//!
//! Points: header `id,x,y,z,sigma_xy,sigma_z[,kind]`, kind `control` (default) or `check`,
//! coordinates in any CRS PROJ knows (x = easting or longitude, y = northing or latitude:
//! GIS order), σ in metres. They are converted to the block's CRS, which must be projected:
//! bundle adjustment needs metric, conformal coordinates, so a geographic block CRS is
//! refused with the UTM zone of the points as a suggestion.
//!
//! Measurements: header `id,image_name,x,y[,sigma_px]`, pixels with the origin at the
//! top-left corner of the top-left pixel (its centre is (0.5, 0.5)).
//!
//! Fields are comma-separated without quoting; `#` starts a comment line.

use super::crs::{Crs, Transformer};
use super::{write_bytes_atomically, FormatError, Result};
use crate::block::{Block, ObjectPoint, Observation, PointId, PointKind};
use nalgebra::Vector3;
use std::collections::HashMap;
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

/// Data rows with their 1-based line numbers: header checked, comments and blanks skipped.
fn rows(path: &Path, header: &[&str], optional: &[&str]) -> Result<Vec<(usize, Vec<String>)>> {
    let text = std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (hno, h) = lines
        .next()
        .ok_or_else(|| FormatError::invalid(path, "empty file: no header line"))?;
    let cols: Vec<String> = h
        .split(',')
        .map(|s| s.trim().to_ascii_lowercase())
        .collect();
    let ok = cols.len() >= header.len()
        && cols.len() <= header.len() + optional.len()
        && cols
            .iter()
            .zip(header.iter().chain(optional))
            .all(|(a, b)| a == b);
    if !ok {
        return Err(FormatError::invalid(
            path,
            format!(
                "line {}: header must be {}[,{}], found {h:?}",
                hno + 1,
                header.join(","),
                optional.join(",")
            ),
        ));
    }
    let n = cols.len();
    let mut out = Vec::new();
    for (i, l) in lines {
        if l.contains('"') {
            return Err(FormatError::invalid(
                path,
                format!("line {}: quoted fields are not supported", i + 1),
            ));
        }
        let f: Vec<String> = l.split(',').map(|s| s.trim().to_string()).collect();
        // Optional trailing columns may be left off row by row.
        if f.len() < header.len() || f.len() > n {
            return Err(FormatError::invalid(
                path,
                format!(
                    "line {}: expected {} to {n} fields, found {}",
                    i + 1,
                    header.len(),
                    f.len()
                ),
            ));
        }
        out.push((i + 1, f));
    }
    Ok(out)
}

fn number(path: &Path, line: usize, field: &str, s: &str) -> Result<f64> {
    s.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| {
            FormatError::invalid(
                path,
                format!("line {line}: {field} {s:?} is not a finite number"),
            )
        })
}

/// Reads a control/check point CSV.
pub fn read_points(path: &Path) -> Result<Vec<SurveyedPoint>> {
    let mut seen = HashMap::new();
    let mut out = Vec::new();
    for (line, f) in rows(
        path,
        &["id", "x", "y", "z", "sigma_xy", "sigma_z"],
        &["kind"],
    )? {
        let id = f[0].clone();
        if id.is_empty() {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: id is empty"),
            ));
        }
        if let Some(prev) = seen.insert(id.clone(), line) {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: point {id} already defined on line {prev}"),
            ));
        }
        let v: Vec<f64> = (1..6)
            .map(|i| {
                number(
                    path,
                    line,
                    ["x", "y", "z", "sigma_xy", "sigma_z"][i - 1],
                    &f[i],
                )
            })
            .collect::<Result<_>>()?;
        if v[3] <= 0.0 || v[4] <= 0.0 {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: point {id}: σ must be positive"),
            ));
        }
        let kind = match f.get(6).map(|s| s.to_ascii_lowercase()).as_deref() {
            None | Some("") | Some("control") => PointKind::Control,
            Some("check") => PointKind::Check,
            Some(k) => {
                return Err(FormatError::invalid(
                    path,
                    format!("line {line}: point {id}: kind {k:?} is neither control nor check"),
                ))
            }
        };
        out.push(SurveyedPoint {
            id,
            xyz: [v[0], v[1], v[2]],
            sigma_xy: v[3],
            sigma_z: v[4],
            kind,
        });
    }
    Ok(out)
}

/// Reads an image measurement CSV.
pub fn read_measurements(path: &Path) -> Result<Vec<Measurement>> {
    rows(path, &["id", "image_name", "x", "y"], &["sigma_px"])?
        .into_iter()
        .map(|(line, f)| {
            let sigma_px = match f.get(4) {
                Some(s) => number(path, line, "sigma_px", s)?,
                None => 1.0,
            };
            if sigma_px <= 0.0 {
                return Err(FormatError::invalid(
                    path,
                    format!("line {line}: sigma_px must be positive"),
                ));
            }
            Ok(Measurement {
                id: f[0].clone(),
                image_name: f[1].clone(),
                pixel: [
                    number(path, line, "x", &f[2])?,
                    number(path, line, "y", &f[3])?,
                ],
                sigma_px,
            })
        })
        .collect()
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
    let points: HashMap<String, PointId> = block
        .points
        .values()
        .filter(|p| !p.name.is_empty())
        .map(|p| (p.name.clone(), p.id))
        .collect();
    let mut add = Vec::with_capacity(measurements.len());
    for m in measurements {
        let photo = *photos.get(m.image_name.as_str()).ok_or_else(|| {
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

// TEMPORARY (replaced by the h1 merge)
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointMeasurement {
    pub line: usize,
    pub photo: String,
    pub id: String,
    pub pixel: [f64; 2],
}
pub fn read_checkpoint_measurements(
    _path: &Path,
    _epoch: &str,
) -> Result<Vec<CheckpointMeasurement>> {
    unimplemented!()
}
