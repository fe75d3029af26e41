//! Approximate exterior orientation files of an epoch (specified in `formats/pos/`):
//!
//! * POS CSV: `name,x,y,z,omega,phi,kappa[,sigma_xyz,sigma_angle]` — projection centre in
//!   world coordinates (m) and photogrammetric omega/phi/kappa in degrees (our camera
//!   frame, see the design overview), with optional 1σ of the centre (m) and of each angle
//!   (degrees);
//! * strips CSV: `strip,photo,x,y,z` — every photo of every strip in flight order, with the
//!   projection centre given for the first and last photo of each strip and left empty for
//!   the photos in between (archives without POS, seed 000).

use super::{FormatError, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Which image axis points along the flight direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FlightAxis {
    /// Image x (the fiducial x axis): the classic film-camera convention.
    #[default]
    ImageX,
    /// Image up (towards row 0): common for digital frame cameras.
    ImageUp,
}

/// A strip given by its end points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StripEnds {
    pub name: String,
    /// Photo names in flight order (first to last).
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
    pub name: String,
    /// World coordinates of the projection centre.
    pub center: [f64; 3],
    /// Omega, phi, kappa (radians).
    pub opk: [f64; 3],
    pub sigma_xyz: Option<f64>,
    /// 1σ of each angle (radians).
    pub sigma_angle: Option<f64>,
}

fn rows(path: &Path) -> Result<Vec<(usize, Vec<String>)>> {
    let text = std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))?;
    let mut out = Vec::new();
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((_, header)) = lines.next() else {
        return Err(FormatError::invalid(path, "empty file (no header)"));
    };
    let header: Vec<String> = header
        .split(',')
        .map(|s| s.trim().to_ascii_lowercase())
        .collect();
    out.push((1, header));
    for (i, l) in lines {
        out.push((i + 1, l.split(',').map(|s| s.trim().to_string()).collect()));
    }
    Ok(out)
}

fn num(path: &Path, line: usize, col: &str, s: &str) -> Result<f64> {
    let v: f64 = s.parse().map_err(|_| {
        FormatError::invalid(
            path,
            format!("line {line}, column {col}: {s:?} is not a number"),
        )
    })?;
    if !v.is_finite() {
        return Err(FormatError::invalid(
            path,
            format!("line {line}, column {col}: not finite"),
        ));
    }
    Ok(v)
}

fn check_header(path: &Path, header: &[String], want: &[&str], optional: &[&str]) -> Result<()> {
    let ok = header.len() >= want.len()
        && header.iter().zip(want).all(|(h, w)| h == w)
        && header[want.len()..]
            .iter()
            .zip(optional)
            .all(|(h, w)| h == w)
        && header.len() <= want.len() + optional.len();
    if ok {
        Ok(())
    } else {
        Err(FormatError::invalid(
            path,
            format!(
                "header is {:?}; expected {}[,{}]",
                header.join(","),
                want.join(","),
                optional.join(",")
            ),
        ))
    }
}

pub fn read_pos(path: &Path) -> Result<Vec<PosRecord>> {
    let rows = rows(path)?;
    let want = ["name", "x", "y", "z", "omega", "phi", "kappa"];
    check_header(path, &rows[0].1, &want, &["sigma_xyz", "sigma_angle"])?;
    let ncol = rows[0].1.len();
    let mut out = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for (line, r) in &rows[1..] {
        if r.len() != ncol {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: {} fields, the header has {ncol}", r.len()),
            ));
        }
        if !seen.insert(r[0].clone()) {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: photo {:?} appears twice", r[0]),
            ));
        }
        let v = |i: usize| num(path, *line, &rows[0].1[i], &r[i]);
        let positive = |i: usize| -> Result<f64> {
            let x = v(i)?;
            if x <= 0.0 {
                return Err(FormatError::invalid(
                    path,
                    format!("line {line}, column {}: σ must be positive", rows[0].1[i]),
                ));
            }
            Ok(x)
        };
        out.push(PosRecord {
            name: r[0].clone(),
            center: [v(1)?, v(2)?, v(3)?],
            opk: [v(4)?.to_radians(), v(5)?.to_radians(), v(6)?.to_radians()],
            sigma_xyz: if ncol > 7 { Some(positive(7)?) } else { None },
            sigma_angle: if ncol > 8 {
                Some(positive(8)?.to_radians())
            } else {
                None
            },
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

/// The photo a POS or strip name refers to: the file name without folders and without
/// an image extension (PNG, TIFF, JPEG), so a name may be given with or without them.
pub fn photo_key(name: &str) -> &str {
    let file = name.rsplit(['/', '\\']).next().unwrap_or(name);
    match file.rsplit_once('.') {
        Some((stem, ext))
            if !stem.is_empty()
                && ["png", "tif", "tiff", "jpg", "jpeg"]
                    .iter()
                    .any(|e| ext.eq_ignore_ascii_case(e)) =>
        {
            stem
        }
        _ => file,
    }
}

/// Reads a strips file into strips with world end points.
pub fn read_strips(path: &Path) -> Result<Vec<StripEnds>> {
    let flight_axis = FlightAxis::default();
    let rows = rows(path)?;
    check_header(path, &rows[0].1, &["strip", "photo", "x", "y", "z"], &[])?;
    // (photo, centre if given, line) per strip, in file order.
    type Row = (String, Option<[f64; 3]>, usize);
    let mut strips: Vec<(String, Vec<Row>)> = Vec::new();
    for (line, r) in &rows[1..] {
        if r.len() != 5 {
            return Err(FormatError::invalid(
                path,
                format!("line {line}: {} fields, expected 5", r.len()),
            ));
        }
        let xyz = if r[2].is_empty() && r[3].is_empty() && r[4].is_empty() {
            None
        } else {
            Some([
                num(path, *line, "x", &r[2])?,
                num(path, *line, "y", &r[3])?,
                num(path, *line, "z", &r[4])?,
            ])
        };
        match strips.iter_mut().find(|s| s.0 == r[0]) {
            Some(s) => s.1.push((r[1].clone(), xyz, *line)),
            None => strips.push((r[0].clone(), vec![(r[1].clone(), xyz, *line)])),
        }
    }
    if strips.is_empty() {
        return Err(FormatError::invalid(path, "no strip listed"));
    }
    strips
        .into_iter()
        .map(|(name, photos)| {
            let n = photos.len();
            if n < 2 {
                return Err(FormatError::invalid(
                    path,
                    format!("strip {name}: needs at least two photos"),
                ));
            }
            let end = |k: usize| {
                photos[k].1.ok_or_else(|| {
                    FormatError::invalid(
                        path,
                        format!(
                            "line {}: strip {name}: the {} photo needs its centre",
                            photos[k].2,
                            if k == 0 { "first" } else { "last" }
                        ),
                    )
                })
            };
            Ok(StripEnds {
                first: end(0)?,
                last: end(n - 1)?,
                photos: photos.iter().map(|p| p.0.clone()).collect(),
                name,
                flight_axis,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pos_round_trip_and_errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pos.csv");
        let recs = vec![
            PosRecord {
                name: "a.tif".into(),
                center: [500100.0, 4400200.0, 1500.0],
                opk: [0.01, -0.02, 1.5],
                sigma_xyz: Some(10.0),
                sigma_angle: Some(3f64.to_radians()),
            },
            PosRecord {
                name: "b.tif".into(),
                center: [500300.0, 4400200.0, 1502.0],
                opk: [0.0, 0.0, 1.5],
                sigma_xyz: Some(10.0),
                sigma_angle: Some(3f64.to_radians()),
            },
        ];
        write_pos(&p, &recs).unwrap();
        let back = read_pos(&p).unwrap();
        for (a, b) in recs.iter().zip(&back) {
            assert_eq!(a.name, b.name);
            assert!((0..3)
                .all(|i| (a.center[i] - b.center[i]).abs() < 1e-4
                    && (a.opk[i] - b.opk[i]).abs() < 1e-9));
        }
        std::fs::write(&p, "name,x,y,z,omega,phi\na,1,2,3,0,0\n").unwrap();
        assert!(read_pos(&p).unwrap_err().to_string().contains("header"));
        std::fs::write(&p, "name,x,y,z,omega,phi,kappa\na,1,2,nan,0,0,0\n").unwrap();
        assert!(read_pos(&p)
            .unwrap_err()
            .to_string()
            .contains("line 2, column z"));
        std::fs::write(&p, "name,x,y,z,omega,phi,kappa\na,1,2,3,0,0,zero\n").unwrap();
        assert!(read_pos(&p)
            .unwrap_err()
            .to_string()
            .contains("\"zero\" is not a number"));
    }

    #[test]
    fn strips_need_their_end_points() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("strips.csv");
        std::fs::write(&p, "strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n1,f3,2000,10,3000\n2,g1,2000,900,3000\n2,g2,0,900,3000\n").unwrap();
        let s = read_strips(&p).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].photos, vec!["f1", "f2", "f3"]);
        assert_eq!(s[1].first, [2000.0, 900.0, 3000.0]);
        std::fs::write(&p, "strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n").unwrap();
        let e = read_strips(&p).unwrap_err().to_string();
        assert!(
            e.contains("last photo needs its centre") && e.contains("line 3"),
            "{e}"
        );
    }
}
