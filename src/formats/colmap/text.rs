//! COLMAP's text encoding (`reconstruction_io_text.cc`): one record per line (two for an
//! image), whitespace-separated, `#` comments. Errors name the file, line and field.

use super::camera_models::{camera_from_colmap, camera_to_colmap, model_by_name, unsupported};
use super::records::{
    pose_from_qt, Cameras, FrameRecord, Image, ImageRow, PointSink, PointsTable, RigSensors,
};
use super::{open, INVALID_POINT3D};
use crate::formats::{FormatError, Result};
use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;

/// Whitespace-token cursor over one text line, with errors naming file, line and field.
/// ASCII whitespace separates, as COLMAP's stream extraction does (a name may hold any
/// other character); the Unicode-aware split was a quarter of reading a model (perf).
struct Tokens<'a> {
    it: std::str::SplitAsciiWhitespace<'a>,
    path: &'a Path,
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(s: &'a str, path: &'a Path, line: usize) -> Self {
        Self {
            it: s.split_ascii_whitespace(),
            path,
            line,
        }
    }
    fn err(&self, m: impl std::fmt::Display) -> FormatError {
        FormatError::invalid(self.path, format!("line {}: {m}", self.line))
    }
    fn next_str(&mut self, field: &str) -> Result<&'a str> {
        let (path, line) = (self.path, self.line);
        self.it.next().ok_or_else(|| {
            FormatError::invalid(path, format!("line {line}: field {field} is missing"))
        })
    }
    fn parse<T: std::str::FromStr>(&mut self, field: &str) -> Result<T> {
        let s = self.next_str(field)?;
        s.parse()
            .map_err(|_| self.err(format!("field {field} is not a valid number: {s:?}")))
    }
    fn f64s<const N: usize>(&mut self, field: &str) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for v in out.iter_mut() {
            *v = self.parse(field)?;
        }
        Ok(out)
    }
    /// A count of `per_item`-field items that follow on the line, refused when the line
    /// holds fewer fields (so a corrupt count never sizes an allocation).
    fn count(&mut self, field: &str, per_item: usize) -> Result<usize> {
        let n: u64 = self.parse(field)?;
        let left = self.it.clone().count();
        if n.saturating_mul(per_item as u64) > left as u64 {
            return Err(self.err(format!(
                "{field} {n} needs {per_item} fields each but the line holds {left} more \
                 (corrupt or truncated)"
            )));
        }
        Ok(n as usize)
    }
    fn rest_is_empty(&mut self) -> Result<()> {
        match self.it.next() {
            None => Ok(()),
            Some(s) => Err(self.err(format!("unexpected trailing field {s:?}"))),
        }
    }
}

/// Data lines of a COLMAP text file (comments and blank lines skipped) with 1-based
/// line numbers; `keep_empty` keeps blank lines (an image's empty POINTS2D line).
fn text_lines(
    path: &Path,
    keep_empty: bool,
) -> Result<impl Iterator<Item = Result<(usize, String)>>> {
    // Each line at most the `line` cap long (formats/README.md, "Input files").
    let lines =
        crate::formats::input::Lines::new(open(path)?, path, crate::formats::input::Cap::line());
    Ok(lines.filter_map(move |l| match l {
        Err(e) => Some(Err(e)),
        Ok((no, l)) => {
            let t = l.trim_start();
            if t.starts_with('#') || (!keep_empty && t.trim().is_empty()) {
                None
            } else {
                Some(Ok((no, l)))
            }
        }
    }))
}

pub(super) fn read_cameras(path: &Path) -> Result<Cameras> {
    let mut out = BTreeMap::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("CAMERA_ID")?;
        let name = t.next_str("MODEL")?;
        let (model, np) = model_by_name(name)
            .ok_or_else(|| t.err(format!("camera {id}: unknown camera model {name:?}")))?;
        if np == usize::MAX {
            return Err(t.err(format!("camera {id}: {}", unsupported(name))));
        }
        let w: u64 = t.parse("WIDTH")?;
        let h: u64 = t.parse("HEIGHT")?;
        let mut p = vec![0.0; np];
        for v in p.iter_mut() {
            *v = t.parse("PARAMS")?;
        }
        t.rest_is_empty()?;
        let cam =
            camera_from_colmap(model, w, h, &p).map_err(|m| t.err(format!("camera {id}: {m}")))?;
        if out.insert(id, cam).is_some() {
            return Err(t.err(format!("camera id {id} appears twice")));
        }
    }
    Ok(out)
}

pub(super) fn read_images(path: &Path) -> Result<Vec<Image>> {
    let mut out = Vec::new();
    let mut lines = text_lines(path, true)?;
    while let Some(line) = lines.next() {
        let (no, l) = line?;
        if l.trim().is_empty() {
            continue;
        }
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("IMAGE_ID")?;
        let q = t.f64s::<4>("QW QX QY QZ")?;
        let tr = t.f64s::<3>("TX TY TZ")?;
        let camera: u32 = t.parse("CAMERA_ID")?;
        let name = t.next_str("NAME")?.to_string();
        t.rest_is_empty()?;
        let pose = pose_from_qt(q, tr).map_err(|m| t.err(format!("image {id} ({name}): {m}")))?;
        let mut points2d = Vec::new();
        match lines.next() {
            None => {
                return Err(FormatError::invalid(
                    path,
                    format!("truncated: image {id} ({name}) has no POINTS2D line"),
                ))
            }
            Some(pl) => {
                let (no2, pl) = pl?;
                let mut t2 = Tokens::new(&pl, path, no2);
                while let Some(x) = t2.it.next() {
                    let x: f64 = x.parse().map_err(|_| {
                        t2.err(format!("image {id}: POINTS2D X is not a number: {x:?}"))
                    })?;
                    let y: f64 = t2.parse("POINTS2D Y")?;
                    let pid: i64 = t2.parse("POINTS2D POINT3D_ID")?;
                    let pid = if pid < 0 { INVALID_POINT3D } else { pid as u64 };
                    points2d.push(([x, y], pid));
                }
            }
        }
        out.push(Image {
            id,
            pose,
            camera,
            name,
            points2d,
        });
    }
    Ok(out)
}

pub(super) fn read_points(path: &Path, sink: &mut PointSink) -> Result<()> {
    let mut track = Vec::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u64 = t.parse("POINT3D_ID")?;
        let xyz = t.f64s::<3>("X Y Z")?;
        let rgb = [t.parse("R")?, t.parse("G")?, t.parse("B")?];
        let _error: f64 = t.parse("ERROR")?;
        track.clear();
        while let Some(s) = t.it.next() {
            let im: u32 = s
                .parse()
                .map_err(|_| t.err(format!("point {id}: TRACK IMAGE_ID is not valid: {s:?}")))?;
            let idx: u32 = t.parse("TRACK POINT2D_IDX")?;
            track.push((im, idx));
        }
        sink(id, xyz, rgb, &track).map_err(|m| t.err(m))?;
    }
    Ok(())
}

fn sensor_type(s: &str) -> i32 {
    match s {
        "CAMERA" => 0,
        "IMU" => 1,
        _ => -1,
    }
}

pub(super) fn read_rigs(path: &Path) -> Result<HashMap<u32, RigSensors>> {
    let mut out = HashMap::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("RIG_ID")?;
        let ns: u32 = t.parse("NUM_SENSORS")?;
        let mut sensors = RigSensors::new();
        if ns > 0 {
            let ty = sensor_type(t.next_str("REF_SENSOR_TYPE")?);
            let sid: u32 = t.parse("REF_SENSOR_ID")?;
            if ty == 0 {
                sensors.insert(sid, None);
            }
            for _ in 1..ns {
                let ty = sensor_type(t.next_str("SENSOR_TYPE")?);
                let sid: u32 = t.parse("SENSOR_ID")?;
                let has: u32 = t.parse("HAS_POSE")?;
                let pose = if has != 0 {
                    let q = t.f64s::<4>("QW QX QY QZ")?;
                    let tr = t.f64s::<3>("TX TY TZ")?;
                    Some(pose_from_qt(q, tr).map_err(|m| t.err(format!("rig {id}: {m}")))?)
                } else {
                    None
                };
                if ty == 0 {
                    sensors.insert(sid, pose);
                }
            }
        }
        out.insert(id, sensors);
    }
    Ok(out)
}

pub(super) fn read_frames(path: &Path) -> Result<Vec<FrameRecord>> {
    let mut out = Vec::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("FRAME_ID")?;
        let rig: u32 = t.parse("RIG_ID")?;
        let q = t.f64s::<4>("QW QX QY QZ")?;
        let tr = t.f64s::<3>("TX TY TZ")?;
        let nd = t.count("NUM_DATA_IDS", 3)?;
        let mut data = Vec::with_capacity(nd);
        for _ in 0..nd {
            let ty = sensor_type(t.next_str("SENSOR_TYPE")?);
            data.push((ty, t.parse("SENSOR_ID")?, t.parse("DATA_ID")?));
        }
        let pose = pose_from_qt(q, tr).map_err(|m| t.err(format!("frame {id}: {m}")))?;
        out.push((id, rig, pose, data));
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------
// Writing (headers as COLMAP writes them)
// ---------------------------------------------------------------------------------------

pub(super) fn write_cameras(w: &mut impl Write, cams: &Cameras) -> std::io::Result<()> {
    write!(w, "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: {}\n", cams.len())?;
    for (&id, c) in cams {
        let (_, name, params) = camera_to_colmap(c);
        write!(w, "{id} {name} {} {}", c.width, c.height)?;
        for p in &params {
            write!(w, " {p}")?;
        }
        writeln!(w)?;
    }
    Ok(())
}

/// A float in its shortest round-trip form (ryu: `1.0`, `1e-7`; COLMAP's and our
/// readers take either notation).
fn push_f64(out: &mut Vec<u8>, x: f64) {
    out.extend_from_slice(ryu::Buffer::new().format(x).as_bytes());
}

fn push_int(out: &mut Vec<u8>, i: impl itoa::Integer) {
    out.extend_from_slice(itoa::Buffer::new().format(i).as_bytes());
}

/// Items per window whose lines are formatted in parallel and then written in order: the
/// text held at once stays a few MB whatever the model's size.
const WINDOW: usize = 8192;

/// Writes one text record per item, formatted in parallel (rayon) and written in item
/// order; `line` gets the item's index. Formatting the 60,000 numbers of a 50-photo
/// model with `write!` took 8 ms of a 0.11 s `cloudcontrol adjust` (perf), as much as
/// two solver iterations.
fn write_lines<T: Sync>(
    w: &mut impl Write,
    items: &[T],
    line: impl Fn(usize, &T, &mut Vec<u8>) + Sync,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    let task = (items.len().min(WINDOW) / (4 * rayon::current_num_threads())).max(1);
    for (wi, window) in items.chunks(WINDOW).enumerate() {
        let parts: Vec<Vec<u8>> = window
            .par_chunks(task)
            .enumerate()
            .map(|(ti, chunk)| {
                let mut buf = Vec::new();
                for (k, it) in chunk.iter().enumerate() {
                    line(wi * WINDOW + ti * task + k, it, &mut buf);
                }
                buf
            })
            .collect();
        for p in &parts {
            w.write_all(p)?;
        }
    }
    Ok(())
}

/// Names were checked to hold no whitespace.
pub(super) fn write_images(w: &mut impl Write, images: &[ImageRow]) -> std::io::Result<()> {
    write!(w, "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: {}\n", images.len())?;
    write_lines(w, images, |_, r, out| {
        push_int(out, r.id);
        for x in r.q.iter().chain(&r.t) {
            out.push(b' ');
            push_f64(out, *x);
        }
        out.push(b' ');
        push_int(out, r.camera);
        out.push(b' ');
        out.extend_from_slice(r.name.as_bytes());
        out.push(b'\n');
        for (k, (xy, pid)) in r.points2d.iter().enumerate() {
            if k > 0 {
                out.push(b' ');
            }
            push_f64(out, xy[0]);
            out.push(b' ');
            push_f64(out, xy[1]);
            out.push(b' ');
            if *pid == INVALID_POINT3D {
                out.extend_from_slice(b"-1");
            } else {
                push_int(out, *pid);
            }
        }
        out.push(b'\n');
    })
}

pub(super) fn write_points(w: &mut impl Write, table: &PointsTable) -> std::io::Result<()> {
    let (points, idx) = (&table.points, table.idx);
    write!(w, "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n# Number of points: {}\n", points.len())?;
    // Where each point's observations start in the flat POINT2D_IDX list.
    let starts: Vec<usize> = points
        .iter()
        .scan(0, |k, p| {
            let s = *k;
            *k += p.observations.len();
            Some(s)
        })
        .collect();
    write_lines(w, points, |i, p, out| {
        push_int(out, p.id);
        for x in [p.position.x, p.position.y, p.position.z] {
            out.push(b' ');
            push_f64(out, x);
        }
        for c in p.color {
            out.push(b' ');
            push_int(out, c);
        }
        out.push(b' ');
        push_f64(out, table.errors[i]);
        for (o, k) in p.observations.iter().zip(&idx[starts[i]..]) {
            out.push(b' ');
            push_int(out, o.photo);
            out.push(b' ');
            push_int(out, *k);
        }
        out.push(b'\n');
    })
}

pub(super) fn write_rigs(w: &mut impl Write, cams: &Cameras) -> std::io::Result<()> {
    write!(w, "# Rig calib list with one line of data per calib:\n#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n# Number of rigs: {}\n", cams.len())?;
    for &id in cams.keys() {
        writeln!(w, "{id} 1 CAMERA {id}")?;
    }
    Ok(())
}

pub(super) fn write_frames(w: &mut impl Write, images: &[ImageRow]) -> std::io::Result<()> {
    write!(w, "# Frame list with one line of data per frame:\n#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS, DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)\n# Number of frames: {}\n", images.len())?;
    for r in images {
        let (q, t) = (r.q, r.t);
        writeln!(
            w,
            "{} {} {} {} {} {} {} {} {} 1 CAMERA {} {}",
            r.id, r.camera, q[0], q[1], q[2], q[3], t[0], t[1], t[2], r.camera, r.id
        )?;
    }
    Ok(())
}
