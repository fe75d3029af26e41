//! The project file (TOML, specified in `formats/project/`): control sources, the
//! reference epoch, archive epochs, thresholds and wanted outputs. It is validated
//! completely before any work starts, and every error names the key.

use crate::matching::fiducial::{check_scan_pixel_um, scan_pixel_um_from_dpi};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ProjectError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: key `{key}`: {message}")]
    Key {
        path: PathBuf,
        key: String,
        message: String,
    },
}

/// The control sources (LiDAR, an orthophoto with a DEM) and the surveyed checkpoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSources {
    /// LAS/LAZ files or folders holding them (none: the orthophoto and DEM control).
    #[serde(default)]
    pub lidar: Vec<PathBuf>,
    /// 1σ accuracy of the LiDAR's datum per axis (m), as its survey report states it: the
    /// reference adjustment estimates the LiDAR's shift from the block with this prior, so
    /// the POS and the LiDAR each place the block as far as their accuracy goes.
    #[serde(default = "default_lidar_datum_sigma")]
    pub lidar_datum_sigma_m: f64,
    /// A georeferenced orthophoto (GeoTIFF, or an image with a world file), given with
    /// `dem`: control points of the archive epochs where it is textured and the DEM planar.
    #[serde(default)]
    pub orthophoto: Option<PathBuf>,
    /// Its CRS when the file has none (a world file gives none); `EPSG:n` or WKT.
    #[serde(default)]
    pub orthophoto_crs: Option<String>,
    /// Acquisition date of the orthophoto's photos (ISO 8601), when known.
    #[serde(default)]
    pub orthophoto_date: Option<String>,
    /// 1σ plan accuracy of the orthophoto (m); default one orthophoto pixel.
    #[serde(default)]
    pub orthophoto_sigma_m: Option<f64>,
    /// DEM GeoTIFF of the orthophoto's area (heights of its control points; the surface
    /// archive photos are predicted over where there is no LiDAR).
    #[serde(default)]
    pub dem: Option<PathBuf>,
    /// Its CRS when the file has none.
    #[serde(default)]
    pub dem_crs: Option<String>,
    /// 1σ height accuracy of the DEM (m).
    #[serde(default = "default_dem_sigma")]
    pub dem_sigma_m: f64,
    /// Surveyed checkpoints (CSV `id,x,y,z,sigma_xy,sigma_z`), for evaluation only.
    #[serde(default)]
    pub checkpoints: Option<PathBuf>,
    /// Checkpoint measurements in the photos (CSV `epoch,photo,id,col,row`), as an
    /// operator takes them: each epoch's checkpoints are intersected from them.
    #[serde(default)]
    pub checkpoint_images: Option<PathBuf>,
    /// CRS of the checkpoint file when it is not the project's (`EPSG:n` or WKT); the
    /// points are converted to the project CRS.
    #[serde(default)]
    pub checkpoints_crs: Option<String>,
}

/// How the approximate exterior orientation of an epoch is known.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Epoch {
    pub name: String,
    /// Acquisition date, ISO 8601 (`1985` or `1985-06-12`).
    pub date: String,
    /// Folder of the photos.
    pub photos: PathBuf,
    /// Camera definition (JSON): a frame camera, or a film camera with fiducials. Required
    /// unless the epoch is an existing `block`, which holds its cameras.
    #[serde(default)]
    pub camera: Option<PathBuf>,
    /// POS file (CSV: name,x,y,z,omega,phi,kappa[,sigma_xyz,sigma_angle]).
    #[serde(default)]
    pub pos: Option<PathBuf>,
    /// Strip end points (CSV: strip,photo,x,y,z for each strip's first and last photo).
    #[serde(default)]
    pub strips: Option<PathBuf>,
    /// Pixel size of film scans (µm); without it (and without `scan_dpi`) the fiducial
    /// interior orientation estimates it and reports the estimate.
    #[serde(default)]
    pub scan_pixel_um: Option<f64>,
    /// The same as a scan resolution (dots per inch; µm = 25 400 / dpi), exclusive with
    /// `scan_pixel_um`.
    #[serde(default)]
    pub scan_dpi: Option<f64>,
    /// The reference only: an existing oriented block taken as the epoch, instead of
    /// orienting the photos against the LiDAR (then no `camera`, `pos` or `strips`).
    #[serde(default)]
    pub block: Option<ExistingBlock>,
    /// Interior parameters adjusted with the epoch's block (self-calibration), by the
    /// names of formats/cameras/: a frame camera's `fx`, `fy`, `cx`, `cy`, `k1`, `k2`,
    /// `k3`, `p1`, `p2`; a film camera's `f_mm`, `x0_mm`, `y0_mm`, `k1`… (one value for all
    /// its scans). Parameters the block cannot determine are held and reported. Default:
    /// `fx`, `fy`, `k1`, `k2` for an archive frame camera; none for film and the reference.
    #[serde(default)]
    pub self_calibration: Option<Vec<String>>,
}

/// An existing oriented block (an earlier aerial triangulation) given as the reference.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExistingBlock {
    /// BlocksExchange XML file, or COLMAP model folder (its side file gives the CRS).
    pub path: PathBuf,
    /// `blocks_exchange` or `colmap`; told by the path when absent (`.xml` or a folder).
    #[serde(default)]
    pub format: Option<String>,
    /// Check the block against the LiDAR: point-to-plane ICP of its tie points, the
    /// offset reported.
    #[serde(default = "default_true")]
    pub lidar_check: bool,
    /// Move the block by the similarity the LiDAR check found.
    #[serde(default)]
    pub apply_lidar_offset: bool,
}

fn default_true() -> bool {
    true
}

fn default_lidar_datum_sigma() -> f64 {
    crate::control::reference::DEFAULT_LIDAR_DATUM_SIGMA_M
}

fn default_dem_sigma() -> f64 {
    0.5
}

impl ExistingBlock {
    /// The format named or told by the path.
    pub fn format(&self) -> Result<crate::formats::convert::BlockFormat, String> {
        use crate::formats::convert::BlockFormat;
        match &self.format {
            Some(f) => BlockFormat::parse(&f.replace('_', "-"))
                .ok_or_else(|| format!("{f:?} is not a block format (blocks_exchange or colmap)")),
            None => BlockFormat::detect(&self.path).map_err(|e| e.to_string()),
        }
    }

    /// Reads the block.
    pub fn read(&self) -> Result<crate::block::Block, crate::formats::FormatError> {
        let format = self
            .format()
            .map_err(|m| crate::formats::FormatError::invalid(&self.path, m))?;
        crate::formats::convert::read_block(&self.path, Some(format))
    }
}

impl Epoch {
    /// Scan pixel size (mm) for the fiducial interior orientation
    /// (`matching::IoOptions::pixel_mm`), from `scan_pixel_um` or `scan_dpi`.
    pub fn scan_pixel_mm(&self) -> Option<f64> {
        match (self.scan_pixel_um, self.scan_dpi) {
            (Some(um), _) => Some(um / 1000.0),
            (None, Some(dpi)) => Some(scan_pixel_um_from_dpi(dpi) / 1000.0),
            (None, None) => None,
        }
    }
}

/// Thresholds of the method (seed 000, 001).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Thresholds {
    /// Spacing of cloud control points in the reference photos (px); never above 1000.
    pub control_interval_px: f64,
    /// Gross-error rejection at k·σ0 (2–3).
    pub reject_k: f64,
    /// Minimum NCC of an accepted patch match.
    pub ncc_min: f64,
    /// Largest distance between the NCC and LSM positions of an accepted match (px).
    pub lsm_agreement_px: f64,
    /// Side of the control patch chips (px).
    pub chip_size_px: u32,
}

impl Thresholds {
    /// Archive epoch options with these thresholds (the `orient` command and the C ABI
    /// start from the same defaults, so every caller orients an epoch alike).
    pub fn archive_options(&self) -> crate::control::archive::ArchiveOptions {
        let mut o = crate::control::archive::ArchiveOptions {
            reject_k: self.reject_k,
            ..Default::default()
        };
        o.photo.patch.matching.ncc_threshold = self.ncc_min;
        o.photo.patch.matching.agreement_px = self.lsm_agreement_px;
        o
    }
}

impl Default for Thresholds {
    fn default() -> Self {
        Self {
            control_interval_px: 250.0,
            reject_k: 2.5,
            ncc_min: 0.6,
            lsm_agreement_px: 2.0,
            chip_size_px: 193,
        }
    }
}

/// The surface an epoch's orthophoto is rectified onto.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrthoSurface {
    /// The control's ground (the LiDAR's, or the project's DEM): the same for every epoch.
    #[default]
    Control,
    /// The epoch's own DSM (`surface-<epoch>/dsm.tif`), the control's ground in its holes:
    /// what stood at the time is where the photo shows it, not where today's ground is.
    Dsm,
}

/// Which products to write for each epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Outputs {
    pub colmap: bool,
    pub blocks_exchange: bool,
    pub orthophoto: bool,
    pub dem: bool,
    /// Each epoch's own surface by dense matching of its photos (`surface-<epoch>/`:
    /// dsm.tif, dsm_count.tif, dsm_spread.tif, dsm.json).
    pub dsm: bool,
    /// The DSM also as points (`surface-<epoch>/dsm_points.laz`, a point a cell).
    pub dsm_points: bool,
    /// Each epoch's surface against the control's and the next younger epoch's
    /// (`change-<epoch>/`: dh, stable terrain, Nuth & Kääb shift, statistics); needs `dsm`.
    pub change: bool,
    pub html_report: bool,
    /// Ground pixel of orthophotos, as a multiple of the epoch's GSD.
    pub ortho_gsd_factor: f64,
    /// What orthophotos are rectified onto (`control` or `dsm`, which needs `dsm`).
    pub ortho_surface: OrthoSurface,
    /// Pixel size (µm) of the fiducial-frame images film scans are resampled into for
    /// the products; by default the mean scan pixel of the epoch's interior orientations.
    pub film_pixel_um: Option<f64>,
    /// Base cell (m) of the project's raster lattice ([`crate::geometry::Lattice`]):
    /// every raster's cell is this times a power of two, and all start at one corner.
    pub grid_base_m: f64,
}

impl Default for Outputs {
    fn default() -> Self {
        Self {
            colmap: true,
            blocks_exchange: true,
            orthophoto: true,
            dem: true,
            dsm: true,
            dsm_points: false,
            change: true,
            html_report: true,
            ortho_gsd_factor: 1.0,
            ortho_surface: OrthoSurface::Control,
            film_pixel_um: None,
            grid_base_m: 1.0,
        }
    }
}

impl Epoch {
    /// The epoch as the one epoch builder takes it ([`EpochInput::build`]).
    ///
    /// [`EpochInput::build`]: crate::control::EpochInput::build
    /// An existing `block` has no such specification: its cameras and poses are in it
    /// (the camera path is then empty, and [`Project::validate`] made sure no other epoch
    /// lacks one).
    pub fn spec(&self) -> crate::control::EpochSpec {
        crate::control::EpochSpec {
            name: self.name.clone(),
            date: Some(self.date.clone()),
            photos: self.photos.clone(),
            camera: self.camera.clone().unwrap_or_default(),
            pos: self.pos.clone(),
            strips: self.strips.clone(),
            scan_pixel_um: self.scan_pixel_mm().map(|mm| mm * 1000.0),
        }
    }
}

/// A project.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Project {
    pub name: String,
    /// CRS of the project (projected, metres): `EPSG:n` or WKT.
    pub crs: String,
    /// Output folder.
    pub output: PathBuf,
    pub control: ControlSources,
    /// The recent epoch oriented against the LiDAR, or an existing block; none when an
    /// orthophoto with a DEM controls the archive epochs alone.
    #[serde(default)]
    pub reference: Option<Epoch>,
    /// Older epochs, oriented in time order (newest first) from the DCPs of the previous one.
    #[serde(default)]
    pub archive: Vec<Epoch>,
    #[serde(default)]
    pub thresholds: Thresholds,
    #[serde(default)]
    pub outputs: Outputs,
    /// SHA-256 (hex) of the project file [`Project::load`] read; the run's report names it.
    #[serde(skip)]
    pub file_sha256: Option<String>,
    /// The project file [`Project::load`] read (problems of its keys name it).
    #[serde(skip)]
    pub file: Option<PathBuf>,
}

impl Project {
    /// Every epoch in time order, newest first: the reference (when there is one), then
    /// the archive epochs.
    pub fn epochs(&self) -> impl Iterator<Item = &Epoch> {
        self.reference.iter().chain(self.archive.iter())
    }

    /// [`Project::epochs`] with the key that names each in the project file
    /// (`reference`, `archive[1]`): messages about an epoch's inputs name it so.
    pub fn keyed_epochs(&self) -> impl Iterator<Item = (String, &Epoch)> {
        let reference = self.reference.iter().map(|e| ("reference".to_string(), e));
        let archive = (self.archive.iter().enumerate()).map(|(i, e)| (format!("archive[{i}]"), e));
        reference.chain(archive)
    }

    /// The project file `path`'s text with the epochs' surfaces and changes turned off,
    /// and an archive orthophoto asked for on its own surface made on the control's ground
    /// instead, the one surface left: what `bench accuracy --no-surfaces` runs, and the
    /// tests that check orientations alone. The text is written anew from its TOML
    /// (comments are not kept); the file itself is not touched.
    pub fn without_surfaces(path: &Path) -> Result<String, ProjectError> {
        let parse = |message: String| ProjectError::Parse {
            path: path.to_path_buf(),
            message,
        };
        let mut doc: toml::Table = read_text(path)?
            .parse()
            .map_err(|e| parse(format!("{e}")))?;
        let outputs = doc
            .entry("outputs")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| ProjectError::Key {
                path: path.to_path_buf(),
                key: "outputs".into(),
                message: "not a table".into(),
            })?;
        outputs.insert("dsm".into(), false.into());
        outputs.insert("change".into(), false.into());
        if outputs.contains_key("ortho_surface") {
            outputs.insert("ortho_surface".into(), "control".into());
        }
        toml::to_string(&doc).map_err(|e| parse(e.to_string()))
    }

    /// Reads and validates a project file. Relative paths are taken from the file's folder.
    pub fn load(path: &Path) -> Result<Self, ProjectError> {
        let text = read_text(path)?;
        let mut p: Project = toml::from_str(&text).map_err(|e| ProjectError::Parse {
            path: path.into(),
            message: e.to_string(),
        })?;
        // Absolute, so that the paths mean the same in products and in another process
        // (a distributed run's workers need not share this one's working folder).
        let base = match path.parent() {
            Some(b) if !b.as_os_str().is_empty() => b,
            _ => Path::new("."),
        };
        let base = std::path::absolute(base).map_err(|e| ProjectError::Io {
            path: path.into(),
            source: e,
        })?;
        p.resolve(&base);
        p.validate(path)?;
        use sha2::Digest;
        let digest = sha2::Sha256::digest(text.as_bytes());
        p.file_sha256 = Some(digest.iter().map(|b| format!("{b:02x}")).collect());
        p.file = Some(path.to_path_buf());
        Ok(p)
    }

    fn resolve(&mut self, base: &Path) {
        let abs = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        abs(&mut self.output);
        self.control.lidar.iter_mut().for_each(abs);
        for p in [&mut self.control.orthophoto, &mut self.control.dem]
            .into_iter()
            .flatten()
        {
            abs(p)
        }
        if let Some(c) = self.control.checkpoints.as_mut() {
            abs(c)
        }
        if let Some(c) = self.control.checkpoint_images.as_mut() {
            abs(c)
        }
        for e in self.reference.iter_mut().chain(self.archive.iter_mut()) {
            abs(&mut e.photos);
            if let Some(c) = e.camera.as_mut() {
                abs(c)
            }
            if let Some(b) = e.block.as_mut() {
                abs(&mut b.path)
            }
            if let Some(p) = e.pos.as_mut() {
                abs(p)
            }
            if let Some(s) = e.strips.as_mut() {
                abs(s)
            }
        }
    }

    /// Every check that can be made before work starts.
    pub fn validate(&self, file: &Path) -> Result<(), ProjectError> {
        let key_err = |key: &str, message: String| ProjectError::Key {
            path: file.into(),
            key: key.into(),
            message,
        };
        let exists = |key: &str, p: &Path| -> Result<(), ProjectError> {
            if !p.exists() && p.symlink_metadata().is_err() {
                return Err(key_err(key, format!("{} does not exist", p.display())));
            }
            check_input(key, p).map_err(|e| key_err(key, e.to_string()))
        };
        let crs = crate::formats::crs::Crs::parse(&self.crs)
            .map_err(|e| key_err("crs", e.to_string()))?;
        crs.require_metric_projected(None)
            .map_err(|e| key_err("crs", e.to_string()))?;
        let c = &self.control;
        for (i, l) in c.lidar.iter().enumerate() {
            exists(&format!("control.lidar[{i}]"), l)?;
        }
        match (&c.orthophoto, &c.dem) {
            (Some(o), Some(d)) => {
                exists("control.orthophoto", o)?;
                exists("control.dem", d)?;
            }
            (Some(_), None) => {
                return Err(key_err(
                    "control.dem",
                    "missing: an orthophoto controls with the heights of a DEM".into(),
                ))
            }
            (None, Some(_)) => {
                return Err(key_err(
                    "control.orthophoto",
                    "missing: the DEM is given for an orthophoto's control points".into(),
                ))
            }
            (None, None) => {
                if c.lidar.is_empty() {
                    return Err(key_err(
                        "control.lidar",
                        "no control source given: LiDAR, or an orthophoto with a DEM".into(),
                    ));
                }
            }
        }
        for (key, crs) in [
            ("control.orthophoto_crs", &c.orthophoto_crs),
            ("control.dem_crs", &c.dem_crs),
        ] {
            if let Some(d) = crs {
                crate::formats::crs::Crs::parse(d).map_err(|e| key_err(key, e.to_string()))?;
            }
        }
        if let Some(d) = &c.orthophoto_date {
            if !valid_date(d) {
                return Err(key_err(
                    "control.orthophoto_date",
                    format!("{d:?} is not an ISO 8601 date (YYYY, YYYY-MM or YYYY-MM-DD)"),
                ));
            }
        }
        if !(c.lidar_datum_sigma_m > 0.0 && c.lidar_datum_sigma_m.is_finite()) {
            return Err(key_err(
                "control.lidar_datum_sigma_m",
                "must be positive and finite".into(),
            ));
        }
        if !(c.dem_sigma_m > 0.0 && c.dem_sigma_m.is_finite()) {
            return Err(key_err("control.dem_sigma_m", "must be positive".into()));
        }
        if let Some(v) = c.orthophoto_sigma_m {
            if !(v > 0.0 && v.is_finite()) {
                return Err(key_err(
                    "control.orthophoto_sigma_m",
                    "must be positive".into(),
                ));
            }
        }
        match &self.reference {
            None if c.orthophoto.is_none() => {
                return Err(key_err(
                    "reference",
                    "missing: without an orthophoto and DEM, the reference epoch is the control of the archive epochs".into(),
                ))
            }
            None if self.archive.is_empty() => {
                return Err(key_err("archive", "no epoch to orient".into()))
            }
            Some(r) if c.lidar.is_empty() && r.block.as_ref().is_none_or(|b| b.lidar_check) => {
                return Err(key_err(
                    "reference",
                    "is oriented (or, as a block, checked) against the LiDAR, and control.lidar is empty".into(),
                ))
            }
            _ => {}
        }
        if let Some(c) = &self.control.checkpoints {
            exists("control.checkpoints", c)?;
        }
        if let Some(c) = &self.control.checkpoint_images {
            exists("control.checkpoint_images", c)?;
            if self.control.checkpoints.is_none() {
                return Err(key_err(
                    "control.checkpoint_images",
                    "given without control.checkpoints (their surveyed coordinates)".into(),
                ));
            }
        }
        let mut names = std::collections::BTreeSet::new();
        let epochs = self
            .reference
            .iter()
            .map(|e| ("reference".to_string(), e))
            .chain(
                self.archive
                    .iter()
                    .enumerate()
                    .map(|(i, e)| (format!("archive[{i}]"), e)),
            );
        let mut prev_date: Option<String> = None;
        for (key, e) in epochs {
            if e.name.trim().is_empty() {
                return Err(key_err(&format!("{key}.name"), "is empty".into()));
            }
            if !names.insert(e.name.clone()) {
                return Err(key_err(
                    &format!("{key}.name"),
                    format!("epoch name {:?} is used twice", e.name),
                ));
            }
            if e.name == super::products::CONTROL_PRODUCTS {
                return Err(key_err(
                    &format!("{key}.name"),
                    format!(
                        "{:?} names the project's control surfaces (run summary products); \
                         call the epoch otherwise",
                        e.name
                    ),
                ));
            }
            if !valid_date(&e.date) {
                return Err(key_err(
                    &format!("{key}.date"),
                    format!(
                        "{:?} is not an ISO 8601 date (YYYY, YYYY-MM or YYYY-MM-DD)",
                        e.date
                    ),
                ));
            }
            if let Some(p) = &prev_date {
                if e.date.as_str() >= p.as_str() {
                    return Err(key_err(
                        &format!("{key}.date"),
                        format!(
                            "archive epochs go back in time: {} is not older than {p}",
                            e.date
                        ),
                    ));
                }
            }
            prev_date = Some(e.date.clone());
            match (e.scan_pixel_um, e.scan_dpi) {
                (Some(_), Some(_)) => {
                    return Err(key_err(
                        &format!("{key}.scan_dpi"),
                        "give either scan_pixel_um or scan_dpi, not both".into(),
                    ))
                }
                (Some(um), None) => check_scan_pixel_um(um)
                    .map_err(|m| key_err(&format!("{key}.scan_pixel_um"), m))?,
                (None, Some(dpi)) => check_scan_pixel_um(scan_pixel_um_from_dpi(dpi))
                    .map_err(|m| key_err(&format!("{key}.scan_dpi"), format!("{dpi} dpi: {m}")))?,
                (None, None) => {}
            }
            exists(&format!("{key}.photos"), &e.photos)?;
            if let Some(b) = &e.block {
                if key != "reference" {
                    return Err(key_err(
                        &format!("{key}.block"),
                        "only the reference epoch can be an existing block".into(),
                    ));
                }
                exists(&format!("{key}.block.path"), &b.path)?;
                b.format()
                    .map_err(|m| key_err(&format!("{key}.block.format"), m))?;
                if b.apply_lidar_offset && !b.lidar_check {
                    return Err(key_err(
                        &format!("{key}.block.apply_lidar_offset"),
                        "needs lidar_check (the offset is what the check finds)".into(),
                    ));
                }
                for (k, given) in [
                    ("camera", e.camera.is_some()),
                    ("pos", e.pos.is_some()),
                    ("strips", e.strips.is_some()),
                    ("scan_pixel_um", e.scan_pixel_um.is_some()),
                    ("scan_dpi", e.scan_dpi.is_some()),
                ] {
                    if given {
                        return Err(key_err(
                            &format!("{key}.{k}"),
                            "given with block: the existing block holds the cameras and orientations".into(),
                        ));
                    }
                }
                continue;
            }
            match &e.camera {
                Some(c) => exists(&format!("{key}.camera"), c)?,
                None => {
                    return Err(key_err(
                        &format!("{key}.camera"),
                        "missing: give the camera file (formats/cameras/)".into(),
                    ))
                }
            }
            match (&e.pos, &e.strips) {
                (Some(p), None) => exists(&format!("{key}.pos"), p)?,
                (None, Some(s)) => exists(&format!("{key}.strips"), s)?,
                (Some(_), Some(_)) => {
                    return Err(key_err(
                        &format!("{key}.pos"),
                        "give either pos or strips, not both".into(),
                    ))
                }
                (None, None) => {
                    return Err(key_err(
                        &format!("{key}.pos"),
                        "missing: give pos (POS file) or strips (strip end points)".into(),
                    ))
                }
            }
        }
        let t = &self.thresholds;
        if !(t.control_interval_px > 0.0 && t.control_interval_px <= 1000.0) {
            return Err(key_err(
                "thresholds.control_interval_px",
                format!("{} is outside (0, 1000]", t.control_interval_px),
            ));
        }
        if !(1.0..=5.0).contains(&t.reject_k) {
            return Err(key_err(
                "thresholds.reject_k",
                format!("{} is outside [1, 5] (2–3 is usual)", t.reject_k),
            ));
        }
        if !(t.ncc_min > 0.0 && t.ncc_min < 1.0) {
            return Err(key_err(
                "thresholds.ncc_min",
                format!("{} is outside (0, 1)", t.ncc_min),
            ));
        }
        if t.lsm_agreement_px.is_nan() || t.lsm_agreement_px <= 0.0 {
            return Err(key_err(
                "thresholds.lsm_agreement_px",
                "must be positive".into(),
            ));
        }
        if t.chip_size_px < 11 || t.chip_size_px % 2 == 0 {
            return Err(key_err(
                "thresholds.chip_size_px",
                format!("{} must be odd and ≥ 11", t.chip_size_px),
            ));
        }
        if self.outputs.ortho_gsd_factor.is_nan() || self.outputs.ortho_gsd_factor <= 0.0 {
            return Err(key_err(
                "outputs.ortho_gsd_factor",
                "must be positive".into(),
            ));
        }
        if !(self.outputs.grid_base_m.is_finite()
            && (1e-3..=1e3).contains(&self.outputs.grid_base_m))
        {
            return Err(key_err(
                "outputs.grid_base_m",
                format!(
                    "{} m: the base cell must be between 1 mm and 1 km",
                    self.outputs.grid_base_m
                ),
            ));
        }
        if let Some(um) = self.outputs.film_pixel_um {
            check_scan_pixel_um(um).map_err(|m| key_err("outputs.film_pixel_um", m))?;
        }
        if self.outputs.ortho_surface == OrthoSurface::Dsm && !self.outputs.dsm {
            return Err(key_err(
                "outputs.ortho_surface",
                "\"dsm\" rectifies onto each epoch's own surface: it needs outputs.dsm = true"
                    .into(),
            ));
        }
        Ok(())
    }
}

/// A project file's text, read within the project files' size cap (as every input is).
fn read_text(path: &Path) -> Result<String, ProjectError> {
    crate::formats::input::read_text(path, crate::formats::input::Cap::project()).map_err(|e| {
        match e {
            crate::formats::FormatError::Io { source, .. } => ProjectError::Io {
                path: path.into(),
                source,
            },
            e => ProjectError::Parse {
                path: path.into(),
                message: e.detail(),
            },
        }
    })
}

/// The checks of a listed input that need not read it (formats/README.md, "Input
/// files"): a regular file (links followed) within its kind's size cap, or for a folder
/// (photos, LiDAR, a COLMAP model) a tree of regular files and folders without link
/// cycles. The kind is told by the key.
fn check_input(key: &str, p: &Path) -> Result<(), crate::formats::FormatError> {
    use crate::formats::input::{check_file, check_tree, Cap};
    let name = key.rsplit('.').next().unwrap_or(key);
    match name {
        "pos" | "strips" | "checkpoints" | "checkpoint_images" => {
            check_file(p, Some(Cap::csv())).map(|_| ())
        }
        "camera" => check_file(p, Some(Cap::camera())).map(|_| ()),
        "orthophoto" | "dem" => check_file(p, None).map(|_| ()),
        _ => check_tree(p),
    }
}

fn valid_date(s: &str) -> bool {
    let parts: Vec<&str> = s.split('-').collect();
    let num = |p: &str, len: usize, lo: u32, hi: u32| {
        p.len() == len
            && p.chars().all(|c| c.is_ascii_digit())
            && p.parse::<u32>().is_ok_and(|v| (lo..=hi).contains(&v))
    };
    match parts.as_slice() {
        [y] => num(y, 4, 1800, 2200),
        [y, m] => num(y, 4, 1800, 2200) && num(m, 2, 1, 12),
        [y, m, d] => num(y, 4, 1800, 2200) && num(m, 2, 1, 12) && num(d, 2, 1, 31),
        _ => false,
    }
}
