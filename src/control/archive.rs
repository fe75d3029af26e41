//! Orientation of an archive epoch from Digital Control Photos (seed 001 whole, seed 000
//! §2.2 (3)–(5)): fiducial interior orientation of film scans, approximate exterior
//! orientation from POS or strip end points, the iterative patch prediction / matching /
//! resection loop of [`super::orient::orient_photo`] per photo with the real matcher
//! ([`DcpPatchMatcher`]: chips aligned through the ground plane, NCC over the pyramid, LSM,
//! cross-check) and resector ([`AdjustResector`]), then the robust archive block
//! adjustment with rejection at k·RMSE, and checkpoint evaluation.
//!
//! Inputs are held in memory ([`EpochInput`]: camera, photo names and image paths,
//! navigation) so the pipeline, the CLI and the benches call the same [`orient_epoch`].

use super::cloud::{
    self, CloudOptions, ControlPointRecord, ControlSurface, ExportInfo, GroundSurface,
};
use super::dcp::{Accuracy, DcpError, DcpIndex, DcpPackage, EpochInfo};
use super::orient::{
    self, ControlPatch, IterationRecord, OrientOptions, PatchMatch, PatchMatcher, Resection,
    Resector,
};
use super::predict::{self, Plane, Prediction, View};
use super::strips;
use crate::adjust::{self, AdjustError, AdjustOptions, AdjustReport, Loss, Rejection};
use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PhotoId, PointKind};
use crate::formats::crs::Crs;
use crate::formats::pos::{self as pos_csv, PosRecord, StripEnds};
use crate::geometry::{
    self, matrix_from_opk, Brown, Camera, Dem, FilmCamera, FrameCamera, GeoTransform, Pose,
};
use crate::matching::{
    self, forstner, match_template, CameraDefinition, ForstnerOptions, GreyImage, IoOptions,
    MatchOptions, Pyramid, Window,
};
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Errors of archive orientation; each names the input (file, epoch, photo, package).
#[derive(Debug, thiserror::Error)]
pub enum ArchiveError {
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    #[error("epoch {epoch}: {message}")]
    Epoch { epoch: String, message: String },
    #[error(transparent)]
    Dcp(#[from] DcpError),
    /// LiDAR tiles (the error names the file).
    #[error(transparent)]
    Lidar(#[from] crate::lidar::LidarError),
    /// An oriented block given in memory (the caller names its file).
    #[error("oriented block: {0}")]
    Block(String),
    #[error("epoch {epoch}: archive block adjustment: {source}")]
    Adjust { epoch: String, source: AdjustError },
}

fn input_err(path: &Path, message: impl Into<String>) -> ArchiveError {
    ArchiveError::Input {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// The camera of an epoch: a calibrated (or nominal) digital frame camera, or a film
/// camera's calibration certificate whose interior orientation is found per scan.
#[derive(Debug, Clone)]
pub enum EpochCamera {
    Frame(FrameCamera),
    Film(CameraDefinition),
}

#[derive(Debug, Clone, PartialEq)]
pub struct PhotoInput {
    pub name: String,
    pub image: PathBuf,
}

impl PhotoInput {
    /// Every image file (PNG, TIFF, JPEG) of a folder, sorted by name; the photo name is
    /// the file stem. An empty folder is an error naming it.
    pub fn from_folder(dir: &Path) -> Result<Vec<Self>, ArchiveError> {
        let mut v: Vec<Self> = std::fs::read_dir(dir)
            .map_err(|e| input_err(dir, e.to_string()))?
            .filter_map(|d| d.ok().map(|d| d.path()))
            .filter(|p| {
                p.extension().and_then(|x| x.to_str()).is_some_and(|x| {
                    matches!(
                        x.to_ascii_lowercase().as_str(),
                        "png" | "tif" | "tiff" | "jpg" | "jpeg"
                    )
                })
            })
            .map(|p| Self {
                name: p
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                image: p,
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        if v.is_empty() {
            return Err(input_err(dir, "no photo (PNG, TIFF or JPEG) in the folder"));
        }
        Ok(v)
    }
}

/// Approximate exterior orientation: a POS (world coordinates, angles with σ), or strips
/// given by their end points only (world coordinates).
#[derive(Debug, Clone, PartialEq)]
pub enum Navigation {
    Pos(Vec<PosRecord>),
    Strips(Vec<StripEnds>),
}

/// One archive epoch to orient.
#[derive(Debug, Clone)]
pub struct EpochInput {
    pub name: String,
    pub date: Option<String>,
    /// CRS of the navigation (must be the DCP packages' CRS).
    pub crs: String,
    /// World coordinates of the block-local origin used for the numerics and the DEM.
    pub origin: [f64; 3],
    pub camera: EpochCamera,
    pub photos: Vec<PhotoInput>,
    pub navigation: Navigation,
}

/// A CSV line: its 1-based line number and its fields.
type CsvRow = (usize, Vec<String>);

fn csv_rows(path: &Path) -> Result<(Vec<String>, Vec<CsvRow>), ArchiveError> {
    let text = std::fs::read_to_string(path).map_err(|e| input_err(path, e.to_string()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .ok_or_else(|| input_err(path, "empty file (no header)"))?;
    let header: Vec<String> = header.split(',').map(|s| s.trim().to_string()).collect();
    let rows = lines
        .map(|(i, l)| (i + 1, l.split(',').map(|s| s.trim().to_string()).collect()))
        .collect();
    Ok((header, rows))
}

/// Column accessor of a CSV with a named header.
struct Csv<'a> {
    path: &'a Path,
    header: &'a [String],
}

impl Csv<'_> {
    fn col(&self, name: &str) -> Result<usize, ArchiveError> {
        self.header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| input_err(self.path, format!("no column {name:?} in the header")))
    }

    fn num(&self, row: &CsvRow, name: &str) -> Result<f64, ArchiveError> {
        let c = self.col(name)?;
        let s = row
            .1
            .get(c)
            .ok_or_else(|| input_err(self.path, format!("line {}: too few fields", row.0)))?;
        let v: f64 = s.parse().map_err(|_| {
            input_err(
                self.path,
                format!("line {}, column {name}: {s:?} is not a number", row.0),
            )
        })?;
        if !v.is_finite() {
            return Err(input_err(
                self.path,
                format!("line {}, column {name}: not finite", row.0),
            ));
        }
        Ok(v)
    }

    fn text<'r>(&self, row: &'r CsvRow, name: &str) -> Result<&'r str, ArchiveError> {
        let c = self.col(name)?;
        row.1
            .get(c)
            .map(|s| s.as_str())
            .ok_or_else(|| input_err(self.path, format!("line {}: too few fields", row.0)))
    }
}

fn read_json(path: &Path) -> Result<serde_json::Value, ArchiveError> {
    let text = std::fs::read_to_string(path).map_err(|e| input_err(path, e.to_string()))?;
    serde_json::from_str(&text).map_err(|e| input_err(path, e.to_string()))
}

impl EpochInput {
    /// Loads an epoch of a synthetic block (formats/synth/README.md): `manifest.json` for
    /// the CRS, origin and photo list, `camera.json`, `pos.csv` or `strips.csv`, `images/`.
    /// Nothing under `truth/` is read.
    pub fn from_synth_epoch(dir: &Path, epoch: &str) -> Result<Self, ArchiveError> {
        let mpath = dir.join("manifest.json");
        let m = read_json(&mpath)?;
        let crs = m["crs"]
            .as_str()
            .ok_or_else(|| input_err(&mpath, "no crs"))?
            .to_string();
        let origin: [f64; 3] = serde_json::from_value(m["origin"].clone())
            .map_err(|e| input_err(&mpath, format!("origin: {e}")))?;
        let e = m["epochs"]
            .as_array()
            .and_then(|a| a.iter().find(|e| e["name"] == epoch))
            .ok_or_else(|| input_err(&mpath, format!("no epoch named {epoch:?}")))?;
        let field = |k: &str| {
            e[k].as_str()
                .map(str::to_string)
                .ok_or_else(|| input_err(&mpath, format!("epoch {epoch}: no {k}")))
        };
        let names: Vec<String> = serde_json::from_value(e["photos"].clone())
            .map_err(|err| input_err(&mpath, format!("epoch {epoch}: photos: {err}")))?;
        let images_dir = dir.join(field("images_dir")?);
        let cam_path = dir.join(field("camera")?);
        let camera =
            match field("kind")?.as_str() {
                "film" => EpochCamera::Film(
                    CameraDefinition::load(&cam_path)
                        .map_err(|e| input_err(&cam_path, e.to_string()))?,
                ),
                _ => {
                    let cam: Camera = serde_json::from_value(read_json(&cam_path)?)
                        .map_err(|e| input_err(&cam_path, e.to_string()))?;
                    match cam {
                        Camera::Frame(f) => EpochCamera::Frame(f),
                        Camera::Film(_) => return Err(input_err(
                            &cam_path,
                            "a film camera needs its certificate (fiducials), not a scan camera",
                        )),
                    }
                }
            };
        let nav_path = dir.join(field("navigation")?);
        let nav_err = |e: crate::formats::FormatError| input_err(&nav_path, e.detail());
        // The navigation names image files; the epoch's photos are named by stem.
        let navigation = if nav_path.file_name().is_some_and(|n| n == "strips.csv") {
            let mut strips = pos_csv::read_strips(&nav_path).map_err(nav_err)?;
            pos_csv::resolve_photo_names(strips.iter_mut().flat_map(|s| &mut s.photos), &names);
            Navigation::Strips(strips)
        } else {
            let mut recs = pos_csv::read_pos(&nav_path).map_err(nav_err)?;
            pos_csv::resolve_photo_names(recs.iter_mut().map(|r| &mut r.name), &names);
            Navigation::Pos(recs)
        };
        let photos = names
            .iter()
            .map(|n| PhotoInput {
                name: n.clone(),
                image: images_dir.join(format!("{n}.png")),
            })
            .collect();
        Ok(Self {
            name: epoch.to_string(),
            date: e["date"].as_str().map(str::to_string),
            crs,
            origin,
            camera,
            photos,
            navigation,
        })
    }
}

/// Options of [`orient_epoch`].
#[derive(Debug, Clone)]
pub struct ArchiveOptions {
    pub orient: OrientOptions,
    pub matching: MatchOptions,
    /// Largest template half size in target pixels (template = 2·h + 1); smaller when the
    /// chip does not hold it at the target's scale, but never below `min_template_half`.
    pub template_half: usize,
    pub min_template_half: usize,
    /// Smallest RANSAC threshold of the resection (px); the threshold is also ≥ 4σ.
    pub resection_threshold_px: f64,
    /// Least number of resection inliers for a photo to count as oriented: three points
    /// have no redundancy, so one mismatch would go unnoticed.
    pub min_inliers: usize,
    /// Floor of the matching σ (px): LSM's σ ignores model errors (relief, chip alignment).
    pub sigma_floor_px: f64,
    /// Rejection in the block adjustment at k·σ0 (seed 000: 2–3).
    pub reject_k: f64,
    pub loss: Loss,
    /// Interior parameters of frame cameras adjusted with the block (archive cameras are
    /// rarely calibrated); empty = fixed. Film cameras keep their certificate.
    pub self_calibration: Vec<String>,
    /// Centre σ (m) of strip end points (flight index) and attitude σ for no-POS epochs.
    pub strip_end_sigma_m: f64,
    pub strip_attitude_sigma_deg: f64,
    /// Replace the POS σ (centre m, attitude rad), e.g. to study EO groups.
    pub pos_sigma_override: Option<(f64, f64)>,
    pub io: IoOptions,
    /// Minimum grey-value standard deviation of an aligned chip (textureless chips are
    /// not offered to NCC).
    pub min_chip_std: f64,
    /// Retry a photo that could not be oriented with every patch's best peak (however
    /// ambiguous) and let RANSAC sort them, requiring `relaxed_min_inliers`.
    pub relaxed_retry: bool,
    pub relaxed_ncc_threshold: f64,
    pub relaxed_min_inliers: usize,
    /// Photos not oriented from the packages try again with the control points as the
    /// epoch's own oriented photos show them.
    pub epoch_second_pass: bool,
    /// Image tie points among the oriented photos of the epoch in the block adjustment,
    /// one per `tie_interval_px` cell, searched ±`tie_window_px` around their prediction
    /// (off by default: the DCP points observed in several photos already tie the block).
    pub ties: bool,
    pub tie_interval_px: f64,
    pub tie_window_px: f64,
    pub tie_ncc_threshold: f64,
}

impl Default for ArchiveOptions {
    fn default() -> Self {
        Self {
            orient: OrientOptions {
                min_half_px: 6.0,
                max_half_px: 400.0,
                ..OrientOptions::default()
            },
            matching: MatchOptions {
                ncc_threshold: 0.6,
                // Large first-round windows over fields and roads hold near-repeats of
                // a patch; the best peak is still mostly right, and the resection's
                // RANSAC removes the rest.
                max_ambiguity: 0.97,
                // The NCC peak of a rescaled template is good to a pixel or two; LSM is
                // the precise one, the cross-check only has to catch its divergence.
                agreement_px: 2.0,
                ..MatchOptions::default()
            },
            template_half: 30,
            min_template_half: 7,
            resection_threshold_px: 3.0,
            min_inliers: 4,
            sigma_floor_px: 0.3,
            reject_k: 2.5,
            loss: Loss::Huber(2.0),
            self_calibration: vec!["k1".into(), "k2".into()],
            strip_end_sigma_m: 10.0,
            strip_attitude_sigma_deg: 3.0,
            pos_sigma_override: None,
            io: IoOptions::default(),
            min_chip_std: 2.0,
            relaxed_retry: true,
            relaxed_ncc_threshold: 0.5,
            relaxed_min_inliers: 6,
            epoch_second_pass: true,
            // Measured on the small synthetic block: no gain yet over the DCP points seen
            // in several photos, and worse heights in the time series (see the report).
            ties: false,
            tie_interval_px: 100.0,
            tie_window_px: 10.0,
            tie_ncc_threshold: 0.8,
        }
    }
}

/// A DCP control point's global id: package index in the high, point index in the low bits.
fn patch_id(package: usize, point: usize) -> u64 {
    ((package as u64) << 32) | point as u64
}

fn patch_index(id: u64) -> (usize, usize) {
    ((id >> 32) as usize, (id & 0xffff_ffff) as usize)
}

/// Why the matcher rejected patches, counted for the report.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct MatchStats {
    pub offered: usize,
    pub no_chip: usize,
    pub textureless: usize,
    pub rejected: usize,
    pub accepted: usize,
}

/// The real [`PatchMatcher`]: aligns a DCP chip to the target photo through the patch's
/// ground plane, then NCC over the pyramid inside the search window, LSM at full
/// resolution and the NCC/LSM cross-check.
pub struct DcpPatchMatcher<'a> {
    camera: &'a Camera,
    pyramid: &'a Pyramid,
    packages: &'a [DcpPackage],
    origin: Vector3<f64>,
    opts: &'a ArchiveOptions,
    /// Chip pyramids by (package, point, measurement); None = chip unreadable.
    chips: HashMap<(usize, usize, usize), Option<Pyramid>>,
    pub stats: MatchStats,
    /// First chip error met (a damaged package is an input error, not a mismatch).
    pub chip_error: Option<String>,
}

impl<'a> DcpPatchMatcher<'a> {
    pub fn new(
        camera: &'a Camera,
        pyramid: &'a Pyramid,
        packages: &'a [DcpPackage],
        origin: Vector3<f64>,
        opts: &'a ArchiveOptions,
    ) -> Self {
        Self {
            camera,
            pyramid,
            packages,
            origin,
            opts,
            chips: HashMap::new(),
            stats: MatchStats::default(),
            chip_error: None,
        }
    }

    /// Chips already in memory, by (package, point, measurement).
    fn preload(&mut self, chips: &HashMap<(usize, usize, usize), Pyramid>) {
        for (k, v) in chips {
            self.chips.insert(*k, Some(v.clone()));
        }
    }

    fn chip(&mut self, k: usize, i: usize, j: usize) -> Option<&Pyramid> {
        let pkg = &self.packages[k];
        let entry = self.chips.entry((k, i, j)).or_insert_with(|| {
            let ms = &pkg.manifest.points[i].measurements[j];
            match pkg.chip(&ms.chip) {
                Ok(img) => {
                    let g = img.to_luma32f();
                    let data: Vec<f32> = g.as_raw().iter().map(|v| v * 255.0).collect();
                    let grey =
                        GreyImage::new(g.width() as usize, g.height() as usize, data).ok()?;
                    Some(Pyramid::new(&grey, 5, 8))
                }
                Err(e) => {
                    self.chip_error.get_or_insert(e.to_string());
                    None
                }
            }
        });
        entry.as_ref()
    }

    /// Chip candidates of a point, best first: the reference photo whose viewing direction
    /// is closest to the target's, then the one with the closest ground pixel.
    fn ranked_chips(&self, k: usize, i: usize, target_pose: &Pose, x: &Vector3<f64>) -> Vec<usize> {
        let pkg = &self.packages[k];
        let pt = &pkg.manifest.points[i];
        let to_target = (target_pose.center - x).normalize();
        let target_dist = (target_pose.center - x).norm() / self.camera.focal_px();
        let mut scored: Vec<(usize, f64, f64)> = pt
            .measurements
            .iter()
            .enumerate()
            .filter_map(|(j, ms)| {
                let ph = pkg.manifest.photos.iter().find(|p| p.id == ms.photo)?;
                let pose = ph.pose(&self.origin);
                let d = (pose.center - x).normalize();
                let gsd = (pose.center - x).norm() / ph.camera.focal_px();
                Some((j, d.dot(&to_target), (gsd / target_dist).ln().abs()))
            })
            .collect();
        scored.sort_by(|a, b| {
            // Directions within ~2.5° are equivalent; then prefer the closer scale.
            let (qa, qb) = ((a.1 * 400.0).round(), (b.1 * 400.0).round());
            qb.total_cmp(&qa).then(a.2.total_cmp(&b.2))
        });
        scored.into_iter().map(|s| s.0).collect()
    }

    /// Aligned template of point (k, i) from chip j for the target at `pixel`, or None when
    /// the chip does not cover the template.
    fn template(
        &mut self,
        k: usize,
        i: usize,
        j: usize,
        pose: &Pose,
        position: &Vector3<f64>,
        pixel: Vector2<f64>,
    ) -> Option<GreyImage> {
        let pkg = &self.packages[k];
        let pt = &pkg.manifest.points[i];
        let ms = &pt.measurements[j];
        let ph = pkg.manifest.photos.iter().find(|p| p.id == ms.photo)?;
        let src_pose = ph.pose(&self.origin);
        let normal = pt.normal.map(Vector3::from).unwrap_or_else(Vector3::z);
        let plane = Plane::through(position, &normal);
        let a = predict::transfer_affine(
            View {
                camera: self.camera,
                pose,
            },
            View {
                camera: &ph.camera,
                pose: &src_pose,
            },
            &plane,
            [pixel.x, pixel.y],
        )
        .ok()?;
        let (x0, y0) = (ms.chip.x0 as f64, ms.chip.y0 as f64);
        let s = Vector2::new(ms.pixel[0] - x0, ms.pixel[1] - y0);
        let l = a.fixed_view::<2, 2>(0, 0).into_owned();
        // The largest template (up to the option) whose footprint stays inside the chip:
        // a coarser target needs more chip pixels per template pixel.
        let stretch = l.column(0).norm().max(l.column(1).norm()).max(1e-9);
        let room = (ms.chip.width.min(ms.chip.height) as f64 / 2.0 - 3.0) / (stretch * 1.05);
        let th = (self.opts.template_half as f64).min(room.floor() - 1.0);
        if th < self.opts.min_template_half as f64 {
            return None;
        }
        let t = 2.0 * th + 1.0;
        let chip = self.chip(k, i, j)?;
        let level = (predict::pyramid_level(&a) as usize).min(chip.levels.len() - 1);
        let f = (1u64 << level) as f64;
        let img = &chip.levels[level];
        // Template pixel u (corner origin) ↦ offset u − t/2 from the point ↦ chip pixel
        // L·offset + s ↦ level pixel /2^level: the chip rotated and rescaled into the
        // target's geometry, centred on the control point's own chip position.
        let c = s - l * Vector2::new(t / 2.0, t / 2.0);
        let warp = matching::PatchWarp::Affine([
            l[(0, 0)] / f,
            l[(0, 1)] / f,
            c.x / f,
            l[(1, 0)] / f,
            l[(1, 1)] / f,
            c.y / f,
        ]);
        let (tpl, outside) = matching::warp_patch(
            img,
            &warp,
            t as usize,
            t as usize,
            matching::Interpolation::Bicubic,
        );
        (outside == 0).then_some(tpl)
    }
}

impl PatchMatcher for DcpPatchMatcher<'_> {
    fn find(
        &mut self,
        patch: &ControlPatch,
        pose: &Pose,
        prediction: &Prediction,
        half_size: [f64; 2],
    ) -> Option<PatchMatch> {
        self.stats.offered += 1;
        let (k, i) = patch_index(patch.id);
        let mut tpl = None;
        for j in self.ranked_chips(k, i, pose, &patch.position) {
            if let Some(t) = self.template(k, i, j, pose, &patch.position, prediction.pixel) {
                tpl = Some(t);
                break;
            }
        }
        let Some(tpl) = tpl else {
            self.stats.no_chip += 1;
            return None;
        };
        if tpl.std_dev() < self.opts.min_chip_std {
            self.stats.textureless += 1;
            return None;
        }
        let img = &self.pyramid.levels[0];
        let th = tpl.width as f64 / 2.0;
        let window = Window::around(
            img,
            prediction.pixel.x,
            prediction.pixel.y,
            half_size[0] + th,
            half_size[1] + th,
        )?;
        let rr = match_template(self.pyramid, &tpl, window, None, &self.opts.matching);
        if let Ok(r) = &rr {
            tracing::debug!(
                patch = patch.id,
                pred_x = prediction.pixel.x,
                pred_y = prediction.pixel.y,
                half = half_size[0],
                x = r.x,
                y = r.y,
                ncc = r.ncc,
                ambiguity = r.ambiguity,
                reason = r.reason.as_deref().unwrap_or(""),
                "control patch match"
            );
        }
        let r = match rr {
            Ok(r) if r.accepted => r,
            _ => {
                self.stats.rejected += 1;
                return None;
            }
        };
        // The match must lie in the window that was searched (LSM may drift out of it).
        if (r.x - prediction.pixel.x).abs() > half_size[0] + 1.0
            || (r.y - prediction.pixel.y).abs() > half_size[1] + 1.0
        {
            self.stats.rejected += 1;
            return None;
        }
        self.stats.accepted += 1;
        let sigma = (0.5 * (r.sigma_x.powi(2) + r.sigma_y.powi(2))).sqrt();
        Some(PatchMatch {
            pixel: Vector2::new(r.x, r.y),
            sigma_px: if sigma.is_finite() { sigma } else { 1.0 },
            ncc: r.ncc,
        })
    }
}

/// The real [`Resector`]: P3P inside RANSAC, Levenberg–Marquardt refinement, data snooping
/// and the covariance, from [`adjust::resect`].
pub struct AdjustResector {
    pub threshold_px: f64,
    pub sigma_floor_px: f64,
    pub min_inliers: usize,
    pub last_rmse_px: f64,
}

impl AdjustResector {
    pub fn new(opts: &ArchiveOptions) -> Self {
        Self {
            threshold_px: opts.resection_threshold_px,
            sigma_floor_px: opts.sigma_floor_px,
            min_inliers: opts.min_inliers,
            last_rmse_px: f64::NAN,
        }
    }
}

impl Resector for AdjustResector {
    fn resect(
        &mut self,
        camera: &Camera,
        approximate: &Pose,
        observations: &[(Vector3<f64>, Vector2<f64>, f64)],
    ) -> Result<Resection, String> {
        if observations.is_empty() {
            return Err("resection without observations".into());
        }
        let mut sig: Vec<f64> = observations
            .iter()
            .map(|o| o.2.max(self.sigma_floor_px))
            .collect();
        sig.sort_by(f64::total_cmp);
        let sigma = sig[sig.len() / 2];
        let opts = adjust::ResectionOptions {
            threshold_px: self.threshold_px.max(4.0 * sigma),
            approximate: Some(*approximate),
            ..adjust::ResectionOptions::default()
        };
        let pixels: Vec<[f64; 2]> = observations.iter().map(|o| [o.1.x, o.1.y]).collect();
        let points: Vec<[f64; 3]> = observations.iter().map(|o| [o.0.x, o.0.y, o.0.z]).collect();
        let r =
            adjust::resect(camera, &pixels, &points, sigma, &opts).map_err(|e| e.to_string())?;
        if r.num_inliers < self.min_inliers {
            return Err(format!(
                "resection kept {} of {} matches, {} needed",
                r.num_inliers,
                observations.len(),
                self.min_inliers
            ));
        }
        self.last_rmse_px = r.rmse_px;
        let mut cov = SMatrix::<f64, 6, 6>::zeros();
        for (a, row) in r.covariance.iter().enumerate() {
            for (b, v) in row.iter().enumerate() {
                cov[(a, b)] = *v;
            }
        }
        Ok(Resection {
            pose: r.pose,
            covariance: cov,
            inliers: r.inliers,
        })
    }
}

/// Film camera of one scan: the certificate plus the scan's fiducial interior orientation.
pub fn film_camera(
    def: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    io: &IoOptions,
) -> Result<(FilmCamera, f64), String> {
    let r = matching::interior_orientation(def, img, name, io).map_err(|e| e.to_string())?;
    Ok((film_from_io(def, img, &r), r.rmse_um))
}

/// Film cameras of one scan: the best fiducial interior orientation first, then, when the
/// fiducial layout is symmetric, every other scan orientation whose marks fit within
/// twice the best RMSE (plus 10 µm).
pub fn film_cameras(
    def: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    io: &IoOptions,
) -> Result<Vec<(FilmCamera, f64)>, String> {
    let r = matching::interior_orientation(def, img, name, io).map_err(|e| e.to_string())?;
    let mut out = vec![(film_from_io(def, img, &r), r.rmse_um)];
    if r.orientation_ambiguous && io.orientation.is_none() {
        for o in matching::ScanOrientation::all() {
            if o == r.orientation {
                continue;
            }
            let forced = IoOptions {
                orientation: Some(o),
                ..io.clone()
            };
            if let Ok(r2) = matching::interior_orientation(def, img, name, &forced) {
                if r2.rmse_um <= 2.0 * r.rmse_um + 10.0 {
                    out.push((film_from_io(def, img, &r2), r2.rmse_um));
                }
            }
        }
    }
    Ok(out)
}

fn film_from_io(def: &CameraDefinition, img: &GreyImage, r: &matching::IoResult) -> FilmCamera {
    let d = &def.distortion;
    FilmCamera {
        width: img.width as u32,
        height: img.height as u32,
        focal_mm: def.focal_mm,
        principal_point_mm: def.principal_point_mm,
        distortion: Brown::from_array([d.k1, d.k2, d.k3, d.p1, d.p2]),
        interior: r.transform.clone(),
    }
}

/// Approximate orientation (block-local) and its 6×6 covariance per photo name.
pub fn approximate_orientations(
    input: &EpochInput,
    dem: &Dem,
    opts: &ArchiveOptions,
) -> Result<BTreeMap<String, (Pose, SMatrix<f64, 6, 6>)>, ArchiveError> {
    let origin = Vector3::from(input.origin);
    let mut out = BTreeMap::new();
    // Navigation may name a photo by file name or stem: key the result by the photo's name.
    let by_key: BTreeMap<&str, &str> = input
        .photos
        .iter()
        .map(|p| (pos_csv::photo_key(&p.name), p.name.as_str()))
        .collect();
    let photo_name = |n: &str| {
        by_key
            .get(pos_csv::photo_key(n))
            .map_or_else(|| n.to_string(), |p| p.to_string())
    };
    match &input.navigation {
        Navigation::Pos(recs) => {
            for r in recs {
                let c = Vector3::from(r.center) - origin;
                let pose = Pose::new(matrix_from_opk(r.opk[0], r.opk[1], r.opk[2]), c);
                let (sc, sa) = opts.pos_sigma_override.unwrap_or((
                    r.sigma_xyz.unwrap_or(10.0),
                    r.sigma_angle.unwrap_or(3f64.to_radians()),
                ));
                out.insert(photo_name(&r.name), (pose, predict::pos_covariance(sc, sa)));
            }
        }
        Navigation::Strips(ss) => {
            let (z0, z1) = dem.z_range();
            let ground = 0.5 * (z0 + z1);
            for s in ss {
                let local = StripEnds {
                    first: (Vector3::from(s.first) - origin).into(),
                    last: (Vector3::from(s.last) - origin).into(),
                    ..s.clone()
                };
                let att = opts.strip_attitude_sigma_deg.to_radians();
                let list = strips::interpolate_strip(&local, 0.05, att).map_err(|e| {
                    ArchiveError::Epoch {
                        epoch: input.name.clone(),
                        message: e.to_string(),
                    }
                })?;
                for (name, (pose, prior)) in s.photos.iter().zip(list) {
                    // The flying height above ground fixes the scale of the prediction; the
                    // end points' heights are as uncertain as their positions.
                    let h = (pose.center.z - ground).abs();
                    let sc = prior.center_sigma[0].max(opts.strip_end_sigma_m);
                    let mut cov = predict::pos_covariance(sc, att);
                    cov[(5, 5)] = (opts.strip_end_sigma_m.max(0.01 * h)).powi(2);
                    out.insert(photo_name(name), (pose, cov));
                }
            }
        }
    }
    Ok(out)
}

/// Per-photo outcome.
#[derive(Debug, Clone, Serialize)]
pub struct PhotoReport {
    pub name: String,
    pub oriented: bool,
    pub reason: Option<String>,
    pub iterations: Vec<IterationRecord>,
    /// Control matches kept by the final resection.
    pub control_matches: usize,
    /// Final σ (px): RMS image residual after the block adjustment, else the resection's.
    pub sigma_px: f64,
    /// Film: RMS of the fiducial interior orientation (µm).
    pub io_rmse_um: Option<f64>,
    /// DCP points predicted inside the photo in the first round.
    pub predicted: usize,
    pub matching: MatchStats,
    /// Oriented only by the relaxed retry (ambiguous first-round matches).
    pub relaxed: bool,
    /// Oriented in the second pass, from the epoch's own oriented photos.
    pub second_pass: bool,
}

/// An oriented epoch.
#[derive(Debug, Clone, Serialize)]
pub struct EpochResult {
    pub epoch: String,
    /// Oriented photos (block-local, `block.origin`), DCP control points with their
    /// observations, after the archive block adjustment.
    #[serde(skip)]
    pub block: Block,
    /// Image file of every photo of the block.
    #[serde(skip)]
    pub images: BTreeMap<PhotoId, PathBuf>,
    pub photos: Vec<PhotoReport>,
    pub adjustment: Option<AdjustReport>,
    /// Mean ground pixel of the oriented photos (m).
    pub gsd_m: f64,
    pub time_s: f64,
}

impl EpochResult {
    pub fn oriented_fraction(&self) -> f64 {
        if self.photos.is_empty() {
            return 0.0;
        }
        self.photos.iter().filter(|p| p.oriented).count() as f64 / self.photos.len() as f64
    }
}

struct PhotoOutcome {
    report: PhotoReport,
    camera: Option<Camera>,
    pose: Pose,
    matches: Vec<(u64, Vector2<f64>, f64)>,
}

fn failed(name: &str, reason: String) -> PhotoOutcome {
    PhotoOutcome {
        report: PhotoReport {
            name: name.to_string(),
            oriented: false,
            reason: Some(reason),
            iterations: Vec::new(),
            control_matches: 0,
            sigma_px: f64::NAN,
            io_rmse_um: None,
            predicted: 0,
            matching: MatchStats::default(),
            relaxed: false,
            second_pass: false,
        },
        camera: None,
        pose: Pose::new(Matrix3::identity(), Vector3::zeros()),
        matches: Vec::new(),
    }
}

/// The polygon pushed outwards from its centroid by `margin` (m): the footprint of an
/// uncertain orientation may be off by the centre σ.
fn grow(poly: &[[f64; 2]], margin: f64) -> Vec<[f64; 2]> {
    let n = poly.len() as f64;
    let c = poly
        .iter()
        .fold([0.0, 0.0], |a, p| [a[0] + p[0] / n, a[1] + p[1] / n]);
    poly.iter()
        .map(|p| {
            let d = [p[0] - c[0], p[1] - c[1]];
            let l = (d[0] * d[0] + d[1] * d[1]).sqrt().max(1e-9);
            [p[0] + d[0] / l * margin, p[1] + d[1] / l * margin]
        })
        .collect()
}

/// Where control patches come from: packages, their spatial index, and chips already in
/// memory (the epoch's own oriented photos, see [`orient_epoch`]'s second pass).
struct ControlSource<'a> {
    packages: &'a [DcpPackage],
    index: &'a DcpIndex,
    preloaded: Option<&'a HashMap<(usize, usize, usize), Pyramid>>,
}

fn orient_one(
    input: &EpochInput,
    photo: &PhotoInput,
    approx: Option<&(Pose, SMatrix<f64, 6, 6>)>,
    src: &ControlSource,
    dem: &Dem,
    opts: &ArchiveOptions,
) -> PhotoOutcome {
    let name = photo.name.as_str();
    let Some((pose0, cov0)) = approx else {
        return failed(
            name,
            "no approximate orientation (not in the navigation)".into(),
        );
    };
    let img = match GreyImage::load(&photo.image) {
        Ok(i) => i,
        Err(e) => return failed(name, format!("image: {e}")),
    };
    // Candidate cameras: one for a frame photo; for a film scan the fiducial interior
    // orientation, plus the other scan orientations that fit the marks equally well when
    // the fiducial layout is symmetric (corner crosses and side dots of many metric
    // cameras): the control patches then decide which one is right.
    let candidates: Vec<(Camera, Option<f64>)> = match &input.camera {
        EpochCamera::Frame(f) => {
            if (f.width as usize, f.height as usize) != (img.width, img.height) {
                return failed(
                    name,
                    format!(
                        "image {} is {}×{} px, the camera {}×{}",
                        photo.image.display(),
                        img.width,
                        img.height,
                        f.width,
                        f.height
                    ),
                );
            }
            vec![(Camera::Frame(f.clone()), None)]
        }
        EpochCamera::Film(def) => match film_cameras(def, &img, name, &opts.io) {
            Ok(v) => v
                .into_iter()
                .map(|(c, r)| (Camera::Film(c), Some(r)))
                .collect(),
            Err(e) => return failed(name, format!("fiducial interior orientation failed: {e}")),
        },
    };
    let pyramid = Pyramid::new(&img, 6, 16);
    let mut best: Option<PhotoOutcome> = None;
    for (camera, io_rmse) in candidates {
        let out = orient_with_camera(
            name, camera, io_rmse, pose0, cov0, src, dem, &pyramid, input, opts,
        );
        let score = |o: &PhotoOutcome| (o.report.oriented, o.report.control_matches);
        // A wrong scan orientation cannot gather many consistent patches: stop early
        // when one clearly works.
        let done = out.report.oriented && out.report.control_matches >= 8;
        if out
            .report
            .reason
            .as_ref()
            .is_some_and(|r| r.starts_with("DCP chip"))
        {
            return out;
        }
        if best.as_ref().is_none_or(|b| score(&out) > score(b)) {
            best = Some(out);
        }
        if done {
            break;
        }
    }
    let best = best.unwrap_or_else(|| failed(name, "no camera candidate".into()));
    if best.report.oriented || !opts.relaxed_retry || best.report.predicted == 0 {
        return best;
    }
    // Second chance for a photo whose first round found too few unambiguous patches: take
    // every patch's best correlation peak, however ambiguous, and let the resection's
    // RANSAC find the consistent ones — with a stricter inlier count, since most of the
    // candidates are now wrong.
    let relaxed = ArchiveOptions {
        matching: MatchOptions {
            max_ambiguity: 1.01,
            ncc_threshold: opts.relaxed_ncc_threshold,
            ..opts.matching.clone()
        },
        min_inliers: opts.relaxed_min_inliers,
        relaxed_retry: false,
        ..opts.clone()
    };
    let Some(camera) = best.camera.clone() else {
        return best;
    };
    let retry = orient_with_camera(
        name,
        camera,
        best.report.io_rmse_um,
        pose0,
        cov0,
        src,
        dem,
        &pyramid,
        input,
        &relaxed,
    );
    if retry.report.oriented {
        let mut r = retry;
        r.report.relaxed = true;
        r
    } else {
        best
    }
}

#[allow(clippy::too_many_arguments)]
fn orient_with_camera(
    name: &str,
    camera: Camera,
    io_rmse: Option<f64>,
    pose0: &Pose,
    cov0: &SMatrix<f64, 6, 6>,
    src: &ControlSource,
    dem: &Dem,
    pyramid: &Pyramid,
    input: &EpochInput,
    opts: &ArchiveOptions,
) -> PhotoOutcome {
    let (packages, index) = (src.packages, src.index);
    let origin = Vector3::from(input.origin);
    let fp = match predict::footprint(&camera, pose0, dem, 8) {
        Ok(f) => f,
        Err(e) => return failed(name, format!("footprint: {e}")),
    };
    let margin = 3.0 * cov0[(3, 3)].max(cov0[(4, 4)]).sqrt();
    let patches: Vec<ControlPatch> = index
        // The index holds world coordinates.
        .query_polygon(
            &grow(&fp, margin)
                .iter()
                .map(|p| [p[0] + origin.x, p[1] + origin.y])
                .collect::<Vec<_>>(),
        )
        .into_iter()
        .map(|(k, i)| {
            let p = &packages[k].manifest.points[i];
            let s = p.sigma;
            ControlPatch {
                id: patch_id(k, i),
                position: Vector3::from(p.xyz) - origin,
                covariance: Matrix3::from_diagonal(&Vector3::new(
                    s[0] * s[0],
                    s[1] * s[1],
                    s[2] * s[2],
                )),
            }
        })
        .collect();
    let mut matcher = DcpPatchMatcher::new(&camera, pyramid, packages, origin, opts);
    if let Some(pre) = src.preloaded {
        matcher.preload(pre);
    }
    let mut resector = AdjustResector::new(opts);
    let o = orient::orient_photo(
        &camera,
        pose0,
        cov0,
        &patches,
        &mut matcher,
        &mut resector,
        &opts.orient,
    );
    let predicted = o.iterations.first().map_or(0, |r| r.predicted);
    let reason = if let Some(e) = &matcher.chip_error {
        Some(format!("DCP chip unusable: {e}"))
    } else if o.oriented {
        None
    } else if predicted == 0 {
        Some(format!(
            "no DCP control point predicted inside the photo ({} in the footprint)",
            patches.len()
        ))
    } else {
        let best = o.iterations.iter().map(|r| r.matched).max().unwrap_or(0);
        Some(format!(
            "{best} of {predicted} control patches matched; a resection with at least {} inliers \
             was not possible",
            opts.min_inliers
        ))
    };
    let oriented = o.oriented && matcher.chip_error.is_none();
    PhotoOutcome {
        report: PhotoReport {
            name: name.to_string(),
            oriented,
            reason,
            iterations: o.iterations.clone(),
            control_matches: o.matches.len(),
            sigma_px: resector.last_rmse_px,
            io_rmse_um: io_rmse,
            predicted,
            matching: matcher.stats.clone(),
            relaxed: false,
            second_pass: false,
        },
        camera: Some(camera),
        pose: o.pose,
        matches: if oriented { o.matches } else { Vec::new() },
    }
}

fn dcp_photo(
    id: u32,
    name: &str,
    camera: &Camera,
    pose: &Pose,
    origin: &Vector3<f64>,
    date: &Option<String>,
) -> super::dcp::DcpPhoto {
    let r = pose.rotation;
    let c = pose.center + origin;
    super::dcp::DcpPhoto {
        id,
        name: name.to_string(),
        camera: camera.clone(),
        rotation: [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
        ],
        center: [c.x, c.y, c.z],
        date: date.clone(),
    }
}

/// A tie point among the epoch's photos: approximate position (block-local, on the DEM)
/// and its image observations (photo index, pixel, σ).
type TieTrack = (Vector3<f64>, Vec<(usize, Vector2<f64>, f64)>);

/// Tie points among the oriented photos of the epoch: Förstner points of each photo, put
/// on the DEM through their ray, predicted in every other oriented photo and matched
/// there with the same alignment, NCC and LSM as the control patches (the chip is cut
/// from the source photo). Points off the DEM (roofs, trees) are still true
/// correspondences; the block adjustment intersects them anew.
fn epoch_ties(
    input: &EpochInput,
    outcomes: &[PhotoOutcome],
    dem: &Dem,
    opts: &ArchiveOptions,
) -> Vec<TieTrack> {
    let origin = Vector3::from(input.origin);
    let oriented: Vec<usize> = (0..outcomes.len())
        .filter(|&n| outcomes[n].report.oriented && outcomes[n].camera.is_some())
        .collect();
    if oriented.len() < 2 || !opts.ties {
        return Vec::new();
    }
    let mut images: BTreeMap<usize, (GreyImage, Pyramid)> = BTreeMap::new();
    for &n in &oriented {
        if let Ok(img) = GreyImage::load(&input.photos[n].image) {
            let pyr = Pyramid::new(&img, 6, 16);
            images.insert(n, (img, pyr));
        }
    }
    let mut m = super::dcp::Manifest::new(
        &input.crs,
        EpochInfo {
            name: input.name.clone(),
            date: input.date.clone(),
        },
        "tie points of the epoch",
        1.0,
        Accuracy {
            plan_m: 1.0,
            height_m: 1.0,
        },
    );
    let half = opts.template_half as i64 + 8;
    let size = (2 * half + 1) as usize;
    let mut chips = HashMap::new();
    let mut sources: Vec<(usize, Vector2<f64>)> = Vec::new();
    for &a in &oriented {
        let (Some((img, _)), Some(cam)) = (images.get(&a), &outcomes[a].camera) else {
            continue;
        };
        let pose = &outcomes[a].pose;
        m.photos.push(dcp_photo(
            a as u32 + 1,
            &input.photos[a].name,
            cam,
            pose,
            &origin,
            &input.date,
        ));
        let cell = opts.tie_interval_px.max(16.0);
        let fo = ForstnerOptions {
            grid: (
                ((img.width as f64 / cell).ceil() as usize).max(1),
                ((img.height as f64 / cell).ceil() as usize).max(1),
            ),
            per_cell: 1,
            border: half as usize + 2,
            ..ForstnerOptions::default()
        };
        for ip in forstner(img, &fo) {
            let Ok(ray) = geometry::back_project(cam, pose, [ip.x, ip.y]) else {
                continue;
            };
            let Ok(x) = dem.intersect(&ray) else {
                continue;
            };
            let (x0, y0) = (ip.x.floor() as i64 - half, ip.y.floor() as i64 - half);
            let Ok(crop) = img.crop(x0.max(0) as usize, y0.max(0) as usize, size, size) else {
                continue;
            };
            if x0 < 0 || y0 < 0 {
                continue;
            }
            let i = m.points.len();
            chips.insert((0, i, 0), Pyramid::new(&crop, 5, 8));
            let w = x + origin;
            m.points.push(super::dcp::DcpPoint {
                id: i as u64 + 1,
                name: format!("tie{}", i + 1),
                xyz: [w.x, w.y, w.z],
                sigma: [1.0, 1.0, 1.0],
                normal: Some([0.0, 0.0, 1.0]),
                quality: Default::default(),
                measurements: vec![super::dcp::DcpMeasurement {
                    photo: a as u32 + 1,
                    pixel: [ip.x, ip.y],
                    chip: super::dcp::ChipRef {
                        file: format!("memory/tie_{a}_{i}"),
                        x0: x0 as u32,
                        y0: y0 as u32,
                        width: size as u32,
                        height: size as u32,
                    },
                }],
            });
            sources.push((a, Vector2::new(ip.x, ip.y)));
        }
    }
    if m.points.is_empty() {
        return Vec::new();
    }
    let pkgs = [DcpPackage {
        dir: PathBuf::from(format!("(epoch {} tie points in memory)", input.name)),
        manifest: m,
    }];
    // Same epoch, same scene: a tie must correlate clearly and unambiguously, there is no
    // resection behind it to catch a mismatch.
    let tie_opts = ArchiveOptions {
        matching: MatchOptions {
            ncc_threshold: opts.tie_ncc_threshold,
            max_ambiguity: 0.8,
            ..opts.matching.clone()
        },
        template_half: opts.template_half.min(15),
        ..opts.clone()
    };
    // Every oriented photo looks for the points of all the others.
    // (point, photo, pixel, σ) per searching photo.
    type TieMatch = (usize, usize, Vector2<f64>, f64);
    let found: Vec<Vec<TieMatch>> = oriented
        .par_iter()
        .filter_map(|&b| {
            let (_, pyr) = images.get(&b)?;
            let cam = outcomes[b].camera.as_ref()?;
            let pose = &outcomes[b].pose;
            let (w, h) = cam.image_size();
            let mut matcher = DcpPatchMatcher::new(cam, pyr, &pkgs, origin, &tie_opts);
            matcher.preload(&chips);
            let mut out = Vec::new();
            for (i, p) in pkgs[0].manifest.points.iter().enumerate() {
                if sources[i].0 == b {
                    continue;
                }
                let x = Vector3::from(p.xyz) - origin;
                let Ok(px) = geometry::project(cam, pose, &x) else {
                    continue;
                };
                let px = px.pixel;
                let margin = opts.tie_window_px + opts.template_half as f64 + 1.0;
                if px.x < margin
                    || px.y < margin
                    || px.x > w as f64 - margin
                    || px.y > h as f64 - margin
                {
                    continue;
                }
                let pred = Prediction {
                    pixel: px,
                    covariance: nalgebra::Matrix2::identity(),
                };
                let patch = ControlPatch {
                    id: patch_id(0, i),
                    position: x,
                    covariance: Matrix3::zeros(),
                };
                if let Some(mt) = matcher.find(
                    &patch,
                    pose,
                    &pred,
                    [opts.tie_window_px, opts.tie_window_px],
                ) {
                    out.push((i, b, mt.pixel, mt.sigma_px.max(opts.sigma_floor_px)));
                }
            }
            Some(out)
        })
        .collect();
    let mut tracks: BTreeMap<usize, TieTrack> = BTreeMap::new();
    for (i, b, px, s) in found.into_iter().flatten() {
        let t = tracks.entry(i).or_insert_with(|| {
            let p = &pkgs[0].manifest.points[i];
            (
                Vector3::from(p.xyz) - origin,
                vec![(sources[i].0, sources[i].1, opts.sigma_floor_px)],
            )
        });
        t.1.push((b, px, s));
    }
    tracks.into_values().collect()
}

/// An in-memory package of the control points matched in the epoch's oriented photos,
/// with chips cut from those photos; also the original patch id of each of its points.
type EpochPackage = (
    DcpPackage,
    HashMap<(usize, usize, usize), Pyramid>,
    Vec<u64>,
);

fn epoch_package(
    input: &EpochInput,
    outcomes: &[PhotoOutcome],
    dcp: &[DcpPackage],
    opts: &ArchiveOptions,
) -> Option<EpochPackage> {
    let origin = Vector3::from(input.origin);
    let mut seen: BTreeMap<u64, Vec<(usize, Vector2<f64>)>> = BTreeMap::new();
    for (n, o) in outcomes
        .iter()
        .enumerate()
        .filter(|(_, o)| o.report.oriented)
    {
        for (id, px, _) in &o.matches {
            seen.entry(*id).or_default().push((n, *px));
        }
    }
    if seen.is_empty() {
        return None;
    }
    let first = &dcp.first()?.manifest;
    let mut m = super::dcp::Manifest::new(
        &input.crs,
        EpochInfo {
            name: input.name.clone(),
            date: input.date.clone(),
        },
        "control points matched in the epoch's own oriented photos",
        first.gsd_m,
        first.accuracy,
    );
    let mut images: BTreeMap<usize, GreyImage> = BTreeMap::new();
    for (n, o) in outcomes
        .iter()
        .enumerate()
        .filter(|(_, o)| o.report.oriented)
    {
        let (Some(cam), Ok(img)) = (&o.camera, GreyImage::load(&input.photos[n].image)) else {
            continue;
        };
        let r = o.pose.rotation;
        let c = o.pose.center + origin;
        m.photos.push(super::dcp::DcpPhoto {
            id: n as u32 + 1,
            name: input.photos[n].name.clone(),
            camera: cam.clone(),
            rotation: [
                r[(0, 0)],
                r[(0, 1)],
                r[(0, 2)],
                r[(1, 0)],
                r[(1, 1)],
                r[(1, 2)],
                r[(2, 0)],
                r[(2, 1)],
                r[(2, 2)],
            ],
            center: [c.x, c.y, c.z],
            date: input.date.clone(),
        });
        images.insert(n, img);
    }
    // Same epoch, similar scale: the chip needs little more than the largest template.
    let half = opts.template_half as i64 + 8;
    let size = (2 * half + 1) as usize;
    let mut chips = HashMap::new();
    let mut original = Vec::new();
    for (id, list) in seen {
        let (k, i) = patch_index(id);
        let Some(p) = dcp.get(k).and_then(|d| d.manifest.points.get(i)) else {
            continue;
        };
        let point_index = m.points.len();
        let mut measurements = Vec::new();
        for (n, px) in list {
            let Some(img) = images.get(&n) else { continue };
            let (x0, y0) = (px.x.floor() as i64 - half, px.y.floor() as i64 - half);
            if x0 < 0 || y0 < 0 {
                continue;
            }
            let Ok(crop) = img.crop(x0 as usize, y0 as usize, size, size) else {
                continue;
            };
            chips.insert(
                (0, point_index, measurements.len()),
                Pyramid::new(&crop, 5, 8),
            );
            measurements.push(super::dcp::DcpMeasurement {
                photo: n as u32 + 1,
                pixel: [px.x, px.y],
                chip: super::dcp::ChipRef {
                    file: format!("memory/{id}_{n}"),
                    x0: x0 as u32,
                    y0: y0 as u32,
                    width: size as u32,
                    height: size as u32,
                },
            });
        }
        if measurements.is_empty() {
            continue;
        }
        m.points.push(super::dcp::DcpPoint {
            id: point_index as u64 + 1,
            measurements,
            ..p.clone()
        });
        original.push(id);
    }
    if m.points.is_empty() {
        return None;
    }
    Some((
        DcpPackage {
            dir: PathBuf::from(format!("(epoch {} in memory)", input.name)),
            manifest: m,
        },
        chips,
        original,
    ))
}

/// Orients an archive epoch from DCP packages over a DEM (block-local coordinates with the
/// epoch's origin): per-photo iterative orientation, then the robust archive block
/// adjustment of all oriented photos with the DCP control (object σ from the packages).
pub fn orient_epoch(
    input: &EpochInput,
    dcp: &[DcpPackage],
    dem: &Dem,
    opts: &ArchiveOptions,
) -> Result<EpochResult, ArchiveError> {
    let t0 = Instant::now();
    let ep = |message: String| ArchiveError::Epoch {
        epoch: input.name.clone(),
        message,
    };
    if dcp.is_empty() {
        return Err(ep("no DCP package given".into()));
    }
    if input.photos.is_empty() {
        return Err(ep("no photo given".into()));
    }
    let crs = Crs::parse(&input.crs).map_err(|e| ep(format!("CRS: {e}")))?;
    for p in dcp {
        let c = Crs::parse(&p.manifest.crs).map_err(|e| ep(e.to_string()))?;
        if c.label() != crs.label() {
            return Err(ep(format!(
                "DCP package {} is in {}, the epoch in {}",
                p.dir.display(),
                c.label(),
                crs.label()
            )));
        }
    }
    let index = DcpIndex::new(dcp);
    let approx = approximate_orientations(input, dem, opts)?;
    let outcomes: Vec<PhotoOutcome> = input
        .photos
        .par_iter()
        .map(|ph| {
            let src = ControlSource {
                packages: dcp,
                index: &index,
                preloaded: None,
            };
            orient_one(input, ph, approx.get(&ph.name), &src, dem, opts)
        })
        .collect();
    if let Some(e) = outcomes.iter().find_map(|o| {
        o.report
            .reason
            .as_ref()
            .filter(|r| r.starts_with("DCP chip"))
    }) {
        return Err(ep(e.clone()));
    }

    // Second pass: photos left unoriented (scene change, ambiguity) try again with the
    // control points as the epoch's own oriented photos show them — same scene state,
    // same radiometry, similar scale — with chips cut from those photos.
    let mut outcomes = outcomes;
    let unoriented: Vec<usize> = (0..outcomes.len())
        .filter(|&i| !outcomes[i].report.oriented)
        .collect();
    if opts.epoch_second_pass
        && !unoriented.is_empty()
        && outcomes.iter().any(|o| o.report.oriented)
    {
        if let Some((pkg, chips, original)) = epoch_package(input, &outcomes, dcp, opts) {
            let pkgs = [pkg];
            let idx = DcpIndex::new(&pkgs);
            let retried: Vec<(usize, PhotoOutcome)> = unoriented
                .par_iter()
                .map(|&i| {
                    let src = ControlSource {
                        packages: &pkgs,
                        index: &idx,
                        preloaded: Some(&chips),
                    };
                    let ph = &input.photos[i];
                    (
                        i,
                        orient_one(input, ph, approx.get(&ph.name), &src, dem, opts),
                    )
                })
                .collect();
            for (i, mut o) in retried {
                if o.report.oriented {
                    for m in &mut o.matches {
                        m.0 = original[patch_index(m.0).1];
                    }
                    o.report.second_pass = true;
                    outcomes[i] = o;
                } else if let (Some(first), Some(second)) =
                    (&outcomes[i].report.reason, &o.report.reason)
                {
                    outcomes[i].report.reason = Some(format!(
                        "{first}; with the epoch's own oriented photos as control: {second}"
                    ));
                }
            }
        }
    }

    // The archive block: oriented photos, DCP control points with all their matches.
    let mut block = Block {
        crs: Some(input.crs.clone()),
        origin: input.origin,
        ..Block::default()
    };
    let mut images = BTreeMap::new();
    let free: Vec<String> = match &input.camera {
        EpochCamera::Frame(_) => opts.self_calibration.clone(),
        EpochCamera::Film(_) => Vec::new(),
    };
    let mut control: BTreeMap<u64, Vec<Observation>> = BTreeMap::new();
    for (n, (o, ph)) in outcomes.iter().zip(&input.photos).enumerate() {
        let (true, Some(cam)) = (o.report.oriented, &o.camera) else {
            continue;
        };
        let pid = n as PhotoId + 1;
        // Film scans each have their own interior orientation; frame photos share one.
        let cid = match cam {
            Camera::Film(_) => pid,
            Camera::Frame(_) => 1,
        };
        block.cameras.entry(cid).or_insert_with(|| BlockCamera {
            id: cid,
            name: format!("{}_{cid}", input.name),
            model: cam.clone(),
            free_params: free.clone(),
        });
        block.photos.insert(
            pid,
            Photo {
                id: pid,
                name: ph.name.clone(),
                camera: cid,
                pose: o.pose,
                oriented: true,
                prior: None,
                date: input.date.clone(),
            },
        );
        images.insert(pid, ph.image.clone());
        for (id, px, s) in &o.matches {
            control.entry(*id).or_default().push(Observation {
                photo: pid,
                pixel: [px.x, px.y],
                sigma_px: s.max(opts.sigma_floor_px),
                provenance: "dcp".into(),
            });
        }
    }
    let origin = Vector3::from(input.origin);
    for (id, obs) in control {
        let (k, i) = patch_index(id);
        let p = &dcp[k].manifest.points[i];
        block.points.insert(
            id,
            ObjectPoint {
                id,
                name: format!("{}:{}", dcp[k].manifest.epoch.name, p.name),
                kind: PointKind::Control,
                position: Vector3::from(p.xyz) - origin,
                sigma: Some(p.sigma),
                color: [0; 3],
                observations: obs,
            },
        );
    }
    let n_ties = {
        let ties = epoch_ties(input, &outcomes, dem, opts);
        let mut next: u64 = 1 << 48;
        for (x, obs) in &ties {
            next += 1;
            block.points.insert(
                next,
                ObjectPoint {
                    id: next,
                    name: String::new(),
                    kind: PointKind::Tie,
                    position: *x,
                    sigma: None,
                    color: [0; 3],
                    observations: obs
                        .iter()
                        .map(|(n, px, s)| Observation {
                            photo: *n as PhotoId + 1,
                            pixel: [px.x, px.y],
                            sigma_px: *s,
                            provenance: "tie".into(),
                        })
                        .collect(),
                },
            );
        }
        ties.len()
    };
    tracing::info!(
        epoch = input.name,
        ties = n_ties,
        "tie points among the epoch's photos"
    );
    let mut photos: Vec<PhotoReport> = outcomes.into_iter().map(|o| o.report).collect();
    // A single oriented photo keeps its resection: there is nothing to adjust jointly.
    let adjustment = if block.photos.len() < 2 {
        None
    } else {
        // Self-calibration needs more observations than a handful per photo.
        let n_obs = block.num_observations();
        if n_obs < 12 * block.photos.len().max(1) {
            for c in block.cameras.values_mut() {
                c.free_params.clear();
            }
        }
        let aopts = AdjustOptions {
            loss: opts.loss,
            rejection: Rejection::Threshold(opts.reject_k),
            max_rounds: 20,
            ..AdjustOptions::default()
        };
        let rep = adjust::adjust(&mut block, &[], None, &aopts).map_err(|source| {
            ArchiveError::Adjust {
                epoch: input.name.clone(),
                source,
            }
        })?;
        for pr in &rep.photo_precision {
            if let Some(r) = photos.iter_mut().find(|r| r.name == pr.name) {
                r.sigma_px = pr.rmse_px;
            }
        }
        Some(rep)
    };
    let gsd_m = mean_gsd(&block, dem);
    Ok(EpochResult {
        epoch: input.name.clone(),
        block,
        images,
        photos,
        adjustment,
        gsd_m,
        time_s: t0.elapsed().as_secs_f64(),
    })
}

/// Mean ground pixel (m) of a block's photos over a DEM: flying height above the ground
/// under the projection centre over the focal length in pixels.
pub fn mean_gsd(block: &Block, dem: &Dem) -> f64 {
    let (z0, z1) = dem.z_range();
    let v: Vec<f64> = block
        .photos
        .values()
        .filter_map(|p| {
            let cam = &block.cameras.get(&p.camera)?.model;
            let g = dem
                .height_at(p.pose.center.x, p.pose.center.y)
                .unwrap_or(0.5 * (z0 + z1));
            Some((p.pose.center.z - g).abs() / cam.focal_px())
        })
        .collect();
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

// ---------------------------------------------------------------------------------------
// Checkpoint evaluation.

/// An operator's measurement of a checkpoint in a photo.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointMeasurement {
    pub photo: String,
    pub id: String,
    pub pixel: [f64; 2],
}

/// A surveyed checkpoint (world coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyedPoint {
    pub id: String,
    pub xyz: [f64; 3],
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CheckpointError {
    pub id: String,
    /// Intersected minus surveyed (m).
    pub error: [f64; 3],
    pub rays: usize,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CheckpointEvaluation {
    pub count: usize,
    pub rmse_plan_m: f64,
    pub rmse_height_m: f64,
    pub max_m: f64,
    pub gsd_m: f64,
    pub rmse_plan_px: f64,
    pub rmse_height_px: f64,
    pub max_px: f64,
    pub points: Vec<CheckpointError>,
}

/// Reads surveyed checkpoints (world), a control-point CSV `id,x,y,z,sigma_xy,sigma_z[,kind]`
/// ([`crate::formats::control_points::read_points`]).
pub fn read_checkpoints(path: &Path) -> Result<Vec<SurveyedPoint>, ArchiveError> {
    let points = crate::formats::control_points::read_points(path)
        .map_err(|e| input_err(path, e.detail()))?;
    Ok(points
        .into_iter()
        .map(|p| SurveyedPoint {
            id: p.id,
            xyz: p.xyz,
        })
        .collect())
}

/// Reads `epoch,photo,id,col,row` checkpoint image measurements of one epoch
/// ([`crate::formats::control_points::read_checkpoint_measurements`]); photos are named by
/// their key (stem), as the epoch's photos.
pub fn read_checkpoint_images(
    path: &Path,
    epoch: &str,
) -> Result<Vec<CheckpointMeasurement>, ArchiveError> {
    let meas = crate::formats::control_points::read_checkpoint_measurements(path, epoch)
        .map_err(|e| input_err(path, e.detail()))?;
    Ok(meas
        .into_iter()
        .map(|m| CheckpointMeasurement {
            photo: pos_csv::photo_key(&m.photo).to_string(),
            id: m.id,
            pixel: m.pixel,
        })
        .collect())
}

/// Intersects every checkpoint measured in at least two oriented photos of `block` (least
/// squares on the reprojection error with the full camera model) and compares it with its
/// surveyed coordinates; errors are also given in ground pixels of `gsd_m`.
pub fn evaluate_checkpoints(
    block: &Block,
    measurements: &[CheckpointMeasurement],
    surveyed: &[SurveyedPoint],
    gsd_m: f64,
) -> Result<CheckpointEvaluation, String> {
    if !(gsd_m.is_finite() && gsd_m > 0.0) {
        return Err(format!("ground pixel {gsd_m} must be positive"));
    }
    let by_name: BTreeMap<&str, &Photo> = block
        .photos
        .values()
        .filter(|p| p.oriented)
        .map(|p| (p.name.as_str(), p))
        .collect();
    let origin = Vector3::from(block.origin);
    let mut points = Vec::new();
    for sp in surveyed {
        let rays: Vec<(&Camera, &Pose, [f64; 2], f64)> = measurements
            .iter()
            .filter(|m| m.id == sp.id)
            .filter_map(|m| {
                let ph = by_name.get(m.photo.as_str())?;
                let cam = &block.cameras.get(&ph.camera)?.model;
                Some((cam, &ph.pose, m.pixel, 1.0))
            })
            .collect();
        let Some(x) = adjust::intersect(&rays) else {
            continue;
        };
        let e = x + origin - Vector3::from(sp.xyz);
        points.push(CheckpointError {
            id: sp.id.clone(),
            error: [e.x, e.y, e.z],
            rays: rays.len(),
        });
    }
    if points.is_empty() {
        return Err("no checkpoint is measured in two or more oriented photos".into());
    }
    let n = points.len() as f64;
    let plan = (points
        .iter()
        .map(|p| p.error[0].powi(2) + p.error[1].powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let height = (points.iter().map(|p| p.error[2].powi(2)).sum::<f64>() / n).sqrt();
    let max = points
        .iter()
        .map(|p| Vector3::from(p.error).norm())
        .fold(0.0, f64::max);
    Ok(CheckpointEvaluation {
        count: points.len(),
        rmse_plan_m: plan,
        rmse_height_m: height,
        max_m: max,
        gsd_m,
        rmse_plan_px: plan / gsd_m,
        rmse_height_px: height / gsd_m,
        max_px: max / gsd_m,
        points,
    })
}

// ---------------------------------------------------------------------------------------
// DCP export from an oriented block, and the LiDAR control surface.

/// Options of [`select_control_points`] and [`export_dcp`].
#[derive(Debug, Clone)]
pub struct DcpExportOptions {
    pub cloud: CloudOptions,
    /// Chip side (px, odd): large enough to hold a template rescaled to a coarser photo.
    /// It also keeps the points half a chip away from the photo borders.
    pub chip_size: u32,
    pub accuracy: Accuracy,
    pub source: String,
    /// Pyramid level of the reference photos the interest operator runs on (2 = 4×
    /// coarser ground pixel).
    pub interest_level: usize,
}

impl Default for DcpExportOptions {
    fn default() -> Self {
        Self {
            cloud: CloudOptions::default(),
            // The workflow's default (project `thresholds.chip_size_px`), so a package
            // made by hand matches one made by `cloudcontrol run`.
            chip_size: 193,
            accuracy: Accuracy {
                plan_m: 0.05,
                height_m: 0.05,
            },
            source: "photos oriented against LiDAR".into(),
            interest_level: 2,
        }
    }
}

impl DcpExportOptions {
    /// Refuses options that would fail only after every photo was read, or that cannot
    /// select anything.
    pub fn validate(&self) -> Result<(), String> {
        let c = &self.cloud;
        if !(c.interval_px.is_finite() && c.interval_px >= 1.0 && c.interval_px <= 1000.0) {
            return Err(format!(
                "interval_px {} is outside [1, 1000]",
                c.interval_px
            ));
        }
        if !(c.max_coplanarity.is_finite() && c.max_coplanarity > 0.0) {
            return Err(format!(
                "max_coplanarity {} must be positive",
                c.max_coplanarity
            ));
        }
        if c.min_photos == 0 {
            return Err("min_photos must be at least 1".into());
        }
        if self.chip_size < 9 || self.chip_size % 2 == 0 {
            return Err(format!(
                "chip_size {} must be odd and at least 9 (the point sits on the centre pixel)",
                self.chip_size
            ));
        }
        if self.interest_level > 8 {
            return Err(format!(
                "interest_level {} is above 8 (256× coarser than the photos)",
                self.interest_level
            ));
        }
        for (name, v) in [
            ("accuracy plan_m", self.accuracy.plan_m),
            ("accuracy height_m", self.accuracy.height_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} {v} must be positive"));
            }
        }
        Ok(())
    }
}

/// The cloud control points of an oriented block (`cloudcontrol dcp generate`): what
/// [`export_dcp`] writes into a package, without the chips.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlPointSet {
    pub crs: String,
    /// Mean ground pixel of the photos the points were picked in (m).
    pub gsd_m: f64,
    pub accuracy: Accuracy,
    pub points: Vec<ControlPointRecord>,
}

/// Selects cloud control points in an oriented block: Förstner candidates at the scale of
/// pyramid level `interest_level`, one per `interval_px` cell, on planar and stable
/// ground of `surface`, measured in every oriented photo with an image that sees them.
pub fn select_control_points(
    block: &Block,
    images: &BTreeMap<PhotoId, PathBuf>,
    surface: &dyn ControlSurface,
    opts: &DcpExportOptions,
) -> Result<ControlPointSet, ArchiveError> {
    opts.validate()
        .map_err(|m| ArchiveError::Block(format!("options: {m}")))?;
    block
        .validate()
        .map_err(|e| ArchiveError::Block(e.to_string()))?;
    let crs = block
        .crs
        .clone()
        .ok_or_else(|| ArchiveError::Block("has no CRS".into()))?;
    // Photos that are not oriented or have no image would give measurements nobody can
    // cut a chip from or trust: the selection sees the others only.
    let mut seen = Block {
        crs: block.crs.clone(),
        origin: block.origin,
        cameras: block.cameras.clone(),
        ..Block::default()
    };
    let mut interest = BTreeMap::new();
    let mut gsd = Vec::new();
    for (&pid, path) in images {
        let Some(ph) = block.photos.get(&pid).filter(|p| p.oriented) else {
            continue;
        };
        let cam = &block.cameras[&ph.camera].model;
        let full = GreyImage::load(path).map_err(|e| input_err(path, e.to_string()))?;
        let (w, h) = cam.image_size();
        // The border below keeps chips inside photos of the camera's size only.
        if (full.width, full.height) != (w as usize, h as usize) {
            return Err(input_err(
                path,
                format!(
                    "is {}×{} pixels, the camera of photo {pid} ({}) is {w}×{h}",
                    full.width, full.height, ph.name
                ),
            ));
        }
        // Interest is taken at the scale of the coarser archive photos the package is
        // for: fine texture (crop rows, tiles) that is distinct at the reference scale
        // aliases into ambiguous patterns there, while corners of parcels and roads stay.
        let pyr = Pyramid::new(&full, opts.interest_level + 1, 32);
        let level = pyr.levels.len() - 1;
        let f = (1usize << level) as f64;
        let img = &pyr.levels[level];
        let cell = (opts.cloud.interval_px / f).max(4.0);
        let fo = ForstnerOptions {
            grid: (
                ((img.width as f64 / cell).ceil() as usize).max(1),
                ((img.height as f64 / cell).ceil() as usize).max(1),
            ),
            per_cell: 8,
            border: ((opts.chip_size / 2 + 2) as f64 / f).ceil() as usize,
            ..ForstnerOptions::default()
        };
        let cands: Vec<cloud::Candidate> = forstner(img, &fo)
            .into_iter()
            .map(|p| ([p.x * f, p.y * f], p.w))
            .collect();
        interest.insert(pid, cands);
        gsd.push(ph.pose.center.z.abs() / cam.focal_px());
        seen.photos.insert(pid, ph.clone());
    }
    if seen.photos.is_empty() {
        return Err(ArchiveError::Block("no oriented photo has an image".into()));
    }
    let cloud_opts = CloudOptions {
        border_px: opts.cloud.border_px.max((opts.chip_size / 2 + 1) as f64),
        ..opts.cloud.clone()
    };
    let points = cloud::select(&seen, surface, &interest, &cloud_opts)
        .map_err(|e| ArchiveError::Block(e.to_string()))?;
    if points.is_empty() {
        return Err(ArchiveError::Block(format!(
            "no cloud control point found in {} photos (no textured, planar, stable ground \
             under the LiDAR)",
            seen.photos.len()
        )));
    }
    Ok(ControlPointSet {
        crs,
        gsd_m: gsd.iter().sum::<f64>() / gsd.len() as f64,
        accuracy: opts.accuracy,
        points: cloud::records(&seen, &points, &opts.accuracy),
    })
}

/// Selects cloud control points in an oriented block ([`select_control_points`]) and
/// writes them with their chips as a DCP package at `out`.
pub fn export_dcp(
    block: &Block,
    images: &BTreeMap<PhotoId, PathBuf>,
    surface: &dyn ControlSurface,
    epoch: EpochInfo,
    out: &Path,
    opts: &DcpExportOptions,
) -> Result<DcpPackage, ArchiveError> {
    let set = select_control_points(block, images, surface, opts)?;
    let info = ExportInfo {
        crs: set.crs.clone(),
        epoch,
        source: opts.source.clone(),
        gsd_m: set.gsd_m,
        accuracy: opts.accuracy,
        chip_size: opts.chip_size,
    };
    // Every chip fits (the selection's border is half a chip and the images have the
    // cameras' size), so the package holds exactly the points of `set`.
    let (m, chips) = cloud::export_records(block, &set.points, &info, |pid| {
        let p = images
            .get(&pid)
            .ok_or_else(|| format!("no image for photo {pid}"))?;
        image::open(p).map_err(|e| format!("{}: {e}", p.display()))
    })
    .map_err(|e| input_err(out, e))?;
    Ok(DcpPackage::write(out, m, &chips)?)
}

/// Cell (m) of the LiDAR ground and surface grids of [`lidar_surfaces`], as the workflow
/// uses.
pub const LIDAR_CELL_M: f64 = 1.0;

/// An oriented block as the workflow writes each epoch — `block.json` (the [`Block`]) and
/// `images.json` (photo id → image path) — with the control surface of its LiDAR: the
/// input of `cloudcontrol dcp generate|export`, `ccp_dcp_export` and the Python binding.
pub struct OrientedBlock {
    /// The `block.json` the block was read from (errors name it).
    pub block_json: PathBuf,
    pub block: Block,
    pub images: BTreeMap<PhotoId, PathBuf>,
    pub surface: GroundSurface,
}

impl OrientedBlock {
    /// Reads the two JSON files and builds the control surface from LAS/LAZ files or
    /// folders of them (grid cell `lidar_cell_m`, e.g. [`LIDAR_CELL_M`]).
    pub fn load(
        block_json: &Path,
        images_json: &Path,
        lidar: &[PathBuf],
        lidar_cell_m: f64,
    ) -> Result<Self, ArchiveError> {
        if !(lidar_cell_m.is_finite() && lidar_cell_m > 0.0) {
            return Err(ArchiveError::Block(format!(
                "LiDAR grid cell {lidar_cell_m} m must be positive"
            )));
        }
        let (block, images) = read_oriented_block(block_json, images_json)?;
        let tiles = crate::lidar::catalogue::expand_inputs(lidar)?;
        let surface = lidar_surfaces(&tiles, block.origin, lidar_cell_m)?;
        Ok(Self {
            block_json: block_json.to_path_buf(),
            block,
            images,
            surface,
        })
    }

    fn named(&self, e: ArchiveError) -> ArchiveError {
        match e {
            ArchiveError::Block(m) => input_err(&self.block_json, m),
            e => e,
        }
    }

    /// The control points a package of this block would hold ([`select_control_points`]).
    pub fn select(&self, opts: &DcpExportOptions) -> Result<ControlPointSet, ArchiveError> {
        select_control_points(&self.block, &self.images, &self.surface, opts)
            .map_err(|e| self.named(e))
    }

    /// Writes the DCP package of this block at `out` ([`export_dcp`]).
    pub fn export(
        &self,
        epoch: EpochInfo,
        out: &Path,
        opts: &DcpExportOptions,
    ) -> Result<DcpPackage, ArchiveError> {
        export_dcp(&self.block, &self.images, &self.surface, epoch, out, opts)
            .map_err(|e| self.named(e))
    }
}

/// Reads an oriented block's `block.json` and `images.json`. An image path that is
/// relative is taken from the working directory, as the workflow writes it, and else
/// from the folder of `images.json` (a moved project). Every oriented photo needs an
/// existing image, and every image a photo of the block.
pub fn read_oriented_block(
    block_json: &Path,
    images_json: &Path,
) -> Result<(Block, BTreeMap<PhotoId, PathBuf>), ArchiveError> {
    let block: Block = serde_json::from_value(read_json(block_json)?)
        .map_err(|e| input_err(block_json, e.to_string()))?;
    block
        .validate()
        .map_err(|e| input_err(block_json, e.to_string()))?;
    if block.crs.is_none() {
        return Err(input_err(
            block_json,
            "the block has no CRS (a DCP package needs a projected one)",
        ));
    }
    let listed: BTreeMap<PhotoId, PathBuf> = serde_json::from_value(read_json(images_json)?)
        .map_err(|e| {
            input_err(
                images_json,
                format!("{e} (expected an object of photo id → image path)"),
            )
        })?;
    let base = images_json.parent().unwrap_or(Path::new(""));
    let mut images = BTreeMap::new();
    for (pid, path) in listed {
        let Some(photo) = block.photos.get(&pid) else {
            return Err(input_err(
                images_json,
                format!(
                    "photo {pid} is not in {} (a block and its images.json from different epochs?)",
                    block_json.display()
                ),
            ));
        };
        let found = if path.is_relative() && !path.exists() {
            base.join(&path)
        } else {
            path.clone()
        };
        if !found.is_file() {
            if !photo.oriented {
                continue;
            }
            return Err(input_err(
                images_json,
                format!(
                    "image {} of photo {pid} ({}) does not exist",
                    path.display(),
                    photo.name
                ),
            ));
        }
        images.insert(pid, found);
    }
    if let Some(p) = block
        .photos
        .values()
        .find(|p| p.oriented && !images.contains_key(&p.id))
    {
        return Err(input_err(
            images_json,
            format!("no image for oriented photo {} ({})", p.id, p.name),
        ));
    }
    Ok((block, images))
}

/// The epoch name a package takes by default: its folder's name without extension.
pub fn package_epoch_name(out: &Path) -> String {
    out.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "dcp".into())
}

/// Ground DEM and control surface (block-local, origin subtracted) from LAS/LAZ tiles:
/// ground (class 2) gridded with holes filled, a surface model of ground, vegetation and
/// buildings (classes 2–6) to tell bare ground from roofs and canopy.
pub fn lidar_surfaces(
    tiles: &[PathBuf],
    origin: [f64; 3],
    cell: f64,
) -> Result<GroundSurface, ArchiveError> {
    let mut ground = Vec::new();
    let mut all = Vec::new();
    for t in tiles {
        let b = crate::lidar::las::read_points(t, None, Some(&[2, 3, 4, 5, 6]))?;
        for (x, c) in b.xyz.iter().zip(&b.class) {
            let l = [x[0] - origin[0], x[1] - origin[1], x[2] - origin[2]];
            if *c == 2 {
                ground.push(l);
            }
            all.push(l);
        }
    }
    let first = tiles.first().map(|p| p.as_path()).unwrap_or(Path::new("."));
    if ground.is_empty() {
        return Err(input_err(first, "no ground (class 2) LiDAR points"));
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in &all {
        for a in 0..2 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let bbox = crate::lidar::Bbox {
        min_x: lo[0],
        min_y: lo[1],
        max_x: hi[0],
        max_y: hi[1],
    };
    let grid = |pts: &[[f64; 3]], fill: usize| {
        crate::lidar::grid_dem(
            pts,
            &crate::lidar::DemOptions {
                cell,
                max_fill_cells: fill,
                bbox: Some(bbox),
                ..Default::default()
            },
        )
        .map_err(|e| input_err(first, e.to_string()))
    };
    // Buildings leave holes of tens of metres in the ground: fill them generously (the
    // surface model marks them unstable anyway).
    let g = grid(&ground, (60.0 / cell).ceil() as usize)?;
    let s = grid(&all, 2)?;
    Ok(GroundSurface {
        ground: g,
        surface: s,
        max_above_ground_m: 0.3,
        radius_m: 2.0,
    })
}

/// Shifts a world-coordinate DEM into block-local coordinates.
pub fn dem_to_local(dem: &Dem, origin: [f64; 3]) -> Result<Dem, String> {
    let t = dem.transform.0;
    let tr = GeoTransform([t[0] - origin[0], t[1], t[2], t[3] - origin[1], t[4], t[5]]);
    let data = dem
        .data
        .iter()
        .map(|v| (*v as f64 - origin[2]) as f32)
        .collect();
    Dem::new(dem.width, dem.height, tr, data).map_err(|e| e.to_string())
}

/// A POS made from known orientations perturbed by Gaussian noise of σ `center_sigma_m`
/// per centre coordinate and `attitude_sigma_rad` per angle (deterministic in `seed`),
/// stating those σ: approximate orientations of a chosen quality, e.g. the EO groups of
/// seed 001's table 1.3.
pub fn perturbed_navigation(
    block: &Block,
    center_sigma_m: f64,
    attitude_sigma_rad: f64,
    seed: u64,
) -> Navigation {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let nc = Normal::new(0.0, center_sigma_m.max(0.0)).ok();
    let na = Normal::new(0.0, attitude_sigma_rad.max(0.0)).ok();
    let origin = Vector3::from(block.origin);
    let mut recs = Vec::new();
    for p in block.photos.values() {
        let mut draw = |n: &Option<Normal<f64>>| n.map_or(0.0, |d| d.sample(&mut rng));
        let dt = Vector3::new(draw(&na), draw(&na), draw(&na));
        let dc = Vector3::new(draw(&nc), draw(&nc), draw(&nc));
        let q = p.pose.perturbed(&dt, &dc);
        let (o, ph, k) = geometry::opk_from_matrix(&q.rotation);
        let c = q.center + origin;
        recs.push(PosRecord {
            name: p.name.clone(),
            center: [c.x, c.y, c.z],
            opk: [o, ph, k],
            sigma_xyz: Some(center_sigma_m),
            sigma_angle: Some(attitude_sigma_rad),
        });
    }
    Navigation::Pos(recs)
}

// ---------------------------------------------------------------------------------------
// Evaluation helpers for synthetic blocks (they read truth/: evaluation code only).

/// The true orientation of a synthetic epoch as an oriented block (block-local), with its
/// images: used to export reference DCPs "as if oriented against the LiDAR" and to perturb
/// the truth for the EO-group bench.
pub fn synth_truth_block(
    dir: &Path,
    epoch: &str,
) -> Result<(Block, BTreeMap<PhotoId, PathBuf>), ArchiveError> {
    let input = EpochInput::from_synth_epoch(dir, epoch)?;
    let cam_path = dir.join("truth/epochs").join(epoch).join("camera.json");
    let eo_path = dir.join("truth/epochs").join(epoch).join("eo.csv");
    let (header, rows) = csv_rows(&eo_path)?;
    let c = Csv {
        path: &eo_path,
        header: &header,
    };
    let mut block = Block {
        crs: Some(input.crs.clone()),
        origin: input.origin,
        ..Block::default()
    };
    let frame = match &input.camera {
        EpochCamera::Frame(_) => Some(
            serde_json::from_value::<Camera>(read_json(&cam_path)?)
                .map_err(|e| input_err(&cam_path, e.to_string()))?,
        ),
        EpochCamera::Film(_) => None,
    };
    let affine = if frame.is_none() {
        let p = dir.join("truth/epochs").join(epoch).join("scan_affine.csv");
        let (h, rs) = csv_rows(&p)?;
        let cc = Csv {
            path: &p,
            header: &h,
        };
        let mut m = BTreeMap::new();
        for r in &rs {
            let v = |k: &str| cc.num(r, k);
            let io = geometry::InteriorOrientation::new(
                geometry::InteriorTransformKind::Affine,
                Matrix3::new(
                    v("a11")?,
                    v("a12")?,
                    v("a13")?,
                    v("a21")?,
                    v("a22")?,
                    v("a23")?,
                    0.0,
                    0.0,
                    1.0,
                ),
            )
            .map_err(|e| input_err(&p, e.to_string()))?;
            m.insert(cc.text(r, "photo")?.to_string(), io);
        }
        m
    } else {
        BTreeMap::new()
    };
    let origin = Vector3::from(input.origin);
    let mut images = BTreeMap::new();
    for r in &rows {
        let name = c.text(r, "photo")?.to_string();
        let Some(k) = input.photos.iter().position(|p| p.name == name) else {
            continue;
        };
        let pid = k as PhotoId + 1;
        let rot = Matrix3::new(
            c.num(r, "r11")?,
            c.num(r, "r12")?,
            c.num(r, "r13")?,
            c.num(r, "r21")?,
            c.num(r, "r22")?,
            c.num(r, "r23")?,
            c.num(r, "r31")?,
            c.num(r, "r32")?,
            c.num(r, "r33")?,
        );
        let centre = Vector3::new(c.num(r, "x")?, c.num(r, "y")?, c.num(r, "z")?) - origin;
        let (cid, model) = match (&frame, &input.camera) {
            (Some(f), _) => (1, f.clone()),
            (None, camera) => {
                let EpochCamera::Film(def) = camera else {
                    return Err(input_err(&cam_path, "neither a frame nor a film camera"));
                };
                let io = affine
                    .get(&name)
                    .ok_or_else(|| input_err(&eo_path, format!("no scan affine for {name}")))?;
                let img = image::image_dimensions(&input.photos[k].image)
                    .map_err(|e| input_err(&input.photos[k].image, e.to_string()))?;
                let d = &def.distortion;
                (
                    pid,
                    Camera::Film(FilmCamera {
                        width: img.0,
                        height: img.1,
                        focal_mm: def.focal_mm,
                        principal_point_mm: def.principal_point_mm,
                        distortion: Brown::from_array([d.k1, d.k2, d.k3, d.p1, d.p2]),
                        interior: io.clone(),
                    }),
                )
            }
        };
        block.cameras.entry(cid).or_insert_with(|| BlockCamera {
            id: cid,
            name: format!("{epoch}_{cid}"),
            model,
            free_params: Vec::new(),
        });
        block.photos.insert(
            pid,
            Photo {
                id: pid,
                name: name.clone(),
                camera: cid,
                pose: Pose::new(rot, centre),
                oriented: true,
                prior: None,
                date: input.date.clone(),
            },
        );
        images.insert(pid, input.photos[k].image.clone());
    }
    Ok((block, images))
}
