//! Reading of XYZ point sets for ICP sources: CSV/text (X,Y,Z in the first three numeric
//! columns), PLY (ascii or binary little endian, vertex x/y/z) and LAS/LAZ.

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

/// PLY vertices (x, y, z as float or double; other properties skipped).
pub fn read_ply(path: &Path) -> Result<Vec<[f64; 3]>> {
    let f = crate::formats::input::open(path).map_err(super::las::input_error)?;
    let file_len = f.metadata().map_err(|e| LidarError::io(path, e))?.len();
    let mut r = BufReader::new(f);
    let mut header_len = 0u64;
    let mut line = String::new();
    let mut format = String::new();
    let mut n_vertex = None;
    let mut in_vertex = false;
    let mut props: Vec<(String, usize)> = Vec::new();
    let size_of = |t: &str| -> Option<usize> {
        Some(match t {
            "char" | "uchar" | "int8" | "uint8" => 1,
            "short" | "ushort" | "int16" | "uint16" => 2,
            "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
            "double" | "float64" => 8,
            _ => return None,
        })
    };
    let mut first = true;
    loop {
        line.clear();
        let got = r
            .read_line(&mut line)
            .map_err(|e| LidarError::io(path, e))?;
        if got == 0 {
            return Err(bad(path, "PLY header has no end_header"));
        }
        header_len += got as u64;
        let t = line.trim();
        if first {
            if t != "ply" {
                return Err(bad(path, "not a PLY file"));
            }
            first = false;
            continue;
        }
        let w: Vec<&str> = t.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, ..] => format = f.to_string(),
            ["element", "vertex", n] => {
                n_vertex = Some(
                    n.parse::<u64>()
                        .map_err(|_| bad(path, format!("bad vertex count {n:?}")))?,
                );
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", "list", ..] if in_vertex => {
                return Err(bad(path, "list properties on vertices are not supported"))
            }
            ["property", ty, name] if in_vertex => {
                let s = size_of(ty).ok_or_else(|| bad(path, format!("unknown PLY type {ty}")))?;
                props.push((format!("{ty}:{name}"), s));
            }
            ["end_header"] => break,
            _ => {}
        }
    }
    let n = n_vertex.ok_or_else(|| bad(path, "PLY has no vertex element"))?;
    let find = |axis: &str| {
        props
            .iter()
            .position(|(p, _)| p.ends_with(&format!(":{axis}")))
            .ok_or_else(|| bad(path, format!("PLY vertices have no {axis} property")))
    };
    let (ix, iy, iz) = (find("x")?, find("y")?, find("z")?);
    // The fewest bytes a vertex can take: its binary record, or in ascii one digit and one
    // separator per property. Nothing is sized from the count before it fits in the file.
    let stride: usize = props.iter().map(|p| p.1).sum();
    let min_record = if format == "ascii" {
        2 * props.len()
    } else {
        stride
    } as u64;
    let body = file_len.saturating_sub(header_len);
    if n.checked_mul(min_record).is_none_or(|need| need > body) {
        return Err(LidarError::TooLarge {
            path: path.to_path_buf(),
            what: "PLY element vertex count".into(),
            claimed: n,
            limit: body / min_record.max(1),
            basis: format!(
                "what the {body} bytes after the header can hold at {min_record} bytes per \
                 vertex"
            ),
        });
    }
    let n = n as usize;
    let mut out = Vec::with_capacity(n);
    match format.as_str() {
        "ascii" => {
            for i in 0..n {
                line.clear();
                if r.read_line(&mut line)
                    .map_err(|e| LidarError::io(path, e))?
                    == 0
                {
                    return Err(bad(path, format!("truncated: {i} of {n} vertices")));
                }
                let v: Vec<f64> = line
                    .split_whitespace()
                    .filter_map(|s| s.parse().ok())
                    .collect();
                if v.len() < props.len() {
                    return Err(bad(
                        path,
                        format!("vertex {i}: {} values, expected {}", v.len(), props.len()),
                    ));
                }
                out.push([v[ix], v[iy], v[iz]]);
            }
        }
        "binary_little_endian" => {
            let offs: Vec<usize> = props
                .iter()
                .scan(0, |o, p| {
                    let at = *o;
                    *o += p.1;
                    Some(at)
                })
                .collect();
            let mut buf = vec![0u8; stride * n];
            r.read_exact(&mut buf)
                .map_err(|_| bad(path, format!("truncated: fewer than {n} vertices")))?;
            let get = |rec: &[u8], k: usize| -> Result<f64> {
                let o = offs[k];
                match props[k].0.split(':').next().unwrap_or("") {
                    "float" | "float32" => {
                        Ok(f32::from_le_bytes(rec[o..o + 4].try_into().unwrap()) as f64)
                    }
                    "double" | "float64" => {
                        Ok(f64::from_le_bytes(rec[o..o + 8].try_into().unwrap()))
                    }
                    t => Err(bad(
                        path,
                        format!("vertex coordinates of type {t} are not supported"),
                    )),
                }
            };
            for rec in buf.chunks_exact(stride) {
                out.push([get(rec, ix)?, get(rec, iy)?, get(rec, iz)?]);
            }
        }
        f => {
            return Err(bad(
                path,
                format!("PLY format {f:?} is not supported (ascii or binary_little_endian)"),
            ))
        }
    }
    if let Some(i) = out.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad(path, format!("vertex {i} is not finite")));
    }
    Ok(out)
}
