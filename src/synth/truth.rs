//! Readers of a synthetic block's truth files (formats/synth/README.md, `truth/`), through
//! the project's one CSV reader. Evaluation code only: a pipeline never reads `truth/`.

use crate::formats::csv::{read_records, Extra, Layout};
use crate::formats::{FormatError, Result};
use crate::geometry::{InteriorOrientation, InteriorTransformKind};
use nalgebra::Matrix3;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Deserialize)]
struct EoRow {
    photo: String,
    x: f64,
    y: f64,
    z: f64,
    r11: f64,
    r12: f64,
    r13: f64,
    r21: f64,
    r22: f64,
    r23: f64,
    r31: f64,
    r32: f64,
    r33: f64,
}

/// A photo's true exterior orientation: name (stem), world-to-camera rotation, projection
/// centre (world).
pub type TrueOrientation = (String, Matrix3<f64>, [f64; 3]);

/// `truth/epochs/<epoch>/eo.csv`: per photo (stem), the true world-to-camera rotation
/// (from the row-major `r11..r33`) and projection centre (world), in file order. The
/// `strip`, `index` and omega/phi/kappa columns are read over.
pub fn read_truth_eo(path: &Path) -> Result<Vec<TrueOrientation>> {
    let table = read_records::<EoRow>(
        path,
        &Layout {
            required: &[
                "photo", "x", "y", "z", "r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32",
                "r33",
            ],
            optional: &[],
            extra: Extra::Ignore,
        },
    )?;
    Ok(table
        .rows
        .into_iter()
        .map(|(_, r)| {
            let rotation = Matrix3::new(
                r.r11, r.r12, r.r13, r.r21, r.r22, r.r23, r.r31, r.r32, r.r33,
            );
            (r.photo, rotation, [r.x, r.y, r.z])
        })
        .collect())
}

#[derive(Deserialize)]
struct AffineRow {
    photo: String,
    a11: f64,
    a12: f64,
    a13: f64,
    a21: f64,
    a22: f64,
    a23: f64,
}

/// `truth/epochs/<epoch>/scan_affine.csv`: the true interior orientation (scan pixel →
/// fiducial mm affine) of every film scan, by photo (stem).
pub fn read_scan_affine(path: &Path) -> Result<BTreeMap<String, InteriorOrientation>> {
    let table = read_records::<AffineRow>(
        path,
        &Layout {
            required: &["photo", "a11", "a12", "a13", "a21", "a22", "a23"],
            optional: &[],
            extra: Extra::Refuse,
        },
    )?;
    let mut out = BTreeMap::new();
    for (line, r) in table.rows {
        let io = InteriorOrientation::new(
            InteriorTransformKind::Affine,
            Matrix3::new(r.a11, r.a12, r.a13, r.a21, r.a22, r.a23, 0.0, 0.0, 1.0),
        )
        .map_err(|e| FormatError::at(path, line, None, e.to_string()))?;
        if out.insert(r.photo.clone(), io).is_some() {
            return Err(FormatError::at(
                path,
                line,
                Some("photo".into()),
                format!("photo {} is listed twice", r.photo),
            ));
        }
    }
    Ok(out)
}

/// One building of an epoch's scene as `truth/epochs/<epoch>/buildings.csv` holds it: its
/// id (the same building keeps its id through the epochs), footprint rectangle (world
/// centre, half length along the ridge and half width, azimuth of the long axis from east
/// in radians) and ground-floor and eave heights (m).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct TrueBuilding {
    pub id: u32,
    pub x: f64,
    pub y: f64,
    pub half_length: f64,
    pub half_width: f64,
    pub angle_rad: f64,
    pub base: f64,
    pub eave: f64,
}

impl TrueBuilding {
    /// Whether world point (x, y) lies within the footprint.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (s, c) = self.angle_rad.sin_cos();
        let (dx, dy) = (x - self.x, y - self.y);
        (c * dx + s * dy).abs() <= self.half_length && (-s * dx + c * dy).abs() <= self.half_width
    }
}

/// The header of `buildings.csv`.
pub const BUILDINGS_HEADER: &str = "id,x,y,half_length,half_width,angle_rad,base,eave";

/// `truth/epochs/<epoch>/buildings.csv`: the buildings standing in that epoch.
pub fn read_buildings(path: &Path) -> Result<Vec<TrueBuilding>> {
    let columns: Vec<&str> = BUILDINGS_HEADER.split(',').collect();
    let table = read_records::<TrueBuilding>(
        path,
        &Layout {
            required: &columns,
            optional: &[],
            extra: Extra::Ignore,
        },
    )?;
    Ok(table.rows.into_iter().map(|(_, b)| b).collect())
}
