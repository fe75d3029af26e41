//! Reading of XYZ point sets for ICP sources: CSV/text (X,Y,Z in the first three numeric
//! columns), PLY (ascii or binary, vertex x/y/z; read by the `ply-rs-bw` crate) and
//! LAS/LAZ.

use super::las::read_points;
use super::{LidarError, Result};
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

fn bad(path: &Path, message: impl Into<String>) -> LidarError {
    LidarError::Las {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Reads XYZ points, choosing the format by extension (.las/.laz, .ply, else text).
pub fn read_xyz(path: &Path) -> Result<Vec<[f64; 3]>> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let pts = match ext.as_str() {
        "las" | "laz" => read_points(path, None, None)?.xyz,
        "ply" => read_ply(path)?,
        _ => read_text(path)?,
    };
    if pts.is_empty() {
        return Err(bad(path, "holds no point"));
    }
    Ok(pts)
}

/// `X,Y,Z` per line (comma, semicolon, tab or blanks); a first line that is not numeric is
/// a header; `#` starts a comment; extra columns are ignored.
pub fn read_text(path: &Path) -> Result<Vec<[f64; 3]>> {
    // A regular file, each line at most the `line` cap (formats/README.md, "Input files").
    let lines = crate::formats::input::lines(path, crate::formats::input::Cap::line())
        .map_err(super::las::input_error)?;
    let mut out = Vec::new();
    for (i, line) in lines.enumerate() {
        let (_, line) = line.map_err(super::las::input_error)?;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = t
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        let nums: Vec<Option<f64>> = fields
            .iter()
            .take(3)
            .map(|s| s.parse::<f64>().ok())
            .collect();
        if nums.len() == 3 && nums.iter().all(|v| v.is_some()) {
            let p = [nums[0].unwrap(), nums[1].unwrap(), nums[2].unwrap()];
            if !p.iter().all(|v| v.is_finite()) {
                return Err(bad(
                    path,
                    format!("line {}: coordinate is not finite", i + 1),
                ));
            }
            out.push(p);
        } else if out.is_empty() && i == 0 {
            continue; // header
        } else {
            return Err(bad(
                path,
                format!("line {}: expected X,Y,Z numbers, got {t:?}", i + 1),
            ));
        }
    }
    Ok(out)
}

/// The longest PLY header read (its lines up to `end_header`): real headers are a few
/// hundred bytes; without a bound a header line without an end would be read whole.
const PLY_HEADER_BYTES: u64 = 1 << 20;

/// A `ply-rs-bw` error on one line (its messages quote the line read, over several).
fn one_line(e: &std::io::Error) -> String {
    e.to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// One vertex as read by `ply-rs-bw`: its x, y and z, whatever their scalar type; other
/// properties are read over.
struct PlyVertex([f64; 3]);

impl ply_rs_bw::ply::PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self([f64::NAN; 3])
    }
    fn set_property(&mut self, name: &str, p: ply_rs_bw::ply::Property) {
        use ply_rs_bw::ply::Property as P;
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return,
        };
        self.0[axis] = match p {
            P::Char(v) => v.into(),
            P::UChar(v) => v.into(),
            P::Short(v) => v.into(),
            P::UShort(v) => v.into(),
            P::Int(v) => v.into(),
            P::UInt(v) => v.into(),
            P::Float(v) => v.into(),
            P::Double(v) => v,
            _ => f64::NAN,
        };
    }
}

/// PLY vertices: x, y, z of the `vertex` element (any scalar type; other properties read
/// over), ascii or binary of either byte order, through the `ply-rs-bw` crate. The header
/// is read by the crate from at most [`PLY_HEADER_BYTES`]; the counts it declares, of the
/// vertices and of the elements before them, are checked against the bytes after the
/// header before the crate reads or sizes anything from them (at least one byte and a
/// separator per property in ascii, the record in binary).
pub fn read_ply(path: &Path) -> Result<Vec<[f64; 3]>> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{Encoding, PropertyType, ScalarType};
    let (f, meta) = crate::formats::input::open_file(path, crate::formats::input::Links::Follow)
        .map_err(super::las::input_error)?;
    let file_len = meta.len();
    let mut r = BufReader::new(f);
    let magic = r.fill_buf().map_err(|e| LidarError::io(path, e))?;
    if !(magic.starts_with(b"ply\n") || magic.starts_with(b"ply\r\n")) {
        return Err(bad(path, "not a PLY file"));
    }
    let parser = Parser::<PlyVertex>::new();
    let mut head = (&mut r).take(PLY_HEADER_BYTES);
    let header = parser.read_header(&mut head).map_err(|e| {
        if head.limit() == 0 {
            bad(
                path,
                format!("PLY header has no end_header in its first {PLY_HEADER_BYTES} bytes"),
            )
        } else if e.kind() == std::io::ErrorKind::UnexpectedEof {
            bad(path, "PLY header has no end_header")
        } else {
            bad(path, format!("PLY header: {}", one_line(&e)))
        }
    })?;
    let header_len = PLY_HEADER_BYTES - head.limit();
    let Some(vertex_at) = header.elements.keys().position(|k| k == "vertex") else {
        return Err(bad(path, "PLY has no vertex element"));
    };
    let vertex = &header.elements[vertex_at];
    if vertex
        .properties
        .values()
        .any(|p| matches!(p.data_type, PropertyType::List(..)))
    {
        return Err(bad(path, "list properties on vertices are not supported"));
    }
    for axis in ["x", "y", "z"] {
        if !vertex.properties.contains_key(axis) {
            return Err(bad(path, format!("PLY vertices have no {axis} property")));
        }
    }
    let size = |t: &ScalarType| -> u64 {
        match t {
            ScalarType::Char | ScalarType::UChar => 1,
            ScalarType::Short | ScalarType::UShort => 2,
            ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
            ScalarType::Double => 8,
        }
    };
    // The fewest bytes a record can take: in binary its scalars (an empty list its
    // count), in ascii one digit and one separator per property. Nothing is sized from a
    // count before it fits in the file.
    let mut room = file_len.saturating_sub(header_len);
    for e in header.elements.values().take(vertex_at + 1) {
        let min_record: u64 = match header.encoding {
            Encoding::Ascii => 2 * e.properties.len() as u64,
            _ => e
                .properties
                .values()
                .map(|p| match &p.data_type {
                    PropertyType::Scalar(t) | PropertyType::List(t, _) => size(t),
                })
                .sum(),
        };
        let count = e.count as u64;
        match count.checked_mul(min_record) {
            Some(need) if need <= room => room -= need,
            _ => {
                return Err(LidarError::TooLarge {
                    path: path.to_path_buf(),
                    what: format!("PLY element {} count", e.name),
                    claimed: count,
                    limit: room / min_record.max(1),
                    basis: format!(
                        "what the {room} bytes after the header can hold at {min_record} bytes \
                         per {}",
                        e.name
                    ),
                })
            }
        }
    }
    let mut vertices = Vec::new();
    for e in header.elements.values().take(vertex_at + 1) {
        let read = parser
            .read_payload_for_element(&mut r, e, &header)
            .map_err(|x| {
                if x.kind() == std::io::ErrorKind::UnexpectedEof {
                    bad(
                        path,
                        format!(
                            "truncated: fewer than {} {} elements ({})",
                            e.count,
                            e.name,
                            one_line(&x)
                        ),
                    )
                } else {
                    bad(path, format!("PLY element {}: {}", e.name, one_line(&x)))
                }
            })?;
        if e.name == "vertex" {
            vertices = read;
        }
    }
    let out: Vec<[f64; 3]> = vertices.into_iter().map(|v| v.0).collect();
    if let Some(i) = out.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad(path, format!("vertex {i} is not finite")));
    }
    Ok(out)
}
