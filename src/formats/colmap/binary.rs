//! COLMAP's binary encoding (`reconstruction_io_binary.cc`): little-endian records, counts
//! as `uint64`, names NUL-terminated. Readers refuse counts that cannot fit in the rest of
//! the file, so a corrupt header never sizes an allocation.

use super::camera_models::{
    camera_from_colmap, camera_to_colmap, model_name, num_params, unsupported,
};
use super::open;
use super::records::{
    pose_from_qt, Cameras, FrameRecord, Image, ImageRow, PointSink, PointsTable, RigSensors,
};
use crate::formats::{FormatError, Result};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};

/// Binary reader that turns short reads into "truncated" errors naming the record.
struct Bin {
    r: BufReader<File>,
    path: PathBuf,
    buf: Vec<u8>,
    len: u64,
}

impl Bin {
    fn open(path: &Path) -> Result<Self> {
        let r = open(path)?;
        let len = r.get_ref().metadata().map(|m| m.len()).unwrap_or(u64::MAX);
        Ok(Self {
            r,
            path: path.to_path_buf(),
            buf: Vec::new(),
            len,
        })
    }
    /// `n` bytes in one read (whole arrays of fixed-size items), in a reused buffer.
    fn chunk(&mut self, n: usize, what: &dyn Fn() -> String) -> Result<&[u8]> {
        self.buf.resize(n, 0);
        if let Err(e) = self.r.read_exact(&mut self.buf) {
            return Err(self.fail(e, what));
        }
        Ok(&self.buf)
    }
    fn fail(&self, e: std::io::Error, what: &dyn Fn() -> String) -> FormatError {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            FormatError::invalid(
                &self.path,
                format!("truncated: the file ends inside {}", what()),
            )
        } else {
            FormatError::io(&self.path, e)
        }
    }
    fn bytes<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[u8; N]> {
        let mut b = [0u8; N];
        match self.r.read_exact(&mut b) {
            Ok(()) => Ok(b),
            Err(e) => Err(self.fail(e, what)),
        }
    }
    fn u8(&mut self, what: &dyn Fn() -> String) -> Result<u8> {
        Ok(self.bytes::<1>(what)?[0])
    }
    fn u32(&mut self, what: &dyn Fn() -> String) -> Result<u32> {
        Ok(u32::from_le_bytes(self.bytes(what)?))
    }
    fn i32(&mut self, what: &dyn Fn() -> String) -> Result<i32> {
        Ok(i32::from_le_bytes(self.bytes(what)?))
    }
    fn u64(&mut self, what: &dyn Fn() -> String) -> Result<u64> {
        Ok(u64::from_le_bytes(self.bytes(what)?))
    }
    fn f64(&mut self, what: &dyn Fn() -> String) -> Result<f64> {
        Ok(f64::from_le_bytes(self.bytes(what)?))
    }
    fn f64s<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for v in out.iter_mut() {
            *v = self.f64(what)?;
        }
        Ok(out)
    }
    fn cstring(&mut self, what: &dyn Fn() -> String) -> Result<String> {
        let mut buf = Vec::new();
        match self.r.read_until(0, &mut buf) {
            Ok(_) if buf.last() == Some(&0) => {
                buf.pop();
                String::from_utf8(buf).map_err(|_| {
                    FormatError::invalid(&self.path, format!("{}: name is not UTF-8", what()))
                })
            }
            Ok(_) => Err(FormatError::invalid(
                &self.path,
                format!("truncated: the file ends inside {}", what()),
            )),
            Err(e) => Err(self.fail(e, what)),
        }
    }
    /// A `uint64` count, refused when it could not fit in the file (corrupt header).
    fn count(&mut self, min_record: u64, what: &dyn Fn() -> String) -> Result<u64> {
        let n = self.u64(what)?;
        self.check_count(n, min_record, what)
    }
    /// A `uint32` count (frames' data ids), checked as [`Self::count`].
    fn count_u32(&mut self, min_record: u64, what: &dyn Fn() -> String) -> Result<u64> {
        let n = u64::from(self.u32(what)?);
        self.check_count(n, min_record, what)
    }
    fn check_count(&self, n: u64, min_record: u64, what: &dyn Fn() -> String) -> Result<u64> {
        let len = self.len;
        if n.saturating_mul(min_record) > len {
            return Err(FormatError::invalid(
                &self.path,
                format!(
                    "{}: count {n} cannot fit in a file of {len} bytes (corrupt or truncated)",
                    what()
                ),
            ));
        }
        Ok(n)
    }
    fn expect_end(&mut self) -> Result<()> {
        let mut b = [0u8; 1];
        match self.r.read(&mut b) {
            Ok(0) => Ok(()),
            Ok(_) => Err(FormatError::invalid(
                &self.path,
                "trailing bytes after the last record",
            )),
            Err(e) => Err(FormatError::io(&self.path, e)),
        }
    }
}

pub(super) fn read_cameras(path: &Path) -> Result<Cameras> {
    let mut b = Bin::open(path)?;
    let n = b.count(24, &|| "the camera count".into())?;
    let mut out = BTreeMap::new();
    for i in 0..n {
        let ctx = || format!("camera record {i}");
        let id = b.u32(&ctx)?;
        let model = b.i32(&ctx)?;
        let w = b.u64(&ctx)?;
        let h = b.u64(&ctx)?;
        let np = num_params(model).ok_or_else(|| {
            FormatError::invalid(
                path,
                format!("camera {id}: {}", unsupported(&model_name(model))),
            )
        })?;
        let mut p = vec![0.0; np];
        for v in p.iter_mut() {
            *v = b.f64(&ctx)?;
        }
        let cam = camera_from_colmap(model, w, h, &p)
            .map_err(|m| FormatError::invalid(path, format!("camera {id}: {m}")))?;
        if out.insert(id, cam).is_some() {
            return Err(FormatError::invalid(
                path,
                format!("camera id {id} appears twice"),
            ));
        }
    }
    b.expect_end()?;
    Ok(out)
}

pub(super) fn read_images(path: &Path) -> Result<Vec<Image>> {
    let mut b = Bin::open(path)?;
    let n = b.count(64, &|| "the image count".into())?;
    let mut out = Vec::with_capacity(n as usize);
    for i in 0..n {
        let ctx = || format!("image record {i}");
        let id = b.u32(&ctx)?;
        let ctx = || format!("image {id}");
        let q = b.f64s::<4>(&ctx)?;
        let t = b.f64s::<3>(&ctx)?;
        let camera = b.u32(&ctx)?;
        let name = b.cstring(&ctx)?;
        let np = b.count(24, &ctx)?;
        let points2d = b
            .chunk(np as usize * 24, &ctx)?
            .chunks_exact(24)
            .map(|c| ([le_f64(&c[0..8]), le_f64(&c[8..16])], le_u64(&c[16..24])))
            .collect();
        let pose = pose_from_qt(q, t)
            .map_err(|m| FormatError::invalid(path, format!("image {id} ({name}): {m}")))?;
        out.push(Image {
            id,
            pose,
            camera,
            name,
            points2d,
        });
    }
    b.expect_end()?;
    Ok(out)
}

pub(super) fn read_points(path: &Path, sink: &mut PointSink) -> Result<()> {
    let mut b = Bin::open(path)?;
    let n = b.count(43, &|| "the point count".into())?;
    let mut track = Vec::new();
    for i in 0..n {
        let ctx = || format!("point record {i}");
        // id, x y z, r g b, error, track length: one fixed 51-byte head.
        let h = b.chunk(51, &ctx)?;
        let id = le_u64(&h[0..8]);
        let xyz = [le_f64(&h[8..16]), le_f64(&h[16..24]), le_f64(&h[24..32])];
        let rgb = [h[32], h[33], h[34]];
        let len = le_u64(&h[43..51]);
        let ctx = || format!("point {id}");
        if len.saturating_mul(8) > b.len {
            return Err(FormatError::invalid(
                path,
                format!(
                    "point {id}: track length {len} cannot fit in the file (corrupt or truncated)"
                ),
            ));
        }
        track.clear();
        track.extend(
            b.chunk(len as usize * 8, &ctx)?
                .chunks_exact(8)
                .map(|c| (le_u32(&c[0..4]), le_u32(&c[4..8]))),
        );
        sink(id, xyz, rgb, &track).map_err(|m| FormatError::invalid(path, m))?;
    }
    b.expect_end()
}

#[inline]
fn le_f64(b: &[u8]) -> f64 {
    f64::from_le_bytes(b.try_into().expect("8 bytes"))
}
#[inline]
fn le_u64(b: &[u8]) -> u64 {
    u64::from_le_bytes(b.try_into().expect("8 bytes"))
}
#[inline]
fn le_u32(b: &[u8]) -> u32 {
    u32::from_le_bytes(b.try_into().expect("4 bytes"))
}

pub(super) fn read_rigs(path: &Path) -> Result<HashMap<u32, RigSensors>> {
    let mut b = Bin::open(path)?;
    let n = b.count(8, &|| "the rig count".into())?;
    let mut out = HashMap::new();
    for i in 0..n {
        let ctx = || format!("rig record {i}");
        let id = b.u32(&ctx)?;
        let ns = b.u32(&ctx)?;
        let mut sensors = RigSensors::new();
        if ns > 0 {
            let ty = b.i32(&ctx)?;
            let sid = b.u32(&ctx)?;
            if ty == 0 {
                sensors.insert(sid, None);
            }
            for _ in 1..ns {
                let ty = b.i32(&ctx)?;
                let sid = b.u32(&ctx)?;
                let has = b.u8(&ctx)?;
                let pose = if has != 0 {
                    let q = b.f64s::<4>(&ctx)?;
                    let t = b.f64s::<3>(&ctx)?;
                    Some(pose_from_qt(q, t).map_err(|m| {
                        FormatError::invalid(path, format!("rig {id}, sensor {sid}: {m}"))
                    })?)
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
    b.expect_end()?;
    Ok(out)
}

pub(super) fn read_frames(path: &Path) -> Result<Vec<FrameRecord>> {
    let mut b = Bin::open(path)?;
    let n = b.count(68, &|| "the frame count".into())?;
    let mut out = Vec::with_capacity(n as usize);
    for i in 0..n {
        let ctx = || format!("frame record {i}");
        let id = b.u32(&ctx)?;
        let rig = b.u32(&ctx)?;
        let q = b.f64s::<4>(&ctx)?;
        let t = b.f64s::<3>(&ctx)?;
        // A data id is sensor type (int32), sensor id (uint32) and data id (uint64).
        let nd = b.count_u32(16, &|| format!("frame record {i}: the data id count"))?;
        let mut data = Vec::with_capacity(nd as usize);
        for _ in 0..nd {
            data.push((b.i32(&ctx)?, b.u32(&ctx)?, b.u64(&ctx)?));
        }
        let pose = pose_from_qt(q, t)
            .map_err(|m| FormatError::invalid(path, format!("frame {id}: {m}")))?;
        out.push((id, rig, pose, data));
    }
    b.expect_end()?;
    Ok(out)
}

// ---------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------

fn put<const N: usize>(w: &mut impl Write, bytes: [u8; N]) -> std::io::Result<()> {
    w.write_all(&bytes)
}

pub(super) fn write_cameras(w: &mut impl Write, cams: &Cameras) -> std::io::Result<()> {
    put(w, (cams.len() as u64).to_le_bytes())?;
    for (&id, c) in cams {
        let (model, _, params) = camera_to_colmap(c);
        put(w, id.to_le_bytes())?;
        put(w, model.to_le_bytes())?;
        put(w, (c.width as u64).to_le_bytes())?;
        put(w, (c.height as u64).to_le_bytes())?;
        for p in &params {
            put(w, p.to_le_bytes())?;
        }
    }
    Ok(())
}

pub(super) fn write_images(w: &mut impl Write, images: &[ImageRow]) -> std::io::Result<()> {
    put(w, (images.len() as u64).to_le_bytes())?;
    for r in images {
        let pts = r.points2d;
        put(w, r.id.to_le_bytes())?;
        for v in r.q.iter().chain(r.t.iter()) {
            put(w, v.to_le_bytes())?;
        }
        put(w, r.camera.to_le_bytes())?;
        w.write_all(r.name.as_bytes())?;
        w.write_all(&[0])?;
        put(w, (pts.len() as u64).to_le_bytes())?;
        let mut rec: Vec<u8> = Vec::with_capacity(pts.len() * 24);
        for (xy, pid) in pts {
            rec.extend_from_slice(&xy[0].to_le_bytes());
            rec.extend_from_slice(&xy[1].to_le_bytes());
            rec.extend_from_slice(&pid.to_le_bytes());
        }
        w.write_all(&rec)?;
    }
    Ok(())
}

pub(super) fn write_points(w: &mut impl Write, table: &PointsTable) -> std::io::Result<()> {
    let (points, idx) = (&table.points, table.idx);
    put(w, (points.len() as u64).to_le_bytes())?;
    let mut k = 0usize;
    let mut rec: Vec<u8> = Vec::with_capacity(256);
    for (p, err) in points.iter().zip(&table.errors) {
        let x = &p.position;
        rec.clear();
        rec.extend_from_slice(&p.id.to_le_bytes());
        for v in [x.x, x.y, x.z] {
            rec.extend_from_slice(&v.to_le_bytes());
        }
        rec.extend_from_slice(&p.color);
        rec.extend_from_slice(&err.to_le_bytes());
        rec.extend_from_slice(&(p.observations.len() as u64).to_le_bytes());
        for o in &p.observations {
            rec.extend_from_slice(&o.photo.to_le_bytes());
            rec.extend_from_slice(&idx[k].to_le_bytes());
            k += 1;
        }
        w.write_all(&rec)?;
    }
    Ok(())
}

pub(super) fn write_rigs(w: &mut impl Write, cams: &Cameras) -> std::io::Result<()> {
    put(w, (cams.len() as u64).to_le_bytes())?;
    for &id in cams.keys() {
        put(w, id.to_le_bytes())?;
        put(w, 1u32.to_le_bytes())?;
        put(w, 0i32.to_le_bytes())?;
        put(w, id.to_le_bytes())?;
    }
    Ok(())
}

pub(super) fn write_frames(w: &mut impl Write, images: &[ImageRow]) -> std::io::Result<()> {
    put(w, (images.len() as u64).to_le_bytes())?;
    for r in images {
        put(w, r.id.to_le_bytes())?;
        put(w, r.camera.to_le_bytes())?;
        for v in r.q.iter().chain(r.t.iter()) {
            put(w, v.to_le_bytes())?;
        }
        put(w, 1u32.to_le_bytes())?;
        put(w, 0i32.to_le_bytes())?;
        put(w, r.camera.to_le_bytes())?;
        put(w, (r.id as u64).to_le_bytes())?;
    }
    Ok(())
}
