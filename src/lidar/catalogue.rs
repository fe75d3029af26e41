//! The source catalogue ("organisation of control sources", seed 000): one entry per
//! LAS/LAZ tile with bounds, point count, density, class and strip histograms, GPS time
//! range and acquisition dates, and the CRS. Built by scanning files or folders, stored
//! as JSON (schema in formats/lidar/README.md).

use super::las::{date_of_standard_gps_time, LasStream, PointBatch};
use super::store::Bbox;
use super::{LidarError, Result};
use crate::formats::crs::Crs;
use crate::formats::write_bytes_atomically;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Version of the catalogue JSON layout. Schema 2: a relative tile `file` is relative to
/// the catalogue's folder. Schema 1 (read too): relative to the working directory of the
/// scan that wrote it.
pub const CATALOGUE_SCHEMA: u32 = 2;

/// One tile (file) of the catalogue. Bounds and counts come from the points, not the header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileEntry {
    /// The tile, absolute in memory; in the JSON relative to the catalogue's folder when the
    /// tile lies below it ([`Catalogue::save`]).
    pub file: PathBuf,
    pub version: String,
    pub point_format: u8,
    pub compressed: bool,
    pub point_count: u64,
    /// [min_x, min_y, min_z, max_x, max_y, max_z] of the points.
    pub bounds: [f64; 6],
    /// Plan area of the bounds (m²).
    pub area_m2: f64,
    /// point_count / area_m2.
    pub density_pts_m2: f64,
    /// ASPRS class → point count.
    pub classes: BTreeMap<u8, u64>,
    /// Point source id (flight strip) → point count.
    pub point_sources: BTreeMap<u16, u64>,
    /// [first, last] GPS time of the points, when the format has GPS time.
    pub gps_time_range: Option<[f64; 2]>,
    /// "standard" (adjusted standard GPS time) or "week" (seconds of the GPS week).
    pub gps_time_type: String,
    /// [first, last] acquisition date (ISO 8601) from standard GPS time.
    pub acquisition_dates: Option<[String; 2]>,
    /// File creation date from the header.
    pub creation_date: Option<String>,
    /// `EPSG:n` or the CRS name (of the file's CRS, compound ones included, or of the
    /// CRS assumed for a file without one).
    pub crs: String,
    /// Where the tile's CRS comes from: the file, or assumed (the file has none).
    #[serde(default)]
    pub crs_source: CrsSource,
    /// The vertical part of a compound CRS in the file (information: heights are used as
    /// they are).
    #[serde(default)]
    pub vertical_crs: Option<String>,
}

/// Where a tile's CRS comes from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CrsSource {
    /// The file's WKT or GeoTIFF keys VLR.
    #[default]
    File,
    /// The file has no CRS (no CRS VLR, or an empty one): the CRS given for such files
    /// (`--crs`, or the project CRS in `cloudcontrol run`).
    Assumed,
}

impl TileEntry {
    pub fn bbox(&self) -> Bbox {
        Bbox::new(
            self.bounds[0],
            self.bounds[1],
            self.bounds[3],
            self.bounds[4],
        )
    }
}

/// Catalogue of a LiDAR source: every tile in one CRS.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Catalogue {
    pub schema: u32,
    /// `EPSG:n` or the CRS name: the horizontal CRS every tile shares.
    pub crs: String,
    /// Full definition of the CRS.
    pub crs_wkt: String,
    /// What a user should know about the scan (tiles whose CRS was assumed, vertical
    /// CRSs that differ between tiles).
    #[serde(default)]
    pub warnings: Vec<String>,
    pub point_count: u64,
    /// [min_x, min_y, min_z, max_x, max_y, max_z] over all tiles.
    pub bounds: [f64; 6],
    pub tiles: Vec<TileEntry>,
}

/// Options of a catalogue scan.
#[derive(Debug, Clone, Default)]
pub struct ScanOptions {
    /// CRS for files that carry none (`EPSG:n`, WKT, ...). Files with a CRS must match
    /// its horizontal part.
    pub assume_crs: Option<String>,
}

/// Expands folders into their `.las`/`.laz` files (sorted, not recursive); files are kept.
pub fn expand_inputs(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| LidarError::io(p, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                // Not only regular files: a tile that is a FIFO or a link to a device is
                // refused when opened, naming it, rather than dropped unsaid.
                .filter(|f| {
                    f.extension().and_then(|x| x.to_str()).is_some_and(|x| {
                        x.eq_ignore_ascii_case("las") || x.eq_ignore_ascii_case("laz")
                    })
                })
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(LidarError::data(
                    p.display().to_string(),
                    "folder holds no .las or .laz file",
                ));
            }
            out.extend(files);
        } else {
            out.push(p.clone());
        }
    }
    if out.is_empty() {
        return Err(LidarError::data("LiDAR inputs", "no file given"));
    }
    Ok(out)
}

struct Scanned {
    entry: TileEntry,
    /// WKT (GDAL's SpatialRef is not Send, so the CRS is parsed after the parallel scan).
    crs_wkt: Option<String>,
}

/// Bounds `[xmin, ymin, zmin, xmax, ymax, zmax]` of nothing: any point or box grows them.
const NO_BOUNDS: [f64; 6] = [
    f64::INFINITY,
    f64::INFINITY,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NEG_INFINITY,
    f64::NEG_INFINITY,
];

/// Grows `b` to contain the box from corner `lo` to corner `hi` (a point: `lo == hi`).
fn grow_bounds(b: &mut [f64; 6], lo: &[f64], hi: &[f64]) {
    for k in 0..3 {
        b[k] = b[k].min(lo[k]);
        b[k + 3] = b[k + 3].max(hi[k]);
    }
}

struct BlockStats {
    bounds: [f64; 6],
    classes: [u64; 256],
    t0: f64,
    t1: f64,
}

impl BlockStats {
    fn of(xyz: &[[f64; 3]], class: &[u8], gps: &[f64]) -> Self {
        let mut s = BlockStats {
            bounds: NO_BOUNDS,
            classes: [0; 256],
            t0: f64::INFINITY,
            t1: f64::NEG_INFINITY,
        };
        for p in xyz {
            grow_bounds(&mut s.bounds, p, p);
        }
        for &c in class {
            s.classes[c as usize] += 1;
        }
        for &t in gps.iter().filter(|t| t.is_finite()) {
            s.t0 = s.t0.min(t);
            s.t1 = s.t1.max(t);
        }
        s
    }
}

/// A CRS error of a file (or of the assumed CRS), without repeating "coordinate
/// reference system" twice in the message.
fn crs_error(path: &Path, e: crate::formats::FormatError) -> LidarError {
    let message = match e {
        crate::formats::FormatError::Crs { crs, message } => format!("{crs:?} {message}"),
        other => other.to_string(),
    };
    LidarError::Crs {
        path: path.to_path_buf(),
        message,
    }
}

fn scan_file(path: &Path) -> Result<Scanned> {
    let mut s = LasStream::open(path)?;
    let info = s.info().clone();
    let mut b = NO_BOUNDS;
    let mut classes = [0u64; 256];
    let mut sources: BTreeMap<u16, u64> = BTreeMap::new();
    let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut batch = PointBatch::with_capacity(1 << 18);
    let mut count = 0u64;
    loop {
        if s.read_batch(1 << 18, &mut batch)? == 0 {
            break;
        }
        count += batch.len() as u64;
        // Block statistics in parallel, merged in block order (min/max/counts: exact).
        const BLOCK: usize = 1 << 15;
        let parts: Vec<BlockStats> = batch
            .xyz
            .par_chunks(BLOCK)
            .zip(batch.class.par_chunks(BLOCK))
            .zip(batch.gps_time.par_chunks(BLOCK))
            .map(|((xyz, cls), gps)| BlockStats::of(xyz, cls, gps))
            .collect();
        for part in parts {
            grow_bounds(&mut b, &part.bounds[..3], &part.bounds[3..]);
            for (c, n) in classes.iter_mut().zip(part.classes.iter()) {
                *c += n;
            }
            t0 = t0.min(part.t0);
            t1 = t1.max(part.t1);
        }
        // Strips are long runs: count runs instead of a map lookup per point.
        let mut i = 0;
        while i < batch.len() {
            let id = batch.source[i];
            let mut j = i;
            while j < batch.len() && batch.source[j] == id {
                j += 1;
            }
            *sources.entry(id).or_default() += (j - i) as u64;
            i = j;
        }
    }
    if count == 0 {
        return Err(LidarError::data(
            path.display().to_string(),
            "the file holds no point",
        ));
    }
    let area = ((b[3] - b[0]) * (b[4] - b[1])).max(1e-6);
    let gps = (t0 <= t1).then_some([t0, t1]);
    let dates = match (gps, info.gps_standard_time) {
        (Some([a, z]), true) => date_of_standard_gps_time(a)
            .zip(date_of_standard_gps_time(z))
            .map(|(a, z)| [a, z]),
        _ => None,
    };
    let entry = TileEntry {
        // Absolute: a catalogue is used from other working directories than the scan's.
        file: std::path::absolute(path).map_err(|e| LidarError::io(path, e))?,
        version: info.version.clone(),
        point_format: info.point_format,
        compressed: info.compressed,
        point_count: count,
        bounds: b,
        area_m2: area,
        density_pts_m2: count as f64 / area,
        classes: classes
            .iter()
            .enumerate()
            .filter(|(_, &n)| n > 0)
            .map(|(c, &n)| (c as u8, n))
            .collect(),
        point_sources: sources,
        gps_time_range: gps,
        gps_time_type: if info.gps_standard_time {
            "standard"
        } else {
            "week"
        }
        .into(),
        acquisition_dates: dates,
        creation_date: info.creation_date.clone(),
        crs: info.crs_label.clone().unwrap_or_default(),
        crs_source: CrsSource::File,
        vertical_crs: None,
    };
    Ok(Scanned {
        entry,
        crs_wkt: info.crs_wkt,
    })
}

/// The absolute folder of a catalogue file.
fn catalogue_folder(path: &Path) -> Result<PathBuf> {
    let abs = std::path::absolute(path).map_err(|e| LidarError::io(path, e))?;
    Ok(abs.parent().map(Path::to_path_buf).unwrap_or(abs))
}

impl Catalogue {
    /// Scans files and folders (every point is read: counts, bounds and histograms are
    /// measured, and a header that disagrees with the records is an error naming the file).
    /// All tiles must share one horizontal CRS, projected and in metres (a compound CRS
    /// matches by its horizontal part); files without a CRS take `opts.assume_crs`, with
    /// a warning.
    pub fn scan(inputs: &[PathBuf], opts: &ScanOptions) -> Result<Self> {
        let files = expand_inputs(inputs)?;
        let assumed_path =
            PathBuf::from("the CRS given for tiles without one (--crs, or the project's crs)");
        let assumed = match &opts.assume_crs {
            Some(d) => {
                let c = Crs::parse(d).map_err(|e| crs_error(&assumed_path, e))?;
                c.require_metric_projected(None)
                    .map_err(|e| crs_error(&assumed_path, e))?;
                Some(c)
            }
            None => None,
        };
        // Files in parallel; results are taken in input order, so the first error in
        // file order is reported and the catalogue is deterministic.
        let scanned: Vec<Result<Scanned>> = files.par_iter().map(|f| scan_file(f)).collect();
        let mut tiles = Vec::with_capacity(files.len());
        // The horizontal CRS all tiles share, and where it came from.
        let mut reference: Option<(Crs, PathBuf)> = match &assumed {
            Some(c) => Some((
                c.horizontal().map_err(|e| crs_error(&assumed_path, e))?,
                assumed_path.clone(),
            )),
            None => None,
        };
        // A national dataset repeats one WKT in every tile: check each distinct one once.
        let mut checked: BTreeMap<String, (Crs, Option<String>)> = BTreeMap::new();
        let mut assumed_files: Vec<PathBuf> = Vec::new();
        for s in scanned {
            let mut s = s?;
            let path = s.entry.file.clone();
            let crs = match s.crs_wkt.take() {
                Some(w) => {
                    if !checked.contains_key(&w) {
                        let crs = Crs::parse(&w).map_err(|e| crs_error(&path, e))?;
                        crs.require_metric_projected(None)
                            .map_err(|e| crs_error(&path, e))?;
                        let vertical = crs
                            .vertical()
                            .map_err(|e| crs_error(&path, e))?
                            .map(|v| v.label());
                        let h = crs.horizontal().map_err(|e| crs_error(&path, e))?;
                        checked.insert(w.clone(), (h, vertical));
                    }
                    let (h, vertical) = &checked[&w];
                    s.entry.vertical_crs = vertical.clone();
                    h.clone()
                }
                None => match &assumed {
                    Some(c) => {
                        s.entry.crs = c.label();
                        s.entry.crs_source = CrsSource::Assumed;
                        assumed_files.push(path.clone());
                        reference
                            .as_ref()
                            .expect("set from the assumed CRS")
                            .0
                            .clone()
                    }
                    None => return Err(LidarError::MissingCrs { path }),
                },
            };
            match &reference {
                None => reference = Some((crs, path.clone())),
                Some((r, rp)) => {
                    if r.spatial_ref() != crs.spatial_ref() {
                        return Err(LidarError::CrsMismatch {
                            path,
                            found: s.entry.crs.clone(),
                            expected: r.label(),
                            reference: rp.clone(),
                        });
                    }
                }
            }
            tiles.push(s.entry);
        }
        let (crs, _) = reference.expect("at least one tile was scanned");
        let mut warnings = Vec::new();
        if let Some(first) = assumed_files.first() {
            let w = format!(
                "{} of {} tiles carry no CRS (first: {}); assumed {}",
                assumed_files.len(),
                tiles.len(),
                first.display(),
                crs.label()
            );
            tracing::warn!("{w}");
            warnings.push(w);
        }
        let verticals: std::collections::BTreeSet<&str> = tiles
            .iter()
            .filter_map(|t| t.vertical_crs.as_deref())
            .collect();
        if verticals.len() > 1 {
            let w = format!(
                "tiles give different vertical CRSs ({}); heights are used as they are",
                verticals.into_iter().collect::<Vec<_>>().join(", ")
            );
            tracing::warn!("{w}");
            warnings.push(w);
        }
        let mut bounds = NO_BOUNDS;
        for t in &tiles {
            grow_bounds(&mut bounds, &t.bounds[..3], &t.bounds[3..]);
        }
        Ok(Self {
            schema: CATALOGUE_SCHEMA,
            crs: crs.label(),
            crs_wkt: crs.to_wkt()?,
            warnings,
            point_count: tiles.iter().map(|t| t.point_count).sum(),
            bounds,
            tiles,
        })
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("catalogue serialises")
    }

    /// Writes the catalogue JSON atomically. Tiles below the catalogue's folder are
    /// written relative to it (the folder can move with its catalogue), the others with
    /// their absolute path.
    pub fn save(&self, path: &Path) -> Result<()> {
        let folder = catalogue_folder(path)?;
        let mut c = self.clone();
        for t in &mut c.tiles {
            let abs = std::path::absolute(&t.file).map_err(|e| LidarError::io(&t.file, e))?;
            t.file = match abs.strip_prefix(&folder) {
                Ok(rel) if !rel.as_os_str().is_empty() => rel.to_path_buf(),
                _ => abs,
            };
        }
        Ok(write_bytes_atomically(path, c.to_json().as_bytes())?)
    }

    /// Reads a catalogue JSON; relative tile paths are resolved (schema 2: against the
    /// catalogue's folder; schema 1: against the working directory when the tile is there,
    /// else the catalogue's folder), so the tiles are found from any working directory.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::formats::input::read_text(path, crate::formats::input::Cap::document())
            .map_err(super::las::input_error)?;
        let mut c: Catalogue = serde_json::from_str(&text).map_err(|e| LidarError::Las {
            path: path.to_path_buf(),
            message: format!("not a catalogue JSON: {e}"),
        })?;
        if !(1..=CATALOGUE_SCHEMA).contains(&c.schema) {
            return Err(LidarError::Las {
                path: path.to_path_buf(),
                message: format!(
                    "catalogue schema {} (this build reads 1 to {CATALOGUE_SCHEMA})",
                    c.schema
                ),
            });
        }
        let folder = catalogue_folder(path)?;
        for t in c.tiles.iter_mut().filter(|t| t.file.is_relative()) {
            let old_meaning = c.schema == 1 && t.file.exists();
            t.file = if old_meaning {
                std::path::absolute(&t.file).map_err(|e| LidarError::io(&t.file, e))?
            } else {
                folder.join(&t.file)
            };
        }
        c.schema = CATALOGUE_SCHEMA;
        Ok(c)
    }

    /// A catalogue from a `.json` catalogue file, or by scanning LAS/LAZ files and folders.
    pub fn open(inputs: &[PathBuf], opts: &ScanOptions) -> Result<Self> {
        match inputs {
            [one]
                if one
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("json")) =>
            {
                Self::load(one)
            }
            _ => Self::scan(inputs, opts),
        }
    }

    pub fn crs(&self) -> Result<Crs> {
        Crs::parse(&self.crs_wkt).map_err(|e| LidarError::Crs {
            path: PathBuf::from("catalogue"),
            message: e.to_string(),
        })
    }

    /// Indices of the tiles whose bounds intersect `bbox`.
    pub fn tiles_in(&self, bbox: &Bbox) -> Vec<usize> {
        (0..self.tiles.len())
            .filter(|&i| self.tiles[i].bbox().intersects(bbox))
            .collect()
    }

    /// Strip (point source) ids over all tiles.
    pub fn point_sources(&self) -> Vec<u16> {
        let mut ids: Vec<u16> = self
            .tiles
            .iter()
            .flat_map(|t| t.point_sources.keys().copied())
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }
}
