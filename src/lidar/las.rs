//! LAS 1.2–1.4 / LAZ ingestion through the `las` crate: header checks, the CRS from the
//! WKT or GeoTIFF-keys VLR, and streaming reads in batches so a tile never has to fit in
//! memory twice.
//!
//! Uncompressed LAS is decoded straight from the point records (the `las` crate parses the
//! header and VLRs; coordinates, class, point source id and GPS time are read from their
//! fixed offsets), which is several times faster than building a full `las::Point` per
//! record. LAZ goes through `las::Reader` (laz-rs), in batches bounded in bytes.
//!
//! Before either crate sees a file, `las_guard` checks the header, VLR and EVLR lengths,
//! the LAZ chunk table and the point count against the file length.

use super::{las_guard, LidarError, Result};
use crate::formats::crs::{Crs, LinearUnit};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Header facts of one LAS/LAZ file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LasInfo {
    pub file: PathBuf,
    /// "1.2", "1.4", ...
    pub version: String,
    pub point_format: u8,
    pub compressed: bool,
    /// Point count declared by the header.
    pub point_count: u64,
    /// Header bounds [min_x, min_y, min_z, max_x, max_y, max_z].
    pub header_bounds: [f64; 6],
    pub scale: [f64; 3],
    pub offset: [f64; 3],
    /// CRS as WKT (from the WKT VLR, or the EPSG code of the GeoTIFF keys), if any.
    pub crs_wkt: Option<String>,
    /// `EPSG:n` or the CRS name.
    pub crs_label: Option<String>,
    /// Whether GPS times are adjusted standard GPS time (else GPS week seconds).
    pub gps_standard_time: bool,
    pub has_gps_time: bool,
    /// File creation date from the header (ISO 8601), if set.
    pub creation_date: Option<String>,
    pub file_source_id: u16,
}

/// Points of one read, structure of arrays.
#[derive(Debug, Clone, Default)]
pub struct PointBatch {
    pub xyz: Vec<[f64; 3]>,
    pub class: Vec<u8>,
    pub source: Vec<u16>,
    /// NaN where the point format carries no GPS time.
    pub gps_time: Vec<f64>,
}

impl PointBatch {
    pub fn len(&self) -> usize {
        self.xyz.len()
    }
    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }
    pub fn with_capacity(n: usize) -> Self {
        Self {
            xyz: Vec::with_capacity(n),
            class: Vec::with_capacity(n),
            source: Vec::with_capacity(n),
            gps_time: Vec::with_capacity(n),
        }
    }
    pub fn clear(&mut self) {
        self.xyz.clear();
        self.class.clear();
        self.source.clear();
        self.gps_time.clear();
    }
    pub fn push(&mut self, xyz: [f64; 3], class: u8, source: u16, gps: f64) {
        self.xyz.push(xyz);
        self.class.push(class);
        self.source.push(source);
        self.gps_time.push(gps);
    }
    pub fn append(&mut self, other: &mut PointBatch) {
        self.xyz.append(&mut other.xyz);
        self.class.append(&mut other.class);
        self.source.append(&mut other.source);
        self.gps_time.append(&mut other.gps_time);
    }
    /// Keeps the points where `keep` is true.
    pub fn retain_mask(&mut self, keep: &[bool]) {
        fn r<T>(v: &mut Vec<T>, keep: &[bool]) {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        }
        r(&mut self.xyz, keep);
        r(&mut self.class, keep);
        r(&mut self.source, keep);
        r(&mut self.gps_time, keep);
    }
    /// Bytes held per point (for memory budgets).
    pub const BYTES_PER_POINT: usize = 24 + 1 + 2 + 8;
}

/// Fixed offsets of the fields we read in an uncompressed point record.
#[derive(Debug, Clone, Copy)]
struct Layout {
    len: usize,
    class_at: usize,
    class_mask: u8,
    source_at: usize,
    gps_at: Option<usize>,
}

impl Layout {
    fn of(format: u8, len: usize) -> Option<Self> {
        let (class_at, class_mask, source_at, gps_at, min_len) = match format {
            0 => (15, 0x1f, 18, None, 20),
            1 => (15, 0x1f, 18, Some(20), 28),
            2 => (15, 0x1f, 18, None, 26),
            3..=5 => (15, 0x1f, 18, Some(20), 28),
            6..=10 => (16, 0xff, 20, Some(22), 30),
            _ => return None,
        };
        (len >= min_len).then_some(Self {
            len,
            class_at,
            class_mask,
            source_at,
            gps_at,
        })
    }
}

enum Inner {
    Raw {
        file: BufReader<File>,
        layout: Layout,
        buf: Vec<u8>,
    },
    /// `batch`: the most points decompressed in one call (bounded in bytes).
    Laz {
        reader: Box<las::Reader>,
        batch: usize,
    },
}

/// Bytes of decompressed point records one LAZ read produces at most: the batch is sized
/// from this, never from the header's count.
const LAZ_BATCH_BYTES: usize = 16 << 20;

/// A streaming reader of one LAS/LAZ file.
pub struct LasStream {
    info: LasInfo,
    inner: Inner,
    read: u64,
}

fn las_err(path: &Path, e: las::Error) -> LidarError {
    let message = match &e {
        las::Error::LaszipNotEnabled => {
            "LAZ (compressed) point data, but this build has no LAZ support (enable the `laz` feature of the las crate)".to_string()
        }
        las::Error::InvalidFileSignature(_) => format!("not a LAS/LAZ file ({e})"),
        las::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "truncated: the file ends inside the header or VLRs".to_string()
        }
        _ => format!("cannot read LAS/LAZ: {e}"),
    };
    LidarError::Las {
        path: path.to_path_buf(),
        message,
    }
}

/// Extracts the CRS of a header: the WKT VLR first (an empty or quoted-empty one counts as
/// absent), else
/// the GeoTIFF keys: the EPSG code of the projected or geodetic CRS, with the vertical CRS
/// key as a compound CRS, and the unit keys (`ProjLinearUnitsGeoKey`,
/// `VerticalUnitsGeoKey`) applied where they differ from the code's own units, so that a
/// file in feet is described in feet (and then refused by the catalogue, not misread).
fn header_crs(path: &Path, header: &las::Header) -> Result<Option<Crs>> {
    let crs_err = |message: String| LidarError::Crs {
        path: path.to_path_buf(),
        message,
    };
    if let Some(bytes) = header.get_wkt_crs_bytes() {
        let wkt = String::from_utf8_lossy(bytes);
        let wkt = wkt.trim_matches(char::from(0)).trim();
        // Some writers store an empty string as a quoted one (`''`, PDAL's
        // warsaw_small.las): no CRS either.
        if !wkt
            .trim_matches(|c: char| c == '\'' || c == '"' || c.is_whitespace())
            .is_empty()
        {
            return Crs::parse(wkt)
                .map(Some)
                .map_err(|e| crs_err(format!("WKT VLR: {e}")));
        }
    }
    let keys = header
        .get_geotiff_crs()
        .map_err(|e| crs_err(format!("GeoTIFF keys VLR: {e}")))?;
    let Some(keys) = keys else {
        return Ok(None);
    };
    let code = keys
        .get_projected_crs_geo_key_value()
        .or_else(|| keys.get_geodetic_crs_geo_key_value());
    let epsg = |c: u16| (1024..32767).contains(&c);
    let crs = match code {
        Some(c) if epsg(c) => Crs::from_epsg(c as u32)
            .map_err(|e| crs_err(format!("GeoTIFF keys VLR: EPSG:{c}: {e}")))?,
        Some(c) if c > 0 => {
            return Err(crs_err(format!(
                "GeoTIFF keys VLR holds a user-defined CRS (key value {c}); add a WKT VLR"
            )))
        }
        _ => return Ok(None),
    };
    let crs = match keys.get_vertical_crs_geo_key_value().filter(|&v| epsg(v)) {
        Some(v) => match Crs::parse(&format!("{}+{v}", crs.label())) {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!(file = %path.display(), "GeoTIFF vertical CRS key EPSG:{v} ignored: {e}");
                crs
            }
        },
        None => crs,
    };
    let unit_key = |id: u16| -> Result<Option<LinearUnit>> {
        let value = keys.entries.iter().find_map(|k| match k.data {
            las::crs::GeoTiffData::U16(v) if k.id == id => Some(v),
            _ => None,
        });
        match value {
            None => Ok(None),
            Some(v) => LinearUnit::from_epsg(v).map(Some).ok_or_else(|| {
                crs_err(format!(
                    "GeoTIFF keys VLR: unit key {id} holds unit code {v}, which this build \
                     does not know; add a WKT VLR"
                ))
            }),
        }
    };
    let differs = |a: &LinearUnit, b: &LinearUnit| (a.metres - b.metres).abs() > 1e-9 * b.metres;
    let to_las = |e: crate::formats::FormatError| crs_err(format!("GeoTIFF keys VLR: {e}"));
    let horizontal = match unit_key(3076)? {
        Some(u)
            if crs.horizontal().map_err(to_las)?.is_projected()
                && differs(&u, &crs.horizontal_unit().map_err(to_las)?) =>
        {
            Some(u)
        }
        _ => None,
    };
    let vertical = match unit_key(4099)? {
        Some(u)
            if differs(
                &u,
                &crs.vertical_unit()
                    .map_err(to_las)?
                    .unwrap_or_else(LinearUnit::metre),
            ) =>
        {
            Some(u)
        }
        _ => None,
    };
    crs.with_units(horizontal.as_ref(), vertical.as_ref())
        .map(Some)
        .map_err(to_las)
}

/// Scale factors a LAS header may give: a point's coordinate is its 32-bit integer times
/// the scale plus the offset, so a scale outside this range puts every point of the tile
/// on one spot (0, 1e-300) or beyond any survey (formats/lidar/README.md).
pub const SCALE_RANGE: [f64; 2] = [1e-9, 1e3];
/// Largest offset magnitude (m or ft) a LAS header may give: far beyond any projected or
/// geocentric coordinate.
pub const MAX_OFFSET: f64 = 1e9;

use crate::formats::number_in_message as num;

/// Refuses a header whose scale factors or offsets are not finite or not plausible
/// ([`SCALE_RANGE`], [`MAX_OFFSET`]): NaN or 0 would make every coordinate NaN or the
/// offset, a tile no selection would ever find, dropped without a word.
fn check_transforms(path: &Path, t: &las::Vector<las::Transform>) -> Result<()> {
    for (axis, tr) in [("x", t.x), ("y", t.y), ("z", t.z)] {
        let message = if !(SCALE_RANGE[0]..=SCALE_RANGE[1]).contains(&tr.scale) {
            format!(
                "header: {axis} scale factor {} is not a coordinate scale ({:e} to {:e})",
                num(tr.scale),
                SCALE_RANGE[0],
                SCALE_RANGE[1]
            )
        } else if !tr.offset.is_finite() || tr.offset.abs() > MAX_OFFSET {
            format!(
                "header: {axis} offset {} is not a coordinate offset (at most {MAX_OFFSET:e} in \
                 magnitude)",
                num(tr.offset)
            )
        } else {
            continue;
        };
        return Err(LidarError::Las {
            path: path.to_path_buf(),
            message,
        });
    }
    Ok(())
}

/// The record layout and start of the point data of an uncompressed file, after checking
/// that the records the header declares are all present, and no more: the count never
/// sizes anything before it is known to fit in the file.
fn raw_points(path: &Path, h: &las_guard::PublicHeader, file_len: u64) -> Result<(Layout, u64)> {
    let n = h.point_count;
    let len = h.record_len as usize;
    let format = h.point_format & 0x3f;
    let layout = Layout::of(format, len).ok_or_else(|| LidarError::Las {
        path: path.to_path_buf(),
        message: format!("point format {format} with record length {len} is not supported"),
    })?;
    let start = h.offset_to_point_data;
    let end = Some(h.first_evlr)
        .filter(|&s| h.evlr_count > 0 && s >= start)
        .unwrap_or(file_len)
        .min(file_len);
    let available = end.saturating_sub(start) / len as u64;
    if available < n {
        return Err(LidarError::Truncated {
            path: path.to_path_buf(),
            declared: n,
            found: available,
        });
    }
    if available > n {
        return Err(LidarError::CountMismatch {
            path: path.to_path_buf(),
            declared: n,
            found: available,
        });
    }
    Ok((layout, start))
}

/// Opens a LAS/LAZ file for reading: a regular file only (a FIFO would block the
/// open, a device would never end; formats/README.md, "Input files").
fn open_las(path: &Path) -> Result<File> {
    crate::formats::input::open(path).map_err(input_error)
}

/// An error of [`crate::formats::input`] as a LiDAR error: an I/O error stays one (a
/// missing file keeps its status at the C ABI).
pub(crate) fn input_error(e: crate::formats::FormatError) -> LidarError {
    match e {
        crate::formats::FormatError::Io { path, source } => LidarError::Io { path, source },
        e => e.into(),
    }
}

impl LasStream {
    /// Opens a file, reads its header and VLRs and checks that the point records the
    /// header declares are present (uncompressed LAS: from the file size).
    pub fn open(path: &Path) -> Result<Self> {
        let mut file = open_las(path)?;
        let file_len = file.metadata().map_err(|e| LidarError::io(path, e))?.len();
        // Bounds first: the crates below size buffers from header fields.
        let guarded = las_guard::guard(path, &mut file, file_len)?;
        let raw_layout = match &guarded {
            Some(h) if !h.compressed() => Some(raw_points(path, h, file_len)?),
            _ => None,
        };
        let header = {
            file.seek(SeekFrom::Start(0))
                .map_err(|e| LidarError::io(path, e))?;
            las::Header::new(BufReader::new(&mut file)).map_err(|e| las_err(path, e))?
        };
        let crs = header_crs(path, &header)?;
        let fmt = header.point_format();
        let b = header.bounds();
        let t = header.transforms();
        check_transforms(path, t)?;
        let info = LasInfo {
            file: path.to_path_buf(),
            version: format!("{}.{}", header.version().major, header.version().minor),
            point_format: fmt.to_u8().map_err(|e| las_err(path, e))?,
            compressed: fmt.is_compressed,
            point_count: header.number_of_points(),
            header_bounds: [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z],
            scale: [t.x.scale, t.y.scale, t.z.scale],
            offset: [t.x.offset, t.y.offset, t.z.offset],
            crs_label: crs.as_ref().map(|c| c.label()),
            crs_wkt: match &crs {
                Some(c) => Some(c.to_wkt().map_err(|e| LidarError::Crs {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                })?),
                None => None,
            },
            gps_standard_time: header.gps_time_type().is_standard(),
            has_gps_time: fmt.has_gps_time,
            creation_date: header.date().map(|d| d.to_string()),
            file_source_id: header.file_source_id(),
        };
        let inner = match raw_layout {
            None if fmt.is_compressed => {
                file.seek(SeekFrom::Start(0))
                    .map_err(|e| LidarError::io(path, e))?;
                let reader =
                    las::Reader::new(BufReader::new(file)).map_err(|e| las_err(path, e))?;
                Inner::Laz {
                    reader: Box::new(reader),
                    batch: (LAZ_BATCH_BYTES / usize::from(fmt.len()).max(1)).max(1),
                }
            }
            Some((layout, start)) => {
                file.seek(SeekFrom::Start(start))
                    .map_err(|e| LidarError::io(path, e))?;
                Inner::Raw {
                    file: BufReader::with_capacity(1 << 20, file),
                    layout,
                    buf: Vec::new(),
                }
            }
            None => {
                return Err(LidarError::Las {
                    path: path.to_path_buf(),
                    message: "the LAS header could not be read".into(),
                })
            }
        };
        Ok(Self {
            info,
            inner,
            read: 0,
        })
    }

    pub fn info(&self) -> &LasInfo {
        &self.info
    }

    /// The CRS of the file, if it has one.
    pub fn crs(&self) -> Result<Option<Crs>> {
        match &self.info.crs_wkt {
            None => Ok(None),
            Some(w) => Crs::parse(w).map(Some).map_err(|e| LidarError::Crs {
                path: self.info.file.clone(),
                message: e.to_string(),
            }),
        }
    }

    /// Points not read yet.
    pub fn remaining(&self) -> u64 {
        self.info.point_count - self.read
    }

    /// Replaces the contents of `batch` (its capacity is kept) with the next up to `max`
    /// points; returns how many were read (0 at the end).
    pub fn read_batch(&mut self, max: usize, batch: &mut PointBatch) -> Result<usize> {
        batch.clear();
        self.read_into(max, batch)
    }

    /// Appends up to `max` points to `out`; returns how many were read (0 at the end).
    pub fn read_into(&mut self, max: usize, out: &mut PointBatch) -> Result<usize> {
        let mut n = (self.remaining().min(max as u64)) as usize;
        if let Inner::Laz { batch, .. } = &self.inner {
            n = n.min(*batch);
        }
        if n == 0 {
            return Ok(0);
        }
        let path = &self.info.file;
        match &mut self.inner {
            Inner::Raw { file, layout, buf } => {
                buf.resize(n * layout.len, 0);
                file.read_exact(buf).map_err(|e| {
                    if e.kind() == std::io::ErrorKind::UnexpectedEof {
                        LidarError::Truncated {
                            path: path.clone(),
                            declared: self.info.point_count,
                            found: self.read,
                        }
                    } else {
                        LidarError::io(path, e)
                    }
                })?;
                let (s, o) = (self.info.scale, self.info.offset);
                let l = *layout;
                let base = out.xyz.len();
                out.xyz.resize(base + n, [0.0; 3]);
                out.class.resize(base + n, 0);
                out.source.resize(base + n, 0);
                out.gps_time.resize(base + n, 0.0);
                // Decode in parallel blocks of records (pure per-record work: deterministic).
                const BLOCK: usize = 1 << 15;
                out.xyz[base..]
                    .par_chunks_mut(BLOCK)
                    .zip(out.class[base..].par_chunks_mut(BLOCK))
                    .zip(out.source[base..].par_chunks_mut(BLOCK))
                    .zip(out.gps_time[base..].par_chunks_mut(BLOCK))
                    .zip(buf.par_chunks(BLOCK * l.len))
                    .for_each(|((((xyz, class), source), gps), bytes)| {
                        for (k, rec) in bytes.chunks_exact(l.len).enumerate() {
                            let i32_at = |k: usize| {
                                i32::from_le_bytes([rec[k], rec[k + 1], rec[k + 2], rec[k + 3]])
                            };
                            xyz[k] = [
                                i32_at(0) as f64 * s[0] + o[0],
                                i32_at(4) as f64 * s[1] + o[1],
                                i32_at(8) as f64 * s[2] + o[2],
                            ];
                            class[k] = rec[l.class_at] & l.class_mask;
                            source[k] =
                                u16::from_le_bytes([rec[l.source_at], rec[l.source_at + 1]]);
                            gps[k] = match l.gps_at {
                                Some(g) => f64::from_le_bytes(rec[g..g + 8].try_into().unwrap()),
                                None => f64::NAN,
                            };
                        }
                    });
            }
            Inner::Laz { reader, .. } => {
                let mut pts = Vec::with_capacity(n);
                let got =
                    reader
                        .read_points_into(n as u64, &mut pts)
                        .map_err(|e| LidarError::Las {
                            path: path.clone(),
                            message: format!(
                                "corrupt or truncated compressed point data after point {}: {e}",
                                self.read
                            ),
                        })?;
                if (got as usize) < n {
                    return Err(LidarError::Truncated {
                        path: path.clone(),
                        declared: self.info.point_count,
                        found: self.read + got,
                    });
                }
                for p in pts {
                    out.push(
                        [p.x, p.y, p.z],
                        u8::from(p.classification),
                        p.point_source_id,
                        p.gps_time.unwrap_or(f64::NAN),
                    );
                }
            }
        }
        self.read += n as u64;
        Ok(n)
    }
}

/// Reads a whole file, keeping the points inside `bbox` ([min_x, min_y, max_x, max_y])
/// and, when given, of the listed classes. Streams in batches so only kept points stay.
pub fn read_points(
    path: &Path,
    bbox: Option<[f64; 4]>,
    classes: Option<&[u8]>,
) -> Result<PointBatch> {
    let mut s = LasStream::open(path)?;
    let keep_all = bbox.is_none() && classes.is_none();
    // An uncompressed file's count was checked against its length; a LAZ file's only
    // bounds its batches, so its points are collected as they come.
    let mut out = PointBatch::with_capacity(if keep_all && !s.info().compressed {
        s.info().point_count as usize
    } else {
        0
    });
    if keep_all {
        while s.read_into(1 << 20, &mut out)? > 0 {}
        return Ok(out);
    }
    let mut batch = PointBatch::with_capacity(1 << 18);
    loop {
        if s.read_batch(1 << 18, &mut batch)? == 0 {
            break;
        }
        for i in 0..batch.len() {
            let p = batch.xyz[i];
            if let Some(b) = bbox {
                if p[0] < b[0] || p[0] > b[2] || p[1] < b[1] || p[1] > b[3] {
                    continue;
                }
            }
            if let Some(c) = classes {
                if !c.contains(&batch.class[i]) {
                    continue;
                }
            }
            out.push(p, batch.class[i], batch.source[i], batch.gps_time[i]);
        }
    }
    Ok(out)
}

/// Civil date (proleptic Gregorian) of a day count from 1970-01-01 (H. Hinnant's algorithm).
#[doc(hidden)]
pub fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

/// UTC date (ISO 8601) of an adjusted standard GPS time (GPS seconds − 10⁹). Leap
/// seconds (≤ 18 s) are ignored: this is an acquisition date, not a timestamp.
pub fn date_of_standard_gps_time(t: f64) -> Option<String> {
    if !t.is_finite() {
        return None;
    }
    // GPS epoch 1980-01-06 is day 3657 after 1970-01-01.
    let secs = t + 1e9;
    let days = 3657 + (secs / 86_400.0).floor() as i64;
    let (y, m, d) = civil_from_days(days);
    Some(format!("{y:04}-{m:02}-{d:02}"))
}

/// Rewrites a LAS/LAZ file point by point: `edit` returns the point to write (changed or
/// not) or None to drop it. Header, VLRs, point format and compression are kept; bounds and
/// counts are recomputed. The output appears atomically; a failure leaves nothing, not even
/// the temporary file (a point the header's scale and offset cannot hold is an error naming
/// it, and a panic in the writer is caught and reported as one).
pub fn rewrite_las(
    input: &Path,
    output: &Path,
    mut edit: impl FnMut(u64, las::Point) -> Option<las::Point>,
) -> Result<u64> {
    let mut f = open_las(input)?;
    let len = f.metadata().map_err(|e| LidarError::io(input, e))?.len();
    if let Some(h) = las_guard::guard(input, &mut f, len)? {
        if !h.compressed() {
            raw_points(input, &h, len)?;
        }
    }
    f.seek(SeekFrom::Start(0))
        .map_err(|e| LidarError::io(input, e))?;
    let mut reader = las::Reader::new(BufReader::new(f)).map_err(|e| las_err(input, e))?;
    check_transforms(input, reader.header().transforms())?;
    let mut builder = las::Builder::from(reader.header().clone());
    // The LAZ writer adds its own laszip VLR.
    builder.vlrs.retain(|v| v.user_id != "laszip encoded");
    let header = builder.into_header().map_err(|e| las_err(input, e))?;
    let transforms = *header.transforms();
    let points = reader.points().enumerate().filter_map(|(i, p)| {
        let fail = |m: String| crate::formats::FormatError::invalid(output, m);
        match p {
            Err(e) => Some(Err(fail(format!(
                "reading {}: point {i}: {e}",
                input.display()
            )))),
            // Named by its index in the input, which the caller's `edit` knows it by.
            Ok(p) => edit(i as u64, p).map(|q| {
                super::las_write::storable(&transforms, &q)
                    .map(|()| q)
                    .map_err(|m| fail(format!("point {i} of {}: {m}", input.display())))
            }),
        }
    });
    Ok(super::las_write::write_points(output, header, points)?)
}
