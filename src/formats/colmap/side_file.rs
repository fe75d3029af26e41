//! The side file: what COLMAP cannot hold (CRS, block origin, roles and σ of control and
//! check points, photo dates), next to the model and ignored by COLMAP.

use crate::block::{Block, PhotoId, PointId, PointKind};
use crate::formats::{write_bytes_atomically, FormatError, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Side file with what COLMAP cannot hold: CRS, block origin, control/check points.
pub const SIDE_FILE: &str = "cloudcontrol_georef.json";

/// What the side file holds.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct SideFile {
    crs: Option<String>,
    origin: [f64; 3],
    /// Control and check points (tie points need no entry).
    #[serde(default)]
    points: Vec<SidePoint>,
    /// Photo metadata COLMAP has no field for.
    #[serde(default)]
    photos: Vec<SidePhoto>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct SidePoint {
    id: PointId,
    name: String,
    kind: PointKind,
    /// σ x, y, z (m); `null` for an unconstrained coordinate (σ = ∞, e.g. the height of a
    /// horizontal control point), which JSON cannot write as a number.
    sigma: Option<[Option<f64>; 3]>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct SidePhoto {
    id: PhotoId,
    date: Option<String>,
}

/// Writes the side file of `block` into the model folder `dir`.
pub(super) fn write(dir: &Path, block: &Block) -> Result<()> {
    let side = SideFile {
        crs: block.crs.clone(),
        origin: block.origin,
        points: block
            .points
            .values()
            .filter(|p| p.kind != PointKind::Tie || !p.name.is_empty() || p.sigma.is_some())
            .map(|p| SidePoint {
                id: p.id,
                name: p.name.clone(),
                kind: p.kind,
                sigma: p.sigma.map(|s| s.map(|v| v.is_finite().then_some(v))),
            })
            .collect(),
        photos: block
            .photos
            .values()
            .filter(|p| p.date.is_some())
            .map(|p| SidePhoto {
                id: p.id,
                date: p.date.clone(),
            })
            .collect(),
    };
    let json = serde_json::to_vec_pretty(&side).expect("side file serialises");
    write_bytes_atomically(&dir.join(SIDE_FILE), &json)
}

/// Applies the side file in the model folder `dir`, when there is one, to the block read
/// from the model.
pub(super) fn apply(dir: &Path, block: &mut Block) -> Result<()> {
    let side = dir.join(SIDE_FILE);
    if !side.is_file() {
        return Ok(());
    }
    let s = crate::formats::input::read_text(&side, crate::formats::input::Cap::document())?;
    let sf: SideFile = serde_json::from_str(&s)
        .map_err(|e| FormatError::invalid(&side, format!("not a valid side file: {e}")))?;
    block.crs = sf.crs;
    block.origin = sf.origin;
    for sp in sf.points {
        let p = block.points.get_mut(&sp.id).ok_or_else(|| {
            FormatError::invalid(&side, format!("point {} is not in points3D", sp.id))
        })?;
        p.name = sp.name;
        p.kind = sp.kind;
        p.sigma = sp.sigma.map(|s| s.map(|v| v.unwrap_or(f64::INFINITY)));
    }
    for ph in sf.photos {
        if let Some(p) = block.photos.get_mut(&ph.id) {
            p.date = ph.date;
        }
    }
    Ok(())
}
