//! `cloudcontrol run`: seed 000's five steps over every epoch of a project, as restartable
//! stages under the project's output folder:
//!
//! 1. `sources` — LiDAR catalogue (CRS, density, dates), cleaning (noise, strip offsets),
//!    evaluation of the LiDAR against the surveyed checkpoints;
//! 2. `epoch-<reference>` — the reference epoch oriented against the LiDAR alone
//!    ([`crate::control::reference`]);
//! 3. `dcp-<epoch>` — each oriented epoch exported as Digital Control Photos;
//! 4. `epoch-<archive>` — each archive epoch, newest first, oriented from the DCPs of all
//!    newer epochs ([`crate::control::archive::orient_epoch`]);
//! 5. `outputs-<epoch>` — COLMAP model, BlocksExchange XML, orthophoto and DEM GeoTIFFs;
//!    `report` — JSON and HTML.
//!
//! A stage's inputs are the files it reads (earlier stages' folders included) and its
//! parameters, so a rerun skips every stage whose inputs are unchanged and redoes the rest.

use super::project::{Epoch, Project, ProjectError};
use super::report::{self, CheckpointError, EpochReport, IcpIteration, OrthoPreview, PhotoSummary};
use super::stages::{Inputs, Runner, StageError};
use crate::adjust::ObservationRef;
use crate::block::{Block, PhotoId};
use crate::control::archive::{
    self, ArchiveOptions, CheckpointEvaluation, DcpExportOptions, EpochCamera, EpochInput,
    EpochResult, Navigation, PhotoInput,
};
use crate::control::cloud::{CloudOptions, GroundSurface};
use crate::control::dcp::{Accuracy, DcpPackage, EpochInfo};
use crate::control::reference::{self, ReferenceOptions};
use crate::formats::crs::Crs;
use crate::formats::pos::FlightAxis;
use crate::formats::{self, write_bytes_atomically};
use crate::geometry::Camera;
use crate::lidar::{self, Catalogue, PlaneIndex, PlaneOptions, ScanOptions, TileStore};
use crate::matching::CameraDefinition;
use serde::{Deserialize, Serialize};
use std::cell::OnceCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Project(#[from] ProjectError),
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error("stopped after stage {0} as asked")]
    Stopped(String),
}

/// What the run reports while it works (the CLI draws progress from it).
#[derive(Debug, Clone)]
pub enum Event {
    Start {
        stage: String,
        index: usize,
        total: usize,
    },
    Done {
        stage: String,
        skipped: bool,
        seconds: f64,
    },
}

/// The outcome of a run.
#[derive(Debug, Clone)]
pub struct RunSummary {
    pub output: PathBuf,
    pub report: report::Report,
    pub ran: Vec<String>,
    pub skipped: Vec<String>,
    /// Product files per epoch (COLMAP folder, XML, GeoTIFFs, DCP package).
    pub products: BTreeMap<String, Vec<PathBuf>>,
}

impl RunSummary {
    /// The machine-readable outcome (CLI `--json`, C ABI, Python): output folder, stages
    /// run and skipped, products per epoch, and the report.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "output": self.output,
            "ran": self.ran,
            "skipped": self.skipped,
            "products": self.products,
            "report": self.report,
        })
    }
}

/// Classes whose LiDAR points give planes for the reference adjustment: ground and
/// buildings (stable, planar, present in the reference photos).
const PLANE_CLASSES: [u8; 2] = [2, 6];
/// DEM cell (m) of the control surface and the output DEM.
const DEM_CELL_M: f64 = 1.0;

/// `sources/origin.json`: the block-local origin shared by every epoch.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Origin {
    origin: [f64; 3],
}

/// Origin of the numerics: the LiDAR's south-west corner rounded down to a kilometre, so
/// local coordinates stay small and the origin reads well.
fn origin_of(cat: &Catalogue) -> [f64; 3] {
    let b = cat.bounds;
    [
        (b[0] / 1000.0).floor() * 1000.0,
        (b[1] / 1000.0).floor() * 1000.0,
        0.0,
    ]
}

fn err(stage: &str) -> impl Fn(String) -> String + '_ {
    move |m| format!("{stage}: {m}")
}

fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<(), String> {
    let bytes = serde_json::to_vec_pretty(v).map_err(|e| e.to_string())?;
    write_bytes_atomically(path, &bytes).map_err(|e| e.to_string())
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

fn first_line(path: &Path) -> Result<String, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(text
        .lines()
        .find(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .unwrap_or("")
        .to_ascii_lowercase())
}

/// The epoch as [`EpochInput`]: photos of its folder, its camera (a frame camera, or a film
/// camera certificate with fiducials), and its POS or strip end points in either
/// documented layout (formats/pos/, or the synthetic block's).
pub fn epoch_input(e: &Epoch, crs: &str, origin: [f64; 3]) -> Result<EpochInput, String> {
    let photos = PhotoInput::from_folder(&e.photos).map_err(|x| x.to_string())?;
    let cam_text = std::fs::read_to_string(&e.camera)
        .map_err(|err| format!("{}: {err}", e.camera.display()))?;
    let cam_json: serde_json::Value = serde_json::from_str(&cam_text)
        .map_err(|err| format!("{}: not JSON: {err}", e.camera.display()))?;
    let camera = if cam_json.get("fiducials").is_some() {
        EpochCamera::Film(
            CameraDefinition::load(&e.camera)
                .map_err(|err| format!("{}: {err}", e.camera.display()))?,
        )
    } else {
        match serde_json::from_value::<Camera>(cam_json)
            .map_err(|err| format!("{}: {err}", e.camera.display()))?
        {
            Camera::Frame(f) => EpochCamera::Frame(f),
            Camera::Film(_) => {
                return Err(format!(
                    "{}: a film camera needs its calibration certificate (fiducials)",
                    e.camera.display()
                ))
            }
        }
    };
    let names: Vec<String> = photos.iter().map(|p| p.name.clone()).collect();
    let navigation = match (&e.pos, &e.strips) {
        (Some(p), _) => {
            let recs = if first_line(p)?.starts_with("photo,") {
                archive::read_synth_pos(p).map_err(|x| x.to_string())?
            } else {
                formats::pos::read_pos(p).map_err(|x| x.to_string())?
            };
            Navigation::Pos(recs)
        }
        (None, Some(s)) => {
            let strips = if first_line(s)?.starts_with("strip,first_photo") {
                archive::read_synth_strips(s, &names, FlightAxis::ImageUp)
                    .map_err(|x| x.to_string())?
            } else {
                formats::pos::read_strips(s, FlightAxis::ImageUp).map_err(|x| x.to_string())?
            };
            Navigation::Strips(strips)
        }
        (None, None) => return Err(format!("epoch {}: neither pos nor strips", e.name)),
    };
    Ok(EpochInput {
        name: e.name.clone(),
        date: Some(e.date.clone()),
        crs: crs.to_string(),
        origin,
        camera,
        photos,
        navigation,
    })
}

/// What the epoch stages need from the cleaned LiDAR, built once per run when first
/// needed (a rerun that skips every epoch stage never reads the LiDAR).
struct LidarControl {
    tiles_dir: PathBuf,
    origin: [f64; 3],
    surface: OnceCell<GroundSurface>,
    planes: OnceCell<PlaneIndex>,
}

impl LidarControl {
    fn surface(&self) -> Result<&GroundSurface, String> {
        if let Some(s) = self.surface.get() {
            return Ok(s);
        }
        let tiles = lidar::catalogue::expand_inputs(std::slice::from_ref(&self.tiles_dir))
            .map_err(|e| e.to_string())?;
        let s =
            archive::lidar_surfaces(&tiles, self.origin, DEM_CELL_M).map_err(|e| e.to_string())?;
        Ok(self.surface.get_or_init(|| s))
    }

    fn planes(&self) -> Result<&PlaneIndex, String> {
        if let Some(p) = self.planes.get() {
            return Ok(p);
        }
        let tiles = lidar::catalogue::expand_inputs(std::slice::from_ref(&self.tiles_dir))
            .map_err(|e| e.to_string())?;
        let p = reference::lidar_plane_index(
            &tiles,
            self.origin,
            &PLANE_CLASSES,
            PlaneOptions::default(),
        )
        .map_err(|e| e.to_string())?;
        Ok(self.planes.get_or_init(|| p))
    }
}

/// `sources/selection.json`: the LiDAR tiles the block needs.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct TileSelection {
    /// World plan extent [x_min, y_min, x_max, y_max] the photos can see.
    pub footprint: [f64; 4],
    pub tiles_total: usize,
    /// Indices into the catalogue of the tiles intersecting the footprint.
    pub selected: Vec<usize>,
}

/// Plan extent every photo of every epoch can see, from the navigation: the projection
/// centres' extent widened by each centre's height above the lowest LiDAR point times
/// `half_view` (tangent of the widest half field of view met in aerial cameras: 230 mm
/// film at 88 mm focal length reaches about 1.85 on the diagonal).
pub fn footprint(centres: &[[f64; 3]], ground_z: f64, half_view: f64) -> Option<[f64; 4]> {
    let mut fp = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for c in centres.iter().filter(|c| c.iter().all(|v| v.is_finite())) {
        let r = (c[2] - ground_z).abs() * half_view;
        fp = [
            fp[0].min(c[0] - r),
            fp[1].min(c[1] - r),
            fp[2].max(c[0] + r),
            fp[3].max(c[1] + r),
        ];
    }
    (fp[0] <= fp[2]).then_some(fp)
}

fn select_tiles(project: &Project, cat: &Catalogue) -> Result<([f64; 4], TileSelection), String> {
    let mut centres = Vec::new();
    for e in std::iter::once(&project.reference).chain(project.archive.iter()) {
        let input = epoch_input(e, &project.crs, [0.0; 3])?;
        match &input.navigation {
            Navigation::Pos(r) => centres.extend(r.iter().map(|r| r.center)),
            Navigation::Strips(s) => centres.extend(s.iter().flat_map(|s| [s.first, s.last])),
        }
    }
    let fp = footprint(&centres, cat.bounds[2], 1.85)
        .ok_or_else(|| "no projection centre in any POS or strip file".to_string())?;
    let selected = cat.tiles_in(&lidar::Bbox::new(fp[0], fp[1], fp[2], fp[3]));
    if selected.is_empty() {
        return Err(format!(
            "no LiDAR tile lies under the photos (footprint {fp:?}, LiDAR bounds {:?}): wrong CRS or wrong tiles?",
            cat.bounds
        ));
    }
    Ok((
        fp,
        TileSelection {
            footprint: fp,
            tiles_total: cat.tiles.len(),
            selected,
        },
    ))
}

/// Checkpoint measurements and surveyed coordinates, when the project has both.
struct Checkpoints {
    surveyed: Vec<archive::SurveyedPoint>,
    images: PathBuf,
}

fn evaluate(
    cps: &Option<Checkpoints>,
    block: &Block,
    epoch: &str,
    gsd_m: f64,
) -> Result<Option<CheckpointEvaluation>, String> {
    let Some(c) = cps else { return Ok(None) };
    let meas = archive::read_checkpoint_images(&c.images, epoch).map_err(|e| e.to_string())?;
    if meas.is_empty() {
        return Ok(None);
    }
    match archive::evaluate_checkpoints(block, &meas, &c.surveyed, gsd_m) {
        Ok(e) => Ok(Some(e)),
        // Too few oriented photos see a checkpoint: the report says so with NaN.
        Err(m) => {
            tracing::warn!(epoch, "checkpoints not evaluated: {m}");
            Ok(None)
        }
    }
}

/// The report rows of an oriented epoch.
fn epoch_report(
    result: &EpochResult,
    date: &str,
    eval: &Option<CheckpointEvaluation>,
    surveyed: &[archive::SurveyedPoint],
    icp: Vec<IcpIteration>,
) -> EpochReport {
    let block = &result.block;
    let origin = block.origin;
    // Mean residual vector and matching counts per photo.
    let mut res: BTreeMap<PhotoId, ([f64; 2], usize)> = BTreeMap::new();
    if let Some(a) = &result.adjustment {
        for r in &a.residuals {
            if let (ObservationRef::Image { photo, .. }, [dx, dy, ..]) =
                (&r.observation, r.residual.as_slice())
            {
                let e = res.entry(*photo).or_insert(([0.0; 2], 0));
                e.0[0] += dx;
                e.0[1] += dy;
                e.1 += 1;
            }
        }
    }
    let by_name: BTreeMap<&str, &archive::PhotoReport> =
        result.photos.iter().map(|p| (p.name.as_str(), p)).collect();
    let photos = block
        .photos
        .values()
        .map(|p| {
            let rep = by_name.get(p.name.as_str());
            let (sum, n) = res.get(&p.id).copied().unwrap_or(([0.0; 2], 0));
            let n = n.max(1) as f64;
            PhotoSummary {
                name: p.name.clone(),
                x: p.pose.center.x + origin[0],
                y: p.pose.center.y + origin[1],
                oriented: p.oriented,
                mean_residual_px: [sum[0] / n, sum[1] / n],
                rmse_px: rep.map_or(f64::NAN, |r| r.sigma_px),
                patches_predicted: rep.map_or(0, |r| r.predicted),
                patches_matched: rep.map_or(0, |r| r.control_matches),
            }
        })
        .collect();
    let checkpoints = eval
        .as_ref()
        .map(|e| {
            e.points
                .iter()
                .filter_map(|p| {
                    let s = surveyed.iter().find(|s| s.id == p.id)?;
                    Some(CheckpointError {
                        id: p.id.clone(),
                        x: s.xyz[0],
                        y: s.xyz[1],
                        dx: p.error[0],
                        dy: p.error[1],
                        dz: p.error[2],
                    })
                })
                .collect()
        })
        .unwrap_or_default();
    let mut rep = EpochReport {
        name: result.epoch.clone(),
        date: date.to_string(),
        gsd_m: result.gsd_m,
        photos_total: result.photos.len(),
        photos_oriented: result.photos.iter().filter(|p| p.oriented).count(),
        check_rmse_plan_m: f64::NAN,
        check_rmse_height_m: f64::NAN,
        check_max_m: f64::NAN,
        sigma0: result.adjustment.as_ref().map_or(f64::NAN, |a| a.sigma0),
        rmse_px: result.adjustment.as_ref().map_or(f64::NAN, |a| a.rmse_px),
        time_s: result.time_s,
        checkpoints,
        photos,
        icp,
    };
    rep.set_check_statistics();
    rep
}

/// Files of an epoch stage: the oriented block, its images, the per-photo results and
/// the report rows.
fn save_epoch(
    dir: &Path,
    result: &EpochResult,
    report: &EpochReport,
    eval: &Option<CheckpointEvaluation>,
) -> Result<(), String> {
    write_json(&dir.join("block.json"), &result.block)?;
    write_json(&dir.join("images.json"), &result.images)?;
    write_json(&dir.join("result.json"), result)?;
    write_json(&dir.join("epoch.json"), report)?;
    if let Some(e) = eval {
        write_json(&dir.join("checkpoints.json"), e)?;
    }
    Ok(())
}

fn load_block(dir: &Path) -> Result<(Block, BTreeMap<PhotoId, PathBuf>), String> {
    Ok((
        read_json(&dir.join("block.json"))?,
        read_json(&dir.join("images.json"))?,
    ))
}

/// DCP export settings for an epoch: the same ground spacing of control points in every
/// epoch, and interest taken at roughly the film's scale (four reference pixels).
fn dcp_options(project: &Project, reference_gsd: f64, gsd: f64, epoch: &str) -> DcpExportOptions {
    let ratio = (gsd / reference_gsd).max(1.0);
    let t = &project.thresholds;
    DcpExportOptions {
        cloud: CloudOptions {
            interval_px: (t.control_interval_px / ratio).max(8.0),
            max_coplanarity: 0.02,
            ..CloudOptions::default()
        },
        chip_size: t.chip_size_px,
        source: format!("{epoch} oriented by cloudcontrol ({})", project.name),
        interest_level: (2 - ratio.log2().round() as i64).max(0) as usize,
        ..DcpExportOptions::default()
    }
}

fn archive_options(project: &Project) -> ArchiveOptions {
    let t = &project.thresholds;
    let mut o = ArchiveOptions {
        reject_k: t.reject_k,
        // Four matches leave a resection two redundant observations, too few to expose
        // one mismatch among them once the control points' own σ absorbs part of it.
        min_inliers: 6,
        ..ArchiveOptions::default()
    };
    o.matching.ncc_threshold = t.ncc_min;
    o.matching.agreement_px = t.lsm_agreement_px;
    o
}

/// The reference adjustment tests its gross errors by Baarda's data snooping (its tie
/// points are many and precise; `reject_k` is the archive adjustments' k·σ0).
fn reference_options(_project: &Project) -> ReferenceOptions {
    ReferenceOptions::default()
}

/// Runs a project. `stop_after` ends the run (as a kill would) once that stage finished;
/// tests use it to prove that a rerun completes.
pub fn run_project(
    project: &Project,
    on_event: &mut dyn FnMut(&Event),
    stop_after: Option<&str>,
) -> Result<RunSummary, RunError> {
    let out = &project.output;
    let mut runner = Runner::new(out).map_err(StageError::from)?;
    let epochs: Vec<&Epoch> = std::iter::once(&project.reference)
        .chain(project.archive.iter())
        .collect();
    let o = &project.outputs;
    let want_outputs = o.colmap || o.blocks_exchange || o.orthophoto || o.dem;
    let total = 1 + epochs.len() * (2 + usize::from(want_outputs));
    let mut index = 0;
    let mut products: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();

    // Each stage: announce, run (or skip), announce, maybe stop.
    macro_rules! stage {
        ($name:expr, $inputs:expr, $work:expr) => {{
            let name: String = $name;
            index += 1;
            on_event(&Event::Start {
                stage: name.clone(),
                index,
                total,
            });
            let t = Instant::now();
            let skipped_before = runner.skipped.len();
            let dir = runner.stage(&name, &$inputs, $work)?;
            on_event(&Event::Done {
                stage: name.clone(),
                skipped: runner.skipped.len() > skipped_before,
                seconds: t.elapsed().as_secs_f64(),
            });
            if stop_after == Some(name.as_str()) {
                return Err(RunError::Stopped(name));
            }
            dir
        }};
    }

    // 1. Control sources.
    let mut src_inputs = Inputs::new().param("crs", &project.crs);
    for l in &project.control.lidar {
        src_inputs = src_inputs.file(l);
    }
    if let Some(c) = &project.control.checkpoints {
        src_inputs = src_inputs.file(c);
    }
    // The navigation decides which tiles the block needs.
    for e in std::iter::once(&project.reference).chain(project.archive.iter()) {
        for f in [&e.pos, &e.strips].into_iter().flatten() {
            src_inputs = src_inputs.file(f);
        }
    }
    let sources = stage!("sources".to_string(), src_inputs, |dir: &Path| {
        let e = err("LiDAR sources");
        // Tiles without a CRS are in the project's (a warning in the catalogue says so);
        // tiles with one must match it horizontally (the scan refuses them otherwise).
        let scan = ScanOptions {
            assume_crs: Some(project.crs.clone()),
        };
        let cat = Catalogue::scan(&project.control.lidar, &scan).map_err(|x| e(x.to_string()))?;
        cat.save(&dir.join("catalogue.json"))
            .map_err(|x| e(x.to_string()))?;
        // Only the tiles under the photos are cleaned and used: the rest of a national
        // dataset never enters memory.
        let (footprint, selection) = select_tiles(project, &cat)?;
        write_json(&dir.join("selection.json"), &selection)?;
        let cat = Catalogue {
            tiles: selection
                .selected
                .iter()
                .map(|&i| cat.tiles[i].clone())
                .collect(),
            ..cat
        };
        tracing::info!(
            selected = cat.tiles.len(),
            of = selection.tiles_total,
            ?footprint,
            "LiDAR tiles under the photos"
        );
        let lidar_dir = dir.join("lidar");
        std::fs::create_dir_all(&lidar_dir).map_err(|x| e(x.to_string()))?;
        let clean =
            lidar::clean::clean_tiles(&cat, &lidar_dir, &lidar::clean::CleanOptions::default())
                .map_err(|x| e(x.to_string()))?;
        write_json(&dir.join("clean.json"), &clean)?;
        if let Some(cp) = &project.control.checkpoints {
            let pts = archive::read_checkpoints(cp).map_err(|x| x.to_string())?;
            let list: Vec<(String, [f64; 3])> = pts.iter().map(|p| (p.id.clone(), p.xyz)).collect();
            let cleaned = Catalogue::scan(std::slice::from_ref(&lidar_dir), &scan)
                .map_err(|x| e(x.to_string()))?;
            let mut store = TileStore::new(cleaned, 50_000_000);
            let rep = lidar::eval::evaluate_checkpoints_store(
                &mut store,
                &list,
                Some(&[2]),
                &lidar::CheckpointOptions::default(),
            )
            .map_err(|x| e(format!("evaluation against checkpoints: {x}")))?;
            write_json(&dir.join("lidar_checkpoints.json"), &rep)?;
            std::fs::write(dir.join("lidar_checkpoints.txt"), rep.to_text())
                .map_err(|x| e(x.to_string()))?;
        }
        write_json(
            &dir.join("origin.json"),
            &Origin {
                origin: origin_of(&cat),
            },
        )
    });
    let origin = read_json::<Origin>(&sources.join("origin.json"))
        .map_err(|m| StageError::Failed {
            stage: "sources".into(),
            message: m,
        })?
        .origin;
    let lidar = LidarControl {
        tiles_dir: sources.join("lidar"),
        origin,
        surface: OnceCell::new(),
        planes: OnceCell::new(),
    };
    let checkpoints = match (
        &project.control.checkpoints,
        &project.control.checkpoint_images,
    ) {
        (Some(c), Some(i)) => Some(Checkpoints {
            surveyed: archive::read_checkpoints(c).map_err(|e| StageError::Failed {
                stage: "sources".into(),
                message: e.to_string(),
            })?,
            images: i.clone(),
        }),
        _ => None,
    };
    let cp_inputs = |i: Inputs| match &project.control.checkpoint_images {
        Some(p) => i.file(p),
        None => i,
    };

    // 2–4. Epochs in time order, each from the DCPs of the epochs before it.
    let mut epoch_dirs: Vec<PathBuf> = Vec::new();
    let mut dcp_dirs: Vec<PathBuf> = Vec::new();
    let mut reference_gsd = f64::NAN;
    for (k, e) in epochs.iter().enumerate() {
        let mut inputs = Inputs::new()
            .file(&sources)
            .file(&e.photos)
            .file(&e.camera)
            .param("thresholds", &project.thresholds)
            .param("date", &e.date);
        if let Some(p) = &e.pos {
            inputs = inputs.file(p);
        }
        if let Some(s) = &e.strips {
            inputs = inputs.file(s);
        }
        for d in &dcp_dirs {
            inputs = inputs.file(d);
        }
        let inputs = cp_inputs(inputs);
        let edir = stage!(format!("epoch-{}", e.name), inputs, |dir: &Path| {
            let input = epoch_input(e, &project.crs, origin)?;
            let (result, icp) = if k == 0 {
                let (r, rep) = reference::orient_reference(
                    &input,
                    lidar.planes()?,
                    &lidar.surface()?.ground,
                    &reference_options(project),
                )
                .map_err(|x| x.to_string())?;
                write_json(&dir.join("reference.json"), &rep)?;
                let icp = rep
                    .icp
                    .as_ref()
                    .map(|i| {
                        i.iterations
                            .iter()
                            .map(|it| IcpIteration {
                                iteration: it.iteration,
                                rmse_m: it.rmse_m,
                                inliers: it.correspondences,
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                (r, icp)
            } else {
                // The DCPs of every newer epoch, combined: the previous epoch's are the
                // closest in time and appearance, the reference's the most accurate.
                let pkgs = dcp_dirs
                    .iter()
                    .map(|d| DcpPackage::open(&d.join("package")).map_err(|x| x.to_string()))
                    .collect::<Result<Vec<_>, _>>()?;
                let r = archive::orient_epoch(
                    &input,
                    &pkgs,
                    &lidar.surface()?.ground,
                    &archive_options(project),
                )
                .map_err(|x| x.to_string())?;
                (r, Vec::new())
            };
            let eval = evaluate(&checkpoints, &result.block, &e.name, result.gsd_m)?;
            let surveyed = checkpoints.as_ref().map_or(&[][..], |c| &c.surveyed[..]);
            let rep = epoch_report(&result, &e.date, &eval, surveyed, icp);
            save_epoch(dir, &result, &rep, &eval)
        });
        let rep: EpochReport =
            read_json(&edir.join("epoch.json")).map_err(|m| StageError::Failed {
                stage: format!("epoch-{}", e.name),
                message: m,
            })?;
        if k == 0 {
            reference_gsd = rep.gsd_m;
        }
        epoch_dirs.push(edir.clone());
        // The oldest epoch has no older one to control.
        if k + 1 == epochs.len() {
            break;
        }
        let ddir = stage!(
            format!("dcp-{}", e.name),
            Inputs::new()
                .file(&sources)
                .file(&edir)
                .param("thresholds", &project.thresholds),
            |dir: &Path| {
                let (block, images) = load_block(&edir)?;
                let mut opts = dcp_options(project, reference_gsd, rep.gsd_m, &e.name);
                // The package's stated accuracy: what the checkpoints showed, never
                // better than half a ground pixel.
                let floor = 0.5 * rep.gsd_m;
                opts.accuracy = Accuracy {
                    plan_m: if rep.check_rmse_plan_m.is_finite() {
                        rep.check_rmse_plan_m.max(floor)
                    } else {
                        rep.gsd_m
                    },
                    height_m: if rep.check_rmse_height_m.is_finite() {
                        rep.check_rmse_height_m.max(floor)
                    } else {
                        rep.gsd_m
                    },
                };
                archive::export_dcp(
                    &block,
                    &images,
                    lidar.surface()?,
                    EpochInfo {
                        name: e.name.clone(),
                        date: Some(e.date.clone()),
                    },
                    &dir.join("package"),
                    &opts,
                )
                .map(|_| ())
                .map_err(|x| x.to_string())
            }
        );
        products
            .entry(e.name.clone())
            .or_default()
            .push(ddir.join("package"));
        dcp_dirs.push(ddir);
    }

    // 5. Products per epoch.
    let mut ortho_preview: Option<OrthoPreview> = None;
    if want_outputs {
        for (k, e) in epochs.iter().enumerate() {
            let edir = epoch_dirs[k].clone();
            let odir = stage!(
                format!("outputs-{}", e.name),
                Inputs::new()
                    .file(&sources)
                    .file(&edir)
                    .param("outputs", &project.outputs),
                |dir: &Path| write_products(project, &lidar, &edir, dir)
            );
            let files = products.entry(e.name.clone()).or_default();
            for f in ["colmap", "blocks_exchange.xml", "orthophoto.tif", "dem.tif"] {
                if odir.join(f).exists() {
                    files.push(odir.join(f));
                }
            }
            if k == 0 && odir.join("preview.png").exists() {
                let png = std::fs::read(odir.join("preview.png")).unwrap_or_default();
                let extent: Option<[f64; 4]> = read_json(&odir.join("preview.json")).ok();
                if let Some(extent) = extent {
                    ortho_preview = Some(OrthoPreview { png, extent });
                }
            }
        }
    }

    // Report.
    let mut rinputs = Inputs::new().param("name", &project.name);
    for d in &epoch_dirs {
        rinputs = rinputs.file(d.join("epoch.json"));
    }
    let preview = ortho_preview.clone();
    let rdir = stage!("report".to_string(), rinputs, |dir: &Path| {
        let mut epochs_rep = Vec::new();
        for d in &epoch_dirs {
            epochs_rep.push(read_json::<EpochReport>(&d.join("epoch.json"))?);
        }
        let rep = report::Report {
            project: project.name.clone(),
            crs: project.crs.clone(),
            epochs: epochs_rep,
            ortho: preview,
        };
        if project.outputs.html_report {
            report::write(&rep, dir).map_err(|x| x.to_string())
        } else {
            write_json(&dir.join("report.json"), &rep)
        }
    });
    let mut report: report::Report =
        read_json(&rdir.join("report.json")).map_err(|m| StageError::Failed {
            stage: "report".into(),
            message: m,
        })?;
    report.ortho = ortho_preview;
    Ok(RunSummary {
        output: out.clone(),
        report,
        ran: runner.ran.clone(),
        skipped: runner.skipped.clone(),
        products,
    })
}

/// COLMAP model, BlocksExchange XML, orthophoto and DEM of one oriented epoch.
fn write_products(
    project: &Project,
    lidar: &LidarControl,
    edir: &Path,
    dir: &Path,
) -> Result<(), String> {
    let (block, images) = load_block(edir)?;
    let o = &project.outputs;
    // Products name photos by their image file, as COLMAP and ContextCapture expect.
    let mut named = block.clone();
    for (id, p) in named.photos.iter_mut() {
        if let Some(f) = images.get(id).and_then(|p| p.file_name()) {
            p.name = f.to_string_lossy().into_owned();
        }
    }
    // A film camera whose scan affine is not a pure scale has no exact COLMAP or
    // BlocksExchange camera: such products are skipped with the reason recorded (the
    // orthophoto and the block JSON hold the epoch in full).
    let mut skipped: BTreeMap<&str, String> = BTreeMap::new();
    // Reasons name files relative to the stage folder (its temporary name is per process).
    let reason =
        |e: &dyn std::fmt::Display| e.to_string().replace(&format!("{}/", dir.display()), "");
    if o.colmap {
        if let Err(e) = formats::colmap::write(
            &dir.join("colmap"),
            &named,
            &formats::colmap::WriteOptions::default(),
        ) {
            let _ = std::fs::remove_dir_all(dir.join("colmap"));
            tracing::warn!("COLMAP model not written: {e}");
            skipped.insert("colmap", reason(&e));
        }
    }
    if o.blocks_exchange {
        let base = images
            .values()
            .next()
            .and_then(|p| p.parent())
            .map(|p| p.display().to_string());
        if let Err(e) = formats::blocks_exchange::write(
            &dir.join("blocks_exchange.xml"),
            &named,
            &formats::blocks_exchange::WriteOptions {
                base_image_path: base,
                block_name: Some(project.name.clone()),
            },
        ) {
            tracing::warn!("BlocksExchange XML not written: {e}");
            skipped.insert("blocks_exchange", reason(&e));
        }
    }
    write_json(&dir.join("skipped.json"), &skipped)?;
    if o.orthophoto || o.dem {
        let crs = Crs::parse(&project.crs).map_err(|e| e.to_string())?;
        // Back to world coordinates: shifting by the negated origin.
        let w = lidar.origin;
        let dem = archive::dem_to_local(&lidar.surface()?.ground, [-w[0], -w[1], -w[2]])?;
        if o.dem {
            formats::raster::write_dem(
                &dir.join("dem.tif"),
                &dem,
                &crs,
                &formats::raster::GeoTiffOptions::default(),
            )
            .map_err(|e| e.to_string())?;
        }
        if o.orthophoto {
            let mut rgb = BTreeMap::new();
            for (id, p) in &images {
                if block.photos.get(id).is_some_and(|p| p.oriented) {
                    rgb.insert(
                        *id,
                        formats::ortho::RgbImage::load(p).map_err(|e| e.to_string())?,
                    );
                }
            }
            let gsd = formats::ortho::default_gsd(&block, &dem).map(|g| g * o.ortho_gsd_factor);
            let rep = formats::ortho::write_orthophoto(
                &dir.join("orthophoto.tif"),
                &block,
                &dem,
                &rgb,
                &crs,
                &formats::ortho::OrthoOptions {
                    gsd,
                    ..Default::default()
                },
            )
            .map_err(|e| e.to_string())?;
            write_json(&dir.join("orthophoto.json"), &rep)?;
            let (png, extent) = preview_png(&dir.join("orthophoto.tif"))?;
            std::fs::write(dir.join("preview.png"), png).map_err(|e| e.to_string())?;
            write_json(&dir.join("preview.json"), &extent)?;
        }
    }
    Ok(())
}

/// A small PNG of an orthophoto for the report's map, and its world extent.
fn preview_png(path: &Path) -> Result<(Vec<u8>, [f64; 4]), String> {
    formats::ortho::preview(path, 800).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::footprint;

    #[test]
    fn footprint_widens_the_centres_by_what_the_camera_sees() {
        // Two centres 1000 m above ground at z = 100: each sees 1.85 × 1000 m around it.
        let fp = footprint(&[[0.0, 0.0, 1100.0], [500.0, 200.0, 1100.0]], 100.0, 1.85).unwrap();
        assert_eq!(fp, [-1850.0, -1850.0, 2350.0, 2050.0]);
        // Non-finite centres are ignored; none at all gives no footprint.
        assert_eq!(footprint(&[[f64::NAN, 0.0, 10.0]], 0.0, 1.0), None);
        assert_eq!(footprint(&[], 0.0, 1.0), None);
    }
}
