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

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pos.csv");
        std::fs::write(&p, text).unwrap();
        (d, p)
    }

    #[test]
    fn pos_as_documented() {
        // Written by hand from formats/pos/README.md.
        let (_d, p) = file(
            "# POS of the 2024 flight, exported by hand\n\
             NAME, X, Y, Z, Omega, Phi, Kappa, Sigma_XYZ, Sigma_Angle\n\
             ref_000.tif,500120.512,4400210.330,1523.10,0.21,-0.35,90.12,10,3\n\
             \n\
             \"ref 001.tif\",500320.5,4400210.3,1524,0,0,-90,0.05,0.01\n",
        );
        let r = read_pos(&p).unwrap();
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].name, "ref_000.tif");
        assert_eq!(r[0].center, [500120.512, 4400210.330, 1523.10]);
        assert!((r[0].opk[2] - 90.12f64.to_radians()).abs() < 1e-15);
        assert_eq!(r[0].sigma_xyz, Some(10.0));
        assert!((r[0].sigma_angle.unwrap() - 3f64.to_radians()).abs() < 1e-15);
        assert_eq!(r[1].name, "ref 001.tif");
        // Without the σ pair.
        let (_d, p) = file("name,x,y,z,omega,phi,kappa\nref_000,1,2,3,0,0,0\n");
        let r = read_pos(&p).unwrap();
        assert_eq!((r[0].sigma_xyz, r[0].sigma_angle), (None, None));
    }

    #[test]
    fn pos_errors_name_line_and_column() {
        let err = |text: &str| read_pos(&file(text).1).unwrap_err().to_string();
        let h = "name,x,y,z,omega,phi,kappa";
        assert!(err(&format!("{h}\na.tif,1,2,3,0,0,zero\n"))
            .ends_with("pos.csv: line 2, column kappa: \"zero\" is not a number"));
        assert!(err(&format!("# c\n{h}\na.tif,1,2,nan,0,0,0\n"))
            .contains("line 3, column z: \"nan\" is not a finite number"));
        assert!(err("name,x,y,z,omega,phi\na,1,2,3,0,0\n")
            .contains("line 1: no column \"kappa\" in the header"));
        assert!(err(&format!("{h},sigma\na,1,2,3,0,0,0,1\n"))
            .contains("line 1: unknown column \"sigma\""));
        assert!(err(&format!("{h},sigma_xyz\na,1,2,3,0,0,0,1\n")).contains("come together"));
        assert!(
            err(&format!("{h},sigma_xyz,sigma_angle\na,1,2,3,0,0,0,0,1\n"))
                .contains("line 2, column sigma_xyz: σ must be positive")
        );
        assert!(err(&format!(
            "{h}\na.tif,1,2,3,0,0,0\nb,1,2,3,0,0,0\na.png,1,2,3,0,0,0\n"
        ))
        .contains("line 4, column name: photo \"a.png\" is already listed on line 2"));
        assert!(err(&format!("{h}\n")).contains("no photo listed"));
    }

    #[test]
    fn pos_round_trip() {
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
    }

    #[test]
    fn photo_keys_match_file_names_and_stems() {
        assert_eq!(photo_key("ref_000.tif"), "ref_000");
        assert_eq!(photo_key("ref_000"), "ref_000");
        assert_eq!(photo_key("scans/1978/F1_001.TIFF"), "F1_001");
        assert_eq!(photo_key("c:\\scans\\f1.JPG"), "f1");
        assert_eq!(photo_key("p.2012.05"), "p.2012.05");
        assert_eq!(photo_key("p.2012.05.png"), "p.2012.05");
        assert_eq!(photo_key(".png"), ".png");
    }

    #[test]
    fn strips_as_documented() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("strips.csv");
        // Written by hand from formats/pos/README.md.
        std::fs::write(
            &p,
            "# flight index of 1978, read off the map\n\
             Strip,Photo,X,Y,Z,Flight_Axis\n\
             1,f1_001.tif,500000.0,4399800.0,3050,+x\n\
             1,f1_002.tif,,,,\n\
             1,\"f1_003.tif\",,,,image_x\n\
             1,f1_004.tif,501800.0,4399810.0,3060,+x\n\
             2,f2_001.tif,501800.0,4400900.0,3050,image_up\n\
             2,f2_002.tif,500000.0,4400910.0,3050,-y\n",
        )
        .unwrap();
        let s = read_strips(&p).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(
            s[0].photos,
            vec!["f1_001.tif", "f1_002.tif", "f1_003.tif", "f1_004.tif"]
        );
        assert_eq!(s[0].first, [500000.0, 4399800.0, 3050.0]);
        assert_eq!(s[0].last, [501800.0, 4399810.0, 3060.0]);
        assert_eq!(s[0].flight_axis, FlightAxis::PlusX);
        assert_eq!(s[1].flight_axis, FlightAxis::MinusY);
        assert_eq!(s[1].first, [501800.0, 4400900.0, 3050.0]);
        // Without the column: +x, the classic film convention.
        std::fs::write(
            &p,
            "strip,photo,x,y,z\n1,a,0,0,3000\n1,b,,,\n1,c,2000,0,3000\n",
        )
        .unwrap();
        let s = read_strips(&p).unwrap();
        assert_eq!(s[0].flight_axis, FlightAxis::PlusX);
        // Round trip through the writer.
        let all = [
            FlightAxis::PlusX,
            FlightAxis::MinusX,
            FlightAxis::PlusY,
            FlightAxis::MinusY,
        ];
        let strips: Vec<StripEnds> = all
            .iter()
            .enumerate()
            .map(|(i, &a)| StripEnds {
                name: format!("s{i}"),
                photos: (0..3).map(|k| format!("s{i}_{k}.png")).collect(),
                first: [i as f64, 0.0, 100.0],
                last: [i as f64, 50.0, 100.0],
                flight_axis: a,
            })
            .collect();
        write_strips(&p, &strips).unwrap();
        assert_eq!(read_strips(&p).unwrap(), strips);
    }

    #[test]
    fn strip_errors_name_the_line() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("strips.csv");
        let err = |text: &str| {
            std::fs::write(&p, text).unwrap();
            read_strips(&p).unwrap_err().to_string()
        };
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n");
        assert!(
            e.ends_with("strips.csv: line 3: strip 1: the last photo needs its centre"),
            "{e}"
        );
        let e =
            err("strip,photo,x,y,z,flight_axis\n1,f1,0,0,3000,-y\n1,f2,,,,\n1,f3,9,0,3000,+x\n");
        assert!(
            e.ends_with(
                "line 4, column flight_axis: strip 1: flight axis +x differs from -y given on line 2"
            ),
            "{e}"
        );
        let e = err("strip,photo,x,y,z,flight_axis\n1,f1,0,0,3000,up\n1,f2,1,0,3000,\n");
        assert!(
            e.contains("line 2, column flight_axis: unknown variant `up`"),
            "{e}"
        );
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,,,\n1,f3,1,x,3000\n");
        assert!(e.contains("line 4, column y: \"x\" is not a number"), "{e}");
        let e = err("strip,photo,x,y\n1,f1,0,0\n");
        assert!(e.contains("line 1: no column \"z\""), "{e}");
        let e = err("strip,photo,x,y,z,kappa\n1,f1,0,0,0,0\n");
        assert!(e.contains("unknown column \"kappa\""), "{e}");
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f2,5,,\n");
        assert!(e.contains("line 3: x, y and z are given together"), "{e}");
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n1,f1.tif,5,0,3000\n");
        assert!(
            e.contains("line 3, column photo: photo \"f1.tif\" is already listed on line 2"),
            "{e}"
        );
        let e = err("strip,photo,x,y,z\n1,f1,0,0,3000\n");
        assert!(
            e.contains("line 2: strip 1: needs at least two photos"),
            "{e}"
        );
    }
}
